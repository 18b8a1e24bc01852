"""Working cycles: joint stops, releases fired by time, coordinate and reaction, holding forces.

Expectations are derived here by hand or by an independent route: the rigid (locked) arm is a
compound pendulum whose equation is written out and integrated with scipy alone; the holding
moment of a locked elbow comes from Newton-Euler on the outer link; a joint stop must give what
the equivalent point contact gives (Example 1), and a pendulum striking one obeys
omega+ = -e omega- with the impulse moment I_O (1 + e) |omega-|.
"""
from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import builders
import pcmm

ROOT = Path(__file__).resolve().parents[1]
G = builders.G
ARM = dict(L1=0.5, m1=1.0, L2=0.4, m2=0.8, phi0=0.5)


# ---- joint stops ---------------------------------------------------------------------------
def _example1(tmp_path, contact_line=None):
    text = (ROOT / "examples" / "three_bar.toml").read_text().replace("../urdf/", f"{ROOT / 'urdf'}/")
    if contact_line is not None:
        text = re.sub(r'contact = \{ a = "link2".*\}', contact_line, text)
    path = tmp_path / ("joint.toml" if contact_line else "point.toml")
    path.write_text(text)
    return pcmm.simulate(pcmm.load_scene(path))


def test_joint_stop_gives_example1s_latch(tmp_path):
    """Example 1's latch written as a joint stop on O3 with the arm 0.0625 m: the same event,
    the same velocity jump, the same final state, and the impulse at the arm is the point
    contact's (the point contact acts at 0.0625 m from O3, normal to link 2)."""
    point = _example1(tmp_path)
    joint = _example1(tmp_path, 'contact = { joint = "O3", arm = 0.0625 }')
    ep, ej = point.events[0], joint.events[0]
    assert ej["t"] == pytest.approx(ep["t"], abs=1e-12)
    for name, w in ep["v_after"].items():
        assert ej["v_after"][name] == pytest.approx(w, abs=1e-10)
    assert ej["impulse"]["normal"] == pytest.approx(ep["impulse"]["normal"], rel=1e-12)
    assert ej["impulse"]["moment"] == pytest.approx(0.0625 * ep["impulse"]["normal"], rel=1e-12)
    assert ej["impulse"]["vector"] == pytest.approx(ep["impulse"]["vector"], abs=1e-12)
    np.testing.assert_allclose(joint.segments[-1].q[-1], point.segments[-1].q[-1], atol=1e-10)


def _pendulum_joint_stop(folder, e, q_stop=-1.0, L=0.6, m=1.5, arm=0.3):
    urdf = builders.robot_xml("p", builders.link_xml("frame"), builders.joint_xml("J1", "revolute", "frame", "bar"), builders.bar_xml("bar", L, m))
    tr = builders.stop("stop", "free", e, {"type": "coordinate", "measure": {"joint": "J1"}, "value": q_stop,
                                     "direction": "decreasing"}, {"joint": "J1", "arm": arm})
    doc = builders.base_doc("pendulum", "free", {"free": "p.urdf"}, {"J1": 0.0}, {"J1": 0.0}, t_end=0.6,
                      transitions=[tr])
    return builders.write_scene(folder, doc, {"p.urdf": urdf})


