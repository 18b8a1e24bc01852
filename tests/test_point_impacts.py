"""Issue 24, item 1 and 6: two-dimensional point impacts with Coulomb friction (Routh's process).

A uniform slender rod (m, L, I = m L^2 / 12) on a URDF planar joint falls in pure translation
(v_G = (0, -v), omega = 0, no gravity) onto the floor with its end A, at angle theta to the
horizontal (A the lower end, A - G = -(L/2)(c, s)).  Derived by hand (Stronge, *Impact Mechanics*
ch. 4; the design note docs/design_24.md section 1):

* the Delassus matrix at A in (t, n) = (x, y): W = (1/m) [[1 + 3 s^2, -3 s c], [-3 s c, 1 + 3 c^2]];
* A does not slip before the impact; held stuck it needs |P_t| / P_n = |W_tn| / W_tt
  = 3 s c / (1 + 3 s^2) = mu_c, independent of e and v;
* mu >= mu_c (stick): P = (m / 4)(1 + e) v (3 s c, 1 + 3 s^2), the contact leaves with (0, e v);
* mu < mu_c (slide towards -x, sigma = -1 throughout): P_n = m (1 + e) v / (1 + 3 c^2 - 3 mu s c),
  P_t = mu P_n;
* then v_G+ = v_G + P / m and omega+ = ((A - G) x P) / I.

pcmm's run must reproduce these to 1e-12 on both sides of mu_c; the energy never rises, the
impulse stays in the friction cone, and the works of the two parts sum to the change of kinetic
energy.  The Routh process itself is checked against the independent reference
``tests/reference_rod_friction.py`` (Newton, Poisson, Stronge).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import pcmm
import reference_rimless_wheel as rw
import reference_rod_friction as rf
from builders import free_bar_urdf, rot
from pcmm.errors import SceneError, SimulationError
from pcmm.events.friction import AmbiguousImpact, routh

M, L, V = 1.3, 0.8, 1.7
H = 0.01  # A starts this high above the floor: the impact at t = H / V


def rod_scene(make_scene, theta, mu, e, vG=(0.0, -V), omega=0.0, law=None, t_end=None):
    s, c = math.sin(theta), math.cos(theta)
    y0 = H + 0.5 * L * s  # A = G - (L/2)(c, s) is H above the floor
    contact = {"a": "frame", "point_a": [0.0, 0.0], "b": "bar", "point_b": [-L / 2, 0.0], "normal": [0.0, 1.0],
               "friction": mu}
    if law is not None:
        contact["restitution_law"] = law
    tr = {"name": "floor", "type": "stop", "from": "c1", "restitution": e, "cut": [],
          "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"}, "contact": contact}
    vA = np.asarray(vG) + omega * np.array([-0.5 * L * s, 0.5 * L * c])  # omega z x (A - G)
    t_hit = H / -vA[1]
    return make_scene({"f.urdf": free_bar_urdf(M, L)}, q0={"P": [0.0, y0, theta]},
                      v0={"P": [*(rot(theta).T @ np.asarray(vG, float)), omega]}, gravity=(0.0, 0.0),
                      t_end=t_end or 1.5 * t_hit, transitions=[tr],
                      solver={"rtol": 1e-12, "atol": 1e-13}), t_hit


def hand(theta, mu, e):
    """(P, v_G+, omega+) of the rod falling in translation, by the closed forms above."""
    s, c = math.sin(theta), math.cos(theta)
    mu_c = 3 * s * c / (1 + 3 * s * s)
    if mu >= mu_c:
        P = M / 4 * (1 + e) * V * np.array([3 * s * c, 1 + 3 * s * s])
    else:
        Pn = M * (1 + e) * V / (1 + 3 * c * c - 3 * mu * s * c)
        P = np.array([mu * Pn, Pn])
    r = -0.5 * L * np.array([c, s])
    return P, np.array([0.0, -V]) + P / M, (r[0] * P[1] - r[1] * P[0]) / (M * L * L / 12)


def run(path):
    traj = pcmm.simulate(pcmm.load_scene(path))
    return traj.events


ANGLES = [15, 30, 45, 60, 75]


@pytest.mark.parametrize("deg", ANGLES)
@pytest.mark.parametrize("e", [0.5, 1.0])
@pytest.mark.parametrize("side", [0.3, 0.97, 1.0, 1.03, 2.0])  # mu as a multiple of mu_c
def test_rod_post_impact_velocities_by_hand(make_scene, deg, e, side):
    theta = math.radians(deg)
    s, c = math.sin(theta), math.cos(theta)
    mu_c = 3 * s * c / (1 + 3 * s * s)
    mu = side * mu_c
    path, t_hit = rod_scene(make_scene, theta, mu, e)
    ev = run(path)[0]
    P, vG, w = hand(theta, mu, e)
    assert ev["t"] == pytest.approx(t_hit, abs=1e-12)
    # exactly at mu_c both labels are right to round-off (the slide then ends at v_t = 0)
    assert ev["friction"]["phases"] in ({"stick"} if side > 1 else {"slide-"} if side < 1 else {"stick", "slide-"})
    np.testing.assert_allclose([ev["impulse"]["tangential"], ev["impulse"]["normal"]], P, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ev["impulse"]["vector"], P, rtol=0, atol=1e-12)  # t = (1, 0), n = (0, 1)
    vl = np.array(ev["v_after"]["P"])  # the planar joint's velocity is in the bar's frame
    np.testing.assert_allclose(rot(theta) @ vl[:2], vG, rtol=0, atol=1e-12)
    assert vl[2] == pytest.approx(w, abs=1e-12)
    # the cone, the energy, and its split
    fr = ev["friction"]
    assert abs(fr["impulse"]["tangential"]) <= mu * fr["impulse"]["normal"] * (1 + 1e-12)
    lost = ev["kinetic_energy_before"] - ev["kinetic_energy_after"]
    assert lost >= -1e-13
    assert fr["energy_lost"]["normal"] + fr["energy_lost"]["tangential"] == pytest.approx(lost, abs=1e-13)
    assert fr["energy_lost"]["tangential"] >= -1e-15
    # by hand: stick loses (1 - e^2) m v^2 (1 + 3 s^2) / 8 to the normal part and nothing to friction
    if side >= 1.0:  # (at mu_c to round-off)
        assert fr["energy_lost"]["normal"] == pytest.approx((1 - e * e) * M * V * V * (1 + 3 * s * s) / 8, abs=1e-13)
        assert fr["energy_lost"]["tangential"] == pytest.approx(0.0, abs=1e-13)
        assert fr["slip"]["after"] == pytest.approx(0.0, abs=1e-12)
    else:
        assert fr["slip"]["after"] < 0  # still sliding away from G's side as it leaves
    assert ev["normal_velocity"]["after"] == pytest.approx(e * V, abs=1e-12)


@pytest.mark.parametrize("deg", ANGLES)
def test_critical_mu_is_the_stick_ratio(make_scene, deg):
    """Just below mu_c the end slides, at mu_c and above it sticks; mu_c = 3 s c / (1 + 3 s^2),
    against the reference's bisection-free critical mu and a "stick" contact."""
    theta = math.radians(deg)
    s, c = math.sin(theta), math.cos(theta)
    mu_c = 3 * s * c / (1 + 3 * s * s)
    assert rf.critical_mu(rf.Rod(M, L), theta, (0.0, -V), 0.0, 0.5) == pytest.approx(mu_c, rel=1e-13)
    below = run(rod_scene(make_scene, theta, mu_c * (1 - 1e-9), 0.5)[0])[0]
    stick = run(rod_scene(make_scene, theta, "stick", 0.5)[0])[0]
    assert below["friction"]["phases"] == "slide-" and stick["friction"]["mu"] == "stick"
    # at the critical mu the two outcomes meet
    np.testing.assert_allclose(below["v_after"]["P"], stick["v_after"]["P"], atol=1e-8)
    assert stick["impulse"]["tangential"] / stick["impulse"]["normal"] == pytest.approx(mu_c, rel=1e-12)


