"""Issue 24, item 5: examples/compass_gait.toml, the passive compass gait as one scene.

The scene starts on the period-one gait of the independent reference
``tests/reference_compass_gait.py`` (Drake's parameters; its fixed point of the step map, which
reproduces the gait Goswami et al. 1998 publish); each heel strike is a ``pin`` transition.
Checked from the event record and the recorded postures alone:

* each heel strike conserves the angular momentum of the whole walker about the new stance foot,
  and of the trailing leg about the hip (to 1e-12): the only impulses are at the new foot and,
  on the trailing leg, at the hip; the old foot leaves without impulse at 0.3936 m/s;
* the strike against the reference's Q+/Q- map, the step period 0.7344606 s;
* the gait is periodic: every post-strike state equals the first one;
* the foot scuffing at mid-stance (the swing foot below the slope, behind the stance leg) fires no
  strike: one event per step;
* the strike takes the step's descent, (2 m + m_h) g d sin gamma, from the kinetic energy.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import pcmm
import reference_compass_gait as cg
from builders import rot
from pcmm.events.momentum import balance

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "compass_gait.toml"
C = cg.DRAKE
MH, M, B = 10.0, 5.0, 0.5


@pytest.fixture(scope="module")
def run():
    return pcmm.simulate(pcmm.load_scene(EXAMPLE))


def posture_at(traj, ev):
    seg, = [s for s in traj.segments if s.configuration == ev["from"] and s.t[-1] == ev["t"]]
    return np.asarray(seg.q[-1])


def masses(q, v):
    """[(mass, position, velocity)] of the hip, leg a's and leg b's point masses, world axes."""
    hip, psi_a, psi_b = q[:2], q[2], q[2] + q[3]
    v_hip = rot(q[2]) @ np.asarray(v[:2])
    w_a, w_b = v[2], v[2] + v[3]
    out = [(MH, hip, v_hip)]
    for psi, w in ((psi_a, w_a), (psi_b, w_b)):
        r = rot(psi) @ np.array([0.0, -B])
        out.append((M, hip + r, v_hip + w * np.array([-r[1], r[0]])))
    return out


def H(points, about):
    return sum(m * ((p - about)[0] * u[1] - (p - about)[1] * u[0]) for m, p, u in points)


def state(ev, key):
    v = ev[key]
    return np.array([*v["base"], v["hip"]])


def test_twelve_steps_one_event_each(run):
    strikes = run.events
    assert len(strikes) == 12 and all(e["transition"] == "pin" for e in strikes)
    _, _, T, _ = C.fixed_point()
    for k, ev in enumerate(strikes):
        assert ev["t"] == pytest.approx((k + 1) * T, abs=1e-8)  # no strike at the mid-stance dip
        assert ev["to"] == ("stance_b" if k % 2 == 0 else "stance_a")


def test_the_mid_stance_dip_is_there_and_ignored(run):
    """The swing foot does pass below the slope in the first step (with the swing leg behind, hip
    joint < 0), and no event fired there."""
    seg = run.segments[0]
    low = []
    for q in seg.q:
        foot_b = q[:2] + rot(q[2] + q[3]) @ np.array([0.0, -1.0])
        if foot_b[1] < -1e-6:
            low.append(q[3])
    assert low and max(low) < 0


def test_a_run_ending_mid_step_reports_the_guard_where_it_can_fire_not_the_dip():
    """Ended at t = 2 s (mid-step), the run reports 'heel strike b' where it can fire.  The plain gap
    crossed 0 upwards as the swing foot came out of its mid-stance dip, which the guard's `when` (hip
    above 0) ignores; the report used to call that a crossing against the guard's direction and say
    "check `direction`" (a wrong diagnosis).  Inside the region (from the legs passing each other,
    both feet at one point, gap 0) the foot only rose: "moved away", with the gap at the end."""
    from pcmm.model.mechanism import Mechanism
    from pcmm.run.approach import guard_series, in_region
    scene = pcmm.load_scene(EXAMPLE)
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=2.0))
    rec, = [r for r in traj.stats["closest_approach"] if r["transition"] == "heel strike b"]
    tr, = [t for t in scene.transitions if t.name == "heel strike b"]
    seg, = [s for s in traj.segments if s.configuration == "stance_a" and s.t[0] > 1.0]
    cfg = Mechanism(scene)["stance_a"]
    gap, region = guard_series(cfg, tr, seg.q), in_region(cfg, tr, seg.q)
    assert gap.min() < -1e-3 and np.any((gap[:-1] < 0) & (gap[1:] > 0))  # the dip, and its way out
    assert region[-1] and not region[0] and gap[region].min() > -1e-9  # in the region: on or above the slope
    assert rec["crossed_against"] is None and rec["moved_away"]
    assert rec["final"] == pytest.approx(gap[-1], abs=1e-12) and rec["t_final"] == 2.0
    assert "check `direction`" not in pcmm.run.approach.describe([rec])


def test_a_run_ending_before_the_region_says_the_guard_could_not_fire(run):
    """The example ends at 9 s with the swing leg still behind (hip < 0): 'heel strike b' could not fire
    since it last did, and the report says so (it gave the gap, 0.0037 m, as a near miss before)."""
    rec, = [r for r in run.stats["closest_approach"] if r["transition"] == "heel strike b"]
    assert rec["closest"] is None and rec["outside_when"] == "joint hip above 0"
    assert rec["t_final"] == 9.0 and rec["t_from"] == pytest.approx(run.events[-1]["t"])
    assert run.segments[-1].q[-1, 3] < 0  # the hip joint: the swing leg behind
    assert "never entered its `when` region (joint hip above 0)" in pcmm.run.approach.describe([rec])


def test_angular_momenta_conserved_at_every_strike(run):
    for ev in run.events:
        q = posture_at(run, ev)
        before, after = masses(q, state(ev, "v_before")), masses(q, state(ev, "v_after"))
        new = "foot_b" if ev["to"] == "stance_b" else "foot_a"
        foot = np.asarray(ev["anchor"][new])
        assert foot[1] == pytest.approx(0.0, abs=1e-9)
        assert H(after, foot) == pytest.approx(H(before, foot), abs=1e-12)
        trailing = 1 if new == "foot_b" else 2  # the old stance leg's point mass
        hip = q[:2]
        assert H([after[trailing]], hip) == pytest.approx(H([before[trailing]], hip), abs=1e-12)
        (old, rec), = ev["released"].items()
        assert rec["impulse"] == 0.0 and rec["normal_velocity_after"] == pytest.approx(0.3936331159, abs=1e-8)
        dL, dH = balance(ev)
        assert np.max(np.abs(dL)) < 1e-11 and abs(dH) < 1e-11
        # the strike's impulse and the friction it needs (design_24.md: 13.602 N s, 0.2458)
        assert ev["impulse"]["normal"] == pytest.approx(13.602, abs=1e-3)
        assert abs(ev["impulse"]["tangential"]) / ev["impulse"]["normal"] == pytest.approx(0.2458, abs=1e-4)


def test_strike_against_the_reference_map_and_periodicity(run):
    """The first strike, in Drake's convention (theta = gamma - psi; theta_s' = -psi_stance'),
    against the reference's step from the same state; every later post-strike state repeats."""
    _, y0, T, _ = C.fixed_point()
    t, y_minus, y_plus = C.step(y0)
    ev = run.events[0]
    vb, va = state(ev, "v_before"), state(ev, "v_after")
    # before: stance a (psi_a' = base rate), swing b; after: stance b, swing a
    np.testing.assert_allclose([-vb[2], -(vb[2] + vb[3])], y_minus[2:], atol=1e-9)
    np.testing.assert_allclose([-(va[2] + va[3]), -va[2]], y_plus[2:], atol=1e-9)
    first = [state(e, "v_after") for e in run.events[1::2]]
    for v in first:
        np.testing.assert_allclose(v, first[0], atol=1e-9)
    # and the gait's post-strike rates are the initial ones: the scene starts on the fixed point
    np.testing.assert_allclose(state(run.events[1], "v_after"), [*rot(0.0) @ [1.0928668105806219, 0.0],
                                                                 -1.0928668105806216, 0.7167322170510311], atol=1e-9)


