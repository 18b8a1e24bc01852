"""Example 2 (double-folded mechanism, closed loop, driven crank, stop with macro-impact).

Checked against the paper's observable values and against an independent
reference model (tests/reference_double_folded.py: Newton-Euler in maximal
coordinates with Lagrange multipliers, numpy/scipy only, no pcmm, no Pinocchio).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import pcmm
import reference_double_folded as ref

SCENE = Path(__file__).resolve().parents[1] / "examples" / "double_folded.toml"
X_STOP = 0.3195


@pytest.fixture(scope="module")
def run(shipped_run):
    return shipped_run(SCENE.name)[1]


@pytest.fixture(scope="module")
def reference_impacts():
    return ref.macro_impact()


def test_first_impact_matches_paper_and_reference(run):
    first = run.events[0]
    assert abs(first["t"] - 3.0039) < 0.05  # the paper's Fig. 12/13 instant
    r = ref.simulate_config1(t_end=3.1)
    assert first["t"] == pytest.approx(r["t_impact"], abs=1e-9)
    assert -first["normal_velocity"]["before"] == pytest.approx(r["v_impact"], rel=1e-8)
    v = run.series("v", "E")
    t = run.t
    # both peaks are maxima over each run's own step grid (max step 5 ms in the reference)
    assert np.nanmax(v[t < first["t"]]) == pytest.approx(r["peak_speed"], rel=1e-4)
    assert 0.05 <= r["peak_speed"] <= 0.06  # the paper's observable peak speed
    assert run.series("q", "E")[0] == pytest.approx(r["x_slider"][0], abs=1e-9)


def test_macro_impact_then_merge(run, reference_impacts):
    impacts = [e for e in run.events if e["impact"] and not e["merge"]]
    assert len(impacts) >= 3
    intervals = np.diff([e["t"] for e in impacts])
    assert np.all(np.diff(intervals[:10]) < 0)  # shrinking intervals
    merge = run.events[-1]
    assert merge["merge"] and merge["from"] == "config1" and merge["to"] == "config2"
    assert merge["kind"] == "stable" and merge["normal_velocity"]["after"] == pytest.approx(0, abs=1e-12)
    assert run.segments[-1].configuration == "config2"
    # after the merge the slider stays at the stop until t = 7 s
    last = run.segments[-1]
    xy = last.xy[:, last.links.index("slider")]
    assert np.allclose(xy[:, 0], X_STOP, atol=1e-12) and last.t[-1] == pytest.approx(7.0)
    # the first impacts against the reference's event-by-event macro-impact (same e = 0.8)
    for ev, (t_ref, P_ref, v_before, v_after) in zip(impacts[:6], reference_impacts[:6]):
        assert ev["t"] == pytest.approx(t_ref, abs=1e-8)
        assert ev["impulse"]["normal"] == pytest.approx(-P_ref, rel=1e-6)  # reference: P on the slider along +x
        assert -ev["normal_velocity"]["before"] == pytest.approx(v_before, rel=1e-6)


def test_whole_macro_impact_against_the_reference_and_its_energy_audit(run):
    """Every impact of the macro-impact down to 3e-6 m/s against the independent reference
    (maximal coordinates, its own event loop): no chatter in either, the same geometric decay.
    The reference stops at a rebound below 3e-6 m/s; its flights then last about 2 us, near its
    1e-6 s event-free restart interval."""
    reference = ref.macro_impact(v_lock=3e-6, dt_lock=1e-9, max_impacts=400)
    impacts = [e for e in run.events if e["impact"]]
    assert len(reference) == 42 and len(impacts) == 47  # pcmm goes on to its 1e-6 m/s accumulation speed
    for ev, (t_ref, P_ref, v_before, v_after) in zip(impacts, reference):
        assert ev["t"] == pytest.approx(t_ref, abs=2e-9)
        assert -ev["normal_velocity"]["before"] == pytest.approx(v_before, rel=5e-5)
    rebound = np.array([e["normal_velocity"]["after"] for e in impacts[:-1]])
    assert rebound[-1] <= 0.8 ** 46 * -impacts[0]["normal_velocity"]["before"] * 1.001
    (macro,) = run.stats["macro_impacts"]
    assert macro["impacts"] == 47 and macro["merged"] and macro["flights"] == 46
    assert macro["flight_energy_relative_max"] < 1e-8  # work of spring, damper and motor vs KE + PE
    assert macro["guard_residual_max"] < 1e-15  # m: every impact where the slider meets the stop


def test_every_impact_obeys_its_law_and_dissipates(run):
    for ev in run.events:
        if not ev["impact"]:
            continue
        vb, va = ev["normal_velocity"]["before"], ev["normal_velocity"]["after"]
        e = 0.0 if ev["merge"] else ev["restitution"]
        assert abs(va + e * vb) < 1e-9
        assert ev["kind"] == "stable"
        # The crank keeps its prescribed speed: the motor's impulsive moment does work mu * omega,
        # so KE may rise by that much; the energy the impact dissipates is -P (vn+ + vn-) / 2 >= 0.
        P = ev["impulse"]["normal"]
        assert ev["energy_dissipated"] == pytest.approx(-0.5 * P * (va + vb), abs=1e-15)
        assert ev["energy_dissipated"] >= -1e-15
        assert ev["drive_work"] == pytest.approx(ev["constraint_impulses"]["A.drive"][2] * math.pi / 5, rel=1e-12)


def test_motor_impulse_is_the_joint_impulse_at_A(run):
    ev = run.events[0]
    fx, fy, mu = ev["constraint_impulses"]["A.drive"]  # [fx, fy, mz] like the joint impulses
    assert mu != 0 and fx == fy == 0.0
    assert ev["joint_impulses"]["A"][2] == pytest.approx(mu, rel=1e-9)  # RNEA route
    # the cut prismatic joint E carries the guide's normal impulse and no impulse along the guide
    fx, fy, mz = ev["cut_impulses"]["E"]
    assert fx == pytest.approx(0.0, abs=1e-14)


def test_closure_and_driving_moment_in_configuration_2(run):
    assert run.stats["constraint_drift_max"] < 1e-8
    seg = run.segments[-1]
    M = seg.constraint_forces[:, seg.constraint_labels.index("A.drive")]
    for t in (3.5, 4.5, 5.5, 6.5):
        i = int(np.argmin(np.abs(seg.t - t)))
        M_ref, _, _ = ref.config2_inverse_dynamics(seg.t[i])
        assert M[i] == pytest.approx(M_ref, abs=1e-7)


def test_without_impact_locks_at_first_arrival():
    run0 = pcmm.simulate(pcmm.load_scene(SCENE), pcmm.RunOptions(impact=False, t_end=4.0))
    assert len(run0.events) == 1
    ev = run0.events[0]
    assert ev["impact"] is False and ev["merge"] and ev["impulse"]["normal"] == 0.0
    assert ev["v_after"]["E"] == 0.0 and ev["dropped_velocities"]["E"] > 0
    assert run0.segments[-1].configuration == "config2"


def test_release_when_the_holding_force_turns_tensile(tmp_path):
    """With unmerge = true the stop-merge is held only by compression: it is undone when the
    stop's normal force, computed independently by the reference's configuration-2 inverse
    dynamics, changes sign."""
    from scipy.optimize import brentq
    text = SCENE.read_text().replace("unmerge = false", "unmerge = true").replace("../urdf/", f"{SCENE.parents[1] / 'urdf'}/")
    (tmp_path / "df.toml").write_text(text)
    run = pcmm.simulate(pcmm.load_scene(tmp_path / "df.toml"), pcmm.RunOptions(t_end=6.5))
    release = [e for e in run.events if e["transition"] == "release"]
    assert len(release) == 1 and release[0]["from"] == "config2" and release[0]["to"] == "config1"
    # the reference's stop force on the slider (x component) is negative (pushing -x, compressive)
    # while the slider is held; the release is where it crosses zero
    fx = lambda t: ref.config2_inverse_dynamics(t)[1]  # noqa: E731
    assert fx(4.0) < 0 < fx(6.5)
    t_zero = brentq(fx, 4.0, 6.5, xtol=1e-12)
    assert release[0]["t"] == pytest.approx(t_zero, abs=1e-6)
    assert run.segments[-1].configuration == "config1"
