"""``friction = "stick"`` obeys the restitution law the scene names (task h-stickpoisson).

With no slip (mu = infinity) Routh's process stops the slip at p = 0+ by the tangential impulse
-v_t^- / D_tt, which leaves the normal velocity

    v_n1 = v_n^- - D_tn v_t^- / D_tt,

and the point then sticks, its normal velocity growing with the normal impulse p at the slope
s = D_nn - D_tn^2 / D_tt (= 1 / (D^-1)_nn), until the law ends the impact:

* Newton's:  v_n^+ = -e v_n^-,   P_n = (-e v_n^- - v_n1) / s;
* Poisson's: P_n = (1 + e) p_c with p_c = -v_n1 / s, so v_n^+ = -e v_n1;
* Stronge's: restitution work -e^2 times the compression's, on this one stick phase v_n^+ = -e v_n1;

and P_t = -v_t^- / D_tt - (D_tn / D_tt) P_n (so that v_t^+ = 0).  Friction dissipates
v_t^-^2 / (2 D_tt), the normal part (v_n1^2 - v_n^+^2) / (2 s).  Before, "stick" took Newton's
impulse whatever ``restitution_law`` said, so Poisson's and Stronge's scenes silently got Newton's
number, and a sweep of mu jumped between mu = 1e8 and "stick".

The mechanism (not in pcmm's examples): a cart (mass MC) on a prismatic joint X along x carries a
uniform bar (M, L) on the revolute J1 at the cart's origin (q = angle from +x), no gravity; the
bar's tip (x + L cos q, L sin q) strikes a floor below it (normal +y, tangent t = (1, 0)).  By hand,
in (x, q): M(q) = [[MC + M, -M L sin q / 2], [-M L sin q / 2, M L^2 / 3]] and the tip's rows
J_c = [[1, -L sin q], [0, L cos q]] (t, n); D = J_c M^-1 J_c^T.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from builders import bar_xml, joint_xml, link_xml, robot_xml, solid_xml

import pcmm
from pcmm.errors import SimulationError
from pcmm.events import friction
from pcmm.events.friction import LAWS, AmbiguousImpact, routh, stick_impulse

MC, M, L = 2.0, 1.2, 0.6
Q0, V0 = -0.9, (0.44, -2.0)  # the tip 2 mm above the floor, falling and slipping along -x
GAP = 0.002


def mass_matrix(q):
    s = math.sin(q)
    return np.array([[MC + M, -M * L * s / 2], [-M * L * s / 2, M * L * L / 3]])


def tip_rows(q):
    """The tip's velocity rows (t, n) = (x, y) in (x', q')."""
    return np.array([[1.0, -L * math.sin(q)], [0.0, L * math.cos(q)]])


def cart_urdf() -> str:
    return robot_xml("cart_bar", link_xml("frame"), joint_xml("X", "prismatic", "frame", "cart", axis=(1.0, 0.0, 0.0)),
                     solid_xml("cart", MC, 0.05), joint_xml("J1", "revolute", "cart", "link1"), bar_xml("link1", L, M))


def cart_scene(make_scene, law, e, friction_="stick", q0=Q0, v0=V0, t_end=0.006):
    contact = {"a": "frame", "point_a": [0.0, L * math.sin(q0) - GAP], "b": "link1", "point_b": [L, 0.0],
               "normal": [0.0, 1.0], "friction": friction_, "restitution_law": law}
    tr = {"name": "tip strikes floor", "type": "stop", "from": "c1", "restitution": e, "cut": [],
          "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"}, "contact": contact}
    return make_scene({"cart.urdf": cart_urdf()}, q0={"X": 0.0, "J1": q0}, v0={"X": v0[0], "J1": v0[1]},
                      gravity=(0.0, 0.0), t_end=t_end, transitions=[tr], solver={"rtol": 1e-12, "atol": 1e-13})


