"""A pin strike in double support: the other foot is held by the source and by the target.

The mechanism: a compass walker of two uniform legs (m, L, I_G = m L^2 / 12 each) hinged at the hip,
leg 1 on a planar joint (its foot A at its origin), leg 2 on the revolute hip joint J2 (its foot B at
its tip), gravity (0, -g).  It stands on A (``single_a``: A pinned where it is, held by compression
only, no slip) and swings B down onto the ground: a ``pin`` strike of B into ``double`` (A and B
pinned: 4 rows on 4 coordinates, the walker locked).  ``single_b`` holds B alone.

By hand (momentum balances, not pcmm's Schur complement), with H_P = I_G w + m (G - P) x v_G:

* both feet held: every velocity after is zero, and the impulses P_A, P_B on the feet follow from
  the angular momentum of the whole walker about B, -H_B(-) = (A - B) x P_A, and of leg 1 about
  the hip, -H1_hip(-) = (A - hip) x P_A (the hip's impulse on leg 1 acts at the hip);
* A released (no impulse at A), B held: the angular momentum of the walker about B and of leg 1
  about the hip are kept, two linear equations for (w1+, w2+); A's velocity after is then
  v_hip+ + w1+ z x (A - hip).

A ground point held by compression only can only push: where holding A would take a tensile impulse
(P_A . n < 0), A leaves the ground at the strike (and its normal velocity after is >= 0: exactly one
of the two outcomes is consistent, the complementarity of a unilateral contact).  Before this was
checked, pcmm applied the tensile impulse and locked the walker (foot_a's impulse -1.17 N s).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from builders import Bar, chain_urdf

import pcmm

L, M = 1.0, 1.0
I_G = M * L * L / 12
STANCE = 0.3  # A's horizontal distance from the hip at the start (the legs' half-spread)


def _e(th):
    return np.array([math.cos(th), math.sin(th)])


def _cross(a, b):
    return float(a[0] * b[1] - a[1] * b[0])


def _z(w, r):  # w z x r
    return w * np.array([-r[1], r[0]])


def _points(q):
    """(A, G1, hip, G2, B, theta1, theta2) at q = [x_A, y_A, theta1, q2]."""
    A = np.array(q[:2], float)
    th1, th2 = q[2], q[2] + q[3]
    hip = A + L * _e(th1)
    return A, A + 0.5 * L * _e(th1), hip, hip + 0.5 * L * _e(th2), hip + L * _e(th2), th1, th2


def _momenta(q, w1, w2, v_A):
    """(H of the walker about B, H of leg 1 about the hip) at rates w1, w2 (absolute) and A's velocity."""
    A, G1, hip, G2, B, _, _ = _points(q)
    vG1 = v_A + _z(w1, G1 - A)
    v_hip = v_A + _z(w1, hip - A)
    vG2 = v_hip + _z(w2, G2 - hip)
    H_B = I_G * w1 + M * _cross(G1 - B, vG1) + I_G * w2 + M * _cross(G2 - B, vG2)
    H1_hip = I_G * w1 + M * _cross(G1 - hip, vG1)
    return H_B, H1_hip


def locked_impulse_at_A(q, w1, w2):
    """P_A (world) if both feet held (every velocity after zero): by hand, above."""
    A, _, hip, _, B, _, _ = _points(q)
    H_B, H1 = _momenta(q, w1, w2, np.zeros(2))
    # (A - B) x P = -H_B, (A - hip) x P = -H1: r x P = r_x P_y - r_y P_x
    r1, r2 = A - B, A - hip
    return np.linalg.solve([[-r1[1], r1[0]], [-r2[1], r2[0]]], [-H_B, -H1])


def released_A(q, w1, w2):
    """(w1+, w2+, A's velocity after) with A released and B pinned: by hand, above."""
    A, _, hip, _, B, _, _ = _points(q)
    H_B, H1 = _momenta(q, w1, w2, np.zeros(2))
    # after: B fixed, so v_hip = w2 z x (hip - B); H is linear in (w1, w2) with v_A = v_hip + w1 z x (A - hip)

    def after(a, b):
        v_hip = _z(b, hip - B)
        return _momenta(q, a, b, v_hip + _z(a, A - hip))
    cols = np.array([after(1.0, 0.0), after(0.0, 1.0)]).T
    w1p, w2p = np.linalg.solve(cols, [H_B, H1])
    v_A = _z(w2p, hip - B) + _z(w1p, A - hip)
    return w1p, w2p, v_A


