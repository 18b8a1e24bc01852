"""What the second new user misread (task h-messages2, issue 22: no silent wrong number, every
message names the value), each on a mechanism of this file's own, checked by hand.

The arm: two uniform bars (upper 0.5 m, 3 kg on J1 at the frame's origin; fore 0.3 m, 1 kg on J2 at
the upper bar's tip) falling from rest under gravity; its tip strikes a floor and is pinned where
it lands (a ``pin``). Hip and tip pinned leave no freedom: the strike stops the arm dead
(P = -J^-T M w-) and the stance is statics (F = J^-T dV/da). The expectations come from the arm's own
Lagrangian in the bars' absolute angles (a1, a2), integrated with scipy to the floor, Routh's process
written out below, and the statics; nothing of pcmm's is used but the run.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import pcmm

sys.path.insert(0, str(Path(__file__).parent))
from builders import Bar, chain_urdf  # noqa: E402

G = 9.81
M1, L1, M2, L2 = 3.0, 0.5, 1.0, 0.3
I1, I2 = M1 * L1 ** 2 / 12, M2 * L2 ** 2 / 12
ARM_URDF = chain_urdf([Bar(L1, M1), Bar(L2, M2)], name="arm")

ARM_TOML = """
[scene]
name = "arm"
description = "two bars falling from rest; the tip strikes the floor and is pinned"
gravity = [0.0, -9.81]
t_end = 0.8
initial_configuration = "free"

[configurations.free]
urdf = "arm.urdf"

[configurations.held]
urdf = "arm.urdf"
cut_joints = [ { name = "tip", type = "revolute", a = "frame", point_a = "entry", b = "link2", point_b = [0.3, 0.0], contact = { normal = [0.0, 1.0]FRICTION } } ]

[initial]
q = { J1 = "A1 deg", J2 = "A2 deg" }
v = { J1 = RATE, J2 = 0.0 }