def by_hand(D, vt, vn, e, law):
    """(P, v_n^+, friction's loss, the normal part's loss) of the no-slip impact, module text."""
    vn1 = vn - D[0, 1] * vt / D[0, 0]
    s = D[1, 1] - D[0, 1] ** 2 / D[0, 0]
    vn_after = -e * vn if law == "newton" else -e * vn1
    Pn = (vn_after - vn1) / s
    Pt = -vt / D[0, 0] - D[0, 1] / D[0, 0] * Pn
    return np.array([Pt, Pn]), vn_after, vt * vt / (2 * D[0, 0]), (vn1 ** 2 - vn_after ** 2) / (2 * s)


def strike(traj):
    """(event, D, v^-, (v_t^-, v_n^-)) of the run's first event, D and the velocities by hand."""
    ev = traj.events[0]
    q = float(np.asarray(traj.segments[0].q[-1])[1])  # J1 at the strike
    assert L * math.sin(q) == pytest.approx(L * math.sin(Q0) - GAP, abs=1e-10)  # the tip on the floor
    Jc = tip_rows(q)
    D = Jc @ np.linalg.solve(mass_matrix(q), Jc.T)
    vm = np.array([ev["v_before"]["X"], ev["v_before"]["J1"]], float).ravel()
    return ev, q, D, vm, Jc @ vm


@pytest.mark.parametrize("law", LAWS)
def test_stick_impulse_by_hand_for_each_law(make_scene, law):
    e = 0.5
    traj = pcmm.simulate(pcmm.load_scene(cart_scene(make_scene, law, e)))
    ev, q, D, vm, (vt, vn) = strike(traj)
    assert vt < -0.4 and vn < -0.6 and D[0, 1] * vt < 0  # slipping along -x; stopping it slows the approach
    P, vn_after, lost_t, lost_n = by_hand(D, vt, vn, e, law)
    # the second route: the stick impulse with the law's target, D^-1 (-v_t^-, v_n^+ - v_n^-)
    np.testing.assert_allclose(P, np.linalg.solve(D, [-vt, vn_after - vn]), rtol=1e-13)
    Jc = tip_rows(q)
    vp = vm + np.linalg.solve(mass_matrix(q), Jc.T @ P)
    lost = 0.5 * vm @ mass_matrix(q) @ vm - 0.5 * vp @ mass_matrix(q) @ vp
    assert lost_t + lost_n == pytest.approx(lost, rel=1e-12)
    # the event record: law, impulse, v^+, the split
    fr = ev["friction"]
    assert fr["mu"] == "stick" and fr["law"] == law and fr["phases"] == "stick"
    assert ev["impulse"]["tangential"] == pytest.approx(P[0], rel=1e-9)
    assert ev["impulse"]["normal"] == pytest.approx(P[1], rel=1e-9)
    assert ev["normal_velocity"]["after"] == pytest.approx(vn_after, rel=1e-9)
    assert fr["slip"]["after"] == pytest.approx(0.0, abs=1e-12)
    assert ev["kinetic_energy_before"] - ev["kinetic_energy_after"] == pytest.approx(lost, rel=1e-9)
    assert fr["energy_lost"]["tangential"] == pytest.approx(lost_t, rel=1e-9)
    assert fr["energy_lost"]["normal"] == pytest.approx(lost_n, rel=1e-9)
    # the limit is continuous: Routh's process at mu = 1e8 (slide, then stick) ends at the same numbers
    big = routh(D, vt, vn, 1e8, e, law)
    np.testing.assert_allclose(big.P, P, rtol=1e-6)
    assert big.vn_after == pytest.approx(vn_after, rel=1e-6)
    assert -big.work_tangential == pytest.approx(lost_t, rel=1e-6)
    assert -big.work_normal == pytest.approx(lost_n, rel=1e-6)
    # the laws really differ here: Poisson's and Stronge's leave at -e v_n1 = 0.1765 m/s, Newton's at
    # -e v_n^- = 0.3708 m/s, with a normal part that feeds 0.0277 J in (Newton's law with the slip stopped)
    assert vn == pytest.approx(-0.741523, abs=1e-6) and vt == pytest.approx(-0.503925, abs=1e-6)
    assert lost_t == pytest.approx(0.081967, abs=1e-6)
    if law == "newton":
        assert vn_after == pytest.approx(0.370762, abs=1e-6) and lost_n == pytest.approx(-0.027671, abs=1e-6)
    else:
        assert vn_after == pytest.approx(0.176482, abs=1e-6) and lost_n == pytest.approx(0.200726, abs=1e-6)


