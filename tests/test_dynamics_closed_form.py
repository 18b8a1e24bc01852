"""Equations of motion of small planar mechanisms against closed-form mechanics.

pcmm's coordinates for a chain are the joint angles (relative angles); a URDF
``planar`` joint is (x, y, theta) with Pinocchio's velocity (vx, vy) in the
bar's own frame.  Every expected number below is written out by hand.
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

import pcmm
from builders import G, Bar, chain_urdf, free_bar_urdf, pendulum_urdf
from builders import rot

# ---- closed forms ------------------------------------------------------------------------


def pendulum_M_h(b: Bar, q: float, v: float, g: float = G):
    """Compound pendulum on J1 at the origin, angle q from +x, centroid c = (cx, cy).

    T = 1/2 (I_c + m |c|^2) q'^2, V = m g y_c, y_c = cx sin q + cy cos q, so
    M = I_c + m |c|^2 (no velocity term: h is gravity only),
    h = dV/dq = m g (cx cos q - cy sin q).
    """
    cx, cy = b.c
    return b.I + b.mass * (cx * cx + cy * cy), b.mass * g * (cx * math.cos(q) - cy * math.sin(q))


def double_pendulum_M_h(b1: Bar, b2: Bar, q, v, g: float = G):
    """Double pendulum, relative coordinates q = (q1, q2) (pcmm's).

    theta1 = q1 + psi1, phi = q2 + psi2 (link 2 against link 1), theta2 = theta1 + phi;
    psi are the URDF joint yaws.  With c2 = (c2x, c2y) in link 2's frame:
      r_c2 = L1 e(theta1) + R(theta2) c2,
      |v_c2|^2 = L1^2 q1'^2 + |c2|^2 th2'^2 + 2 f(phi) q1' th2',   th2' = q1' + q2',
      f(phi) = L1 (c2x cos phi - c2y sin phi)    [= L1 e_perp(theta1) . R(theta2) k x c2].
    T = 1/2 (I1 + m1|c1|^2) q1'^2 + 1/2 m2 |v_c2|^2 + 1/2 I2 th2'^2 gives
      M11 = I1 + m1|c1|^2 + I2 + m2 (L1^2 + |c2|^2 + 2 f),
      M12 = I2 + m2 (|c2|^2 + f),   M22 = I2 + m2 |c2|^2.
    Christoffel symbols (only dM/dq2 != 0, f' = df/dphi = -L1 (c2x sin phi + c2y cos phi)):
      h1 = m2 f' (2 q1' q2' + q2'^2),   h2 = -m2 f' q1'^2.
    Gravity, V = m1 g y_c1 + m2 g y_c2:
      G2 = m2 g (c2x cos th2 - c2y sin th2),
      G1 = m1 g (c1x cos th1 - c1y sin th1) + m2 g L1 cos th1 + G2.
    """
    (c1x, c1y), (c2x, c2y) = b1.c, b2.c
    m1, m2, I1, I2, L1 = b1.mass, b2.mass, b1.I, b2.I, b1.length
    q1, q2 = q
    v1, v2 = v
    th1 = q1 + b1.yaw
    phi = q2 + b2.yaw
    th2 = th1 + phi
    f = L1 * (c2x * math.cos(phi) - c2y * math.sin(phi))
    fp = -L1 * (c2x * math.sin(phi) + c2y * math.cos(phi))
    c2sq = c2x ** 2 + c2y ** 2
    M = np.array([[I1 + m1 * (c1x ** 2 + c1y ** 2) + I2 + m2 * (L1 ** 2 + c2sq + 2 * f), I2 + m2 * (c2sq + f)],
                  [I2 + m2 * (c2sq + f), I2 + m2 * c2sq]])
    G2 = m2 * g * (c2x * math.cos(th2) - c2y * math.sin(th2))
    G1 = m1 * g * (c1x * math.cos(th1) - c1y * math.sin(th1)) + m2 * g * L1 * math.cos(th1) + G2
    h = np.array([m2 * fp * (2 * v1 * v2 + v2 ** 2) + G1, -m2 * fp * v1 ** 2 + G2])
    return M, h


def pcmm_bias(cfg, q, v):
    """pcmm's h(q, v) through its own forward dynamics with no force elements: M a = -h."""
    a, _ = cfg.coords.accelerations(0.0, np.asarray(q, float), np.asarray(v, float))
    return -cfg.mass_matrix(np.asarray(q, float)) @ a


ZERO = {"J1": 0.0, "J2": 0.0}

# ---- compound pendulum --------------------------------------------------------------------
PENDULA = [
    Bar(0.6, 1.5),  # uniform bar
    Bar(0.4, 0.7, com=(0.3, 0.0), izz=0.011),  # off-centre mass
    Bar(0.5, 2.0, com=(0.2, -0.07), izz=0.05),  # centroid off the bar's axis
]
STATES_1 = [(0.0, 0.0), (0.7, -3.0), (-2.2, 5.5), (3.5, 0.1), (11.0, -20.0)]


@pytest.mark.parametrize("bar", PENDULA)
@pytest.mark.parametrize("q,v", STATES_1)
def test_compound_pendulum_mass_and_bias(configuration, bar, q, v):
    _, cfg = configuration({"p.urdf": pendulum_urdf(bar.length, bar.mass, com=bar.com, izz=bar.izz)},
                           q0={"J1": 0.0}, v0={"J1": 0.0})
    M, h = pendulum_M_h(bar, q, v)
    np.testing.assert_allclose(cfg.mass_matrix(np.array([q])), [[M]], rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(pcmm_bias(cfg, [q], [v]), [h], rtol=1e-12, atol=1e-12)
    nle = pin.nonLinearEffects(cfg.model, cfg.data, cfg.to_pin(np.array([q])), np.array([v]))
    np.testing.assert_allclose(nle, [h], rtol=1e-12, atol=1e-12)


# ---- double pendulum -----------------------------------------------------------------------
DOUBLES = [
    (Bar(0.5, 1.0), Bar(0.5, 1.0)),
    (Bar(0.3, 2.0, com=(0.1, 0.02), izz=0.02), Bar(0.45, 0.6, com=(0.3, -0.05), izz=0.013)),
    (Bar(0.25, 0.39, yaw=0.3), Bar(0.125, 0.195, yaw=-1.1, com=(0.05, 0.01))),
]
STATES_2 = [((0.0, 0.0), (0.0, 0.0)), ((0.3, -1.2), (2.0, -1.0)), ((-2.0, 2.5), (-4.0, 7.0)),
            ((1.5707963267948966, 3.14159), (0.5, 0.0)), ((9.0, -7.5), (12.0, 3.0))]


@pytest.mark.parametrize("bars", DOUBLES)
@pytest.mark.parametrize("q,v", STATES_2)
def test_double_pendulum_mass_and_bias(configuration, bars, q, v):
    _, cfg = configuration({"d.urdf": chain_urdf(list(bars))}, q0=ZERO, v0=ZERO)
    M, h = double_pendulum_M_h(*bars, q, v)
    np.testing.assert_allclose(cfg.mass_matrix(np.array(q)), M, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(pcmm_bias(cfg, q, v), h, rtol=1e-11, atol=1e-11)


# ---- force elements --------------------------------------------------------------------------
# Each row: scene [[forces]] tables and the generalized force Q(q, v) they must produce in
# pcmm's coordinates (joint angles).  Virtual work: a torque tau on joint J2 does work tau dq2;
# a torque tau on link 2 from the frame does work tau dtheta2 = tau (dq1 + dq2) -> Q = tau (1, 1).
B1, B2 = Bar(0.4, 1.2, com=(0.15, 0.03), izz=0.02), Bar(0.3, 0.8, yaw=0.5)
PSI2 = B2.yaw  # link 2 sits at theta2 - theta1 = q2 + psi2 against link 1
FORCE_ROWS = [
    pytest.param([{"name": "motor", "type": "torque", "on": {"joint": "J1"}, "value": 1.7}],
                 lambda q, v: np.array([1.7, 0.0]), id="torque-on-J1"),
    pytest.param([{"name": "motor", "type": "torque", "on": {"link": "link2"}, "value": -0.9}],
                 lambda q, v: np.array([-0.9, -0.9]), id="torque-on-link2"),
    pytest.param([{"name": "spring", "type": "spring", "on": {"joint": "J2"},
                   "measure": {"between": ["link1", "link2"]}, "k": 3.0, "rest": 0.2}],
                 # tau = -k (theta2 - theta1 - rest) = -k (q2 + psi2 - rest) on J2
                 lambda q, v: np.array([0.0, -3.0 * (q[1] + PSI2 - 0.2)]), id="spring-relative-angle"),
    pytest.param([{"name": "damper", "type": "damper", "on": {"link": "link2"},
                   "measure": {"link": "link2"}, "c": 0.4}],
                 # tau = -c theta2' = -c (q1' + q2') on link 2 -> Q = tau (1, 1)
                 lambda q, v: -0.4 * (v[0] + v[1]) * np.ones(2), id="damper-absolute-angle"),
    pytest.param([{"name": "tau1", "type": "linear", "on": {"link": "link1"}, "measure": {"link": "link1"},
                   "value": 1.955, "c": 0.0196},
                  {"name": "tau2", "type": "linear", "on": {"link": "link2"},
                   "measure": {"between": ["link1", "link2"]}, "value": 0.1625, "k": 0.0161}],
                 # Eq. 44-style pair: tau1 on link 1 -> Q += tau1 (1, 0); tau2 on link 2 -> Q += tau2 (1, 1)
                 lambda q, v: (1.955 - 0.0196 * v[0]) * np.array([1.0, 0.0])
                 + (0.1625 - 0.0161 * (q[1] + PSI2)) * np.ones(2), id="eq44-style"),
    pytest.param([{"name": "sd", "type": "spring_damper", "on": {"joint": "J1"}, "measure": {"joint": "J1"},
                   "k": 2.0, "c": 0.3, "rest": -0.4}],
                 lambda q, v: np.array([-2.0 * (q[0] + 0.4) - 0.3 * v[0], 0.0]), id="spring-damper-J1"),
]


@pytest.mark.parametrize("forces,Q", FORCE_ROWS)
@pytest.mark.parametrize("q,v", [((0.3, -1.2), (2.0, -1.0)), ((-2.0, 2.5), (-4.0, 7.0)), ((1.0, 0.0), (0.0, 0.0))])
def test_accelerations_with_force_elements(configuration, forces, Q, q, v):
    _, cfg = configuration({"d.urdf": chain_urdf([B1, B2])}, q0=ZERO, v0=ZERO, forces=forces)
    M, h = double_pendulum_M_h(B1, B2, q, v)
    expected = np.linalg.solve(M, Q(q, v) - h)  # D q'' + H = tau_a + tau_c (Eq. 1)
    a, lam = cfg.coords.accelerations(0.0, np.array(q, float), np.array(v, float))
    np.testing.assert_allclose(a, expected, rtol=1e-11, atol=1e-11)
    assert lam.size == 0
    # the same through the integrator's right-hand side y' = (q', q'')
    y = cfg.coords.pack(0.0, np.array(q, float), np.array(v, float))
    np.testing.assert_allclose(cfg.coords.rhs(0.0, y), np.concatenate([v, expected]), rtol=1e-11, atol=1e-11)


# ---- absolute angles ----------------------------------------------------------------------------
def test_absolute_angle_map_with_yaws_and_a_fixed_link(configuration):
    """theta = A q + b: a revolute joint adds its angle and its origin's yaw to the parent's
    angle, a fixed joint only its yaw.  link3 is welded to link2 with yaw psi3."""
    psi1, psi2, psi3 = 0.25, -1.3, 2.0
    bars = [Bar(0.5, 1.0, yaw=psi1), Bar(0.4, 1.0, yaw=psi2), Bar(0.3, 1.0, yaw=psi3, joint="fixed")]
    _, cfg = configuration({"c.urdf": chain_urdf(bars, first_xyz=(0.1, -0.2))}, q0=ZERO, v0=ZERO)
    assert cfg.joint_names == ["J1", "J2"]
    order = [cfg.link_index[n] for n in ("frame", "link1", "link2", "link3")]
    np.testing.assert_allclose(cfg.A[order], [[0, 0], [1, 0], [1, 1], [1, 1]], atol=1e-15)
    np.testing.assert_allclose(cfg.b[order], [0, psi1, psi1 + psi2, psi1 + psi2 + psi3], atol=1e-15)
    for q in ([0.0, 0.0], [0.7, -2.0], [13.0, -25.0]):  # angles never wrap: 13 rad stays 13 rad
        q = np.array(q)
        th1, th2 = q[0] + psi1, q[0] + q[1] + psi1 + psi2
        poses = cfg.link_poses(q)
        np.testing.assert_allclose(poses[order, 2], [0.0, th1, th2, th2 + psi3], atol=1e-13)
        # link origins: link1 at (0.1, -0.2); link2 at its tip L1 e(th1); link3 at L2 e(th2) further
        o1 = np.array([0.1, -0.2])
        o2 = o1 + rot(th1) @ [0.5, 0.0]
        o3 = o2 + rot(th2) @ [0.4, 0.0]
        np.testing.assert_allclose(poses[order[1:], :2], [o1, o2, o3], atol=1e-13)


def test_free_bar_angle_map(configuration):
    _, cfg = configuration({"f.urdf": free_bar_urdf(1.0, 0.4)}, q0={"P": [0.0, 0.0, 0.0]},
                           v0={"P": [0.0, 0.0, 0.0]})
    np.testing.assert_allclose(cfg.A[cfg.link_index["bar"]], [0, 0, 1])
    assert cfg.b[cfg.link_index["bar"]] == 0.0
    assert cfg.nv == 3 and cfg.model.nq == 4


# ---- free planar bar --------------------------------------------------------------------------
FREE_STATES = [((0.0, 1.0, 0.0), (0.0, 0.0, 0.0)), ((0.3, -0.4, 0.8), (1.0, 0.5, 2.0)),
               ((-1.0, 2.0, -2.5), (-3.0, 0.2, -7.0))]


@pytest.mark.parametrize("com", [(0.0, 0.0), (0.1, -0.03)])
@pytest.mark.parametrize("q,v", FREE_STATES)
def test_free_bar_falls_with_g_and_keeps_its_spin(configuration, com, q, v):
    """Newton-Euler for a free body under gravity only: a_c = (0, -g), omega' = 0.

    pcmm's velocity of a planar joint is Pinocchio's, (vx, vy) in the bar's frame, so the
    joint origin's world acceleration is R (v_l' + omega k x v_l) and the centroid's
    a_c = a_origin + omega' k x r - omega^2 r, r = R c."""
    _, cfg = configuration({"f.urdf": free_bar_urdf(0.8, 0.5, com=com)}, q0={"P": [0.0, 0.0, 0.0]},
                           v0={"P": [0.0, 0.0, 0.0]})
    q, v = np.array(q), np.array(v)
    a, _ = cfg.coords.accelerations(0.0, q, v)
    R = rot(q[2])
    w = v[2]
    a_origin = R @ (a[:2] + w * np.array([-v[1], v[0]]))
    r = R @ np.array(com)
    a_c = a_origin + a[2] * np.array([-r[1], r[0]]) - w * w * r
    np.testing.assert_allclose(a_c, [0.0, -G], atol=1e-12)
    assert abs(a[2]) < 1e-12


@pytest.mark.parametrize("com", [(0.0, 0.0), (0.12, 0.04)])
def test_free_bar_flight_is_a_parabola(make_scene, com):
    """Integrated flight: the centroid follows r0 + v0 t + g t^2 / 2, theta = theta0 + omega t."""
    x0, y0, th0 = 0.2, 1.0, 0.3
    vl = np.array([1.0, 0.5])  # bar-frame velocity of the joint origin
    w, T = 2.0, 0.6
    path = make_scene({"f.urdf": free_bar_urdf(1.0, 0.4, com=com)}, q0={"P": [x0, y0, th0]},
                      v0={"P": [*vl, w]}, t_end=T)
    traj = pcmm.simulate(pcmm.load_scene(path))
    c = np.array(com)
    rc0 = np.array([x0, y0]) + rot(th0) @ c
    r0 = rot(th0) @ c
    vc0 = rot(th0) @ vl + w * np.array([-r0[1], r0[0]])
    th = th0 + w * T
    rc = rc0 + vc0 * T + 0.5 * np.array([0.0, -G]) * T ** 2
    seg = traj.segments[-1]
    assert seg.t[-1] == pytest.approx(T, abs=1e-15)
    np.testing.assert_allclose(seg.q[-1, 2], th, atol=1e-9)
    np.testing.assert_allclose(seg.q[-1, :2] + rot(th) @ c, rc, atol=1e-9)
    # velocity: world centroid velocity vc0 + g T, spin unchanged (the recorded v of a planar
    # joint is the rate of its coordinates: the origin's velocity in world axes)
    r = rot(th) @ c
    vc = seg.v[-1, :2] + seg.v[-1, 2] * np.array([-r[1], r[0]])
    np.testing.assert_allclose(vc, vc0 + np.array([0.0, -G]) * T, atol=1e-9)
    np.testing.assert_allclose(seg.v[-1, 2], w, atol=1e-10)
    # energy: T + V constant in a conservative flight
    E = seg.kinetic + seg.potential
    np.testing.assert_allclose(E, E[0], atol=1e-8 * max(1.0, abs(E[0])))


def test_springs_conserve_energy_along_the_run(make_scene):
    """Gravity and springs only (on a joint, on a relative angle, on an absolute angle):
    T + V_gravity + sum k (x - rest)^2 / 2 is a first integral."""
    forces = [
        {"name": "s1", "type": "spring", "on": {"joint": "J1"}, "measure": {"joint": "J1"}, "k": 4.0, "rest": 0.3},
        {"name": "s2", "type": "spring", "on": {"joint": "J2"}, "measure": {"between": ["link1", "link2"]},
         "k": 2.5, "rest": -0.2},
        {"name": "s3", "type": "spring", "on": {"link": "link2"}, "measure": {"link": "link2"}, "k": 1.5},
    ]
    path = make_scene({"d.urdf": chain_urdf([B1, B2])}, q0={"J1": 0.4, "J2": -0.8}, v0={"J1": 1.0, "J2": -2.0},
                      forces=forces, t_end=1.5)
    traj = pcmm.simulate(pcmm.load_scene(path))
    seg = traj.segments[0]
    # spring energy by hand from the recorded coordinates
    q1, q2 = seg.q[:, 0], seg.q[:, 1]
    th2 = q1 + q2 + B1.yaw + B2.yaw
    V_springs = 0.5 * 4.0 * (q1 - 0.3) ** 2 + 0.5 * 2.5 * (q2 + PSI2 + 0.2) ** 2 + 0.5 * 1.5 * th2 ** 2
    # gravity energy by hand: V = m1 g y_c1 + m2 g y_c2
    th1 = q1 + B1.yaw
    (c1x, c1y), (c2x, c2y) = B1.c, B2.c
    y1 = c1x * np.sin(th1) + c1y * np.cos(th1)
    y2 = B1.length * np.sin(th1) + c2x * np.sin(th2) + c2y * np.cos(th2)
    V_grav = G * (B1.mass * y1 + B2.mass * y2)
    np.testing.assert_allclose(seg.potential, V_springs + V_grav, atol=1e-12)
    E = seg.kinetic + seg.potential
    assert np.ptp(E) < 1e-8 * max(1.0, float(np.max(np.abs(E))))
    assert np.ptp(seg.kinetic) > 0.1  # the motion is not trivial