def test_pendulum_striking_a_joint_stop(tmp_path):
    """omega+ = -e omega-; the impulse moment is the jump of angular momentum about the pivot
    (the pivot's impulse has no moment there): I_O (1 + e) |omega-|, reported at the arm too.
    omega- from energy: I_O w^2 / 2 = m g (L/2) (sin 0 - sin q_stop)."""
    e, L, m, q_stop = 0.5, 0.6, 1.5, -1.0
    traj = pcmm.simulate(pcmm.load_scene(_pendulum_joint_stop(tmp_path, e, q_stop, L, m)))
    ev = traj.events[0]
    I_O = m * L * L / 3
    w_minus = -math.sqrt(2 * m * G * (L / 2) * (0.0 - math.sin(q_stop)) / I_O)
    assert ev["v_before"]["J1"] == pytest.approx(w_minus, rel=1e-9)
    assert ev["v_after"]["J1"] == pytest.approx(-e * w_minus, rel=1e-9)
    assert ev["impulse"]["moment"] == pytest.approx(I_O * (1 + e) * abs(w_minus), rel=1e-9)
    assert ev["impulse"]["normal"] == pytest.approx(I_O * (1 + e) * abs(w_minus) / 0.3, rel=1e-9)
    # the stop pushes the bar back (counter-clockwise): the force at the arm is along the bar's +y
    th = q_stop
    assert ev["impulse"]["vector"] == pytest.approx([-math.sin(th) * ev["impulse"]["normal"],
                                                      math.cos(th) * ev["impulse"]["normal"]], abs=1e-9)
    assert ev["contact_point"] == pytest.approx([0.3 * math.cos(th), 0.3 * math.sin(th)], abs=1e-12)
    from pcmm.results.summary import event_table  # the table says the joint stop's vn is a joint rate
    row = event_table(traj).splitlines()[2]
    assert "joint stop J1: vn in rad/s, P at its 0.3 m arm" in row
    assert f"{ev['impulse']['normal']:11.4e}" in row and "-0.0000e+00" not in row


def test_joint_stop_needs_a_guard_on_its_joint(tmp_path):
    path = _pendulum_joint_stop(tmp_path, 0.5)
    doc = tomllib.loads(path.read_text())
    assert doc["transitions"][0]["guard"]["measure"] == {"joint": "J1"}
    doc["transitions"][0]["guard"]["measure"] = {"link": "bar"}
    path.write_text(builders.dump_toml(doc))
    with pytest.raises(pcmm.SceneError, match=r"contact\.joint.*must measure that joint"):
        pcmm.load_scene(path)


# ---- releases of a two-link arm ------------------------------------------------------------------
def _arm(folder, release_guard, t_end=0.6):
    """Two bars (shoulder S at the origin, elbow E at the tip of link 1) under gravity, starting
    horizontal at rest with the elbow locked at phi0 ('locked': E fixed in the URDF); a release
    transition frees the elbow ('free')."""
    p = ARM
    parts = (builders.link_xml("frame"), builders.joint_xml("S", "revolute", "frame", "link1"), builders.bar_xml("link1", p["L1"], p["m1"]))
    free = builders.robot_xml("arm", *parts, builders.joint_xml("E", "revolute", "link1", "link2", xyz=(p["L1"], 0.0)),
                    builders.bar_xml("link2", p["L2"], p["m2"]))
    locked = builders.robot_xml("arm_locked", *parts, builders.joint_xml("E", "fixed", "link1", "link2", xyz=(p["L1"], 0.0),
                                                      yaw=p["phi0"]), builders.bar_xml("link2", p["L2"], p["m2"]))
    tr = {"name": "elbow release", "type": "release", "from": "locked", "to": "free", "guard": release_guard}
    doc = builders.base_doc("arm", "locked", {"locked": "locked.urdf", "free": "free.urdf"}, {"S": 0.0}, {"S": 0.0},
                      t_end=t_end, transitions=[tr])
    return builders.write_scene(folder, doc, {"locked.urdf": locked, "free.urdf": free})