def test_energy_never_rises_with_poisson_or_stronge_where_newtons_rises(make_scene):
    """e = 1 on the same strike: Newton's stick impulse gains 1/2 P_t v_t^- = +0.8316 J (its normal part
    feeds energy in once the slip is stopped) and the run is refused, naming it; Poisson's and Stronge's
    lose exactly friction's v_t^-^2 / (2 D_tt) = 0.0820 J (the normal part, elastic from v_n1 to -v_n1,
    loses none)."""
    import re
    with pytest.raises(SimulationError, match="Newton's kinematic restitution with friction creates energy here "
                                              r"\(the slip -0\.50\d* m/s stopped") as refused:
        pcmm.simulate(pcmm.load_scene(cart_scene(make_scene, "newton", 1.0)))
    ke = [float(x) for x in re.search(r"kinetic energy (\S+) -> (\S+) J", str(refused.value)).groups()]
    for law in ("poisson", "energetic"):
        ev, q, D, vm, (vt, vn) = strike(pcmm.simulate(pcmm.load_scene(cart_scene(make_scene, law, 1.0))))
        P_newton = np.linalg.solve(D, [-vt, -2 * vn])
        gain_newton = 0.5 * P_newton[0] * vt  # P . (v^- + v^+) / 2 with v^+ = (0, -v_n^-)
        assert gain_newton == pytest.approx(ke[1] - ke[0], rel=1e-6) and gain_newton == pytest.approx(0.8316, abs=1e-4)
        assert ev["kinetic_energy_before"] == pytest.approx(ke[0], rel=1e-8)
        lost = ev["kinetic_energy_before"] - ev["kinetic_energy_after"]
        assert lost == pytest.approx(vt * vt / (2 * D[0, 0]), rel=1e-9) and lost == pytest.approx(0.0820, abs=1e-4)
        assert ev["friction"]["energy_lost"]["normal"] == pytest.approx(0.0, abs=1e-12)
        assert ev["normal_velocity"]["after"] == pytest.approx(-(vn - D[0, 1] * vt / D[0, 0]), rel=1e-9)


def test_energy_never_rises_over_drawn_contacts():
    """Poisson's and Stronge's no-slip impulse on 2000 drawn Delassus matrices, velocities and e in [0, 1]:
    KE^+ - KE^- = P . (v^- + v^+) / 2 = -v_t^2 / (2 D_tt) - (1 - e^2) v_n1^2 / (2 s) <= 0 wherever it is
    not refused (v_n1 < 0), and equal to the works; Newton's gains energy on some of the same draws."""
    rng = np.random.default_rng(7)
    newton_gains = taken = 0
    for _ in range(2000):
        A = rng.normal(size=(2, 2))
        D = A @ A.T + 0.05 * np.eye(2)
        vt, vn, e = rng.normal(), -abs(rng.normal()), rng.uniform()
        vn1 = vn - D[0, 1] * vt / D[0, 0]
        for law in ("poisson", "energetic"):
            if vn1 >= 0:
                with pytest.raises(AmbiguousImpact, match="finite friction mu"):
                    stick_impulse(D, vt, vn, e, law)
                continue
            fr = stick_impulse(D, vt, vn, e, law)
            v = np.array([vt, vn])
            dke = fr.P @ (2 * v + D @ fr.P) / 2
            s = D[1, 1] - D[0, 1] ** 2 / D[0, 0]
            assert dke == pytest.approx(-vt * vt / (2 * D[0, 0]) - (1 - e * e) * vn1 ** 2 / (2 * s), abs=1e-12 * (1 + abs(dke)))
            assert dke <= 1e-12 and fr.work_normal + fr.work_tangential == pytest.approx(dke, abs=1e-12 * (1 + abs(dke)))
            taken += 1
        try:
            P = stick_impulse(D, vt, vn, e, "newton").P
        except AmbiguousImpact:
            continue
        if vn1 < 0:  # e = 0: the three laws give one impulse, D^-1 (-v_t^-, -v_n^-)
            for law in LAWS:
                np.testing.assert_allclose(stick_impulse(D, vt, vn, 0.0, law).P, np.linalg.solve(D, [-vt, -vn]),
                                           rtol=1e-9, atol=1e-12)
        newton_gains += P @ (2 * np.array([vt, vn]) + D @ P) / 2 > 1e-9
    assert taken > 1000 and newton_gains > 50


