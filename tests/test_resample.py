"""Output at a chosen rate (``pcmm run --dt``, ``Trajectory.resampled``): the CSV and figures are
sampled on the integrator's dense output, not drawn as polygons between its (long) steps.

Checked against a closed form between steps: a body on a torsion spring, no gravity,
q(t) = q0 cos(w t), w = sqrt(k / I).  At rtol 1e-10 the integrator's steps are long (a straight
line between them is off by ~1e-3 rad), while the resampled values follow the cosine to the
integration error.  A closed loop with a drive (Example 2: integrated loop, impacts, and the
fully driven stay after the merge) is checked against the same run with steps 20x shorter.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

import builders
import pcmm
from pcmm.cli import main as cli_main
from pcmm.model.mechanism import Mechanism

K, I_C, Q0 = 1.0, 1e-2, 0.1  # w = 10 rad/s
W = math.sqrt(K / I_C)
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def closed_form(t):
    return Q0 * np.cos(W * t), -Q0 * W * np.sin(W * t)


@pytest.mark.parametrize("method, interpolation", [("DOP853", 1e-10), ("DOP853F", 1e-10), ("auto", 1e-10),
                                                   ("RK4", 1e-6)])
def test_resampled_run_follows_the_closed_form_between_steps(tmp_path, method, interpolation):
    """Between steps the resampled values are off the cosine by no more than the integration error
    at the steps themselves plus the dense output's own error (DOP853: 7th order; RK4's cubic
    Hermite over h = 0.02 s: (w h)^4 q0 / 384 = 4e-7 rad)."""
    scene = pcmm.load_scene(builders.spring_pendulum(tmp_path, K, I_C, q0=Q0, t_end=2.0))
    opts = pcmm.RunOptions(method=method, **({"step": 0.02} if method == "RK4" else {}))
    traj = pcmm.simulate(scene, opts)
    at_steps = np.max(np.abs(traj.series("q", "J1") - closed_form(traj.t)[0]))
    dt = 1e-3
    r = traj.resampled(dt)
    # the requested grid, exactly k * dt, ends included
    assert r.t[0] == 0.0 and r.t[-1] == 2.0 and len(r.t) == 2001
    assert np.array_equal(r.t, np.arange(2001) * dt)
    q_ref, v_ref = closed_form(r.t)
    q, v = r.series("q", "J1"), r.series("v", "J1")
    assert np.max(np.abs(q - q_ref)) < at_steps + interpolation
    assert np.max(np.abs(v - v_ref)) < W * (at_steps + interpolation) * 2
    # the steps themselves are long: a polygon through them is far off the cosine
    polygon = np.interp(r.t, traj.t, traj.series("q", "J1"))
    assert np.max(np.abs(polygon - q_ref)) > 1e-4
    # the derived series are computed at the resampled states
    assert np.allclose(r.series("kinetic"), 0.5 * I_C * v ** 2, rtol=1e-12, atol=1e-15)
    assert np.allclose(r.series("potential"), 0.5 * K * q ** 2, rtol=1e-12, atol=1e-15)
    assert np.array_equal(r.series("theta", "body"), q)


def test_cli_dt_writes_the_csv_on_the_grid(tmp_path):
    path = builders.spring_pendulum(tmp_path, K, I_C, q0=Q0, t_end=1.0)
    out = tmp_path / "run.csv"
    assert cli_main(["run", str(path), "--dt", "0.01", "--csv", str(out), "--quiet"]) == 0
    with open(out) as f:
        rows = list(csv.reader(f))
    header, data = rows[0], rows[1:]
    t = np.array([float(r[0]) for r in data])
    q = np.array([float(r[header.index("q_J1 [rad]")]) for r in data])
    assert len(t) == 101 and np.allclose(t, np.arange(101) * 0.01, rtol=0, atol=1e-15)
    assert np.max(np.abs(q - closed_form(t)[0])) < 1e-8


def test_cli_dt_must_be_positive(tmp_path, capsys):
    path = builders.spring_pendulum(tmp_path, K, I_C, q0=Q0, t_end=1.0)
    with pytest.raises(SystemExit) as exc:
        cli_main(["run", str(path), "--dt", "0", "--quiet"])
    assert exc.value.code == 2
    assert "dt" in capsys.readouterr().err


def test_loaded_trajectory_cannot_be_resampled(tmp_path):
    scene = pcmm.load_scene(builders.spring_pendulum(tmp_path, K, I_C, q0=Q0, t_end=0.1))
    pcmm.simulate(scene).save(tmp_path / "r.npz")
    with pytest.raises(pcmm.UsageError, match="pcmm run --dt"):
        pcmm.Trajectory.load(tmp_path / "r.npz").resampled(0.01)


@pytest.mark.slow  # a closed loop run twice, once at a fine tolerance
def test_closed_loop_with_impacts_and_a_driven_stay_resamples_like_a_finer_run():
    """Example 2 to 3.3 s: the loop integrated in partitioned coordinates, 36 impacts, the merge,
    then the fully driven configuration (a known function of time).  Resampled at 5 ms from the
    default run and from a run whose steps are at most 5 ms, the slider and the crank's moment
    agree; every event instant is kept as a sample."""
    scene = pcmm.load_scene(EXAMPLES / "double_folded.toml")
    coarse = pcmm.simulate(scene, pcmm.RunOptions(t_end=3.3))
    fine = pcmm.simulate(scene, pcmm.RunOptions(t_end=3.3, max_step=5e-3))
    a, b = coarse.resampled(5e-3), fine.resampled(5e-3)
    assert np.array_equal(a.t[:600], b.t[:600])  # before the first impact the grids coincide
    for t_ev in (e["t"] for e in coarse.events):
        assert np.any(a.t == t_ev)
    n = np.searchsorted(a.t, 3.0)
    assert np.max(np.abs(a.series("q", "E")[:n] - b.series("q", "E")[:n])) < 1e-9
    m_a = a.series("constraint_forces", "A.drive")[:n]
    m_b = b.series("constraint_forces", "A.drive")[:n]
    assert np.max(np.abs(m_a - m_b)) < 1e-7
    # after the merge (fully driven): the resampled grid is exact evaluation, equal to the fine run's
    ta, tb = a.t[-25:], b.t[-25:]  # 3.18 ... 3.3 s, after the merge at 3.163 s
    assert np.array_equal(ta, tb) and a.segments[-1].configuration == "config2"
    assert np.max(np.abs(a.series("q", "B")[-25:] - b.series("q", "B")[-25:])) < 1e-12


def test_deferred_series_are_the_same_from_another_thread_and_after_pickling(tmp_path):
    """A run records the integrator's states only; its series are computed when first read.
    Read from another thread (while this thread runs the same scene again, on the same cached
    Pinocchio model) or after a pickle round trip (a process pool), they are the same numbers."""
    import pickle
    import threading
    scene = pcmm.load_scene(EXAMPLES / "three_bar.toml")
    first, second = pcmm.simulate(scene), pcmm.simulate(scene)
    expected = second.series("theta", "link3").copy()
    got, started, finished, paused_at = {}, threading.Event(), threading.Event(), []

    def read():
        started.wait()
        try:
            got.update(theta=first.series("theta", "link3"), omega=first.series("omega", "link2"))
        finally:
            finished.set()

    def progress(t):  # the run waits for the reads at its first report: they happen mid-run for certain
        if not started.is_set():
            paused_at.append(t)
            started.set()
            finished.wait(timeout=120)
    reader = threading.Thread(target=read)
    reader.start()
    during = pcmm.simulate(scene, progress=progress)
    started.set()  # (a run that never reported: the reads after it, and paused_at says so)
    reader.join()
    assert paused_at and paused_at[0] < during.t[-1] and np.array_equal(during.series("theta", "link3"), expected)
    assert np.array_equal(got["theta"], expected)
    third = pickle.loads(pickle.dumps(pcmm.simulate(scene)))
    assert np.array_equal(third.series("theta", "link3"), expected)
    assert np.array_equal(third.series("omega", "link2"), got["omega"])


def test_cli_dt_draws_the_figures_from_the_resampled_run(tmp_path, monkeypatch):
    """``--plots`` with ``--dt``: the run reaches the figures resampled on the grid (the curves
    are drawn through the dense output)."""
    import pcmm.viz.plots as plots
    seen = []
    real = plots.write_figures

    def spy(traj, out, compare=None, **kw):
        seen.append((traj.t.copy(), None if compare is None else compare.t.copy()))
        return real(traj, out, compare=compare, **kw)
    monkeypatch.setattr(plots, "write_figures", spy)
    path = builders.spring_pendulum(tmp_path, K, I_C, q0=Q0, t_end=0.5)
    out = tmp_path / "figs"
    out.mkdir()
    assert cli_main(["run", str(path), "--dt", "0.005", "--plots", str(out), "--quiet"]) == 0
    (t, t_other), = seen
    # a scene without transitions has no run without impact to compare (it would be the same run)
    assert np.array_equal(t, np.arange(101) * 0.005) and t_other is None
    assert any(out.glob("*.png"))


def test_a_resampled_run_keeps_what_its_views_need(tmp_path):
    """``--dt`` replaces the run by its resampling: that one is saved, replayed and plotted, so it
    keeps the recorded views (a file without them needs its scene and URDFs where they were)."""
    traj = pcmm.simulate(pcmm.load_scene(builders.spring_pendulum(tmp_path, K, I_C, q0=Q0, t_end=0.2)))
    fine = traj.resampled(0.01)
    assert fine.views == traj.views and fine.views["configurations"]["c1"]["joints"]["J1"]["type"] == "revolute"


def test_a_loop_resampled_after_a_release_stays_on_its_assembly(tmp_path):
    """A four-bar whose coupler latches onto the rocker at J3 = -1.5 and is let go at t = 0.8 s
    (:func:`builders.four_bar_latch`).  Resampling the free stay after the release at 0.01 s
    gave the mirrored assembly with angles 20-50 rad off (the dense steps had left the loop's warm
    starts at the stay's end, and its first solve started from there): every resampled state now
    equals the recorded one where their times coincide, and closes the loop."""
    scene = pcmm.load_scene(builders.four_bar_latch(tmp_path))
    traj = pcmm.simulate(scene)
    assert [e["name"] for e in traj.events][:2] == ["latch", "let go"]
    after = next(k for k, s in enumerate(traj.segments) if s.t[0] == pytest.approx(0.8) and s.configuration == "open")
    seg = traj.segments[after]
    fine = seg.resampled(np.concatenate(([seg.t[0]], np.arange(0.81, seg.t[-1], 0.01), [seg.t[-1]])))
    for t_shared, q_rec in ((seg.t[0], seg.q[0]), (seg.t[-1], seg.q[-1])):
        i = int(np.flatnonzero(fine.t == t_shared)[0])
        np.testing.assert_allclose(fine.q[i], q_rec, rtol=0, atol=1e-9)
    cfg = Mechanism(scene)["open"]
    assert max(cfg.coords.residual(0.0, q) for q in fine.q) < 1e-10  # every state closes the loop
    # and the whole run's resampling agrees with its steps at every segment's ends
    whole = traj.resampled(0.01)
    for s, f in zip(traj.segments, whole.segments):
        np.testing.assert_allclose(f.q[[0, -1]], s.q[[0, -1]], rtol=0, atol=1e-9)