def _rigid_arm():
    """The locked arm as one compound pendulum about S: I_S theta'' = -g (x of m r_c)."""
    p = ARM
    r1 = np.array([p["L1"] / 2, 0.0])
    r2 = np.array([p["L1"] + p["L2"] / 2 * math.cos(p["phi0"]), p["L2"] / 2 * math.sin(p["phi0"])])
    I_S = p["m1"] * p["L1"] ** 2 / 12 + p["m1"] * r1 @ r1 + p["m2"] * p["L2"] ** 2 / 12 + p["m2"] * r2 @ r2
    mrc = p["m1"] * r1 + p["m2"] * r2

    def alpha(th):
        c, s = math.cos(th), math.sin(th)
        return -G * (mrc[0] * c - mrc[1] * s) / I_S

    def rhs(t, y):
        return [y[1], alpha(y[0])]

    def state(t):
        sol = solve_ivp(rhs, (0.0, t), [0.0, 0.0], method="DOP853", rtol=1e-13, atol=1e-14)
        return sol.y[0, -1], sol.y[1, -1]

    def elbow_moment(t):
        """Newton-Euler on link 2 about the elbow: M = I2c alpha + m2 (r x (a_c2 - g))_z, with the
        elbow and link 2's centre moving with the rigid body."""
        th, w = state(t)
        a = alpha(th)
        c, s = math.cos(th), math.sin(th)
        R = np.array([[c, -s], [s, c]])
        rc2 = R @ r2
        r_e = R @ np.array([p["L1"], 0.0])
        a_c2 = a * np.array([-rc2[1], rc2[0]]) - w * w * rc2
        rel = rc2 - r_e
        f = p["m2"] * (a_c2 - np.array([0.0, -G]))
        return p["m2"] * p["L2"] ** 2 / 12 * a + (rel[0] * f[1] - rel[1] * f[0])
    return state, elbow_moment


def _check_release(traj, t_release):
    ev = [e for e in traj.events if e["transition"] == "release"]
    assert len(ev) == 1
    ev = ev[0]
    assert ev["t"] == pytest.approx(t_release, abs=1e-9)
    assert ev["impact"] is False and ev["impulse"]["normal"] == 0.0
    assert ev["from"] == "locked" and ev["to"] == "free"
    # no impulse: every body keeps its velocity, the kinetic energy is unchanged
    assert ev["velocity_jump_max"] < 1e-12
    assert ev["kinetic_energy_after"] == pytest.approx(ev["kinetic_energy_before"], rel=1e-12, abs=1e-15)
    # the freed elbow starts where it was locked, at rest relative to link 1
    assert ev["freed"]["E"] == pytest.approx(ARM["phi0"], abs=1e-12)
    assert ev["v_after"]["E"] == pytest.approx(0.0, abs=1e-12)
    state, _ = _rigid_arm()
    th, w = state(ev["t"])
    assert ev["v_after"]["S"] == pytest.approx(w, rel=1e-9)
    # poses continuous: link 2's centre the same in both segments at the release
    a, b = traj.segments[-2], traj.segments[-1]
    assert a.t[-1] == b.t[0]
    np.testing.assert_allclose(a.xy[-1], b.xy[0], atol=1e-12)
    np.testing.assert_allclose(a.omega[-1], b.omega[0], atol=1e-12)
    return ev


def test_release_fired_by_time(tmp_path):
    traj = pcmm.simulate(pcmm.load_scene(_arm(tmp_path, {"type": "time", "at": 0.3})))
    ev = _check_release(traj, 0.3)
    assert ev["cause"] == "time"


def test_release_fired_by_a_coordinate(tmp_path):
    """The elbow frees when the shoulder reaches -0.8 rad: the instant from the compound
    pendulum integrated independently."""
    state, _ = _rigid_arm()
    t_star = brentq(lambda t: state(t)[0] + 0.8, 0.05, 0.6, xtol=1e-14)
    guard = {"type": "coordinate", "measure": {"joint": "S"}, "value": -0.8, "direction": "decreasing"}
    _check_release(pcmm.simulate(pcmm.load_scene(_arm(tmp_path, guard))), t_star)


