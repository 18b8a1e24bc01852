"""A sticking stop's split of the energy lost is Routh's (task h-stick, issue 22: no silent wrong number).

A ``stop`` with ``friction = "stick"`` takes the impulse P = D^-1 (-v_t^-, -(1 + e) v_n^-) (no slip,
Newton's restitution).  What its normal and its tangential part did is Routh's process in the limit
mu -> infinity (pcmm.events.friction.stuck_at_once): the slip is stopped at p = 0+ by the tangential
impulse -v_t^- / D_tt, so friction dissipates v_t^-^2 / (2 D_tt) >= 0, and the point then sticks
(dv_n/dp = D_nn - D_tn^2 / D_tt) from v_n1 = v_n^- - D_tn v_t^- / D_tt to -e v_n^-, the normal part
losing (v_n1^2 - e^2 v_n^-^2) / (2 (D_nn - D_tn^2 / D_tt)).  The split used to be the proportional
path's P_i (v_i^- + v_i^+) / 2, whose tangential part is -P_t v_t^- / 2: negative, friction feeding
energy in, whenever P_t has the sign of the slip (here: -0.562 J).

The mechanism: a double pendulum (two uniform bars, 0.5 m, 1 kg, no gravity) whose tip strikes an
oblique wall (normal at 255 deg) with stick friction and e = 0.5, from a state 2 mm before the wall.
Its mass matrix and the tip's Jacobian are written by hand (closed forms), not taken from pcmm.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from builders import Bar, chain_urdf

import pcmm
from pcmm.errors import SimulationError
from pcmm.events.friction import AmbiguousImpact, stick_impulse, stuck_at_once

L, MASS, E = 0.5, 1.0, 0.5
Q0, V0 = (-0.1, 0.6), (2.0, -0.7)
WALL = math.radians(255.0)


def mass_matrix(q):
    """Two uniform bars (m, L, I = m L^2 / 12) on revolute joints, the second at the first's tip."""
    I, c2 = MASS * L * L / 12, math.cos(q[1])
    m12 = I + MASS * (L * L / 4 + L * L / 2 * c2)
    return np.array([[2 * I + MASS * L * L / 4 + MASS * (L * L + L * L / 4 + L * L * c2), m12],
                     [m12, I + MASS * L * L / 4]])


def tip(q):
    return L * np.array([math.cos(q[0]) + math.cos(q[0] + q[1]), math.sin(q[0]) + math.sin(q[0] + q[1])])


def tip_jacobian(q):
    s1, s12, c1, c12 = math.sin(q[0]), math.sin(q[0] + q[1]), math.cos(q[0]), math.cos(q[0] + q[1])
    return L * np.array([[-s1 - s12, -s12], [c1 + c12, c12]])


def wall_scene(make_scene, friction="stick", law=None):
    n = np.array([math.cos(WALL), math.sin(WALL)])
    contact = {"a": "frame", "point_a": [*(tip(Q0) - 0.002 * n)], "b": "link2", "point_b": [L, 0.0],
               "normal": [*n], "friction": friction}
    if law is not None:
        contact["restitution_law"] = law
    tr = {"name": "tip strikes wall", "type": "stop", "from": "c1", "restitution": E, "cut": [],
          "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"}, "contact": contact}
    return make_scene({"dp.urdf": chain_urdf([Bar(L, MASS)] * 2)}, q0={"J1": Q0[0], "J2": Q0[1]},
                      v0={"J1": V0[0], "J2": V0[1]}, gravity=(0.0, 0.0), t_end=0.01, transitions=[tr],
                      solver={"rtol": 1e-12, "atol": 1e-13})