@pytest.mark.parametrize("case", range(40))
def test_routh_against_the_reference(case):
    """The impact law on a 2 x 2 Delassus matrix against the reference's Routh process on the rod,
    with spin and initial slip, every law; equal to round-off (the same arithmetic in a second
    implementation), Painleve cases refused."""
    rng = np.random.default_rng(case)
    rod = rf.Rod(1.0, 1.0)
    e = [0.0, 0.5, 1.0][case % 3]
    law = ["newton", "poisson", "energetic"][(case // 3) % 3]
    v0 = np.zeros(2)
    while v0[1] >= -0.05:  # an approaching contact
        theta = rng.uniform(0.05, 1.5)
        vG = np.array([rng.uniform(-1, 1), -rng.uniform(0.2, 1.5)])
        omega, mu = rng.uniform(-2, 2), rng.uniform(0, 1.3)
        v0 = rod.contact_velocity(theta, vG, omega)
    ref = rf.routh(rod, theta, vG, omega, mu, e, law)
    W = rod.delassus(theta)
    if ref.painleve:
        with pytest.raises(AmbiguousImpact, match="Painleve"):
            routh(W, v0[0], v0[1], mu, e, law)
        return
    out = routh(W, v0[0], v0[1], mu, e, law)
    np.testing.assert_allclose(out.P, ref.P, atol=1e-14)
    assert out.work_normal + out.work_tangential == pytest.approx(ref.energy_change, abs=1e-14)
    assert abs(out.P_t) <= mu * out.P_n * (1 + 1e-12)
    assert out.work_tangential <= 1e-15


def test_energy_gain_of_newtons_law_stops_with_its_cause(make_scene):
    """The reference's ENERGY_GAIN case (45 deg, v_G = (0.1, -1), mu = 0.9, e = 1): by hand the
    stick outcome gains 1/2 P_t v_t- = +0.034375 J (m = L = 1); pcmm refuses it naming Newton's
    law, and Stronge's energetic law on the same data loses energy."""
    global M, L
    keep = M, L
    M, L = 1.0, 1.0
    try:
        g = rf.ENERGY_GAIN
        path, _ = rod_scene(make_scene, g["theta"], g["mu"], g["e"], vG=g["vG"])
        with pytest.raises(SimulationError, match="Newton's kinematic restitution with friction creates energy"):
            pcmm.simulate(pcmm.load_scene(path))
        path, _ = rod_scene(make_scene, g["theta"], g["mu"], g["e"], vG=g["vG"], law="energetic")
        ev = run(path)[0]
        assert ev["kinetic_energy_after"] < ev["kinetic_energy_before"]
        ref = rf.routh(rf.UNIFORM, g["theta"], g["vG"], 0.0, g["mu"], g["e"], "energetic")
        assert ev["impulse"]["normal"] == pytest.approx(ref.P[1], abs=1e-12)
        assert rf.routh(rf.UNIFORM, g["theta"], g["vG"], 0.0, g["mu"], g["e"]).energy_change == \
            pytest.approx(0.034375, abs=1e-12)
    finally:
        M, L = keep


def test_painleve_stops_with_a_message(make_scene):
    """tan theta = 2, mu = 1.5 > 4/3 (the smallest Painleve threshold (1 + 3 c^2)/(3 s c)), the end
    slipping away from G's side as it strikes: the sliding normal slope W_nn - sigma mu W_nt < 0."""
    theta = math.atan(2.0)
    s, c = math.sin(theta), math.cos(theta)
    assert (1 + 3 * c * c) / (3 * s * c) == pytest.approx(4 / 3, rel=1e-14)
    path, _ = rod_scene(make_scene, theta, 1.5, 0.5, vG=(-1.0, -0.2))
    with pytest.raises(SimulationError, match="Painleve.*no unique answer"):
        pcmm.simulate(pcmm.load_scene(path))


def test_plastic_slide_is_refused(make_scene):
    """e = 0 and mu < mu_c: the end would go on sliding on the floor, which pcmm does not model;
    the message gives the friction a no-slip outcome needs (mu_c)."""
    theta = math.radians(30)
    s, c = math.sin(theta), math.cos(theta)
    path, _ = rod_scene(make_scene, theta, 0.1, 0.0)
    with pytest.raises(SimulationError, match=f"friction >= {3 * s * c / (1 + 3 * s * s):.6g}"):
        pcmm.simulate(pcmm.load_scene(path))


def test_friction_key_is_checked(make_scene):
    path, _ = rod_scene(make_scene, 0.5, -0.2, 0.5)
    with pytest.raises(SceneError, match=r"contact.friction.*>= 0"):
        pcmm.load_scene(path)
    path, _ = rod_scene(make_scene, 0.5, "sticky", 0.5)
    with pytest.raises(SceneError, match="stick"):
        pcmm.load_scene(path)


# ==================================================================== a struck point pinned where it lands
from builders import Bar, chain_urdf  # noqa: E402

LB = 0.5  # three bars of 0.5 m, 1 kg
Q3 = [-0.3, 0.5, -0.4]  # link angles relative to their parents at the start (the tip above the floor)


def chain_tip(q):
    th = np.cumsum(q)
    return LB * np.array([np.cos(th).sum(), np.sin(th).sum()])


def pinned_chain(make_scene, floor, t_end=0.6, friction=None, unilateral=False):
    pin_joint = {"name": "tip", "type": "revolute", "a": "frame", "point_a": "entry", "b": "link3",
                 "point_b": [LB, 0.0]}
    if unilateral:
        pin_joint["contact"] = {"normal": [0.0, 1.0]}
    contact = {"a": "frame", "point_a": [0.0, floor], "b": "link3", "point_b": [LB, 0.0], "normal": [0.0, 1.0]}
    if friction is not None:
        contact["friction"] = friction
    tr = {"name": "strike", "type": "pin", "from": "free", "to": "pinned",
          "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"}, "contact": contact}
    return make_scene({"chain.urdf": chain_urdf([Bar(LB, 1.0)] * 3)},
                      configurations={"free": "chain.urdf", "pinned": {"urdf": "chain.urdf", "cut_joints": [pin_joint]}},
                      q0={"J1": Q3[0], "J2": Q3[1], "J3": Q3[2]}, v0={"J1": 0.0, "J2": 0.0, "J3": 0.0},
                      t_end=t_end, transitions=[tr], solver={"rtol": 1e-11, "atol": 1e-12})


def test_pin_impulse_is_the_projection_onto_the_pinned_motion(make_scene):
    """A triple pendulum whose tip strikes the floor and is pinned where it lands.  By hand (impulse
    and momentum with the pin's two rows J): M (v+ - v-) = J^T P and J v+ = 0, so v+ lies in the null
    space of J, spanned by z, and z^T M (v+ - v-) = 0: v+ = z (z^T M v-) / (z^T M z).  M and J here
    from Pinocchio directly, not through pcmm."""
    import pinocchio as pin
    floor = chain_tip(Q3)[1] - 0.05
    traj = pcmm.simulate(pcmm.load_scene(pinned_chain(make_scene, floor)))
    ev = traj.events[0]
    assert ev["transition"] == "pin" and ev["to"] == "pinned"
    q = np.asarray(traj.segments[0].q[-1])  # (n, nv): the posture at the strike
    model = pin.buildModelFromXML(chain_urdf([Bar(LB, 1.0)] * 3))
    data = model.createData()
    vm = np.array([ev["v_before"][j] for j in ("J1", "J2", "J3")])
    vp = np.array([ev["v_after"][j] for j in ("J1", "J2", "J3")])
    assert abs(chain_tip(q)[1] - floor) < 1e-9
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    th = np.cumsum(q)
    # the tip's Jacobian by hand: d tip / d q_k = L sum_{i >= k} (-sin th_i, cos th_i)
    J = np.array([[-LB * np.sin(th[k:]).sum() for k in range(3)], [LB * np.cos(th[k:]).sum() for k in range(3)]])
    z = np.linalg.svd(J)[2][-1]
    expect = z * (z @ M @ vm) / (z @ M @ z)
    np.testing.assert_allclose(vp, expect, atol=1e-12)
    P = np.linalg.lstsq(J.T, M @ (vp - vm), rcond=None)[0]  # the pin's impulse on the tip
    np.testing.assert_allclose(ev["impulse"]["vector"], P, atol=1e-11)
    assert ev["impulse"]["normal"] == pytest.approx(P[1], abs=1e-11) and P[1] > 0
    assert ev["impulse"]["tangential"] == pytest.approx(P[0], abs=1e-11)
    np.testing.assert_allclose(ev["anchor"]["tip"], [chain_tip(q)[0], floor], atol=1e-9)
    assert ev["kinetic_energy_after"] < ev["kinetic_energy_before"]
    # the split of the loss, with the tip's velocity by hand (J v): no slip (mu -> infinity in Routh's
    # process) stops the slip at once, at p = 0+, by the tangential impulse -vt0 / D_tt (D = J M^-1 J^T):
    # friction dissipates vt0^2 / (2 D_tt), the normal part the rest (not P_t vt0 / 2, the
    # proportional path's, which may be negative: task h-messages2)
    vt0, vn0 = J @ vm
    D = J @ np.linalg.solve(M, J.T)
    fr = ev["friction"]
    assert fr["slip"]["before"] == pytest.approx(vt0, abs=1e-12) and abs(vt0) > 0.1
    assert fr["slip"]["after"] == pytest.approx(0.0, abs=1e-12)
    assert fr["energy_lost"]["tangential"] == pytest.approx(0.5 * vt0 ** 2 / D[0, 0], abs=1e-11)
    assert fr["energy_lost"]["tangential"] > 0
    assert fr["energy_lost"]["normal"] + fr["energy_lost"]["tangential"] == pytest.approx(
        ev["kinetic_energy_before"] - ev["kinetic_energy_after"], abs=1e-12)
    # the run goes on pinned: the tip stays at the anchor
    last = traj.segments[-1]
    assert last.configuration == "pinned" and len(last.t) > 3
    for qk in last.q:
        np.testing.assert_allclose(chain_tip(qk), ev["anchor"]["tip"], atol=1e-9)


def knee_strike(make_scene, bar3: Bar, v1: float, floor: float = 0.0):
    """The chain's tip already pinned on the floor (held by compression only: its cut joint has a
    contact normal); its knee (link 3's origin) strikes the line y = floor and is pinned there
    (bilaterally); the target holds the knee only."""
    def joint(name, point_b, unilateral=True):
        out = {"name": name, "type": "revolute", "a": "frame", "point_a": "entry", "b": "link3", "point_b": point_b}
        if unilateral:
            out["contact"] = {"normal": [0.0, 1.0]}
        return out
    tr = {"name": "knee strike", "type": "pin", "from": "A", "to": "B",
          "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"},
          "contact": {"a": "frame", "point_a": [0.0, floor], "b": "link3", "point_b": [0.0, 0.0], "normal": [0.0, 1.0]}}
    urdf = chain_urdf([Bar(LB, 0.2), Bar(LB, 0.2), bar3])
    return make_scene({"c.urdf": urdf}, configurations={"A": {"urdf": "c.urdf", "cut_joints": [joint("tip", [LB, 0.0])]},
                                                        "B": {"urdf": "c.urdf", "cut_joints": [joint("knee", [0.0, 0.0], False)]}},
                      q0={"J1": -0.3, "J2": 1.2, "J3": -1.8}, v0={"J1": v1, "J2": 0.0, "J3": 0.0}, independent=["J1"],
                      t_end=0.6, transitions=[tr], solver={"rtol": 1e-11, "atol": 1e-12}), urdf