[[transitions]]
name = "tip strike"
type = "pin"
from = "free"
to = "held"
contact = { a = "frame", point_a = [0.0, FLOOR], b = "link2", point_b = [0.3, 0.0], normal = [0.0, 1.0]FRICTION }
guard = { type = "gap", value = 0.0, direction = "decreasing" }
"""


def arm_scene(tmp_path: Path, q1: float, q2: float, floor: float, friction: str = ", friction = 0.8",
              rate: float = 0.0):
    (tmp_path / "arm.urdf").write_text(ARM_URDF)
    path = tmp_path / "arm.toml"
    path.write_text(ARM_TOML.replace("A1", repr(q1)).replace("A2", repr(q2)).replace("FLOOR", repr(floor))
                    .replace("FRICTION", friction).replace("RATE", repr(rate)))
    return pcmm.load_scene(path)


def mass(a1, a2):
    c = math.cos(a1 - a2)
    return np.array([[I1 + M1 * L1 ** 2 / 4 + M2 * L1 ** 2, M2 * L1 * L2 / 2 * c],
                     [M2 * L1 * L2 / 2 * c, I2 + M2 * L2 ** 2 / 4]])


def dV(a1, a2):
    return np.array([(M1 * L1 / 2 + M2 * L1) * G * math.cos(a1), M2 * L2 / 2 * G * math.cos(a2)])


def tip_jacobian(a1, a2):
    return np.array([[-L1 * math.sin(a1), -L2 * math.sin(a2)], [L1 * math.cos(a1), L2 * math.cos(a2)]])


def strike_state(q1_deg, q2_deg, floor, rate=0.0):
    """Lagrange's equations integrated from the start (J1 turning at ``rate``, J2 at rest) to the tip's crossing of the floor: (t, a1, a2, w1, w2)."""
    def rhs(t, y):
        a1, a2, w1, w2 = y
        s = math.sin(a1 - a2)
        f = np.array([-M2 * L1 * L2 / 2 * s * w2 ** 2, M2 * L1 * L2 / 2 * s * w1 ** 2]) - dV(a1, a2)
        return [w1, w2, *np.linalg.solve(mass(a1, a2), f)]

    def gap(t, y):
        return L1 * math.sin(y[0]) + L2 * math.sin(y[1]) - floor
    gap.terminal, gap.direction = True, -1
    a1 = math.radians(q1_deg)
    sol = solve_ivp(rhs, (0, 2), [a1, a1 + math.radians(q2_deg), rate, rate], events=gap, rtol=1e-12, atol=1e-13,
                    method="DOP853")
    return sol.t_events[0][0], sol.y_events[0][0]


def routh_slide_then_stick(D, u, mu):
    """Routh's process, e = 0, written out for a slip that stops before compression ends and then
    sticks: returns (P_t, P_n, friction work, normal work). Slide: dP_t = -sigma mu dp, the contact
    velocity changes by D (-sigma mu, 1) dp; stick: dP_t = kappa dp (kappa = -D_tn / D_tt), v_t = 0."""
    sigma = math.copysign(1.0, u[0])
    slide = D @ np.array([-sigma * mu, 1.0])
    p1 = -u[0] / slide[0]
    assert 0 < p1 < -u[1] / slide[1]
    kappa = -D[0, 1] / D[0, 0]
    assert abs(kappa) <= mu
    un1 = u[1] + slide[1] * p1
    p2 = -un1 / (D @ np.array([kappa, 1.0]))[1]
    work_t = -sigma * mu * (u[0] * p1 / 2)               # v_t falls linearly to 0 over p1
    work_n = (u[1] + un1) / 2 * p1 + un1 / 2 * p2         # v_n linear in p within each phase
    return -sigma * mu * p1 + kappa * p2, p1 + p2, work_t, work_n


# ---- 1. a pin's friction.energy_lost is what friction dissipated (Routh's process) -------------------
def test_pin_energy_split_is_rouths_friction_only_dissipates(tmp_path):
    """Upper bar at 50 deg, fore bar at +80 deg to it, from rest; the floor 0.65 m below J1. The tip
    lands sliding forwards (v_t = +1.20 m/s); pinned, P = -J^-T M w- = (3.21018, 8.84786) N s
    (|P_t|/P_n = 0.363 < 0.8). Routh's process (mu = 0.8) slides, then sticks, and ends at that same
    impulse: friction dissipates 0.18931 J, the normal part the rest of the kinetic energy. The
    proportional path's split P_t v_t- / 2 (what the event said before) is -1.93 J: friction feeding
    energy in."""
    traj = pcmm.simulate(arm_scene(tmp_path, 50.0, 80.0, -0.65))
    t_hand, y = strike_state(50.0, 80.0, -0.65)
    (ev,) = traj.events
    assert ev["t"] == pytest.approx(t_hand, abs=1e-9)
    a1, a2, w = y[0], y[1], y[2:]
    J, M = tip_jacobian(a1, a2), mass(a1, a2)
    P = -np.linalg.solve(J.T, M @ w)
    assert ev["impulse"]["vector"] == pytest.approx(list(P), rel=1e-8)
    u = J @ w
    D = J @ np.linalg.solve(M, J.T)
    Pt, Pn, work_t, work_n = routh_slide_then_stick(D, u, 0.8)
    assert (Pt, Pn) == pytest.approx(tuple(P), rel=1e-9)            # Routh ends at the pin's impulse
    ke = 0.5 * w @ M @ w
    assert work_t + work_n == pytest.approx(-ke, rel=1e-9)
    assert -0.5 * P[0] * u[0] == pytest.approx(-1.9258, abs=1e-4)     # the old, misleading split
    fr = ev["friction"]
    assert fr["phases"] == "slide+ -> stick"
    assert fr["energy_lost"]["tangential"] == pytest.approx(-work_t, rel=1e-8)
    assert fr["energy_lost"]["tangential"] == pytest.approx(0.18931, abs=1e-5)
    assert fr["energy_lost"]["normal"] == pytest.approx(-work_n, rel=1e-8)


def test_pin_without_friction_stops_the_slip_at_once(tmp_path):
    """The same strike with no friction given (neither on the transition nor on the cut joint ("stick", mu -> infinity)): Routh's process stops the
    slip at p = 0+ by the tangential impulse -v_t / D_tt, which dissipates v_t^2 / (2 D_tt); then the
    tip sticks to the end of compression, ending at the same impulse. Friction's share is >= 0."""
    traj = pcmm.simulate(arm_scene(tmp_path, 50.0, 80.0, -0.65, friction=""))
    _, y = strike_state(50.0, 80.0, -0.65)
    a1, a2, w = y[0], y[1], y[2:]
    J, M = tip_jacobian(a1, a2), mass(a1, a2)
    u, D = J @ w, J @ np.linalg.solve(M, J.T)
    fr = traj.events[0]["friction"]
    assert fr["mu"] == "stick"
    assert fr["energy_lost"]["tangential"] == pytest.approx(u[0] ** 2 / (2 * D[0, 0]), rel=1e-8)
    assert fr["energy_lost"]["normal"] + fr["energy_lost"]["tangential"] == pytest.approx(0.5 * w @ M @ w, rel=1e-9)


