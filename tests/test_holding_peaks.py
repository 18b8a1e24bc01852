"""``stats.holding``'s extremes are the force's peaks along the run, not its largest recorded sample
(task h-holdpeak; pcmm.results.peaks).

DOP853 steps up to 0.05 s apart over a walker's stance, so between two steps the stance force peaks
higher than any recorded sample: on the first stance (to 0.7 s) the compass gait's normal force
peaks at 202.9707 N where the samples reach 202.940 N, the rimless wheel's at 8.39584 N where they
reach 8.39001 N.  Each extreme is checked against the samples (beyond them), a resampling of the run
at 1e-3 s over the extreme's segment and one at 1e-5 s within 0.02 s of its time (no value of them beyond the extreme), one at 1e-8 s
around the extreme's time (its extreme to 1e-10 relative), and the walker's own Lagrangian KKT solve (tests/test_audit3_pins.py's) at the dense
output's state at that time; a lock's holding force likewise (the double-folded mechanism's slider
stop, compiled and PCMM_COMPILED=0; the five-bar's J3.hold against its KKT multiplier is in
tests/test_run_loop.py); the extremes of a run to 0.7 s are those of the same run to 1.5 s where they
lie in the common part; a run streamed to a store (``--store``) has the same extremes.
"""
from __future__ import annotations

import numpy as np
import pytest

import pcmm
from builders import EXAMPLES
from test_audit3_pins import gait_by_hand, wheel_by_hand


def fine_and_local(traj, label, ext, key):
    """(the extreme of ``label`` over a 1e-3 s resampling of the segment of ``ext``'s time ``t_<key>``
    and a 1e-5 s one within 0.02 s of it, over a 1e-8 s one within 1e-6 s of it; the record at that
    time)."""
    pick = np.nanmax if key == "max" else np.nanmin
    t = ext[f"t_{key}"]
    (seg,) = [s for s in traj.segments if s.t[0] <= t <= s.t[-1] and label in s.constraint_labels][:1]
    k = seg.constraint_labels.index(label)
    coarse = pick(seg.resampled(np.arange(seg.t[0], seg.t[-1], 1e-3)).constraint_forces[:, k])

    def around(half, n):
        return pick(seg.resampled(np.unique(np.clip(t + np.linspace(-half, half, n), seg.t[0], seg.t[-1])))
                    .constraint_forces[:, k])
    return max(coarse, around(0.02, 4001), key=lambda x: x if key == "max" else -x), around(1e-6, 201), \
        seg.resampled(np.array([t]))


@pytest.mark.parametrize("name, foot, hand, peak, sampled", [
    ("compass_gait", "foot_a", gait_by_hand, 202.9707, 202.940), ("rimless_wheel", "foot0", wheel_by_hand, 8.39584, 8.39001)])
def test_a_walkers_stance_force_peaks_between_the_steps(name, foot, hand, peak, sampled):
    traj = pcmm.simulate(pcmm.load_scene(EXAMPLES / f"{name}.toml"), pcmm.RunOptions(t_end=0.7))
    held = traj.stats["holding"][foot]["normal"]
    fy = traj.series("constraint_forces", f"{foot}.fy")  # the normal is the slope frame's y
    assert np.nanmax(fy) == pytest.approx(sampled, abs=1e-3)
    assert held["max"] == pytest.approx(peak, abs=1e-4) and held["max"] > np.nanmax(fy) + 5e-3
    fine, local, at = fine_and_local(traj, f"{foot}.fy", held, "max")
    tol = 1e-10 * (1 + peak)  # pcmm.results.peaks.F_TOL
    assert held["max"] >= fine - tol and held["max"] == pytest.approx(local, abs=tol)
    assert held["max"] - fine < 1e-6  # the 1e-5 s grid misses the peak by (5e-6 s)^2 |F''| / 2 at most
    _, _, F, pinned = hand(at.configuration, dict(zip(at.coordinates, at.q[0])), dict(zip(at.coordinates, at.v[0])))
    assert pinned == foot and held["max"] == pytest.approx(F[1], abs=1e-10 * peak)


@pytest.mark.parametrize("compiled", ["1", "0"])
def test_a_locks_holding_force_peaks_between_the_steps(compiled, monkeypatch):
    """The double-folded mechanism's slider held at its stop (unmerge = false): the holding force's
    maximum 8.280564 N between the steps where the samples reach 8.280395 N, on either route."""
    monkeypatch.setenv("PCMM_COMPILED", compiled)
    traj = pcmm.simulate(pcmm.load_scene(EXAMPLES / "double_folded.toml"))
    assert set(traj.stats["evaluations"].values()) == ({"compiled"} if compiled == "1" else
                                                       {"python: PCMM_COMPILED=0 in the environment"})
    label = "slider stop E.hold"
    held = traj.stats["holding"][label]
    hold = traj.series("constraint_forces", label)
    assert np.nanmax(hold) == pytest.approx(8.280395, abs=1e-6)
    assert held["max"] == pytest.approx(8.280564, abs=1e-6) and held["min"] <= np.nanmin(hold)
    for key in ("max", "min"):
        fine, local, _ = fine_and_local(traj, label, held, key)
        sign = 1 if key == "max" else -1
        tol = 1e-10 * (1 + abs(held[key]))  # pcmm.results.peaks.F_TOL
        assert sign * held[key] >= sign * fine - tol and held[key] == pytest.approx(local, abs=tol)


