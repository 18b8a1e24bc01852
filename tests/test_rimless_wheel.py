"""Issue 24, item 5: examples/rimless_wheel.toml, McGeer's rimless wheel as one scene.

Every strike is a ``pin`` transition (the next spoke's tip pinned where it lands, the old foot
released by the complementarity solve); the numbers are those of the independent reference
``tests/reference_rimless_wheel.py`` (stance by quadrature, strike by angular momentum about the
new foot), and of the issue: omega+ = r omega- with r = (I + m l^2 cos 2 alpha)/(I + m l^2) at
every strike to 1e-9; the post-strike rate within 1e-6 of omega+* after at least 10 strikes.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import pcmm
import reference_rimless_wheel as rw
from builders import rot
from pcmm.events.momentum import balance

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "rimless_wheel.toml"
W = rw.ISSUE
M_HUB, I_HUB = 1.0, 0.05


@pytest.fixture(scope="module")
def run():
    traj = pcmm.simulate(pcmm.load_scene(EXAMPLE))
    return traj, [e for e in traj.events if e["transition"] == "pin"]


def posture_at(traj, ev):
    """The posture at an event: the last sample of the segment that ends there in its source."""
    seg, = [s for s in traj.segments if s.configuration == ev["from"] and s.t[-1] == ev["t"]]
    return np.asarray(seg.q[-1])


def hub_state(traj, ev):
    """(hub position, world hub velocity before and after, omega before and after) at a strike."""
    q = posture_at(traj, ev)
    vb, va = np.asarray(ev["v_before"]["hub"]), np.asarray(ev["v_after"]["hub"])
    return q[:2], rot(q[2]) @ vb[:2], rot(q[2]) @ va[:2], vb[2], va[2]


def test_issue_numbers_by_hand():
    alpha = math.pi / 6
    r = (I_HUB + M_HUB * math.cos(2 * alpha)) / (I_HUB + M_HUB)
    assert r == pytest.approx(0.55 / 1.05, abs=1e-15) and W.r == pytest.approx(r, abs=1e-15)


def test_every_strike_scales_omega_by_r(run):
    traj, strikes = run
    assert len(strikes) >= 10 and len(strikes) == len(traj.events)
    r = 0.55 / 1.05
    for ev in strikes:
        assert ev["omega_after"]["wheel"] / ev["omega_before"]["wheel"] == pytest.approx(r, abs=1e-9)
        # plastic, no slip: KE+ = r^2 KE- (both are J omega^2 / 2 about a foot)
        assert ev["kinetic_energy_after"] == pytest.approx(r * r * ev["kinetic_energy_before"], rel=1e-9)


def test_strikes_against_the_reference_and_the_fixed_point(run):
    _, strikes = run
    ref = W.strikes(1.5, len(strikes))
    for ev, (t, wm, wp) in zip(strikes, ref):
        assert ev["t"] == pytest.approx(t, abs=1e-9)
        assert -ev["omega_before"]["wheel"] == pytest.approx(wm, abs=1e-8)  # the wheel turns clockwise
        assert -ev["omega_after"]["wheel"] == pytest.approx(wp, abs=1e-8)
    wp_star, _ = W.fixed_point()
    assert wp_star == pytest.approx(1.1847806767776679, rel=1e-13)
    assert abs(-strikes[9]["omega_after"]["wheel"] - wp_star) < 1e-6
    assert abs(-strikes[-1]["omega_after"]["wheel"] - wp_star) < 1e-7


def test_angular_momentum_about_the_new_foot_and_the_old_foot_leaving(run):
    traj, strikes = run
    for ev in strikes:
        new = ev["to"].replace("spoke", "foot")
        foot = np.asarray(ev["anchor"][new])
        assert foot[1] == pytest.approx(0.0, abs=1e-9)  # the strike is on the slope
        hub, vb, va, wb, wa = hub_state(traj, ev)
        r = hub - foot
        H = [I_HUB * w + M_HUB * (r[0] * v[1] - r[1] * v[0]) for w, v in ((wb, vb), (wa, va))]
        assert H[1] == pytest.approx(H[0], abs=1e-12)
        # the new foot does not move after the strike; the old one leaves, without impulse
        tip = hub + rot(posture_at(traj, ev)[2]) @ rw.spoke_tip(W, int(ev["to"][-1]))
        np.testing.assert_allclose(tip, foot, atol=1e-12)
        (old, rec), = ev["released"].items()
        assert rec["impulse"] == 0.0 and rec["normal_velocity_after"] > 0.5
        assert ev["constraint_impulses"][old] == [0.0, 0.0, 0.0]
        # the impulse: compressive, the no-slip ratio |P_t| / P_n = 0.54127 of the reference (any omega)
        assert ev["impulse"]["normal"] > 0
        assert abs(ev["impulse"]["tangential"]) / ev["impulse"]["normal"] == pytest.approx(0.5412658773652739, rel=1e-9)
        # the impulse-momentum balance of the whole wheel from the event's external impulses
        dL, dH = balance(ev)
        assert np.max(np.abs(dL)) < 1e-12 and abs(dH) < 1e-12


def test_energy_never_rises_and_its_split(run):
    """The energy lost to the strike's normal and tangential parts (each P_i (v_i- + v_i+) / 2, the
    relative velocity linear along the impulse) sums to KE- - KE+.  By hand, the striking tip does not
    slip before the strike either: the wheel turns about the old foot, and the new tip lies along the
    slope from it, so its velocity omega z x (2 l sin alpha, 0) is normal to the slope; the whole
    loss is the normal part's, KE- (1 - r^2)."""
    _, strikes = run
    for ev in strikes:
        assert ev["energy_dissipated"] >= 0.0
        fr = ev["friction"]
        assert fr["energy_lost"]["normal"] + fr["energy_lost"]["tangential"] == pytest.approx(
            ev["kinetic_energy_before"] - ev["kinetic_energy_after"], abs=1e-12)
        assert fr["slip"]["after"] == pytest.approx(0.0, abs=1e-12)
        assert fr["slip"]["before"] == pytest.approx(0.0, abs=1e-12)
        assert fr["energy_lost"]["tangential"] == pytest.approx(0.0, abs=1e-12)
        r = 0.55 / 1.05
        assert fr["energy_lost"]["normal"] == pytest.approx(ev["kinetic_energy_before"] * (1 - r * r), rel=1e-9)