def two_active_sets(urdf, q, vm):
    """By hand, the two candidate outcomes of the knee strike: (v+ and the tip's normal speed with
    the tip released; the tip's normal impulse with the tip held, when v+ = 0 (both ends of link 3
    pinned, links 1-2 pinned at both ends: no motion left))."""
    import pinocchio as pin
    model = pin.buildModelFromXML(urdf)
    data = model.createData()
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    th = np.cumsum(q)
    J_tip = np.array([[-LB * np.sin(th[k:]).sum() for k in range(3)], [LB * np.cos(th[k:]).sum() for k in range(3)]])
    J_knee = np.array([[-LB * np.sin(th[k:2]).sum() for k in range(3)], [LB * np.cos(th[k:2]).sum() for k in range(3)]])
    z = np.array([0.0, 0.0, 1.0])  # the knee's rows do not involve J3: its null space is e3
    v_rel = z * (z @ M @ vm) / (z @ M @ z)
    A = np.vstack([J_knee, J_tip[1:]])  # held: M (0 - v-) = A^T lam
    lam = np.linalg.solve(A.T, -M @ vm)
    return v_rel, float(J_tip[1] @ v_rel), float(lam[2])


KNEE_Y0 = 0.24390335148307188  # the knee's height at the start; it strikes the line 0.03 m below