def bounce_on_A(q, w1, w2, e):
    """(w1+, w2+, P_B, P_A) of B striking the ground frictionless with restitution e while A stays
    pinned: the walker's angular momentum about A and leg 2's about the hip change by B's impulse
    (0, P_B) only, B's normal velocity after is -e times before; P_A is the rest of the momentum change."""
    A, G1, hip, G2, B, _, _ = _points(q)

    def state(a, b):  # (H about A, H2 about the hip, vB_y, total momentum) at rates a, b with A fixed
        vG1, v_hip = _z(a, G1 - A), _z(a, hip - A)
        vG2, vB = v_hip + _z(b, G2 - hip), v_hip + _z(b, B - hip)
        H_A = I_G * a + M * _cross(G1 - A, vG1) + I_G * b + M * _cross(G2 - A, vG2)
        H2 = I_G * b + M * _cross(G2 - hip, vG2)
        return np.array([H_A, H2, vB[1]]), M * (vG1 + vG2)
    (H_A, H2, vB_y), p0 = state(w1, w2)
    c1, c2 = state(1.0, 0.0)[0], state(0.0, 1.0)[0]
    # [c1 c2 -lever] (w1+, w2+, P) = (H_A, H2, -e vB_y), the levers (B - A) x (0, 1) and (B - hip) x (0, 1)
    K = np.array([[c1[0], c2[0], -(B - A)[0]], [c1[1], c2[1], -(B - hip)[0]], [c1[2], c2[2], 0.0]])
    w1p, w2p, P_B = np.linalg.solve(K, [H_A, H2, -e * vB_y])
    P_A = state(w1p, w2p)[1] - p0 - np.array([0.0, P_B])
    return w1p, w2p, P_B, P_A


def walker(make_scene, w1, w2, target="double", configurations=("single_a", "double", "single_b"), t_end=0.05,
           bounce=None, stance=STANCE):
    """The walker on A, its feet ``stance`` from the hip across, leg 1 leaning 0.02 rad back from that
    posture, turning at w1 and leg 2 at w2 (absolute rates), B above the ground, with a pin strike of B
    into ``target`` (or a bounce off the ground)."""
    th1 = math.acos(stance / L) + 0.02
    th2 = -math.acos(stance / L)

    def pin_(name, link, x):
        return {"name": name, "type": "revolute", "a": "frame", "point_a": "entry", "b": link, "point_b": [x, 0.0],
                "contact": {"normal": [0.0, 1.0], "friction": "stick"}}
    fa, fb = pin_("foot_a", "link1", 0.0), pin_("foot_b", "link2", L)
    cuts = {"single_a": [fa], "double": [fa, fb], "single_b": [fb]}
    land = {"name": "B lands", "type": "pin", "from": "single_a", "to": target,
            "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"},
            "contact": {"a": "frame", "point_a": [0.0, 0.0], "b": "link2", "point_b": [L, 0.0], "normal": [0.0, 1.0],
                        "friction": "stick"}}
    if bounce is not None:  # B bounces off the ground (a stop, frictionless, restitution ``bounce``) instead
        land = {"name": "B hits", "type": "stop", "from": "single_a", "restitution": bounce, "cut": [],
                "guard": land["guard"], "contact": {**land["contact"], "friction": None}}
        del land["contact"]["friction"]
    return make_scene({"c.urdf": chain_urdf([Bar(L, M, joint="planar"), Bar(L, M)])},
                      configurations={c: {"urdf": "c.urdf", "cut_joints": cuts[c]} for c in configurations},
                      q0={"J1": [0.0, 0.0, th1], "J2": th2 - th1}, v0={"J1": [0.0, 0.0, w1], "J2": w2 - w1},
                      independent=["J1.theta", "J2"], t_end=t_end, transitions=[land],
                      solver={"rtol": 1e-11, "atol": 1e-12})


def _strike_state(traj):
    seg = traj.segments[0]
    assert seg.configuration == "single_a"
    q, v = seg.q[-1], seg.v[-1]
    return q, v[2], v[2] + v[3]