def test_sticking_stop_splits_its_loss_by_routh(make_scene):
    traj = pcmm.simulate(pcmm.load_scene(wall_scene(make_scene)))
    ev = traj.events[0]
    assert ev["name"] == "tip strikes wall" and ev["friction"]["mu"] == "stick"
    q = np.asarray(traj.segments[0].q[-1])  # the posture at the strike
    n = np.array([math.cos(WALL), math.sin(WALL)])
    t = np.array([n[1], -n[0]])
    assert n @ tip(q) == pytest.approx(n @ tip(Q0) - 0.002, abs=1e-10)  # on the wall
    M, J = mass_matrix(q), tip_jacobian(q)
    Jc = np.vstack([t @ J, n @ J])
    vm = np.array([ev["v_before"][j] for j in ("J1", "J2")]).ravel()
    D = Jc @ np.linalg.solve(M, Jc.T)
    vt, vn = Jc @ vm
    # impulse and momentum by hand: the tip sticks and leaves at -e vn
    P = np.linalg.solve(D, [-vt, -(1 + E) * vn])
    vp = vm + np.linalg.solve(M, Jc.T @ P)
    assert ev["impulse"]["tangential"] == pytest.approx(P[0], abs=1e-10)
    assert ev["impulse"]["normal"] == pytest.approx(P[1], abs=1e-10)
    lost = 0.5 * vm @ M @ vm - 0.5 * vp @ M @ vp
    assert ev["kinetic_energy_before"] - ev["kinetic_energy_after"] == pytest.approx(lost, abs=1e-10)
    # the mechanism is one where the proportional split reads as friction feeding energy in
    assert P[0] * vt > 0 and -0.5 * P[0] * vt == pytest.approx(-0.562, abs=1e-3)
    # Routh's process with no slip, by hand
    friction_lost = 0.5 * vt * vt / D[0, 0]
    vn1 = vn - D[0, 1] * vt / D[0, 0]
    slope = D[1, 1] - D[0, 1] ** 2 / D[0, 0]
    normal_lost = (vn1 ** 2 - E * E * vn ** 2) / (2 * slope)
    assert vn1 < 0 and friction_lost + normal_lost == pytest.approx(lost, rel=1e-12)
    fr = ev["friction"]
    assert fr["phases"] == "stick"
    assert fr["slip"]["before"] == pytest.approx(vt, abs=1e-10) and fr["slip"]["after"] == pytest.approx(0, abs=1e-10)
    assert fr["energy_lost"]["tangential"] == pytest.approx(friction_lost, rel=1e-9)
    assert fr["energy_lost"]["tangential"] > 0.05
    assert fr["energy_lost"]["normal"] == pytest.approx(normal_lost, rel=1e-9)
    assert fr["energy_lost"]["normal"] + fr["energy_lost"]["tangential"] == pytest.approx(
        ev["kinetic_energy_before"] - ev["kinetic_energy_after"], rel=1e-12)


def test_sticking_stop_with_a_poisson_law_takes_rouths_limit(make_scene):
    """Poisson's law in Routh's stick limit ends at v_n = -e v_n1, v_n1 = v_n^- - D_tn v_t^- / D_tt (task
    h-stickpoisson; before, the event kept Newton's -e v_n^- and gave no split): the run leaves at
    -e v_n1 and splits its loss by that process (tests/test_stick_law.py derives it by hand)."""
    ev = pcmm.simulate(pcmm.load_scene(wall_scene(make_scene, law="poisson"))).events[0]
    fr = ev["friction"]
    assert fr["law"] == "poisson" and fr["phases"] == "stick"
    vt, vn = fr["slip"]["before"], ev["normal_velocity"]["before"]
    assert vn == pytest.approx(-1.4545, abs=1e-4) and vt == pytest.approx(0.6106, abs=1e-4)
    assert ev["normal_velocity"]["after"] != pytest.approx(-E * vn, rel=1e-3)  # not Newton's
    assert fr["energy_lost"]["normal"] + fr["energy_lost"]["tangential"] == pytest.approx(
        ev["kinetic_energy_before"] - ev["kinetic_energy_after"], rel=1e-12)


def test_stuck_at_once_against_routh_at_large_mu():
    """The limit itself: Routh's process at mu = 1e7 (slide, then stick) converges to stuck_at_once's
    impulse and works, for each law; stick_impulse keeps its impulse and takes the limit's works."""
    from pcmm.events.friction import routh
    D = np.array([[2.01383988, -1.42150164], [-1.42150164, 1.58086658]])
    vt, vn = 0.6097403360862746, -1.457275890808593
    for law in ("newton", "poisson", "energetic"):
        lim, big = stuck_at_once(D, vt, vn, E, law), routh(D, vt, vn, 1e7, E, law)
        np.testing.assert_allclose(lim.P, big.P, rtol=1e-6)
        assert lim.work_tangential == pytest.approx(big.work_tangential, rel=1e-6)
        assert lim.work_normal == pytest.approx(big.work_normal, rel=1e-6)
        # the sum is the kinetic energy change of the limit's impulse: P . (v- + v+) / 2
        v_after = np.array([vt, vn]) + D @ lim.P
        assert lim.work_normal + lim.work_tangential == pytest.approx(0.5 * lim.P @ (np.array([vt, vn]) + v_after),
                                                                      rel=1e-12)
    fr = stick_impulse(D, vt, vn, E)
    np.testing.assert_array_equal(fr.P, np.linalg.solve(D, [-vt, -(1 + E) * vn]))
    assert fr.work_tangential == -0.5 * vt * vt / D[0, 0] and fr.no_split is None
    # a slip whose stop already separates the point (v_n1 = v_n - D_tn v_t / D_tt >= 0): no compression,
    # no split; the impulse stays compressive while v_n1 <= -e v_n (4 v_t: v_n1 = 0.264 m/s <= 0.729 m/s)
    vn1 = vn - D[0, 1] * 4 * vt / D[0, 0]
    assert 0 < vn1 < -E * vn
    with pytest.raises(AmbiguousImpact, match="separating"):
        stuck_at_once(D, 4 * vt, vn, E)
    fr = stick_impulse(D, 4 * vt, vn, E)
    assert fr.no_split.startswith("Routh's process with no slip has no answer") and fr.work_normal is None
    assert fr.P_n == pytest.approx((-E * vn - vn1) / (D[1, 1] - D[0, 1] ** 2 / D[0, 0]), rel=1e-12) and fr.P_n > 0
    # beyond it (10 v_t: v_n1 = 2.85 m/s > -e v_n) the no-slip impulse would pull: refused
    with pytest.raises(AmbiguousImpact, match="pulling normal impulse"):
        stick_impulse(D, 10 * vt, vn, E)