# ---- 2. the strike that would need the floor to pull: the refusal names the point and the numbers ----
def test_tensile_pin_refusal_names_point_impulse_and_speeds(tmp_path):
    """Both bars level from rest, the floor 0.7 m below J1: the tip lands sweeping backwards
    (v_t = -5.45 m/s) faster than it falls (v_n = -3.69 m/s); pinning it needs P = -J^-T M w- with
    P_n < 0: the floor would pull. The refusal gives the point, its speeds and that impulse, and no
    empty list of active sets."""
    _, y = strike_state(0.0, 0.0, -0.7)
    a1, a2, w = y[0], y[1], y[2:]
    J, M = tip_jacobian(a1, a2), mass(a1, a2)
    P = -np.linalg.solve(J.T, M @ w)
    u = J @ w
    assert P[1] < 0
    with pytest.raises(pcmm.SimulationError) as err:
        pcmm.simulate(arm_scene(tmp_path, 0.0, 0.0, -0.7))
    text = str(err.value)
    assert "link2's point [0.3, 0.0] (the cut joint 'tip')" in text
    assert f"normal velocity {u[1]:.6g} m/s and tangential velocity {u[0]:.6g} m/s" in text
    assert f"the normal impulse {P[1]:.6g} N s (tangential {P[0]:.6g} N s): frame would pull" in text
    assert "active sets tried" not in text and "closed contacts []" not in text


# ---- 3. a pinned point tensile from the strike on: the lift-off refusal says so and gives N ----------
def test_lift_off_refusal_says_tensile_at_the_strike_and_gives_n(tmp_path):
    """Upper bar at -75 deg turning at 2 rad/s, fore bar at +100 deg to it, the floor 0.55 m below J1.
    The strike stops the arm dead; pinned at rest, the floor would have to pull the tip
    (F = J^-T dV/da, F_n < 0) from the strike on; freed, the tip's acceleration from rest, J (-M^-1 dV/da),
    points into the floor. The run stops there saying the force was tensile at entry (not that it
    turned tensile) and giving N."""
    t_hand, y = strike_state(-75.0, 100.0, -0.55, rate=2.0)
    a1, a2 = y[0], y[1]
    J, M = tip_jacobian(a1, a2), mass(a1, a2)
    F = np.linalg.solve(J.T, dV(a1, a2))
    a_free = J @ np.linalg.solve(M, -dV(a1, a2))
    assert F[1] < 0 and a_free[1] < 0
    with pytest.raises(pcmm.SimulationError) as err:
        pcmm.simulate(arm_scene(tmp_path, -75.0, 100.0, -0.55, rate=2.0))
    text = str(err.value)
    assert f"t = {t_hand:.9f} s" in text
    assert f"already tensile where 'held' is entered (the strike that pinned it): N = {F[1]:.6g} N" in text
    assert f"tangential force {F[0]:.6g} N" in text and f"normal acceleration {a_free[1]:.6g} m/s^2" in text
    assert "turns tensile" not in text