def test_first_strike_against_pinocchios_impulse_dynamics(run):
    """The first strike against Pinocchio 4.1's ``impulseDynamics`` in its Jacobian form (e = 0,
    no damping) with the new foot's two world rows: what design_24.md section 6 found to agree with
    a KKT solve to round-off for bilateral plastic pins on a positive-definite M."""
    import pinocchio as pin
    traj, strikes = run
    ev = strikes[0]
    q = posture_at(traj, ev)
    model = pin.buildModelFromXML((EXAMPLE.parents[1] / "urdf" / "rimless_wheel.urdf").read_text())
    jid = model.getJointId("hub")
    tip = rw.spoke_tip(W, 1)
    fid = model.addFrame(pin.Frame("tip1", jid, 0, pin.SE3(np.eye(3), np.array([tip[0], tip[1], 0.0])),
                                   pin.FrameType.OP_FRAME))
    data = model.createData()
    qp = np.array([q[0], q[1], math.cos(q[2]), math.sin(q[2])])
    pin.computeJointJacobians(model, data, qp)
    pin.updateFramePlacements(model, data)
    J = pin.getFrameJacobian(model, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:2]
    v_before = np.asarray(ev["v_before"]["hub"])  # pcmm's planar velocity is Pinocchio's (body frame)
    v_after = pin.impulseDynamics(model, data, qp, v_before, J, 0.0, 0.0)
    np.testing.assert_allclose(ev["v_after"]["hub"], v_after, atol=1e-13)


def test_check_walks_every_strike_without_warnings():
    """`pcmm check` enters each spoke's configuration at the previous strike's posture (its foot
    anchored where it strikes) and finds the next strike's posture there: six guard postures, each
    with the next tip on the slope and the wheel turned by pi/3 per strike (before the fix, the
    posture solve took the planar joint's body-frame velocity columns for dPhi/dq and diverged,
    and the anchors of a checked configuration were never set: a warning on 'strike 2')."""
    from pcmm.run.checks import check_scene
    report = check_scene(pcmm.load_scene(EXAMPLE))
    assert not report.problems and not report.warnings
    assert len(report.postures) == 6
    for k in range(1, 7):
        q = report.postures[f"strike {k}"]
        tip = q[:2] + rot(q[2]) @ rw.spoke_tip(W, k % 6)
        assert tip[1] == pytest.approx(0.0, abs=1e-12)
        assert q[2] == pytest.approx(math.pi / 6 - k * math.pi / 3, abs=1e-9)


def test_the_drawing_shows_each_pinned_foot_where_it_struck(run):
    """The 2D drawing (pcmm replay --video, pcmm.viz.sketch) draws a cut joint anchored at entry as
    a grounded pin at the anchor of each stay, shown during that stay only: at the middle of every
    stance exactly one pin, at the event's recorded anchor (the start's: spoke 0's tip, the origin)."""
    from pcmm.viz import sketch as sk
    traj, strikes = run
    syms = sk.symbols(traj)
    starts = [0.0] + [e["t"] for e in strikes] + [float(traj.t[-1])]
    anchors = [[0.0, 0.0]] + [next(iter(e["anchor"].values())) for e in strikes]
    for (a, b), anchor in zip(zip(starts, starts[1:]), anchors):
        shown = [p for p in sk.world(traj, syms, 0.5 * (a + b)) if p.symbol.kind == "cut"]
        assert len(shown) == 1
        np.testing.assert_allclose(shown[0].xy, anchor, atol=1e-9)
    assert sk.plate_text(strikes[0]) == "pin: impact, point pinned, foot0 lifts off"