@pytest.mark.parametrize("v1", [-3.0, -1.5, 1.5])
def test_old_contact_released_because_the_new_pin_separates_it(make_scene, v1):
    """Link 3's mass outside the segment between its two ends (centroid 0.1 m behind the knee):
    the knee's pin makes the tip rise, and holding the tip would need a tensile impulse, so the
    complementarity problem's only solution releases it, with no impulse (design_24.md 2.3)."""
    path, urdf = knee_strike(make_scene, Bar(LB, 5.0, com=(-0.1, 0.0), izz=0.01), v1, floor=KNEE_Y0 - 0.03)
    traj = pcmm.simulate(pcmm.load_scene(path))
    ev = traj.events[0]
    q = np.asarray(traj.segments[0].q[-1])
    vm = np.array([ev["v_before"][j] for j in ("J1", "J2", "J3")])
    v_rel, vn_tip, lam_tip = two_active_sets(urdf, q, vm)
    assert vn_tip > 0 and lam_tip < 0  # by hand: released is admissible, held is not
    np.testing.assert_allclose([ev["v_after"][j] for j in ("J1", "J2", "J3")], v_rel, atol=1e-11)
    assert ev["released"]["tip"]["normal_velocity_after"] == pytest.approx(vn_tip, abs=1e-11)
    assert ev["constraint_impulses"]["tip"] == [0.0, 0.0, 0.0]
    assert traj.segments[-1].configuration == "B"
    assert ev["kinetic_energy_after"] <= ev["kinetic_energy_before"]