def test_slip_stop_that_separates_is_refused_for_poisson_and_stronge(make_scene):
    """q = -0.6, (x', q') = (-0.5, -2.5): stopping the slip leaves v_n1 = v_n^- - D_tn v_t^- / D_tt > 0, the
    point already separating with no compression.  Poisson's and Stronge's are refused naming the numbers
    and the fix (a finite mu: Routh's process at mu = 1e8 then ends with P_n ~ 1e-8, the point leaving at
    about v_n1 with its slip stopped by friction alone); Newton's stick impulse still pushes and is taken,
    with no split (as before)."""
    q0, v0 = -0.6, (-0.5, -2.5)
    Jc = tip_rows(q0)
    D = Jc @ np.linalg.solve(mass_matrix(q0), Jc.T)
    vt, vn = Jc @ np.array(v0)
    vn1 = vn - D[0, 1] * vt / D[0, 0]
    assert vn1 == pytest.approx(0.3348, abs=1e-4)
    big = routh(D, vt, vn, 1e8, 0.5, "poisson")
    assert big.P_n < 1e-7 and big.vn_after == pytest.approx(vn1, rel=1e-6)
    for law in ("poisson", "energetic"):
        with pytest.raises(SimulationError, match=r"tip strikes floor.*no slip and the (poisson|energetic) law.*"
                                                  r"normal velocity 0\.33\d* m/s >= 0.*finite friction mu"):
            pcmm.simulate(pcmm.load_scene(cart_scene(make_scene, law, 0.5, q0=q0, v0=v0)))
    ev = pcmm.simulate(pcmm.load_scene(cart_scene(make_scene, "newton", 0.5, q0=q0, v0=v0))).events[0]
    assert ev["impulse"]["normal"] > 0 and ev["friction"]["energy_lost"] is None
    assert ev["friction"]["energy_split"].startswith("none: Routh's process with no slip has no answer here")


def test_painleve_side_has_no_large_mu_but_stick_takes_the_limit_process():
    """Slipping along +x (D_tn v_t^- > 0) every mu above D_nn / D_tn is a Painleve case, refused; "stick"
    is still the no-slip process (stopping the slip deepens the approach, v_n1 < v_n^-), Poisson's
    leaving at -e v_n1, faster than Newton's -e v_n^-."""
    Jc = tip_rows(Q0)
    D = Jc @ np.linalg.solve(mass_matrix(Q0), Jc.T)
    vt, vn = Jc @ np.array([1.5, -1.0])
    assert D[0, 1] * vt > 0
    with pytest.raises(AmbiguousImpact, match="Painleve"):
        routh(D, vt, vn, 1.01 * D[1, 1] / D[0, 1], 0.5, "poisson")
    vn1 = vn - D[0, 1] * vt / D[0, 0]
    fr = stick_impulse(D, vt, vn, 0.5, "poisson")
    assert vn1 < vn and fr.vn_after == pytest.approx(-0.5 * vn1, rel=1e-12) and fr.vn_after > -0.5 * vn
    np.testing.assert_allclose(D @ fr.P + [vt, vn], [0.0, -0.5 * vn1], atol=1e-12)


def test_planted_faults_are_caught(make_scene, monkeypatch):
    """The event's checks accept the new outcome (the runs above) and catch a wrong one: Newton's stick
    impulse labelled Poisson's (the old behaviour) breaks the law check, which reads -e v_n1 from the
    Delassus matrix itself; with e = 1 the same fault creates energy and the energy check stops it first."""
    newton = friction.stick_impulse

    def old(W, vt, vn, e, law="newton"):
        return replace(newton(W, vt, vn, e, "newton"), law=law)
    monkeypatch.setattr(friction, "stick_impulse", old)
    with pytest.raises(SimulationError, match=r"tip strikes floor': the bounce breaks Poisson's restitution law "
                                              r"with no slip .*after, where the law gives 0\.1764"):
        pcmm.simulate(pcmm.load_scene(cart_scene(make_scene, "poisson", 0.5)))
    with pytest.raises(SimulationError, match=r"\(energetic law, phases stick\) creates energy"):
        pcmm.simulate(pcmm.load_scene(cart_scene(make_scene, "energetic", 1.0)))


