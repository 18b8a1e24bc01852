"""Issue 24, item 3: a point pinned by compression only lifts off by itself where its normal
force turns tensile, into the scene's configuration without its cut joint (no release written).

The mechanism: a uniform rod (m, L, I_G = m L^2 / 12) on a planar joint, its lower end A pinned on
a surface whose normal n = (sin beta, cos beta) leans by beta (a revolute cut joint anchored at
entry, held by compression only, no slip), gravity (0, -g).  The rod leans at phi from the
vertical and falls forward (phi' = w > 0).  By hand, about the fixed pivot A (I_A = m L^2 / 3),
with d = G - A = (L/2)(sin phi, cos phi):

* energy: w^2 = w0^2 + (3 g / L)(cos phi0 - cos phi);  moments about A: phi'' = (3 g / (2 L)) sin phi;
* a_G = (L/2)[phi'' (cos phi, -sin phi) - w^2 (sin phi, cos phi)] and the force on the rod at A,
  F = m (a_G - g_vec), so along n and t = (n_y, -n_x) = (cos beta, -sin beta):

      N   / m = g cos beta - (L/2)[phi'' sin(phi - beta) + w^2 cos(phi - beta)],
      F_t / m = (L/2)[phi'' cos(phi - beta) - w^2 sin(phi - beta)] - g sin beta;

  on flat ground (beta = 0), with c = cos phi and B = L w0^2 / (2 g) + (3/2) c0, this is
  N / (m g) = (9/4) c^2 - B c + 1/4, zero first at c* = (B + sqrt(B^2 - 9/4)) / (9/2);
* the lift-off angle phi* is N's first zero (brentq on the formula above), its time the quadrature
  t* = int_phi0^phi* dphi / w(phi) (scipy.integrate.quad: an independent route to the run's event);
* freed there the rod flies (G falls with g, no moment about G), so A's acceleration is
  g_vec + w^2 d; its normal part n . (g_vec + w^2 d) = -g cos beta + w^2 (L/2) cos(phi - beta) is,
  with N = 0, -(3 g / 4) sin phi sin(phi - beta): the point leaves only with the centre between the surface's
  normal and the vertical through A (0 < phi < beta).  On flat ground it would be pushed back
  into the surface (it would slide: the tangential force the pin held is gone), which pcmm
  refuses with that message; on a surface leaning by beta = 0.5 it lifts off.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

import pcmm
from builders import free_bar_urdf, rot
from pcmm.errors import SimulationError

M, L, G_ = 1.0, 1.0, 9.81
PHI0 = 0.05
BETA, W0 = 0.5, 4.0  # lifts off at phi* = 0.376 < beta
FLAT_W0 = 2.0  # on flat ground


def by_hand(phi, phi0, w0, beta):
    """(N, F_t, w, a_n after release) at phi, by the formulas above (per unit mass times m)."""
    w2 = w0 ** 2 + 3 * G_ / L * (math.cos(phi0) - math.cos(phi))
    dd = 1.5 * G_ / L * math.sin(phi)
    N = M * (G_ * math.cos(beta) - 0.5 * L * (dd * math.sin(phi - beta) + w2 * math.cos(phi - beta)))
    Ft = M * (0.5 * L * (dd * math.cos(phi - beta) - w2 * math.sin(phi - beta)) - G_ * math.sin(beta))
    a_n = -G_ * math.cos(beta) + w2 * 0.5 * L * math.cos(phi - beta)
    return N, Ft, math.sqrt(w2), a_n


def closed_form(phi0=PHI0, w0=W0, beta=BETA):
    """(t*, phi*, w*): the lift-off by hand."""
    grid = np.linspace(phi0, math.pi / 2, 4000)
    N = np.array([by_hand(p, phi0, w0, beta)[0] for p in grid])
    i = int(np.argmax(N < 0))
    phi = brentq(lambda p: by_hand(p, phi0, w0, beta)[0], grid[i - 1], grid[i], xtol=1e-15, rtol=1e-15)
    t, _ = quad(lambda p: 1.0 / by_hand(p, phi0, w0, beta)[2], phi0, phi, epsabs=1e-14, epsrel=1e-13)
    return t, phi, by_hand(phi, phi0, w0, beta)[2]


def rod_scene(make_scene, flight=True, phi0=PHI0, w0=W0, beta=BETA, t_end=None, friction="stick"):
    theta0 = math.pi / 2 - phi0  # the bar's x axis from A to B; phi grows as theta falls
    xg, yg = 0.5 * L * math.cos(theta0), 0.5 * L * math.sin(theta0)
    foot = {"name": "foot", "type": "revolute", "a": "frame", "point_a": "entry", "b": "bar", "point_b": [-L / 2, 0.0],
            "contact": {"normal": [math.sin(beta), math.cos(beta)], "friction": friction}}
    configs = {"pinned": {"urdf": "rod.urdf", "cut_joints": [foot]}}
    if flight:
        configs["flight"] = {"urdf": "rod.urdf"}
    # body-axes velocity of the planar joint: G moves at omega x (G - A), i.e. (0, theta' L / 2) in the bar's axes
    return make_scene({"rod.urdf": free_bar_urdf(M, L)}, configurations=configs,
                      q0={"P": [xg, yg, theta0]}, v0={"P": [0.0, -w0 * L / 2, -w0]}, gravity=(0.0, -G_),
                      t_end=t_end or closed_form(phi0, w0, beta)[0] + 0.05, solver={"rtol": 1e-12, "atol": 1e-13})


def test_closed_form_is_self_consistent():
    """On flat ground the root of N is the quadratic's c*; N > 0 before phi*, < 0 after (a
    crossing, not a touch: a rod from rest upright only touches N = 0, at cos phi = 1/3); on the
    leaning surface the lift-off falls inside 0 < phi* < beta."""
    c0 = math.cos(PHI0)
    B = L * FLAT_W0 ** 2 / (2 * G_) + 1.5 * c0
    _, phi, _ = closed_form(w0=FLAT_W0, beta=0.0)
    assert math.cos(phi) == pytest.approx((B + math.sqrt(B * B - 9 / 4)) / 4.5, abs=1e-13)
    assert by_hand(math.acos(1 / 3), 0.0, 0.0, 0.0)[0] == pytest.approx(0.0, abs=1e-14)  # the touch from rest
    for w0, beta in ((FLAT_W0, 0.0), (W0, BETA)):
        t, phi, w = closed_form(w0=w0, beta=beta)
        assert all(by_hand(p, PHI0, w0, beta)[0] > 0 for p in np.linspace(PHI0, phi - 1e-6, 200))
        assert by_hand(phi + 1e-3, PHI0, w0, beta)[0] < 0
    _, phi, _ = closed_form()
    assert 0 < phi < BETA and by_hand(phi, PHI0, W0, BETA)[3] > 0


def test_pinned_point_lifts_off_by_itself_at_the_closed_form(make_scene):
    t_star, phi_star, w_star = closed_form()
    _, Ft, _, a_n = by_hand(phi_star, PHI0, W0, BETA)
    traj = pcmm.simulate(pcmm.load_scene(rod_scene(make_scene)))
    assert [e["name"] for e in traj.events] == ["lift-off foot"]
    ev = traj.events[0]
    assert ev["transition"] == "release" and ev["from"] == "pinned" and ev["to"] == "flight"
    assert ev["cause"] == "tensile contact force" and ev["impact"] is False
    # the event time and posture: the closed form (the event is located to solver.event_tol on the
    # dense output; what remains is the integration's error)
    assert ev["t"] == pytest.approx(t_star, abs=1e-11)
    seg0, seg1 = traj.segments[0], traj.segments[1]
    assert seg0.configuration == "pinned" and seg1.configuration == "flight"
    q_lift = np.asarray(seg0.q[-1])
    assert q_lift[2] == pytest.approx(math.pi / 2 - phi_star, abs=1e-9)
    assert ev["omega_before"]["bar"] == pytest.approx(-w_star, abs=1e-9)
    lifted = ev["lifted"]["foot"]
    assert lifted["normal_force"] == pytest.approx(0.0, abs=1e-10)
    assert lifted["tangential_force"] == pytest.approx(Ft, abs=1e-9)
    assert lifted["anchor"] == pytest.approx([0.0, 0.0], abs=1e-12)
    assert lifted["normal_acceleration_after"] == pytest.approx(a_n, abs=1e-9)
    assert a_n == pytest.approx(-0.75 * G_ * math.sin(phi_star) * math.sin(phi_star - BETA), abs=1e-12)
    # no impulse, the velocity continuous: the event's, and the series' across the switch
    assert ev["impulse"]["normal"] == 0.0
    np.testing.assert_allclose(ev["v_after"]["P"], ev["v_before"]["P"], rtol=0, atol=1e-14)
    assert ev["kinetic_energy_after"] == pytest.approx(ev["kinetic_energy_before"], rel=1e-13)
    assert ev["velocity_jump_max"] <= 1e-14
    assert seg1.t[0] == seg0.t[-1]
    np.testing.assert_allclose(np.asarray(seg1.q[0]), q_lift, atol=1e-14)
    np.testing.assert_allclose(np.asarray(seg1.v[0]), np.asarray(seg0.v[-1]), atol=1e-13)
    # in flight the foot leaves the surface: its distance along n grows, from 0
    n = np.array([math.sin(BETA), math.cos(BETA)])

    def foot_gap(q):
        return float(n @ (q[:2] - 0.5 * L * np.array([math.cos(q[2]), math.sin(q[2])])))
    gaps = [foot_gap(np.asarray(q)) for q in seg1.q]
    assert gaps[0] == pytest.approx(0.0, abs=1e-12)
    assert all(b > a for a, b in zip(gaps[1:], gaps[2:])) and gaps[-1] > 1e-4


def test_lift_off_that_would_push_the_point_back_stops_the_run(make_scene):
    """On flat ground the rod's foot, freed where N = 0, would accelerate into the floor,
    -(3 g / 4) sin^2 phi*: the tangential force the pin held is gone and the foot would slide.
    The run stops at the lift-off instant with that cause."""
    t_star, phi_star, _ = closed_form(w0=FLAT_W0, beta=0.0)
    a_n = by_hand(phi_star, PHI0, FLAT_W0, 0.0)[3]
    assert a_n == pytest.approx(-0.75 * G_ * math.sin(phi_star) ** 2, abs=1e-12) and a_n < 0
    with pytest.raises(SimulationError, match=r"cut joint 'foot' lifts off.*pushed back into the surface \(normal "
                                              r"acceleration (-[0-9.]+) m/s\^2\).*slide") as err:
        pcmm.simulate(pcmm.load_scene(rod_scene(make_scene, w0=FLAT_W0, beta=0.0)))
    import re
    text = str(err.value)
    assert float(re.search(r"t = ([0-9.]+) s", text).group(1)) == pytest.approx(t_star, abs=1e-8)
    assert float(re.search(r"acceleration (-[0-9.]+)", text).group(1)) == pytest.approx(a_n, rel=1e-5)


def test_without_a_configuration_to_lift_into_the_run_stops_at_the_same_instant(make_scene):
    """The same rod with no configuration without the pin: the run stops where the force turns
    tensile, naming what to add."""
    t_star, _, _ = closed_form()
    with pytest.raises(SimulationError, match=r"cut joint 'foot' would lift off.*add a configuration with the "
                                              r"same URDF and drives and the cut joints of 'pinned' but 'foot'") as err:
        pcmm.simulate(pcmm.load_scene(rod_scene(make_scene, flight=False)))
    import re
    assert float(re.search(r"t = ([0-9.]+) s", str(err.value)).group(1)) == pytest.approx(t_star, abs=1e-8)


def test_a_point_pinned_with_a_tensile_force_from_the_start_lifts_off_at_once(make_scene):
    """Started past the lift-off (phi0 = 0.3, w0 = 4.5: N < 0 by hand), the pin never holds: the
    point is released at t = 0, before any step, and the rod flies (its foot leaving, by hand)."""
    N, _, _, a_n = by_hand(0.3, 0.3, 4.5, BETA)
    assert N < 0 and a_n > 0
    traj = pcmm.simulate(pcmm.load_scene(rod_scene(make_scene, phi0=0.3, w0=4.5, t_end=0.05)))
    assert [(e["name"], e["t"]) for e in traj.events] == [("lift-off foot", 0.0)]
    assert traj.events[0]["lifted"]["foot"]["normal_force"] == pytest.approx(N, rel=1e-9)
    assert traj.segments[-1].configuration == "flight"


def test_the_graph_draws_the_lift_off_before_and_after_the_run(make_scene):
    """The working-cycle graph has the lift-off pcmm adds (no transition written) as a release
    edge pinned -> flight, and the run's event lands on it."""
    from pcmm.results.trajectory import record_views
    from pcmm.viz.graph import edges, fired
    scene = pcmm.load_scene(rod_scene(make_scene))
    views = record_views(scene)
    assert [(e.name, e.kind, e.source, e.target) for e in edges(views)] == [("lift-off foot", "release", "pinned", "flight")]
    traj = pcmm.simulate(scene)
    (edge,) = fired(edges(views), traj.events)
    assert edge.times == [traj.events[0]["t"]]