def test_energy_lost_at_a_strike_is_the_steps_descent(run):
    _, y0, _, _ = C.fixed_point()
    step = 2 * C.l * math.sin((y0[1] - y0[0]) / 2)  # the distance between the feet at the strike
    for ev in run.events:
        lost = ev["kinetic_energy_before"] - ev["kinetic_energy_after"]
        assert ev["energy_dissipated"] >= 0
        assert lost == pytest.approx((2 * M + MH) * C.g * step * math.sin(C.gamma), rel=1e-8)


def pcmm_step_map(scene, x):
    """pcmm's step map on the post-strike section x = (theta_s, theta_s', theta_w') (Drake's
    convention, leg a in stance): one run from the section to its first heel strike, the state
    just after it read back from the event record and the posture."""
    s = cg.slope_frame_state(C, C.section(x))
    th = float(s["psi_stance"])
    vb = rot(th).T @ s["hip_velocity"]
    traj = pcmm.simulate(scene.with_values({
        "initial.q.base": [float(s["hip"][0]), float(s["hip"][1]), th], "initial.q.hip": float(s["hip_joint"]),
        "initial.v.base": [float(vb[0]), float(vb[1]), float(s["psi_stance_rate"])],
        "initial.v.hip": float(s["hip_joint_rate"]), "scene.t_end": 1.0}))
    ev = traj.events[0]
    q, va = posture_at(traj, ev), ev["v_after"]
    return np.array([C.gamma - (q[2] + q[3]), -(va["base"][2] + va["hip"]), -va["base"][2]])


def test_periodic_gait_by_a_fixed_point_search_on_pcmms_step_map():
    """fsolve on pcmm's own step map (one run per evaluation) finds the reference's period-one gait,
    which reproduces Goswami et al.'s published one (design_24.md section 1)."""
    from scipy.optimize import fsolve
    scene = pcmm.load_scene(EXAMPLE)
    guess = np.array([-0.2187, 1.0918, 0.3772])  # the published gait, rounded, in Drake's convention
    x = fsolve(lambda x: pcmm_step_map(scene, x) - x, guess, xtol=1e-12)
    ref, _, _, eig = C.fixed_point()
    np.testing.assert_allclose(x, ref, atol=1e-9)
    assert max(abs(eig)) < 1  # a stable gait (|lambda| = 0.580)