def test_old_contact_that_stays_closed_needs_a_target_holding_it(make_scene):
    """A uniform link 3: pinned at its knee it would turn the other way (its angular momentum about
    the knee, -omega m L^2 / 6 before, changes sign), pushing the tip into the floor: the tip stays,
    by hand its held impulse is compressive, and the scene's target (knee only) is refused by name."""
    path, urdf = knee_strike(make_scene, Bar(LB, 5.0), -1.5, floor=KNEE_Y0 - 0.03)
    with pytest.raises(SimulationError, match=r"\['tip'\] stay closed through the strike.*'B' does not hold them"):
        pcmm.simulate(pcmm.load_scene(path))


# ==================================================================== scene checks and refusals
from builders import URDF_DIR, example_text, free_bar_urdf as _free_bar  # noqa: E402


def wheel_scene(tmp_path, edit):
    (tmp_path / "rimless_wheel.urdf").write_text((URDF_DIR / "rimless_wheel.urdf").read_text())
    path = tmp_path / "wheel.toml"
    path.write_text(edit(example_text("rimless_wheel.toml")))
    return path


def test_pin_outside_its_friction_cone_is_refused(tmp_path):
    """The wheel's no-slip strike needs mu >= |P_t| / P_n = 0.5412658773652739 (the reference's
    pin solve); with mu = 0.5 at the contact the first strike stops the run and says so."""
    path = wheel_scene(tmp_path, lambda s: s.replace('normal = [0.0, 1.0], friction = "stick" }\nguard',
                                                     'normal = [0.0, 1.0], friction = 0.5 }\nguard'))
    with pytest.raises(SimulationError, match=r"strike 1'.*would slip.*friction >= 0.541266.*mu = 0.5"):
        pcmm.simulate(pcmm.load_scene(path))
    path = wheel_scene(tmp_path, lambda s: s.replace('normal = [0.0, 1.0], friction = "stick" }\nguard',
                                                     'normal = [0.0, 1.0], friction = 0.55 }\nguard'))
    scene = pcmm.load_scene(path)
    scene = scene.with_values({"scene.t_end": 1.0})
    assert len(pcmm.simulate(scene).events) == 1  # 0.55 is enough