def test_a_held_foot_that_would_be_pulled_is_released_at_the_strike(make_scene):
    """Leg 1 falling forward (w1 = -1 rad/s), leg 2 still: holding A would pull it (by hand); A is
    released in the same event, the walker continues on B ('single_b') with the rates by hand."""
    traj = pcmm.simulate(pcmm.load_scene(walker(make_scene, -1.0, 0.0)))
    q, w1, w2 = _strike_state(traj)
    P_A = locked_impulse_at_A(q, w1, w2)
    assert P_A[1] < -0.5  # tensile by hand (-1.17 N s): A cannot be held
    w1p, w2p, v_A = released_A(q, w1, w2)
    assert v_A[1] > 0.1  # ... and released, A leaves the ground: the consistent outcome
    strike = traj.events[0]
    assert strike["name"] == "B lands" and strike["to"] == "single_b"
    assert strike["released"]["foot_a"]["normal_velocity_after"] == pytest.approx(v_A[1], rel=1e-9)
    assert strike["released"]["foot_a"]["impulse"] == 0.0
    after = strike["v_after"]
    assert after["J1"][2] == pytest.approx(w1p, rel=1e-9)
    assert after["J1"][2] + after["J2"] == pytest.approx(w2p, rel=1e-9)
    assert traj.segments[1].configuration == "single_b" and traj.segments[1].t[0] == strike["t"]


def test_a_held_foot_that_pushes_stays_held(make_scene):
    """Leg 2 swinging back onto the ground fast (w2 = -4 rad/s), leg 1 slowly (w1 = -0.5 rad/s): holding A takes a
    compressive impulse (by hand), so both feet stay held and the walker stops dead ('double')."""
    traj = pcmm.simulate(pcmm.load_scene(walker(make_scene, -0.5, -4.0)))
    q, w1, w2 = _strike_state(traj)
    P_A = locked_impulse_at_A(q, w1, w2)
    assert P_A[1] > 0.05
    assert released_A(q, w1, w2)[2][1] < -0.05  # released, A would be driven into the ground: inconsistent
    strike = traj.events[0]
    assert strike["to"] == "double" and strike["released"] == {}
    np.testing.assert_allclose(strike["constraint_impulses"]["foot_a"][:2], P_A, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(strike["v_after"]["J1"], 0.0, atol=1e-12)
    assert strike["v_after"]["J2"] == pytest.approx(0.0, abs=1e-12)


def test_without_a_configuration_to_release_into_the_strike_stops_with_the_reason(make_scene):
    """No 'single_b': the tensile impulse is not applied silently; the run stops at the strike,
    naming the foot, its impulse and the configuration to add."""
    path = walker(make_scene, -1.0, 0.0, configurations=("single_a", "double"))
    with pytest.raises(pcmm.SimulationError) as caught:
        pcmm.simulate(pcmm.load_scene(path))
    text = str(caught.value)
    assert "'B lands'" in text and "'foot_a'" in text and "pulled" in text
    assert "'double'" in text and "without 'foot_a'" in text
    assert caught.value.partial.segments[-1].configuration == "single_a"


@pytest.mark.parametrize("w1, w2, stance, pulled", [(-1.0, 0.0, STANCE, True), (0.0, -2.0, 0.7, False)])
def test_a_bounce_that_would_pull_a_held_foot_stops_with_the_reason(make_scene, w1, w2, stance, pulled):
    """B bouncing off the ground (a stop, e = 0.5) while A stays pinned.  Where the bounce's impulse on
    A is compressive (by hand) the run bounces with it; where it is tensile, A would leave the ground
    in the same impact, which a stop does not resolve: the run stops there, naming A and its impulse,
    instead of pulling it silently.  (With B frictionless the ratio P_A / P_B is the walker's geometry's:
    tensile with the feet 0.3 m from the hip across, compressive at 0.7 m.)"""
    path = walker(make_scene, w1, w2, configurations=("single_a",), bounce=0.5, t_end=0.03, stance=stance)
    if not pulled:
        traj = pcmm.simulate(pcmm.load_scene(path))
        q, a, b = _strike_state(traj)
        w1p, w2p, P_B, P_A = bounce_on_A(q, a, b, 0.5)
        assert P_A[1] > 0.05 and P_B > 0
        hit = traj.events[0]
        assert hit["name"] == "B hits" and hit["impulse"]["normal"] == pytest.approx(P_B, rel=1e-9)
        np.testing.assert_allclose(hit["constraint_impulses"]["foot_a"][:2], P_A, rtol=1e-9, atol=1e-12)
        assert hit["v_after"]["J1"][2] == pytest.approx(w1p, rel=1e-9)
        return
    with pytest.raises(pcmm.SimulationError) as caught:
        pcmm.simulate(pcmm.load_scene(path))
    seg = caught.value.partial.segments[-1]
    q, a, b = seg.q[-1], seg.v[-1][2], seg.v[-1][2] + seg.v[-1][3]
    P_A = bounce_on_A(q, a, b, 0.5)[3]
    assert P_A[1] < -0.05  # tensile by hand
    text = str(caught.value)
    assert "'B hits'" in text and "'foot_a'" in text and "pull" in text
    assert f"{P_A[1]:.4g}" in text