# ---- 5. a driven joint outside every loop is named with its drive, not "the loop" -----------------
def _loop_with_side_arms(make_scene):
    """A three-bar chain J1-J2-J3 (0.3 m bars) whose tip is pinned to the frame where it starts (a loop
    with one freedom), and two arms on the frame outside the loop: J4 driven by q = 30 deg + 1.5 t,
    J5 free. [initial] gives J4 = 50 deg at rest (the drive says 30 deg and 1.5 rad/s) and no rate for J5."""
    from builders import bar_xml, joint_xml, link_xml, robot_xml
    urdf = robot_xml("side", link_xml("frame"),
                     joint_xml("J1", "revolute", "frame", "l1"), bar_xml("l1", 0.3, 1.0),
                     joint_xml("J2", "revolute", "l1", "l2", xyz=(0.3, 0.0)), bar_xml("l2", 0.3, 1.0),
                     joint_xml("J3", "revolute", "l2", "l3", xyz=(0.3, 0.0)), bar_xml("l3", 0.3, 1.0),
                     joint_xml("J4", "revolute", "frame", "driven"), bar_xml("driven", 0.2, 0.5),
                     joint_xml("J5", "revolute", "frame", "free"), bar_xml("free", 0.2, 0.5))
    pin = {"name": "tip", "type": "revolute", "a": "frame", "point_a": "entry", "b": "l3", "point_b": [0.3, 0.0]}
    return make_scene({"side.urdf": urdf}, configurations={"loop": {"urdf": "side.urdf", "cut_joints": [pin]}},
                      q0={"J1": "80 deg", "J2": "-60 deg", "J3": "-60 deg", "J4": "50 deg", "J5": "10 deg"},
                      v0={"J1": 0.5, "J4": 0.0}, independent=["J1"],
                      drives=[{"joint": "J4", "coefficients": ["30 deg", 1.5]}])


def test_driven_joint_is_named_with_its_drive_not_the_loop(make_scene):
    from pcmm.model.assembly import assemble
    from pcmm.model.mechanism import Mechanism
    scene = pcmm.load_scene(_loop_with_side_arms(make_scene))
    q, v, notes = assemble(scene, Mechanism(scene)["loop"])
    assert q[3] == pytest.approx(math.radians(30), abs=1e-12) and v[3] == pytest.approx(1.5, abs=1e-12)
    text = "\n".join(notes)
    assert (f"J4 is driven (drives[0]): its drive gives {math.radians(30):.6g} rad at t = 0, "
            f"given {math.radians(50):.6g}") in text
    assert "J4 is driven (drives[0]): its drive gives 1.5 rad/s at t = 0, given 0" in text
    assert "the loop was assembled away" not in text          # J4 is in no loop; the others are as given
    assert "initial.v has no value for J5, kept as an independent coordinate: it starts at rest" in text
    assert "of the loop" not in text and "J4, " not in text


# ---- 6. a pinned point's stance force is listed beside the holds -----------------------------------
def test_stance_force_extremes_are_in_stats_holding(tmp_path):
    """The arm of test 1 planted (upper bar 50 deg, fore bar +80 deg, floor 0.65 m): at rest after the
    strike the floor holds the tip with F = J^-T dV/da (statics), the same at every sample; with the
    flat floor (n = (0, 1), t = (1, 0)) its normal part is F_y and its tangential part F_x. Both are in
    stats["holding"] beside the holds, their extremes at the first sample of the stance; the oracle's
    own reading of the series (n . F, t . F from foot.fx, foot.fy) agrees to the bit."""
    sys.path.insert(0, str(Path(__file__).parent))
    import oracle
    traj = pcmm.simulate(arm_scene(tmp_path, 50.0, 80.0, -0.65))
    _, y = strike_state(50.0, 80.0, -0.65)
    F = np.linalg.solve(tip_jacobian(y[0], y[1]).T, dV(y[0], y[1]))
    assert F[1] > 0 and abs(F[0]) < 0.8 * F[1]
    stance = traj.stats["holding"]["tip"]
    t_strike = traj.events[0]["t"]
    for part, value in (("normal", F[1]), ("tangential", F[0])):
        assert stance[part]["min"] == pytest.approx(value, rel=1e-8)
        assert stance[part]["max"] == pytest.approx(value, rel=1e-8)
        assert stance[part]["t_min"] == pytest.approx(t_strike, abs=1e-12)
    assert not oracle.check_records(traj, tmp_path)
    stance["normal"]["max"] += 1e-9
    assert any(p.startswith("stats holding tip (normal)") for p in oracle.check_records(traj, tmp_path))