def test_sticking_stop_that_would_pull_is_refused(make_scene, monkeypatch):
    """A stop with no slip whose slip's stop already moves the tip away faster than Newton's -e v_n^-:
    the stick impulse W^-1 (-v_t, -(1 + e) v_n) has P_n < 0 (by hand at the start, 2 mm before the wall: -0.1514 N s; at the wall -0.147), a wall pulling the tip
    back, which pcmm applied silently.  Refused, naming the pull; with a finite mu (Routh's process)
    the same strike runs, its impulse compressive and its friction share >= 0."""
    import test_stick_split as here
    monkeypatch.setattr(here, "Q0", (-0.392, -1.245))
    monkeypatch.setattr(here, "V0", (-1.839, -1.717))
    monkeypatch.setattr(here, "WALL", math.radians(309.1))
    n = np.array([math.cos(here.WALL), math.sin(here.WALL)])
    t = np.array([n[1], -n[0]])
    Jc = np.vstack([t @ tip_jacobian(here.Q0), n @ tip_jacobian(here.Q0)])
    D = Jc @ np.linalg.solve(mass_matrix(here.Q0), Jc.T)
    vt, vn = Jc @ np.array(here.V0)
    assert np.linalg.solve(D, [-vt, -(1 + E) * vn])[1] == pytest.approx(-0.1514, abs=1e-4)  # at the start, 2 mm before
    with pytest.raises(SimulationError, match=r"tip strikes wall.*pulling normal impulse \(P_n = -0\.147"):
        pcmm.simulate(pcmm.load_scene(wall_scene(make_scene)))
    ev = pcmm.simulate(pcmm.load_scene(wall_scene(make_scene, friction=2.0))).events[0]
    assert ev["impulse"]["normal"] > 0 and ev["friction"]["energy_lost"]["tangential"] >= 0
    assert ev["friction"]["energy_lost"]["normal"] + ev["friction"]["energy_lost"]["tangential"] == pytest.approx(
        ev["kinetic_energy_before"] - ev["kinetic_energy_after"], rel=1e-9)


def test_no_example_reports_friction_feeding_energy():
    """Every event of every shipped example with a frictional contact (a stop's or a pin's): friction's
    share of the energy lost is >= 0 (to round-off) and the shares sum to the kinetic energy lost;
    where an event gives no split it says why.  Examples without friction have no friction block."""
    from pathlib import Path
    root = Path(__file__).resolve().parents[1] / "examples"
    checked = 0
    for path in sorted(root.glob("*.toml")):
        if "friction" not in path.read_text():
            continue
        for ev in pcmm.simulate(pcmm.load_scene(path)).events:
            fr = ev.get("friction")
            if fr is None:
                continue
            lost = ev["kinetic_energy_before"] - ev["kinetic_energy_after"]
            if fr["energy_lost"] is None:
                assert fr["energy_split"].startswith("none: "), (path.name, ev["t"])
                continue
            scale = max(ev["kinetic_energy_before"], 1e-300)
            assert fr["energy_lost"]["tangential"] >= -1e-12 * scale, (path.name, ev["name"], ev["t"], fr)
            assert fr["energy_lost"]["normal"] + fr["energy_lost"]["tangential"] == pytest.approx(lost, abs=1e-9 * scale)
            checked += 1
    assert checked >= 20  # the compass gait's and the rimless wheel's strikes