def test_release_fired_by_the_holding_moment(tmp_path):
    """The elbow frees when the moment holding it crosses a threshold: the instant from
    Newton-Euler on link 2 of the independently integrated rigid arm.  The holding moment is
    also recorded over time (constraint force 'E.hold') and its extremes land in stats."""
    _, moment = _rigid_arm()
    m0, m1 = moment(0.0), moment(0.3)
    threshold = 0.5 * (m0 + m1)
    t_star = brentq(lambda t: moment(t) - threshold, 0.0, 0.3, xtol=1e-14)
    guard = {"type": "reaction", "of": "E", "value": threshold, "direction": "increasing" if m1 > m0 else "decreasing"}
    traj = pcmm.simulate(pcmm.load_scene(_arm(tmp_path, guard)))
    ev = _check_release(traj, t_star)
    assert ev["cause"] == "reaction"
    seg = traj.segments[0]
    hold = seg.constraint_forces[:, seg.constraint_labels.index("E.hold")]
    for i in (0, len(seg.t) // 2, -1):
        assert hold[i] == pytest.approx(moment(seg.t[i]), rel=1e-8, abs=1e-10)
    ext = traj.stats["holding"]["E.hold"]
    assert ext["min"] == pytest.approx(hold.min()) and ext["max"] == pytest.approx(hold.max())


@pytest.mark.parametrize("guard,message", [
    ({"type": "time"}, "either at .* or every"),
    ({"type": "time", "at": 0.1, "every": 0.2}, "either at .* or every"),
    ({"type": "reaction", "of": "nowhere", "value": 0.0, "direction": "increasing"}, "names neither a joint"),
    ({"type": "gap", "value": 0.0, "direction": "increasing"}, "a release has no contact"),
])
def test_release_guard_errors_name_the_field(tmp_path, guard, message):
    with pytest.raises(pcmm.SceneError, match=message):
        pcmm.load_scene(_arm(tmp_path, guard))


def test_release_must_add_freedom(tmp_path):
    path = _arm(tmp_path, {"type": "time", "at": 0.3})
    path.write_text(path.read_text().replace('to = "free"', 'to = "locked"'))
    with pytest.raises(pcmm.SceneError, match="a release goes to a configuration with more freedom"):
        pcmm.load_scene(path)


# ---- a merge watched across a later lock -----------------------------------------------------------
THREE = dict(L1=0.5, L2=0.4, L3=0.3, m1=1.0, m2=0.8, m3=0.5, E_s=-0.3, W_s=0.8)


def _three_link(folder):
    """Three bars (shoulder S, elbow E, wrist W) falling from horizontal. The elbow strikes a
    plastic joint stop at E = -0.3 and merges (held by compression only); later the wrist
    latches at W = 0.8.  Configurations: free, elbow_locked, both_locked, and wrist_locked (the
    elbow free again with the wrist locked: where a tensile elbow hold releases to)."""
    p = THREE

    def arm(name, E, W):
        return builders.robot_xml(
            name, builders.link_xml("frame"), builders.joint_xml("S", "revolute", "frame", "link1"), builders.bar_xml("link1", p["L1"], p["m1"]),
            builders.joint_xml("E", "revolute" if E is None else "fixed", "link1", "link2", xyz=(p["L1"], 0.0), yaw=E or 0.0),
            builders.bar_xml("link2", p["L2"], p["m2"]),
            builders.joint_xml("W", "revolute" if W is None else "fixed", "link2", "link3", xyz=(p["L2"], 0.0), yaw=W or 0.0),
            builders.bar_xml("link3", p["L3"], p["m3"]))
    urdfs = {"free.urdf": arm("free", None, None), "elbow.urdf": arm("elbow", p["E_s"], None),
             "both.urdf": arm("both", p["E_s"], p["W_s"]), "wrist.urdf": arm("wrist", None, p["W_s"])}
    trs = [builders.stop("elbow stop", "free", 0.0, {"type": "coordinate", "measure": {"joint": "E"}, "value": p["E_s"],
                                                "direction": "decreasing"}, {"joint": "E", "arm": 0.1},
                   merge_to="elbow_locked", cut=["E"]),
           {"name": "wrist latch", "type": "latch", "from": "elbow_locked", "to": "both_locked", "cut": ["W"],
            "guard": {"type": "coordinate", "measure": {"joint": "W"}, "value": p["W_s"], "direction": "decreasing"},
            "contact": {"joint": "W", "arm": 0.1}}]
    doc = builders.base_doc("three", "free", {"free": "free.urdf", "elbow_locked": "elbow.urdf",
                                        "both_locked": "both.urdf", "wrist_locked": "wrist.urdf"},
                      {"S": 0.0, "E": 0.0, "W": 0.0}, {"S": 0.0, "E": 0.0, "W": 0.0}, t_end=1.5, transitions=trs)
    return builders.write_scene(folder, doc, urdfs)


def test_elbow_merge_released_when_its_moment_turns_tensile_after_the_wrist_latch(tmp_path):
    """After the wrist latch the whole arm is one rigid body on S.  The elbow stop's holding
    moment is what links 2 and 3 (rigid) need at the elbow: by Newton-Euler about the elbow,
    M = sum_i I_ci alpha + m_i (r_Eci x (a_ci - g)), with the rigid body integrated here from
    the state just after the latch.  pcmm must release the elbow where M falls through zero,
    into wrist_locked, with no impulse."""
    p = THREE
    traj = pcmm.simulate(pcmm.load_scene(_three_link(tmp_path)))
    names = [(e["name"], e["transition"], e["to"]) for e in traj.events]
    latch = next(i for i, n in enumerate(names) if n[0] == "wrist latch")
    # a plastic merge whose hold is tensile from its first instant separates at once
    assert names[:2] == [("elbow stop", "stop", "elbow_locked"), ("elbow stop", "release", "free")]
    assert traj.events[0]["t"] == traj.events[1]["t"]
    assert names[latch + 1] == ("elbow stop", "release", "wrist_locked")
    release = traj.events[latch + 1]
    assert release["cause"] == "tensile holding force" and release["velocity_jump_max"] < 1e-12

    seg = next(s for s in traj.segments if s.configuration == "both_locked")
    th0, w0 = seg.q[0, 0], traj.events[latch]["v_after"]["S"]
    c, s_ = math.cos(p["E_s"]), math.sin(p["E_s"])
    R_E = np.array([[c, -s_], [s_, c]])
    c, s_ = math.cos(p["E_s"] + p["W_s"]), math.sin(p["E_s"] + p["W_s"])
    R_W = np.array([[c, -s_], [s_, c]])
    elbow = np.array([p["L1"], 0.0])
    wrist = elbow + R_E @ np.array([p["L2"], 0.0])
    # centres in link 1's frame, masses, central inertias
    bodies = [(np.array([p["L1"] / 2, 0.0]), p["m1"], p["m1"] * p["L1"] ** 2 / 12),
              (elbow + R_E @ np.array([p["L2"] / 2, 0.0]), p["m2"], p["m2"] * p["L2"] ** 2 / 12),
              (wrist + R_W @ np.array([p["L3"] / 2, 0.0]), p["m3"], p["m3"] * p["L3"] ** 2 / 12)]
    I_S = sum(Ic + m * r @ r for r, m, Ic in bodies)
    mrc = sum(m * r for r, m, _ in bodies)

    def alpha(th):
        return -G * (mrc[0] * math.cos(th) - mrc[1] * math.sin(th)) / I_S
    t_latch = traj.events[latch]["t"]
    sol = solve_ivp(lambda t, y: [y[1], alpha(y[0])], (t_latch, t_latch + 1.0), [th0, w0], method="DOP853",
                    rtol=1e-13, atol=1e-14, dense_output=True)

    def moment(t):
        th, w = sol.sol(t)
        a = alpha(th)
        R = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        e_w = R @ elbow
        total = 0.0
        for r, m, Ic in bodies[1:]:
            rc = R @ r
            acc = a * np.array([-rc[1], rc[0]]) - w * w * rc
            rel, f = rc - e_w, m * (acc - np.array([0.0, -G]))
            total += Ic * a + rel[0] * f[1] - rel[1] * f[0]
        return total
    assert moment(t_latch) > 0  # compressive: the stop holds the elbow
    t_zero = brentq(moment, t_latch, release["t"] + 0.05, xtol=1e-14)
    assert release["t"] == pytest.approx(t_zero, abs=1e-8)
    # the recorded hold follows the same moment while both are locked
    hold = seg.constraint_forces[:, seg.constraint_labels.index("elbow stop.hold")]
    for i in (0, len(seg.t) // 3, -1):
        assert hold[i] == pytest.approx(moment(seg.t[i]), rel=1e-7, abs=1e-9)


# ---- Example 2 past its merge -------------------------------------------------------------------------
@pytest.mark.slow  # a 17 s run of the double-folded cycle
def test_example2_cycle_repeats_every_crank_turn():
    """examples/double_folded_cycle.toml: impact, macro-impact, merge, release when the stop would
    pull, and again one crank turn (10 s) later, to 1e-7 s: the cycle closes (i = i - c)."""
    traj = pcmm.simulate(pcmm.load_scene(ROOT / "examples" / "double_folded_cycle.toml"), pcmm.RunOptions(t_end=17.0))
    first = [e for e in traj.events if e["transition"] != "stop" or e["merge"] or e is traj.events[0]]
    kinds = [(e["transition"], e["from"], e["to"]) for e in traj.events if e["transition"] == "release" or e["merge"]]
    assert kinds == [("stop", "config1", "config2"), ("release", "config2", "config1")] * 2
    cycle = [e for e in traj.events if e["t"] < 10.0]
    again = [e for e in traj.events if e["t"] >= 10.0]
    assert len(cycle) == len(again) and len(first) >= 4
    for a, b in zip(cycle, again):
        assert b["t"] - a["t"] == pytest.approx(10.0, abs=1e-7)
        # the same to the integration accuracy (rtol 1e-10 over a 10 s cycle) and round-off at tiny speeds
        assert b["normal_velocity"]["before"] == pytest.approx(a["normal_velocity"]["before"], rel=1e-6, abs=5e-10)
    release = [e for e in traj.events if e["transition"] == "release"]
    assert all(e["cause"] == "tensile holding force" and e["velocity_jump_max"] < 1e-9 for e in release)


def test_example2_locked_slider_jams_the_driven_loop_with_a_message():
    with pytest.raises(pcmm.SimulationError, match="jams the driven loop") as info:
        pcmm.simulate(pcmm.load_scene(ROOT / "examples" / "double_folded.toml"), pcmm.RunOptions(t_end=8.0))
    assert info.value.partial.segments[-1].t[-1] == pytest.approx(7.677, abs=2e-3)


# ---- a slider-crank held at its stop by its motor ----------------------------------------------
SC_TAU, SC_THETA = 0.5, -1.0  # motor torque (N m) and the crank angle at the stop


def _motor_hold(tau=SC_TAU, theta=SC_THETA, a=0.1, b=0.3) -> float:
    """The stop's normal force holding :func:`builders.slider_crank_stop`'s slider against the
    crank torque ``tau`` at crank angle ``theta``, by virtual work: N = tau / (dx/dtheta), with
    x = a cos(theta) + sqrt(b^2 - a^2 sin^2(theta))."""
    dxdth = -a * math.sin(theta) - a * a * math.sin(theta) * math.cos(theta) / math.sqrt(b * b - (a * math.sin(theta)) ** 2)
    return tau / dxdth


def _slider_crank(tmp_path, edit):
    """:func:`builders.slider_crank_stop` (e = 0, no gravity, torque SC_TAU, the stop at SC_THETA,
    1 s) with ``edit(doc)`` applied to its scene document."""
    path = builders.slider_crank_stop(tmp_path, e=0.0, torque=SC_TAU, g=0.0, theta_stop=SC_THETA, t_end=1.0)
    doc = tomllib.loads(path.read_text())
    edit(doc)
    path.write_text(builders.dump_toml(doc))
    return path


def _held_until(tmp_path, value) -> dict:
    """The closest-approach record of a release watching the stop's holding force for a drop
    to ``value``, where the motor holds the slider for good (the stop held by compression only
    would otherwise be undone there)."""
    def edit(doc):
        doc["transitions"][0]["unmerge"] = False
        doc["transitions"].append({"name": "let go", "type": "release", "from": "locked", "to": "free",
                                   "guard": {"type": "reaction", "of": "stop", "value": value, "direction": "decreasing"}})
    traj = pcmm.simulate(pcmm.load_scene(_slider_crank(tmp_path, edit)))
    assert traj.segments[-1].configuration == "locked"
    (rec,) = traj.stats["closest_approach"]
    return rec


@pytest.mark.parametrize("motor_in", [("free", "locked"), ("locked", "coast")])
def test_a_stop_holds_against_the_forces_of_the_configuration_it_holds_in(tmp_path, motor_in):
    """A slider-crank's slider merges with its stop (e = 0, no gravity) and is let go by a timer
    into 'coast', a configuration with the same joints free as 'free'.  A constant 1.5 N on the
    slider's joint P (listed where P is free: it is internal once P is locked, but the stop holds
    it) pushes it into the stop too.  While locked, by virtual work N = tau / (dx/dtheta) + 1.5 N
    at the stop posture.  The hold is solved on a configuration with the slider free; whichever
    that is, the forces are those of 'locked' plus P's own (it used to take 'coast's: no motor
    there, and 'coast' had not registered the contact point, a traceback)."""
    def edit(doc):
        doc["configurations"]["coast"] = dict(doc["configurations"]["free"])
        doc["forces"][0]["configurations"] = list(motor_in)
        doc["forces"].append({"name": "push", "type": "torque", "on": {"joint": "P"}, "value": 1.5,
                              "configurations": ["free", "coast"]})
        doc["transitions"].append({"name": "let go", "type": "release", "from": "locked", "to": "coast",
                                   "guard": {"type": "time", "at": 0.9}})
        if "free" not in motor_in:  # the slider must still reach the stop: push it from the start
            doc["initial"]["v"] = {"A": 6.0, "B": 0.0, "P": 0.0}
    traj = pcmm.simulate(pcmm.load_scene(_slider_crank(tmp_path, edit)))
    assert [(e["from"], e["to"]) for e in traj.events][-2:] == [("free", "locked"), ("locked", "coast")]
    hold = traj.stats["holding"]["stop.hold"]
    assert hold["min"] == pytest.approx(_motor_hold() + 1.5, abs=1e-9)
    assert hold["max"] == pytest.approx(_motor_hold() + 1.5, abs=1e-9)


def test_switches_that_take_no_time_are_named_not_counted_to_the_event_budget():
    """64 configuration switches at one instant are a cycle no impulse can end (a release into a
    configuration whose guard sends it straight back): the run stops naming the transitions of
    the cycle (it used to say "more than 10000 events ... raise solver.max_events", advice that
    cannot help).  Bounces at one instant (same configuration) and switches at different times
    are not such a cycle."""
    from pcmm.run.actions import ZERO_TIME_CYCLE, zero_time_cycle as _zero_time_cycle
    back_and_forth = [{"t": 0.9, "name": "let go", "from": "locked", "to": "coast"},
                      {"t": 0.9, "name": "stop again", "from": "coast", "to": "locked"}] * (ZERO_TIME_CYCLE // 2)
    assert _zero_time_cycle(back_and_forth) == "'let go' (locked -> coast), 'stop again' (coast -> locked)"
    assert _zero_time_cycle(back_and_forth[:-1]) == ""  # one switch short of the limit
    later = [dict(e, t=0.9 + 1e-9 * k) for k, e in enumerate(back_and_forth)]
    assert _zero_time_cycle(later) == ""  # time passes between them
    bounces = [dict(e, to=e["from"]) for e in back_and_forth]
    assert _zero_time_cycle(bounces) == ""  # impacts without a switch: the accumulation rule's business


@pytest.mark.parametrize("torque", [0.4, 0.6, 0.8])
def test_a_latch_pushed_closed_when_released_latches_again_at_once(tmp_path, torque):
    """A four-bar whose coupler latches onto its rocker (J3 rising through -1.5) is let go at
    t = 0.8 s while the motor still drives it: the freed joint starts at rest exactly at its latch
    value and is pushed into the latch, so the latch closes again at that instant with no impulse
    and the mechanism stays latched (the timer fires once).  The freed joint's value, re-read from
    the links' poses, lands an ulp either side of -1.5 depending on the torque: that ulp used to
    decide between re-latching at once (then a 64-switch cycle with the timer) and swinging on
    past the latch for a whole crank turn."""
    traj = pcmm.simulate(pcmm.load_scene(builders.four_bar_latch(tmp_path, torque=torque)))
    assert [(e["name"], e["t"]) for e in traj.events][1:] == [("let go", 0.8), ("latch", 0.8)]
    relatch = traj.events[2]
    assert abs(relatch["impulse"]["normal"]) < 1e-12  # at rest: nothing to absorb
    assert traj.segments[-1].configuration == "latched" and traj.segments[-1].t[-1] == pytest.approx(1.2)


def test_a_reaction_guard_that_never_fires_reports_its_closest_approach(tmp_path):
    """A release watching the stop's holding force for a drop to 1 N never fires: the motor holds
    the slider at N = tau / (dx/dtheta) for good.  The run says so, as for a coordinate guard
    (it used to end in 'locked' with no word)."""
    rec = _held_until(tmp_path, 1.0)
    assert rec["transition"] == "let go" and rec["guard"] == "holding force of 'stop'"
    assert rec["closest"] == pytest.approx(_motor_hold(), abs=1e-9)
    assert rec["distance"] == pytest.approx(_motor_hold() - 1.0, abs=1e-9)


def test_a_guard_nearest_where_its_configuration_was_entered_says_so(tmp_path):
    """Let go at t = 0.9 s into 'coast' at the stop itself, where a spring on P pulls the slider
    back: coast's own stop guard is at its value at entry and never nearer afterwards.  The
    closest-approach line says it was nearest where the run entered (it read as a near miss)."""
    def edit(doc):
        doc["configurations"]["coast"] = dict(doc["configurations"]["free"])
        doc["forces"][0]["configurations"] = ["free", "locked"]
        doc["forces"].append({"name": "return", "type": "torque", "on": {"joint": "P"}, "value": -3.0,
                              "configurations": ["coast"]})
        again = dict(doc["transitions"][0], name="stop again", **{"from": "coast"})
        doc["transitions"] += [again, {"name": "let go", "type": "release", "from": "locked", "to": "coast",
                                       "guard": {"type": "time", "at": 0.9}}]
    path = _slider_crank(tmp_path, edit)
    traj = pcmm.simulate(pcmm.load_scene(path))
    assert traj.segments[-1].configuration == "coast"
    (rec,) = traj.stats["closest_approach"]
    assert rec["transition"] == "stop again" and rec["at_entry"] and rec["t"] == pytest.approx(0.9, abs=1e-12)
    assert rec["distance"] < 1e-12
    from pcmm.run.approach import describe
    assert "at t = 0.9 s (where the run entered the configuration), " in describe([rec])


def test_a_reaction_guard_on_a_joint_that_moves_freely_is_refused_at_load(tmp_path):
    """A reaction guard watching a joint that its configuration does not lock has no holding
    force to watch: it was accepted and silently never fired; now the loader names the joint,
    the configuration and what that configuration does lock."""
    def edit(doc):
        doc["configurations"]["coast"] = dict(doc["configurations"]["free"])
        doc["transitions"].append({"name": "let go", "type": "release", "from": "locked", "to": "coast",
                                   "guard": {"type": "reaction", "of": "A", "value": 1.0, "direction": "decreasing"}})
    path = _slider_crank(tmp_path, edit)
    with pytest.raises(pcmm.SceneError) as err:
        pcmm.load_scene(path)
    assert err.value.problems == [
        f"{path}: transitions[1] (let go).guard.of: = 'A': moves freely in 'locked', where this guard is watched, "
        "so nothing holds it and its holding force is never defined; a reaction guard watches a joint that "
        "configuration locks (P) or a stop that merged into it"]


def test_a_reaction_guard_already_past_its_value_says_so(tmp_path):
    """Waiting for the hold (N = tau / (dx/dtheta), about 5 N) to drop below 10 N: it is below from
    the merge on and never crosses, so the guard never fires; the run says it stayed past the
    value (it read "4.997 short", as if the force had to fall further)."""
    rec = _held_until(tmp_path, 10.0)
    assert rec["past"] and rec["distance"] == pytest.approx(10.0 - _motor_hold(), abs=1e-9)
    from pcmm.run.approach import describe
    assert "past it, on the side it fires to (a guard fires on a crossing in its direction)" in describe([rec])