def test_the_extremes_in_the_common_part_do_not_depend_on_t_end():
    """The rimless wheel pivots on spoke 0 until 0.726 s (then not again before 6 s): its stance
    force's extremes there are the same for runs to 0.7 s and to 1.5 s, the peak's to the bit."""
    short = pcmm.simulate(pcmm.load_scene(EXAMPLES / "rimless_wheel.toml"), pcmm.RunOptions(t_end=0.7))
    long = pcmm.simulate(pcmm.load_scene(EXAMPLES / "rimless_wheel.toml"), pcmm.RunOptions(t_end=1.5))
    a, b = short.stats["holding"]["foot0"]["normal"], long.stats["holding"]["foot0"]["normal"]
    assert b["t_max"] < 0.7 and (a["max"], a["t_max"]) == (b["max"], b["t_max"])


def test_a_stored_run_has_the_same_extremes(tmp_path, monkeypatch):
    """``--store``: the extremes are refined on each chunk's dense output as the chunk is written (its
    records read back from the files have none); the same numbers as the run kept in memory."""
    from pcmm.results import store
    from pcmm.results.store import StoreWriter, read_store
    monkeypatch.setattr(store, "RECENT", 1)  # (a chunk's last RECENT segments are kept in memory)
    scene = pcmm.load_scene(EXAMPLES / "rimless_wheel.toml")
    kept = pcmm.simulate(scene, pcmm.RunOptions(t_end=3.0)).stats["holding"]
    stored = pcmm.simulate(scene, pcmm.RunOptions(t_end=3.0), store=StoreWriter(tmp_path / "s", chunk_records=1))
    assert stored.stats["holding"] == kept
    assert read_store(tmp_path / "s")["stats"]["holding"] == kept  # (its end.json: JSON keeps floats exactly)


def _two_peaks(t):
    """A holding force with two peaks: 10 N at 1 s and 10.02 N at 2 s, each 0.05 s wide."""
    t = np.asarray(t, float)
    return 10.0 * np.exp(-((t - 1.0) / 0.05) ** 2) + 10.02 * np.exp(-((t - 2.0) / 0.05) ** 2)


def _synthetic_run(times):
    """A trajectory of one segment whose only series is the holding force ``_two_peaks`` of lock "x",
    recorded at ``times`` and read on its 'dense output' (the function itself) anywhere."""
    from pcmm.results.segment import SegmentRecord
    from pcmm.results.trajectory import RunStats, Trajectory, holding_extremes

    def series(ts):
        n = len(ts)
        return dict(q=np.zeros((n, 0)), v=np.zeros((n, 0)), theta=np.zeros((n, 0)), omega=np.zeros((n, 0)),
                    xy=np.zeros((n, 0, 2)), kinetic=np.zeros(n), potential=np.zeros(n), forces=np.zeros((n, 0)),
                    constraint_forces=_two_peaks(ts)[:, None])
    times = np.asarray(times, float)
    seg = SegmentRecord.deferred(lambda: series(times), times, resample=series, configuration="held",
                                 coordinates=[], links=[], force_names=[], constraint_labels=["x.hold"])
    traj = Trajectory(scene="synthetic", scene_name="synthetic", impact=True, segments=[seg])
    traj.stats = RunStats({}, holding=lambda: holding_extremes(traj))
    return traj


def test_a_second_peak_the_samples_under_read_more_is_found(monkeypatch):
    """Samples on the first peak's top (10 N at 1 s) but 0.01 s either side of the second's (9.627 N):
    the true maximum is the second peak's 10.02 N, found because every local maximum sample within
    5 % of the range of the largest is refined (pcmm.results.peaks.MARGIN); with the margin 0 only
    the first would be, and the maximum would read 10 N."""
    from pcmm.results import peaks
    times = np.concatenate((np.linspace(0.0, 1.0, 11), [1.1, 1.5, 1.9, 1.99, 2.01, 2.1, 2.5, 3.0]))
    samples = _two_peaks(times)
    assert samples.max() == pytest.approx(10.0, abs=1e-12) and samples[times == 1.99] == pytest.approx(9.6271, abs=1e-4)
    held = _synthetic_run(times).stats["holding"]["x.hold"]
    assert held["max"] == pytest.approx(_two_peaks(2.0), abs=1e-9) and held["t_max"] == pytest.approx(2.0, abs=1e-4)
    assert held["min"] == samples.min()  # the minimum is a sample's (the ends, far from both peaks)
    monkeypatch.setattr(peaks, "MARGIN", 0.0)
    assert _synthetic_run(times).stats["holding"]["x.hold"]["max"] == pytest.approx(10.0, abs=1e-9)