def test_a_strike_whose_pin_would_pull_lifts_off_at_once(make_scene):
    """A spinning rod without gravity strikes the leaning surface with its foot A (a `pin`,
    flight -> pinned).  By hand: the impulse acts at A, so the angular momentum about A is kept,
    I_A w+ = I_G w- + m (d x v_G-), d = G - A = (L/2)(sin phi, cos phi); pinned, nothing turns the rod
    about A, so G circles A and the surface pulls on it, F = -m w+^2 d: N = -m w+^2 (L/2) cos(phi - beta)
    < 0 and F_t = -m w+^2 (L/2) sin(phi - beta).  The pin holds no instant: the point lifts off at
    the strike's instant, with no impulse, and freed leaves the surface at n . (w+^2 d) > 0."""
    phi, w_minus, V, t_hit = 0.2, -6.0, 1.0, 0.01
    I_G, I_A = M * L * L / 12, M * L * L / 3
    d = 0.5 * L * np.array([math.sin(phi), math.cos(phi)])
    vG = np.array([0.0, -V])
    w_plus = (I_G * w_minus + M * (d[0] * vG[1] - d[1] * vG[0])) / I_A
    N = -M * w_plus ** 2 * 0.5 * L * math.cos(phi - BETA)
    Ft = -M * w_plus ** 2 * 0.5 * L * math.sin(phi - BETA)
    a_n = w_plus ** 2 * 0.5 * L * math.cos(phi - BETA)
    # the rod's state t_hit before the strike (no gravity: G moves straight, the rod turns at w-)
    theta_hit = math.pi / 2 - phi
    th0 = theta_hit - w_minus * t_hit
    G0 = d - vG * t_hit
    n = np.array([math.sin(BETA), math.cos(BETA)])
    foot0 = G0 - 0.5 * L * np.array([math.cos(th0), math.sin(th0)])
    assert n @ foot0 > 0  # A above the surface before
    foot = {"name": "foot", "type": "revolute", "a": "frame", "point_a": "entry", "b": "bar", "point_b": [-L / 2, 0.0],
            "contact": {"normal": list(n), "friction": "stick"}}
    strike = {"name": "strike", "type": "pin", "from": "flight", "to": "pinned",
              "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"},
              "contact": {"a": "frame", "point_a": [0.0, 0.0], "b": "bar", "point_b": [-L / 2, 0.0], "normal": list(n),
                          "friction": "stick"}}
    path = make_scene({"rod.urdf": free_bar_urdf(M, L)},
                      configurations={"flight": {"urdf": "rod.urdf"}, "pinned": {"urdf": "rod.urdf", "cut_joints": [foot]}},
                      q0={"P": [G0[0], G0[1], th0]}, v0={"P": [*(rot(th0).T @ vG), w_minus]}, gravity=(0.0, 0.0),
                      t_end=2 * t_hit, transitions=[strike], solver={"rtol": 1e-12, "atol": 1e-13})
    traj = pcmm.simulate(pcmm.load_scene(path))
    assert [e["name"] for e in traj.events] == ["strike", "lift-off foot"]
    pin_ev, lift = traj.events
    assert pin_ev["t"] == pytest.approx(t_hit, abs=1e-11) and lift["t"] == pin_ev["t"]
    assert pin_ev["omega_after"]["bar"] == pytest.approx(w_plus, abs=1e-10)
    assert lift["omega_after"]["bar"] == pin_ev["omega_after"]["bar"]
    np.testing.assert_allclose(lift["v_after"]["P"], pin_ev["v_after"]["P"], atol=1e-14)
    lifted = lift["lifted"]["foot"]
    assert lifted["normal_force"] == pytest.approx(N, rel=1e-9) and N < 0
    assert lifted["tangential_force"] == pytest.approx(Ft, rel=1e-9)
    assert lifted["normal_acceleration_after"] == pytest.approx(a_n, rel=1e-9)
    assert traj.segments[-1].configuration == "flight"