def test_a_stick_contact_takes_the_python_route_in_both_modes(make_scene, monkeypatch):
    """The compiled impulse (pcmm/model/_impulse.hpp: ImpulsePlan, BouncePlan) takes frictionless contacts
    only: a "stick" contact's plan says it is solved in Python (Routh's process), and the run with the
    compiled evaluations on and off gives the same strike (the same law, impulse and v^+; the stepping
    before it differs by round-off only)."""
    from pcmm.events import impulse_compiled
    from pcmm.events.impulse import _plan
    from pcmm.model import compiled
    from pcmm.model.mechanism import Mechanism
    if not compiled.enabled():
        pytest.skip(f"the compiled evaluations do not run here: {compiled.why_not()}")
    path = cart_scene(make_scene, "poisson", 0.5)
    scene = pcmm.load_scene(path)
    cfg = Mechanism(scene)["c1"]
    plan = _plan(cfg, scene.transitions[0].contact, ())
    assert impulse_compiled.compiled_impulse(cfg, plan) is None
    assert impulse_compiled.reason(cfg, plan) == "a frictional point contact (Routh's process) is solved in Python"
    events = {}
    for flag in ("1", "0"):
        monkeypatch.setenv(compiled.ENV, flag)
        events[flag] = pcmm.simulate(pcmm.load_scene(path)).events[0]
    a, b = events["1"], events["0"]
    assert a["friction"]["law"] == b["friction"]["law"] == "poisson"
    for key in ("normal", "tangential"):
        assert a["impulse"][key] == pytest.approx(b["impulse"][key], rel=1e-9)
        assert a["friction"]["energy_lost"][key] == pytest.approx(b["friction"]["energy_lost"][key], rel=1e-9)
    assert a["normal_velocity"]["after"] == pytest.approx(b["normal_velocity"]["after"], rel=1e-9)
    assert a["normal_velocity"]["after"] == pytest.approx(0.176482, abs=1e-6)


def test_contacts_closed_at_once_refuse_a_poisson_stick_law(make_scene):
    """A bar dropped flat and drifting along x onto two stops under its ends: both close at once and take
    one solve, Newton's law per contact (pcmm.events.simultaneous).  With "stick" and Poisson's law on one
    of them that solve would silently give Newton's outcome; it is refused, naming the contact and the law.
    With Newton's law on both the same drop runs."""
    from builders import free_bar_urdf
    Lb, h = 1.0, 0.05

    def scene(law):
        trs = [{"name": name, "type": "stop", "from": "c1", "restitution": 0.5, "cut": [],
                "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"},
                "contact": {"a": "frame", "point_a": [x, 0.0], "b": "bar", "point_b": [x, 0.0], "normal": [0.0, 1.0],
                            "friction": "stick", "restitution_law": law if name == "right" else "newton"}}
               for name, x in (("left", -Lb / 2), ("right", Lb / 2))]
        return make_scene({"flat.urdf": free_bar_urdf(1.0, Lb)}, q0={"P": [0.0, h, 0.0]}, v0={"P": [0.3, -1.0, 0.0]},
                          gravity=(0.0, 0.0), t_end=0.07, transitions=trs)
    with pytest.raises(SimulationError, match=r"contacts closed at once.*'right' names restitution_law = \"poisson\""
                                              r" with friction and restitution > 0"):
        pcmm.simulate(pcmm.load_scene(scene("poisson")))
    ev = pcmm.simulate(pcmm.load_scene(scene("newton"))).events[0]
    assert set(ev["simultaneous"]) == {"left", "right"}
    assert ev["simultaneous"]["right"]["normal_velocity"]["after"] == pytest.approx(0.5, rel=1e-9)