def test_pin_scene_errors(tmp_path):
    # the target must hold the struck point with a cut joint anchored at entry
    path = wheel_scene(tmp_path, lambda s: s.replace('to = "spoke1"', 'to = "spoke2"'))
    with pytest.raises(SceneError, match=r"strike 1.*to: = 'spoke2': a pin's target holds the struck point"):
        pcmm.load_scene(path)
    # an anchor at entry is fixed in the world: only on the frame
    path = wheel_scene(tmp_path, lambda s: s.replace('name = "foot3", type = "revolute", a = "frame"',
                                                     'name = "foot3", type = "revolute", a = "wheel"'))
    with pytest.raises(SceneError, match=r"spoke3.cut_joints\[0\].point_a: = 'entry'.*must be the frame"):
        pcmm.load_scene(path)
    # a region arms a guard from one side only
    path = wheel_scene(tmp_path, lambda s: s.replace(
        'guard = { type = "gap", value = 0.0, direction = "decreasing" }',
        'guard = { type = "gap", value = 0.0, direction = "decreasing", when = { measure = { link = "wheel" }, '
        'above = 0.0, below = 1.0 } }', 1))
    with pytest.raises(SceneError, match="when: give exactly one of above"):
        pcmm.load_scene(path)
    # a pin has no restitution
    path = wheel_scene(tmp_path, lambda s: s.replace('type = "pin"', 'type = "pin"\nrestitution = 0.5', 1))
    with pytest.raises(SceneError, match="restitution: not used by a pin"):
        pcmm.load_scene(path)


def test_point_mass_on_a_free_joint_is_refused(make_scene):
    """A planar body with zero inertia: its rotation is set by nothing in the tree (singular M)."""
    from builders import joint_xml, link_xml, robot_xml
    point = ('<link name="bar"><inertial><origin xyz="0 0 0" rpy="0 0 0"/><mass value="1.0"/>'
             '<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial></link>')
    urdf = robot_xml("point", link_xml("frame"), joint_xml("P", "planar", "frame", "bar"), point)
    path = make_scene({"f.urdf": urdf}, q0={"P": [0.0, 0.0, 0.0]}, v0={"P": [0.0, 0.0, 0.0]})
    with pytest.raises(pcmm.errors.ModelError, match=r"\['bar'\] are point masses on a free \(planar\) joint"):
        pcmm.simulate(pcmm.load_scene(path))


