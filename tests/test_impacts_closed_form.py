"""Impacts against closed-form rigid-body impulse mechanics and against Pinocchio.

(a) a compound pendulum striking a stop fixed on the frame (stable impact, coordinate guard);
(b) a free bar dropped on the frame (stable impact, gap guard);
(c) a mobile impact between two links of a 3-bar chain against
    ``pinocchio.impulseDynamics`` in its Jacobian form.
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

import pcmm
from builders import G, Bar, chain_urdf, free_bar_urdf
from builders import cross2, rot
from pcmm.model.mechanism import Mechanism
from pcmm.events.impulse import solve_impulse

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED

# ---- (a) compound pendulum on a stop ------------------------------------------------------------
# A uniform bar (mass m, length L) on J1 at the origin; q = angle from +x.  The stop is on the
# frame at the point the bar's contact point (distance d from the pivot) reaches at q = qs.
# Falling means q decreasing, so the contact point moves along -t, t = (-sin qs, cos qs); the
# normal from the frame (a) towards the bar (b) is +t, and the normal velocity is d * omega.
#
#   I_O = I_c + m l_c^2 = m L^2 / 3,   l_c = L / 2.
#   Newton's law at the contact: d omega+ = -e d omega-  ->  omega+ = -e omega-.
#   Angular momentum about the pivot (the pivot impulse has no moment about O, the contact
#   impulse P t at distance d has moment d P):   I_O (omega+ - omega-) = d P.
#   Linear momentum: m (v_c+ - v_c-) = P t + P_pivot with v_c = omega l_c t, so
#   P_pivot = (m l_c - I_O / d) (omega+ - omega-) t   (zero at the centre of percussion d = 2L/3).
#   Release from rest at q0:  omega^2 = 2 k (sin q0 - sin q),  k = m g l_c / I_O.
M_BAR, L_BAR = 1.5, 0.6
I_O = M_BAR * L_BAR ** 2 / 3
K_PEND = M_BAR * G * (L_BAR / 2) / I_O


def stop_transition(qs, d, e, cut=(), merge_to=None):
    tr = {"name": "stop", "type": "stop", "from": "c1", "restitution": e, "cut": list(cut),
          "guard": {"type": "coordinate", "measure": {"joint": "J1"}, "value": qs, "direction": "decreasing"},
          "contact": {"a": "frame", "point_a": [d * math.cos(qs), d * math.sin(qs)],
                      "b": "link1", "point_b": [d, 0.0], "normal": [-math.sin(qs), math.cos(qs)]}}
    if merge_to:
        tr["merge_to"] = merge_to
    return tr


def pendulum_scene(make_scene, qs, e, d=L_BAR, q0=0.0, cut=(), t_end=None):
    """A pendulum released from rest at q0 onto a stop at qs; the stop merges into 'rest'
    (the bar welded to the frame at qs) when the impact is plastic."""
    urdfs = {"p.urdf": chain_urdf([Bar(L_BAR, M_BAR)]),
             "rest.urdf": chain_urdf([Bar(L_BAR, M_BAR, joint="fixed", yaw=qs)])}
    return make_scene(urdfs, configurations={"c1": "p.urdf", "rest": "rest.urdf"},
                      q0={"J1": q0}, v0={"J1": 0.0}, t_end=t_end or 1.0,
                      transitions=[stop_transition(qs, d, e, cut, merge_to="rest")])


def fall_time(q0, qs):
    """t = integral of dq / |omega| from qs to q0; with q = q0 - s^2 the 1/sqrt singularity
    at the release point goes away: t = int_0^sqrt(q0 - qs) 2 s ds / sqrt(2k (sin q0 - sin(q0 - s^2)))."""
    f = lambda s: 2 * s / math.sqrt(2 * K_PEND * (math.sin(q0) - math.sin(q0 - s * s)))  # noqa: E731
    val, err = quad(f, 0.0, math.sqrt(q0 - qs), epsabs=1e-14, epsrel=1e-13, limit=200)
    assert err < 1e-11
    return val


def omega_minus(q0, qs):
    return -math.sqrt(2 * K_PEND * (math.sin(q0) - math.sin(qs)))


@pytest.mark.parametrize("q0,qs", [(0.0, -1.2), (0.0, -math.pi / 2), (0.5, -2.5)])
@pytest.mark.parametrize("e", [0.0, 0.3, 0.8, 1.0])
def test_pendulum_stop_run(make_scene, q0, qs, e):
    t_hit = fall_time(q0, qs)
    w_minus = omega_minus(q0, qs)
    traj = pcmm.simulate(pcmm.load_scene(pendulum_scene(make_scene, qs, e, q0=q0, t_end=t_hit + 0.02)))
    ev = traj.events[0]
    assert ev["transition"] == "stop" and ev["kind"] == "stable"
    assert ev["t"] == pytest.approx(t_hit, abs=1e-9)
    assert ev["v_before"]["J1"] == pytest.approx(w_minus, rel=1e-8)
    assert ev["v_after"]["J1"] == pytest.approx(-e * w_minus, rel=1e-8, abs=1e-10)
    # P = I_O (omega+ - omega-) / d = -(1 + e) I_O omega- / L
    assert ev["impulse"]["normal"] == pytest.approx(-(1 + e) * I_O * w_minus / L_BAR, rel=1e-8)
    assert ev["kinetic_energy_after"] == pytest.approx(e * e * ev["kinetic_energy_before"], rel=1e-9, abs=1e-12)
    if e == 0.0 and math.cos(qs) >= -1e-12:
        # a plastic stop where gravity presses the bar onto it (its moment -m g L/2 cos qs <= 0,
        # towards the stop): the bar comes to rest and merges into the welded configuration
        assert ev["merge"] and traj.segments[-1].configuration == "rest"
    elif e == 0.0:
        # past the bottom (cos qs < 0) gravity pulls the bar off the stop: the merge could only
        # hold by pulling, so it is released at the same instant and the bar falls back from rest
        assert ev["merge"] and traj.events[1]["transition"] == "release" and traj.events[1]["t"] == ev["t"]
        assert traj.segments[-1].configuration == "c1" and traj.segments[-1].v[0, 0] == pytest.approx(0.0, abs=1e-12)
        assert traj.segments[-1].v[-1, 0] > 0  # falling back, away from the stop
    else:
        assert not ev["merge"] and traj.segments[-1].configuration == "c1"
        assert traj.segments[-1].v[0, 0] == pytest.approx(-e * w_minus, rel=1e-8)


@pytest.mark.parametrize("d", [L_BAR, 2 * L_BAR / 3, L_BAR / 2, 0.25 * L_BAR])
@pytest.mark.parametrize("cut", [(), ("J1",)])
@pytest.mark.parametrize("e", [0.0, 0.6, 1.0])
def test_pendulum_pivot_impulse(make_scene, d, cut, e):
    qs = -1.2
    scene = pcmm.load_scene(pendulum_scene(make_scene, qs, e, d=d, cut=cut))
    cfg = Mechanism(scene)["c1"]
    tr = scene.transitions[0]
    w_minus = omega_minus(0.0, qs)
    imp = solve_impulse(cfg, 0.3, np.array([qs]), np.array([w_minus]), tr.contact, e, cut)
    t_dir = np.array([-math.sin(qs), math.cos(qs)])
    dw = -(1 + e) * w_minus
    assert imp.kind == "stable"
    assert imp.v_after[0] == pytest.approx(-e * w_minus, rel=1e-12, abs=1e-12)
    assert imp.P == pytest.approx(I_O * dw / d, rel=1e-12)
    np.testing.assert_allclose(imp.normal, t_dir, atol=1e-15)
    assert imp.vn_before == pytest.approx(d * w_minus, rel=1e-12)
    assert imp.vn_after == pytest.approx(-e * d * w_minus, rel=1e-12, abs=1e-12)
    # linear momentum: m (v_c+ - v_c-) = P t + P_pivot
    p_pivot = (M_BAR * L_BAR / 2 - I_O / d) * dw * t_dir
    np.testing.assert_allclose(imp.joint_impulses["J1"][:2], p_pivot, atol=1e-12)
    assert abs(imp.joint_impulses["J1"][2]) < 1e-12  # a revolute joint carries no moment
    np.testing.assert_allclose(imp.rnea_residual, [0.0], atol=1e-12)  # passive joint: no actuator impulse
    if cut:
        np.testing.assert_allclose(imp.cut_impulses["J1"], [*p_pivot, 0.0], atol=1e-12)
    else:
        assert imp.cut_impulses == {}


def test_pendulum_pivot_impulse_in_the_run(make_scene):
    """The event record carries the same pivot impulse as the closed form."""
    qs, e, d = -1.0, 0.4, 0.45
    traj = pcmm.simulate(pcmm.load_scene(pendulum_scene(make_scene, qs, e, d=d, cut=("J1",),
                                                        t_end=fall_time(0.0, qs) + 0.01)))
    ev = traj.events[0]
    dw = -(1 + e) * omega_minus(0.0, qs)
    t_dir = np.array([-math.sin(qs), math.cos(qs)])
    p_pivot = (M_BAR * L_BAR / 2 - I_O / d) * dw * t_dir
    np.testing.assert_allclose(ev["joint_impulses"]["J1"][:2], p_pivot, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(ev["cut_impulses"]["J1"][:2], p_pivot, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(ev["impulse"]["vector"], I_O * dw / d * t_dir, rtol=1e-8)


# ---- (b) a free bar dropped on the frame -----------------------------------------------------------
# A uniform bar (m, L, I_c = m L^2 / 12) on a URDF planar joint (origin at the centroid); its
# end b = (-L/2, 0) strikes the ground y = 0 of the frame (normal n = (0, 1), frame -> bar).
# With r = p_contact - p_c, r x n = r_x n_y - r_y n_x, the frictionless impulse P n gives
#   m dv_c = P n,  I_c d omega = (r x n) P,  n.(dv_c + d omega k x r) = -(1 + e) v_n
#   ->  P = -(1 + e) v_n / (1/m + (r x n)^2 / I_c).
M_FB, L_FB = 0.8, 0.5
IC_FB = M_FB * L_FB ** 2 / 12


def drop_transition(e, point_b=(-L_FB / 2, 0.0), normal=(0.0, 1.0), point_a=(0.0, 0.0)):
    return {"name": "ground", "type": "stop", "from": "c1", "restitution": e, "cut": [],
            "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"},
            "contact": {"a": "frame", "point_a": list(point_a), "b": "bar", "point_b": list(point_b),
                        "normal": list(normal)}}


def hand_impulse(r, n, v_c, w, e):
    """(P, v_c+, omega+) of the frictionless stable impact, r = contact - centroid (world)."""
    v_point = v_c + w * np.array([-r[1], r[0]])
    vn = float(n @ v_point)
    rn = cross2(r, n)
    P = -(1 + e) * vn / (1 / M_FB + rn * rn / IC_FB)
    return P, vn, v_c + P * n / M_FB, w + rn * P / IC_FB


@pytest.mark.parametrize("tilt,h,vx,w0", [(0.3, 0.2, 0.0, 0.0), (1.0, 0.05, 0.7, 0.0), (-0.6, 0.3, -0.4, 0.0),
                                          (0.5, 0.15, 0.2, 1.5)])
@pytest.mark.parametrize("e", [0.4, 0.9])
def test_bar_drop_run(make_scene, tilt, h, vx, w0, e):
    # with a negative tilt the +L/2 end is lowest: hit with that one
    end = -L_FB / 2 if tilt > 0 else L_FB / 2
    y0 = h - end * math.sin(tilt)  # the end starts h above the ground

    def gap(t):  # end height in free flight: y0 - g t^2 / 2 + end sin(tilt + w0 t)
        return y0 - 0.5 * G * t * t + end * math.sin(tilt + w0 * t)
    t_hit = brentq(gap, 1e-9, 2.0, xtol=1e-15, rtol=1e-15)
    th = tilt + w0 * t_hit
    v_c = np.array([vx, -G * t_hit])
    r = rot(th) @ np.array([end, 0.0])
    n = np.array([0.0, 1.0])
    P, vn, v_c_plus, w_plus = hand_impulse(r, n, v_c, w0, e)
    path = make_scene({"f.urdf": free_bar_urdf(M_FB, L_FB)}, q0={"P": [0.0, y0, tilt]},
                      v0={"P": [*(rot(tilt).T @ [vx, 0.0]), w0]}, t_end=t_hit + 1e-3,
                      transitions=[drop_transition(e, point_b=(end, 0.0))])
    traj = pcmm.simulate(pcmm.load_scene(path))
    ev = traj.events[0]
    assert ev["kind"] == "stable" and ev["transition"] == "stop"
    assert ev["t"] == pytest.approx(t_hit, abs=1e-9)
    assert ev["normal_velocity"]["before"] == pytest.approx(vn, rel=1e-8)
    assert ev["normal_velocity"]["after"] == pytest.approx(-e * vn, rel=1e-8)
    assert ev["impulse"]["normal"] == pytest.approx(P, rel=1e-8)
    np.testing.assert_allclose(ev["impulse"]["vector"], [0.0, P], rtol=1e-8, atol=1e-12)
    # post-impact state: joint velocity is in the bar's frame
    vl = np.array(ev["v_after"]["P"])
    np.testing.assert_allclose(rot(th) @ vl[:2], v_c_plus, rtol=1e-8, atol=1e-10)
    assert vl[2] == pytest.approx(w_plus, rel=1e-8)
    assert ev["omega_after"]["bar"] == pytest.approx(w_plus, rel=1e-8)


DROP_STATES = [
    # (x, y, theta), world centroid velocity, omega, contact point on the bar, ground normal in the frame
    ((0.0, 0.1, 0.4), (0.0, -2.0), 0.0, (-L_FB / 2, 0.0), (0.0, 1.0)),
    ((0.3, 0.0, -1.1), (1.5, -0.5), 3.0, (L_FB / 2, 0.0), (0.0, 1.0)),
    ((-0.2, 0.5, 2.0), (-0.7, -1.0), -4.0, (0.1, 0.02), (0.6, 0.8)),
    ((0.0, 0.0, math.pi / 2), (0.0, -1.0), 0.0, (-L_FB / 2, 0.0), (0.0, 1.0)),  # vertical: r x n = 0
]


@pytest.mark.parametrize("q,vc,w,point,normal", DROP_STATES)
@pytest.mark.parametrize("e", [0.0, 0.5, 1.0])
def test_bar_drop_impulse_by_hand(configuration, q, vc, w, point, normal, e):
    _, cfg = configuration({"f.urdf": free_bar_urdf(M_FB, L_FB)}, q0={"P": [0.0, 0.0, 0.0]},
                           v0={"P": [0.0, 0.0, 0.0]},
                           transitions=[drop_transition(e, point_b=point, normal=normal)])
    tr = cfg.scene.transitions[0]
    R = rot(q[2])
    v = np.array([*(R.T @ np.array(vc)), w])  # pcmm/Pinocchio planar velocity: bar frame
    imp = solve_impulse(cfg, 0.0, np.array(q), v, tr.contact, e, ())
    n = np.array(normal) / np.linalg.norm(normal)
    r = R @ np.array(point)
    P, vn, v_c_plus, w_plus = hand_impulse(r, n, np.array(vc), w, e)
    assert imp.kind == "stable"
    assert imp.vn_before == pytest.approx(vn, rel=1e-12)
    assert imp.P == pytest.approx(P, rel=1e-12)
    np.testing.assert_allclose(R @ imp.v_after[:2], v_c_plus, rtol=1e-12, atol=1e-12)
    assert imp.v_after[2] == pytest.approx(w_plus, rel=1e-12, abs=1e-12)
    assert imp.vn_after == pytest.approx(-e * vn, rel=1e-12, abs=1e-12)
    # energy: the impulse works at the mean normal velocity, KE+ - KE- = P (vn- + vn+) / 2
    assert imp.ke_after - imp.ke_before == pytest.approx(P * (vn - e * vn) / 2, rel=1e-10, abs=1e-14)
    # a free joint carries no impulse
    np.testing.assert_allclose(imp.joint_impulses["P"], [0.0, 0.0, 0.0], atol=1e-12)


# ---- (c) a mobile impact in a 3-bar chain against pinocchio.impulseDynamics ----------------------------
CHAIN = [Bar(0.4, 1.2, com=(0.18, 0.02), izz=0.021), Bar(0.3, 0.7, com=(0.12, -0.03), izz=0.008, yaw=0.4),
         Bar(0.35, 0.5, izz=0.006)]
CHAINS = {
    "revolute": CHAIN,
    # a slider along a tilted axis carrying a pendulum that carries a second slider
    "sliders": [Bar(0.3, 2.0, joint="prismatic", axis=(0.6, 0.8, 0.0), com=(0.05, 0.02), izz=0.05, yaw=0.2),
                Bar(0.4, 0.7), Bar(0.35, 0.5, joint="prismatic", axis=(1.0, 0.0, 0.0))],
    # a free (URDF planar) bar carrying a double pendulum
    "floating": [Bar(0.3, 2.0, joint="planar", com=(0.1, 0.02), izz=0.05), Bar(0.4, 0.7, yaw=-0.5), Bar(0.35, 0.5)],
}
CONTACT = {"a": "link1", "point_a": [0.25, 0.01], "b": "link3", "point_b": [0.3, -0.02], "normal": [0.3, 1.0]}


def build_chain(configuration, bars):
    """(pcmm Configuration, the scene's contact, an independent Pinocchio model of the URDF)."""
    tr = {"name": "hit", "type": "stop", "from": "c1", "restitution": 0.5, "cut": [],
          "guard": {"type": "gap", "value": -10.0, "direction": "decreasing"}, "contact": CONTACT}
    zero = {"J1": [0.0, 0.0, 0.0] if bars[0].joint == "planar" else 0.0, "J2": 0.0, "J3": 0.0}
    scene, cfg = configuration({"c.urdf": chain_urdf(bars)}, q0=zero, v0=zero, transitions=[tr])
    model = pin.buildModelFromUrdf(str(scene.configurations["c1"].urdf))  # our own, independent model
    model.gravity.linear[:] = [0.0, -G, 0.0]
    return cfg, scene.transitions[0].contact, model


@pytest.fixture
def chain3(configuration):
    return build_chain(configuration, CHAIN)


def point_jacobian(model, data, jid, local):
    """2 x nv world Jacobian of a point fixed on joint jid's body (Pinocchio, not pcmm)."""
    return pin.getFrameJacobian(model, data, jid, pin.SE3(np.eye(3), np.array([*local, 0.0])), LWA)[:2]


def random_state(bars, seed):
    """pcmm (q, v) and Pinocchio's q (a planar joint is x, y, cos, sin there)."""
    rng = np.random.default_rng(seed)
    nv = 3 + 2 * (bars[0].joint == "planar")
    q = rng.uniform(-math.pi, math.pi, nv)
    v = rng.uniform(-5.0, 5.0, nv)
    q_pin = np.concatenate([q[:2], [math.cos(q[2]), math.sin(q[2])], q[3:]]) if nv == 5 else q
    return q, v, q_pin


@pytest.mark.parametrize("variant", list(CHAINS))
@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("cut", [(), ("J3",), ("J2",), ("J1",), ("J2", "J3"), ("J1", "J2", "J3")])
@pytest.mark.parametrize("e", [0.0, 0.7])
def test_mobile_impulse_matches_pinocchio(configuration, variant, seed, cut, e):
    bars = CHAINS[variant]
    cfg, contact, model = build_chain(configuration, bars)
    q, v, q_pin = random_state(bars, seed)
    data = model.createData()
    pin.computeJointJacobians(model, data, q_pin)
    pin.updateFramePlacements(model, data)
    ja, jb = model.getJointId("J1"), model.getJointId("J3")
    n = data.oMi[ja].rotation[:2, :2] @ np.array(CONTACT["normal"])
    n /= np.linalg.norm(n)
    J = (n @ (point_jacobian(model, data, jb, CONTACT["point_b"])
              - point_jacobian(model, data, ja, CONTACT["point_a"])))[None, :]
    v_plus = pin.impulseDynamics(model, data, q_pin, v, J, e, 0.0).copy()
    P_pin = float(np.asarray(data.impulse_c).ravel()[0])
    np.testing.assert_allclose(J @ v_plus, -e * (J @ v), atol=1e-12)  # Pinocchio's own law holds

    imp = solve_impulse(cfg, 0.0, q, v, contact, e, cut)
    assert imp.kind == "mobile"
    scale = max(1.0, float(np.max(np.abs(v))))
    np.testing.assert_allclose(imp.v_after, v_plus, rtol=0, atol=1e-10 * scale)
    assert imp.P == pytest.approx(P_pin, rel=1e-10, abs=1e-12)
    assert imp.vn_before == pytest.approx(float((J @ v)[0]), rel=1e-12, abs=1e-14)
    # the impulse of a cut joint (multiplier of the cut system) is the impulse the joint carries (RNEA)
    for j in cut:
        np.testing.assert_allclose(imp.cut_impulses[j], imp.joint_impulses[j], atol=1e-10 * scale)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("cut", [(), ("J2",)])
def test_mobile_joint_impulses_balance_each_link(chain3, seed, cut):
    """Each link's momentum jump equals the impulses on it: from its own joint (F_i, on it),
    from the next joint (-F_{i+1}) and from the contact (+P n on link 3, -P n on link 1):
        m_i dv_ci = sum F,   I_i d omega_i = sum (p - c_i) x F + sum mz."""
    cfg, contact, model = chain3
    q, v, _ = random_state(CHAIN, 100 + seed)
    imp = solve_impulse(cfg, 0.0, q, v, contact, 0.5, cut)
    data = model.createData()
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    dv = imp.v_after - v
    pa = data.oMi[1].act(np.array([*CONTACT["point_a"], 0.0]))[:2]
    pb = data.oMi[3].act(np.array([*CONTACT["point_b"], 0.0]))[:2]
    Pvec = imp.P * imp.normal
    for i, bar in enumerate(CHAIN, start=1):
        Jc = point_jacobian(model, data, i, bar.c)
        c = data.oMi[i].act(np.array([*bar.c, 0.0]))[:2]
        dw = float(cfg.A[cfg.link_index[f"link{i}"]] @ dv)
        forces = [(data.oMi[i].translation[:2], np.array(imp.joint_impulses[f"J{i}"]))]
        if i < 3:
            Fn = np.array(imp.joint_impulses[f"J{i + 1}"])
            forces.append((data.oMi[i + 1].translation[:2], -Fn))
        if i == 1:
            forces.append((pa, np.array([*(-Pvec), 0.0])))
        if i == 3:
            forces.append((pb, np.array([*Pvec, 0.0])))
        lin = sum(F[:2] for _, F in forces)
        ang = sum(cross2(p - c, F[:2]) + F[2] for p, F in forces)
        np.testing.assert_allclose(bar.mass * (Jc @ dv), lin, atol=1e-11)
        assert bar.I * dw == pytest.approx(ang, abs=1e-11)