def test_leg_stance_force_in_stats_holding_matches_the_statics(tmp_path):
    """The second newcomer's leg (tests/test_newcomer2_mechanisms.py, hip and knee at 60 deg, floor
    0.7 m): its statics by hand is F = (8.08030, 23.33376) N."""
    from test_newcomer2_mechanisms import leg_scene
    stance = pcmm.simulate(leg_scene(tmp_path, 60.0, 60.0, -0.7)).stats["holding"]["foot"]
    assert stance["normal"]["max"] == pytest.approx(23.33376, abs=1e-5)
    assert stance["tangential"]["max"] == pytest.approx(8.08030, abs=1e-5)


# ---- 4. a two-dimensional impulse is shown whole: the event table and impulses.png ------------------
def test_event_table_and_impulse_figure_show_the_tangential_part(tmp_path):
    """The arm of test 1: the pin's impulse P = -J^-T M w- = (3.21018, 8.84786) N s has a tangential
    part of a third of its normal one; the table row gives P_t and |P| beside the P_n column, and
    impulses.png draws P_t and |P| beside P_n (their data are the hand values)."""
    from pcmm.results.summary import event_table
    from pcmm.viz.plots import figures
    traj = pcmm.simulate(arm_scene(tmp_path, 50.0, 80.0, -0.65))
    _, y = strike_state(50.0, 80.0, -0.65)
    P = -np.linalg.solve(tip_jacobian(y[0], y[1]).T, mass(y[0], y[1]) @ y[2:])
    row = event_table(traj).splitlines()[-1]
    assert f"{P[1]:11.4e}" in row
    assert f"2-D impulse: P_t {P[0]:.4e}, |P| {math.hypot(*P):.4e} N s (the P column is P_n)" in row
    ax = figures(traj)["impulses"].axes[0]
    drawn = {line.get_label(): line.get_ydata() for line in ax.lines}
    assert drawn["$|P|$"] == pytest.approx([math.hypot(*P)], rel=1e-8)
    tangential = next(v for k, v in drawn.items() if k.startswith("$P_t$"))
    assert tangential == pytest.approx([P[0]], rel=1e-8)
    assert ax.get_ylabel() == "impulse (N·s)"


def test_event_table_of_a_one_dimensional_impulse_is_unchanged(tmp_path):
    """A frictionless ball's bounces (no tangential part): no 2-D note, P_n alone on the figure."""
    from builders import ball
    from pcmm.results.summary import event_table
    from pcmm.viz.plots import figures
    traj = pcmm.simulate(pcmm.load_scene(ball(tmp_path, 0.5, t_end=0.7)))
    assert traj.events and "2-D impulse" not in event_table(traj)
    ax = figures(traj)["impulses"].axes[0]
    assert ax.get_ylabel() == "$P_n$ (N·s)" and "$|P|$" not in [line.get_label() for line in ax.lines]