def test_pinned_foot_lifts_off_when_its_normal_force_turns_tensile(tmp_path):
    """A rimless wheel rolling too fast (2.9 rad/s after a strike): during the stance the ground's
    normal force at the pinned foot, by hand F = m a - m g (the reference's stance_forces along its
    stance ODE), reaches zero at phi_lift; a `release` whose reaction guard watches the foot's cut
    joint fires there.  Freed, the wheel flies (the hub falls with g, no moment about it), so the
    foot's acceleration is g_vec + w^2 l (sin phi, cos phi): along the slope normal
    -g cos gamma + w^2 l cos phi_lift < 0 by hand.  The foot would be pushed back into the slope
    (the pin's tangential force is gone: it would slide, issue 24 item 3, docs/point_impacts.md):
    the run stops at the lift-off instant and says so, where it used to fly on with the foot
    sinking into the slope."""
    from scipy.integrate import solve_ivp
    W = rw.ISSUE
    w0 = 2.9

    def lift(t, y):
        return W.stance_forces(y[0], y[1])[1]
    lift.terminal, lift.direction = True, -1
    sol = solve_ivp(W.rhs, (0, 2.0), [-W.alpha, w0], method="DOP853", rtol=1e-13, atol=1e-14, events=lift)
    t_lift = float(sol.t_events[0][0])
    phi_lift, w_lift = (float(x) for x in sol.y_events[0][0])
    assert -W.alpha < phi_lift < W.alpha
    a_n = -W.g * math.cos(W.gamma) + w_lift ** 2 * W.l * math.cos(phi_lift)
    assert a_n < 0

    def edit(s):
        s = s.replace('v = { hub = ["1.5*', f'v = {{ hub = ["{w0}*').replace('", "1.5*(', f'", "{w0}*(')
        s = s.replace(", -1.5] }", f", -{w0}] }}").replace("t_end = 15.0", "t_end = 0.8")
        s = s.replace("[initial]", '[configurations.flight]\nurdf = "rimless_wheel.urdf"\n\n[initial]')
        return s + ('\n[[transitions]]\nname = "lift-off"\ntype = "release"\nfrom = "spoke0"\nto = "flight"\n'
                    'guard = { type = "reaction", of = "foot0", value = 0.0, direction = "decreasing" }\n')
    path = wheel_scene(tmp_path, edit)
    with pytest.raises(SimulationError, match=r"'foot0' lifts off.*pushed back into the surface.*slide") as err:
        pcmm.simulate(pcmm.load_scene(path))
    import re
    text = str(err.value)
    assert float(re.search(r"t = ([0-9.]+) s", text).group(1)) == pytest.approx(t_lift, abs=1e-8)
    assert float(re.search(r"acceleration (-[0-9.]+)", text).group(1)) == pytest.approx(a_n, rel=1e-5)
    # without the release, but with the configuration to lift into, the same stop (pcmm's own lift-off)
    path = wheel_scene(tmp_path, lambda s: edit(s).split("\n[[transitions]]\nname = \"lift-off\"")[0])
    with pytest.raises(SimulationError, match=r"'foot0' lifts off.*pushed back") as err:
        pcmm.simulate(pcmm.load_scene(path))
    assert float(re.search(r"t = ([0-9.]+) s", str(err.value)).group(1)) == pytest.approx(t_lift, abs=1e-8)


def test_cut_accepts_a_loops_cut_joint(make_scene):
    """`cut` may name a loop's cut joint (the chain's tip pinned on the floor): it is already a set
    of rows of the cut system, so the impact is the same as without it, and the event reports its
    impulse among the cut impulses (the same as its constraint impulse)."""
    pin_joint = {"name": "tip", "type": "revolute", "a": "frame", "point_a": "entry", "b": "link3", "point_b": [LB, 0.0]}
    results = {}
    for c in ([], ["tip"]):
        tr = {"name": "stop", "type": "stop", "from": "pinned", "restitution": 1.0, "cut": c,
              "guard": {"type": "coordinate", "measure": {"joint": "J1"}, "value": Q3[0] - 0.05, "direction": "decreasing"},
              "contact": {"joint": "J1"}}
        path = make_scene({"chain.urdf": chain_urdf([Bar(LB, 1.0)] * 3)},
                          configurations={"pinned": {"urdf": "chain.urdf", "cut_joints": [pin_joint]}},
                          q0={"J1": Q3[0], "J2": Q3[1], "J3": Q3[2]}, v0={"J1": 0.0, "J2": 0.0, "J3": 0.0},
                          independent=["J1"], t_end=0.3, transitions=[tr], solver={"rtol": 1e-11, "atol": 1e-12})
        results[tuple(c)] = pcmm.simulate(pcmm.load_scene(path)).events[0]
    plain, cut_tip = results[()], results[("tip",)]
    assert plain["name"] == "stop" and plain["normal_velocity"]["before"] < 0
    np.testing.assert_allclose(cut_tip["v_after"]["J1"], plain["v_after"]["J1"], atol=1e-13)
    assert "tip" not in plain["cut_impulses"]
    np.testing.assert_allclose(cut_tip["cut_impulses"]["tip"], plain["constraint_impulses"]["tip"], atol=1e-12)
    assert np.linalg.norm(cut_tip["cut_impulses"]["tip"][:2]) > 0.01