def test_the_other_pinned_point_keeps_its_anchor(make_scene):
    """An arch of three unit bars (a planar base and two revolutes) with both feet pinned at entry
    (a four-bar with the floor), swung at 3.5 rad/s: foot a's force is tensile from the start (by
    the run: -2.97 N), so it lifts off at t = 0 into 'single_b', where foot b stays pinned at the
    anchor it had, (2, 0), through the whole segment (the loop's closure, to 1e-12)."""
    from builders import Bar, chain_urdf
    urdf = chain_urdf([Bar(1.0, 1.0, joint="planar"), Bar(1.0, 1.0), Bar(1.0, 1.0)])

    def pin_(name, link, pt):
        return {"name": name, "type": "revolute", "a": "frame", "point_a": "entry", "b": link, "point_b": pt,
                "contact": {"normal": [0.0, 1.0], "friction": "stick"}}
    fa, fb = pin_("foot_a", "link1", [0.0, 0.0]), pin_("foot_b", "link3", [1.0, 0.0])
    th, w = math.pi / 3, 3.5
    path = make_scene({"c.urdf": urdf},
                      configurations={"double": {"urdf": "c.urdf", "cut_joints": [fa, fb]},
                                      "single_a": {"urdf": "c.urdf", "cut_joints": [fa]},
                                      "single_b": {"urdf": "c.urdf", "cut_joints": [fb]}},
                      q0={"J1": [0.0, 0.0, th], "J2": -th, "J3": -th}, v0={"J1": [0.0, 0.0, w], "J2": -w, "J3": 0.0},
                      independent=["J1.theta"], t_end=0.1, solver={"rtol": 1e-11, "atol": 1e-12})
    traj = pcmm.simulate(pcmm.load_scene(path))
    assert [(e["name"], e["t"], e["to"]) for e in traj.events] == [("lift-off foot_a", 0.0, "single_b")]
    lifted = traj.events[0]["lifted"]["foot_a"]
    assert lifted["normal_force"] < 0 and lifted["normal_acceleration_after"] > 0
    seg = traj.segments[-1]
    assert seg.configuration == "single_b" and len(seg.t) > 10
    for q in seg.q:  # link3's tip: J1's origin + link1, link2, link3 along their absolute angles
        x, y, a1 = q[0], q[1], q[2]
        a2, a3 = a1 + q[3], a1 + q[3] + q[4]
        tip = np.array([x + math.cos(a1) + math.cos(a2) + math.cos(a3), y + math.sin(a1) + math.sin(a2) + math.sin(a3)])
        np.testing.assert_allclose(tip, [2.0, 0.0], atol=1e-11)


def test_check_names_the_lift_off_pcmm_adds(make_scene, capsys):
    import pcmm.cli
    assert pcmm.cli.main(["check", str(rod_scene(make_scene))]) == 0
    out = capsys.readouterr().out
    assert "'pinned': the point held by 'foot' lifts off into 'flight' where its normal force turns tensile" in out
    assert pcmm.cli.main(["check", str(rod_scene(make_scene, flight=False))]) == 0
    assert "lifts off" not in capsys.readouterr().out