def test_pin_that_coulomb_would_not_stick_says_so(tmp_path):
    """Upper bar at -60 deg, fore bar at +120 deg to it, from rest; the floor 0.3 m below J1. The pin's
    impulse P = -J^-T M w- lies inside the cone (|P_t|/P_n < 0.8), but the stick ratio
    kappa = |D_tn| / D_tt exceeds 0.8: in Routh's process the slip stops and reverses (slide+ -> slide-)
    and compression ends sliding, at another impulse (written out here). So no split of the energy lost is
    Routh's; the event gives none, says why, and warns that the pin is not Coulomb's outcome."""
    traj = pcmm.simulate(arm_scene(tmp_path, -60.0, 120.0, -0.3))
    _, y = strike_state(-60.0, 120.0, -0.3)
    J, M = tip_jacobian(y[0], y[1]), mass(y[0], y[1])
    P = -np.linalg.solve(J.T, M @ y[2:])
    D = J @ np.linalg.solve(M, J.T)
    u = J @ y[2:]
    mu = 0.8
    assert u[0] > 0 and abs(P[0]) / P[1] < mu and abs(D[0, 1]) / D[0, 0] > mu
    # Routh's process by hand: slide+ until the slip stops, then slide- (it cannot stick) to the end of compression
    s1 = D @ np.array([-mu, 1.0])
    p1 = -u[0] / s1[0]
    un1 = u[1] + s1[1] * p1
    assert 0 < p1 and un1 < 0
    s2 = D @ np.array([mu, 1.0])
    p2 = -un1 / s2[1]
    routh_P = np.array([-mu * p1 + mu * p2, p1 + p2])
    assert abs(routh_P[0] - P[0]) > 0.1
    ev = traj.events[0]
    assert ev["impulse"]["vector"] == pytest.approx(list(P), rel=1e-8)
    fr = ev["friction"]
    assert fr["energy_lost"] is None
    assert "phases slide+ -> slide-" in fr["energy_split"]
    assert f"impulse ({routh_P[0]:.6g}, {routh_P[1]:.6g}) N s" in fr["energy_split"]
    assert any("Coulomb's law from this state would not stick" in w for w in ev["warnings"])


def test_lift_off_refusal_after_a_stance_says_the_force_turned_tensile(make_scene):
    """Three bars (0.4 m 2 kg, 0.3 m 1 kg, 0.3 m 1 kg) from 30/90/60 deg at rest; the tip is pinned (no
    friction limit) on a floor 0.3 m below J1 and the chain swings on it (one freedom). Its normal force
    falls through zero during the stance, where freed the tip would be pushed into the floor: the
    refusal says the force turned tensile at that instant (N at round-off), not that it was tensile at
    the strike, and comes after the strike."""
    bars = [Bar(0.4, 2.0), Bar(0.3, 1.0), Bar(0.3, 1.0)]
    pin = {"name": "tip", "type": "revolute", "a": "frame", "point_a": "entry", "b": "link3", "point_b": [0.3, 0.0],
           "contact": {"normal": [0.0, 1.0]}}
    tr = {"name": "tip strike", "type": "pin", "from": "free", "to": "held",
          "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"},
          "contact": {"a": "frame", "point_a": [0.0, -0.3], "b": "link3", "point_b": [0.3, 0.0], "normal": [0.0, 1.0]}}
    path = make_scene({"tri.urdf": chain_urdf(bars, name="tri")},
                      configurations={"free": "tri.urdf", "held": {"urdf": "tri.urdf", "cut_joints": [pin]}},
                      q0={"J1": "30 deg", "J2": "90 deg", "J3": "60 deg"}, v0={"J1": 0.0, "J2": 0.0, "J3": 0.0},
                      t_end=1.5, transitions=[tr])
    with pytest.raises(pcmm.SimulationError) as err:
        pcmm.simulate(pcmm.load_scene(path))
    text = str(err.value)
    assert "its normal force turns tensile at this instant: N crosses 0, " in text
    assert "already tensile" not in text
    N = float(text.split("N crosses 0, ")[1].split(" N")[0])
    assert abs(N) < 1e-9
    t_stop = float(text.split("t = ")[1].split(" s")[0])
    strike = [e for e in err.value.partial.events if e["name"] == "tip strike"]
    assert strike and t_stop > strike[0]["t"] + 0.1