def test_stance_outside_the_cone_or_tensile_stops_the_run(tmp_path):
    """The wheel's stance needs mu >= 0.5525 at its start (the reference's stance forces, F = m a
    - m g), more than the strike's 0.5413: with mu = 0.545 on the cut joints the first strike
    passes and the stance that begins is refused.  Rolling at 2.9 rad/s without a release in the
    scene, the foot's normal force turns tensile mid-stance: the run stops there, saying so, at
    the reference's lift-off time."""
    from scipy.integrate import solve_ivp
    W = rw.ISSUE
    Ft, Fn = W.stance_forces(-W.alpha, W.strikes(1.5, 1)[0][2])
    assert 0.545 < abs(Ft) / Fn  # by hand at strike 1's omega+: the stance starts outside mu = 0.545
    path = wheel_scene(tmp_path, lambda s: s.replace('contact = { normal = [0.0, 1.0], friction = "stick" } }',
                                                     'contact = { normal = [0.0, 1.0], friction = 0.545 } }'))
    with pytest.raises(SimulationError, match=r"strike 1'.*right after the strike the point held by 'foot1' would "
                                              r"slip.*friction >= 0.55"):
        pcmm.simulate(pcmm.load_scene(path))
    w0 = 2.9

    def lift(t, y):
        return W.stance_forces(y[0], y[1])[1]
    lift.terminal, lift.direction = True, -1
    sol = solve_ivp(W.rhs, (0, 2.0), [-W.alpha, w0], method="DOP853", rtol=1e-13, atol=1e-14, events=lift)
    t_lift = float(sol.t_events[0][0])

    def fast(s):
        s = s.replace('v = { hub = ["1.5*', f'v = {{ hub = ["{w0}*').replace('", "1.5*(', f'", "{w0}*(')
        return s.replace(", -1.5] }", f", -{w0}] }}")
    with pytest.raises(SimulationError, match=r"foot0' would lift off.*add a configuration.*or a release") as err:
        pcmm.simulate(pcmm.load_scene(wheel_scene(tmp_path, fast)))
    import re
    assert float(re.search(r"t = ([0-9.]+) s", str(err.value)).group(1)) == pytest.approx(t_lift, abs=1e-8)


def test_redundant_rows_give_the_unique_velocity_and_say_so():
    """A free planar body (m = 2, I = 0.3; v = (vx, vy, w) of its centre) pinned at two points:
    four rows of rank 3, so v+ = 0 exactly and the split is flagged; one pin: two rows, by hand
    v+ keeps the angular momentum about the pin, I_pin w+ = I w + m (r x v), r = centre - pin."""
    from pcmm.events.pins import impact_with_rows
    m, I = 2.0, 0.3
    M = np.diag([m, m, I])
    v = np.array([0.4, -1.1, 2.5])

    def rows(p):  # the velocity of the body point at p (from the centre): (vx - w p_y, vy + w p_x)
        return np.array([[1.0, 0.0, -p[1]], [0.0, 1.0, p[0]]])
    v2, lam2, red2 = impact_with_rows(M, "body", v, np.vstack([rows((0.5, 0.0)), rows((-0.3, 0.2))]), np.zeros(4))
    assert red2 and np.allclose(v2, 0.0, atol=1e-14)
    p = np.array([0.5, 0.0])
    v1, lam1, red1 = impact_with_rows(M, "body", v, rows(p), np.zeros(2))
    r = -p
    H = I * v[2] + m * (r[0] * v[1] - r[1] * v[0])
    assert not red1 and v1[2] == pytest.approx(H / (I + m * r @ r), abs=1e-14)
    np.testing.assert_allclose(rows(p) @ v1, 0.0, atol=1e-14)
