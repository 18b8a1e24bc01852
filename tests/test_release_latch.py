"""A latch let go at its value is one release (issue 22, h-release2: every guard kind).

A timed release frees a latched joint exactly at the latch's value.  The latch's coordinate guard
then sits at its value at the segment's first instant; read plain, round-off there (the compiled
loop's solve reads it +2.2e-16 past the value where the Python one reads 0.0) could be taken for a
crossing and latch the joint again at once.  It is not, by two readings (docs/limits.md, "Grazing
and resting"): a latch always has a contact (the scene loader requires one), so
:func:`pcmm.run.loop._pending` reads its normal speed at the release, lists it ``leaving`` where the
loads pull the joint away, and the segment watches it re-armed (:func:`pcmm.events.guards.left_at_value`);
and even read plain, a state the release leaves *at or past* the value, moving back out, is no sign
change in the guard's direction: the scans need the value below it first.  Where the loads push the
joint into the latch it latches again at once, with no impulse (the physics: h-release's rule).

Two mechanisms of our own: a two-bar arm on a tree (its elbow angle an entry of the state, exact),
checked against the arm's equations of motion written out by hand; and a four-bar whose latch is on
the loop's dependent joint (read through the closure solve, where the round-off is).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import pcmm
from pcmm.run import loop

from builders import Bar, arm_free_rates, arm_mass_matrix, bar_xml, chain_urdf, joint_xml, link_xml, robot_xml, scene_doc, write_scene

# ---- a two-bar arm in a horizontal plane, its elbow latched and let go by a timer ------------------
L1, L2, M1, M2 = 0.5, 0.4, 1.0, 0.6
LATCH = 0.5          # the elbow angle J2 the latch locks at (increasing)
K, C = 0.3, 0.02     # the elbow's spring (rest at J2 = 0) and damper, in 'free' only
W2 = 4.0             # the elbow's initial rate (the shoulder at rest)
T_RELEASE = 0.4


def arm(folder: Path, t_end: float = 1.0, contact: str = "joint") -> Path:
    """Upper arm on J1 (the frame), forearm on J2 at its tip; no gravity.  The elbow opens against its
    spring, latches at J2 = LATCH (into 'locked', J2 locked; a joint stop or the forearm's tip against
    a point of the upper arm) and a timer lets it go at T_RELEASE."""
    urdf = robot_xml("arm", link_xml("frame"), joint_xml("J1", "revolute", "frame", "upper"), bar_xml("upper", L1, M1),
                     joint_xml("J2", "revolute", "upper", "fore", xyz=(L1, 0.0)), bar_xml("fore", L2, M2))
    if contact == "joint":
        where = {"joint": "J2", "arm": L2}
    else:  # the forearm's tip strikes the upper arm's point where that tip is at the latch
        where = {"a": "upper", "point_a": [L1 + L2 * math.cos(LATCH), L2 * math.sin(LATCH)], "b": "fore",
                 "point_b": [L2, 0.0], "normal": [math.sin(LATCH), -math.cos(LATCH)]}
    doc = scene_doc({"free": "arm.urdf", "locked": {"from": "free", "lock": ["J2"]}},
                    {"J1": 0.0, "J2": 0.0}, {"J1": 0.0, "J2": W2}, gravity=(0.0, 0.0), t_end=t_end,
                    forces=[{"name": "elbow spring", "type": "linear", "on": {"joint": "J2"},
                             "measure": {"joint": "J2"}, "value": 0.0, "k": K, "c": C, "configurations": ["free"]}],
                    transitions=[{"name": "elbow latch", "type": "latch", "from": "free", "to": "locked", "cut": ["J2"],
                                  "guard": {"type": "coordinate", "measure": {"joint": "J2"}, "value": LATCH,
                                            "direction": "increasing"},
                                  "contact": where},
                                 {"name": "elbow release", "type": "release", "from": "locked", "to": "free",
                                  "guard": {"type": "time", "at": T_RELEASE}}])
    return write_scene(folder, doc, {"arm.urdf": urdf})


def _mass(q2):
    """The arm's mass matrix in (J1, J2) (:func:`builders.arm_mass_matrix`, by hand)."""
    return arm_mass_matrix(q2, M1, L1, M2, L2)


def _free(t, y):
    """The free arm's equations of motion (:func:`builders.arm_free_rates`, by hand)."""
    return arm_free_rates(y, M1, L1, M2, L2, k=K, c=C)


def by_hand(t_end: float):
    """(latch time, the locked arm's rate, the state at t_end): the free arm to the latch (an event of
    solve_ivp), the plastic latch keeping the angular momentum about the pivot (the first row of
    M q': no moment about J1 in the latch's impulse), rigid rotation to T_RELEASE, free again."""
    reach = lambda t, y: y[1] - LATCH
    reach.terminal, reach.direction = True, 1
    tol = {"method": "DOP853", "rtol": 1e-12, "atol": 1e-14}
    a = solve_ivp(_free, (0.0, 1.0), [0.0, 0.0, 0.0, W2], events=reach, **tol)
    t_l, (q1, q2, w1, w2) = a.t_events[0][0], a.y_events[0][0]
    momentum = _mass(q2)[0] @ [w1, w2]
    omega = momentum / _mass(LATCH)[0, 0]
    b = solve_ivp(_free, (T_RELEASE, t_end), [q1 + omega * (T_RELEASE - t_l), LATCH, omega, 0.0],
                  dense_output=True, **tol)
    return t_l, omega, b


@pytest.mark.parametrize("compiled", ["1", "0"])
@pytest.mark.parametrize("contact", ["joint", "point"])
def test_an_elbow_latch_let_go_by_a_timer_is_one_release(tmp_path, monkeypatch, compiled, contact):
    """Latched at t_l (by hand: the free arm's equations to J2 = LATCH), the arm turns rigidly at the
    rate the latch's angular momentum gives; the timer lets the elbow go at T_RELEASE with J2 at the
    latch's value and at rest relative to the upper arm, and the spring (with the turning arm's
    centrifugal load) pulls it back: no latch after the release.  Not ever: no moment acts about J1,
    so the angular momentum p1 (M q')_1 is kept, and at any J2 the kinetic energy is at least
    p1^2 / (2 M11(J2)) (the least over J2' at that p1), which at J2 = LATCH is the release's (J2' = 0
    there); with the spring's energy the same there, coming back needs at least the release's energy,
    while the damper has taken some away since: one latch and one release whatever t_end, compiled
    and Python."""
    monkeypatch.setenv("PCMM_COMPILED", compiled)
    t_l, omega, free = by_hand(1.5)
    for t_end in (1.0, 1.5):
        traj = pcmm.simulate(pcmm.load_scene(arm(tmp_path / f"{contact}{t_end}", t_end, contact)))
        assert all(v.startswith("compiled" if compiled == "1" else "python")
                   for v in traj.stats["evaluations"].values()), traj.stats["evaluations"]
        assert [e["transition"] for e in traj.events] == ["latch", "release"]
        latch, release = traj.events
        assert latch["t"] == pytest.approx(t_l, abs=1e-8)
        assert release["t"] == T_RELEASE and release["cause"] == "time"
        q2, w1 = traj.series("q", "J2"), traj.series("v", "J1")
        locked = (traj.t > latch["t"]) & (traj.t <= T_RELEASE)
        assert np.allclose(w1[locked], omega, rtol=0, atol=1e-9)
        after = traj.t > T_RELEASE
        assert np.all(q2[after] < LATCH)
        assert np.allclose(q2[after], free.sol(traj.t[after])[1], rtol=0, atol=1e-7)
    # by hand the elbow never comes back to the latch: its largest angle after the release is LATCH itself
    ts = np.linspace(T_RELEASE, 1.5, 20001)[1:]
    assert free.sol(ts)[1].max() < LATCH


# ---- a four-bar whose latch is on the loop's dependent joint, let go by a timer ---------------------
# crank J1 (0.06 m at the origin), coupler J2 (0.18 m), rocker J3 (0.12 m), the rocker's end pinned to
# the frame at (0.2, 0) by the cut joint D: builders.four_bar_latch's loop, with a spring on the crank
# (rest at VALUE / STIFF rad) instead of a constant torque, so the crank reaches the latch and is then
# pulled back.  The latch (J3 = -1.5, increasing) makes the loop rigid: it rests there until the timer.
BARS = [Bar(0.06, 0.0936), Bar(0.18, 0.2808), Bar(0.12, 0.1872)]
PIVOT, J3_LATCH, FB_RELEASE = 0.2, -1.5, 0.8
VALUE, STIFF, DAMP = 0.6, 0.5, 0.002


def sprung_four_bar(folder: Path, t_end: float, value: float = VALUE, stiff: float = STIFF) -> Path:
    cut = [{"name": "D", "type": "revolute", "a": "frame", "point_a": [PIVOT, 0.0], "b": "link3", "point_b": [0.12, 0.0]}]
    doc = scene_doc({"open": {"urdf": "fb.urdf", "cut_joints": cut}, "latched": {"from": "open", "lock": ["J3"]}},
                    {"J1": 0.0, "J2": 0.7287, "J3": -2.2519}, {"J1": 0.0, "J2": 0.0, "J3": 0.0},
                    t_end=t_end, independent=["J1"],
                    forces=[{"name": "crank spring", "type": "linear", "on": {"joint": "J1"}, "measure": {"joint": "J1"},
                             "value": value, "k": stiff, "c": DAMP, "configurations": ["open"]}],
                    transitions=[{"name": "latch", "type": "latch", "from": "open", "to": "latched", "cut": ["J3"],
                                  "guard": {"type": "coordinate", "measure": {"joint": "J3"}, "value": J3_LATCH,
                                            "direction": "increasing"},
                                  "contact": {"joint": "J3", "arm": 0.05}},
                                 {"name": "let go", "type": "release", "from": "latched", "to": "open",
                                  "guard": {"type": "time", "at": FB_RELEASE}}])
    doc["initial"]["branch"] = {"joint": "J3", "sign": "-"}
    return write_scene(folder, doc, {"fb.urdf": chain_urdf(BARS)})


def loop_angles(j1):
    """(J2, J3) at crank angle j1 on the assembly the scene starts in (J2 = 0.7287, J3 = -2.2519 at
    j1 = 0): the coupler's tip at distance 0.18 from the crank's tip and 0.12 from the pivot."""
    a, b, c = (bar.length for bar in BARS)
    p1 = np.array([a * math.cos(j1), a * math.sin(j1)])
    d = np.array([PIVOT, 0.0]) - p1
    r = float(np.hypot(*d))
    phi2 = math.atan2(d[1], d[0]) + math.acos((b * b + r * r - c * c) / (2 * b * r))
    p2 = p1 + b * np.array([math.cos(phi2), math.sin(phi2)])
    phi3 = math.atan2(-p2[1], PIVOT - p2[0])
    wrap = lambda x: (x + math.pi) % (2 * math.pi) - math.pi
    return wrap(phi2 - j1), wrap(phi3 - phi2)


def crank_load(j1, value=VALUE, stiff=STIFF, h=1e-6):
    """The generalized force on J1 of the loop at rest at j1 (no damping): the spring's minus the
    derivative of gravity's potential along the loop (the bars' centroids' heights)."""
    def height(x):
        j2, j3 = loop_angles(x)
        a, b, c = (bar.length for bar in BARS)
        m1, m2, m3 = (bar.mass for bar in BARS)
        y1 = a * math.sin(x)
        y2 = y1 + b * math.sin(x + j2)
        return 9.81 * (m1 * y1 / 2 + m2 * (y1 + y2) / 2 + m3 * (y2 + c * math.sin(x + j2 + j3) / 2))
    return value - stiff * j1 - (height(j1 + h) - height(j1 - h)) / (2 * h)


def latch_crank() -> float:
    """The crank angle where the closure gives J3 = -1.5 (bisection on :func:`loop_angles`)."""
    from scipy.optimize import brentq
    return brentq(lambda x: loop_angles(x)[1] - J3_LATCH, 1.0, 2.5, xtol=1e-14)


def test_loop_angles_are_the_scene_start():
    j2, j3 = loop_angles(0.0)
    assert (j2, j3) == (pytest.approx(0.7287, abs=1e-4), pytest.approx(-2.2519, abs=1e-4))


@pytest.mark.parametrize("compiled", ["1", "0"])
def test_a_loop_latch_let_go_at_its_value_is_one_release(tmp_path, monkeypatch, compiled):
    """By hand: the latch is where the closure gives J3 = -1.5 (crank angle j1_l, by bisection on
    :func:`loop_angles`); latched, the loop is rigid and rests there; at the release the crank's load
    (the spring's torque less gravity's, :func:`crank_load`) turns the crank back, and J3 increases
    with the crank there, so J3 leaves the latch's value decreasing: one release and no latch after
    it (to t_end 1.0 and 1.2 s, compiled and Python).  At the release the latch's guard reads the
    round-off of the closure solve (+2.2e-16 compiled, 0.0 Python): :func:`pcmm.run.loop._pending`
    lists it leaving, and the segment watches it re-armed."""
    j1_l = latch_crank()
    assert loop_angles(j1_l + 1e-4)[1] > J3_LATCH > loop_angles(j1_l - 1e-4)[1]  # J3 increases with J1
    assert crank_load(j1_l) < -0.05  # pulled back, beyond any round-off
    monkeypatch.setenv("PCMM_COMPILED", compiled)
    listed = []
    real = loop._pending

    def pending(cfg, guards, t, y0, leaving=None):
        found = real(cfg, guards, t, y0, leaving)
        if t == FB_RELEASE and cfg.name == "open":
            listed.append((found, [guards[i].transition.name for i in leaving],
                           guards[0].transition.guard.direction * guards[0](t, y0)))
        return found
    monkeypatch.setattr(loop, "_pending", pending)
    for t_end in (1.0, 1.2):
        traj = pcmm.simulate(pcmm.load_scene(sprung_four_bar(tmp_path / f"fb{t_end}", t_end)))
        assert all(v.startswith("compiled" if compiled == "1" else "python")
                   for v in traj.stats["evaluations"].values()), traj.stats["evaluations"]
        assert [e["transition"] for e in traj.events] == ["latch", "release"]
        latch, release = traj.events
        assert release["t"] == FB_RELEASE and release["cause"] == "time"
        j1, j3 = traj.series("q", "J1"), traj.series("q", "J3")
        held = (traj.t >= latch["t"]) & (traj.t <= FB_RELEASE)
        assert np.allclose(j1[held], j1_l, rtol=0, atol=1e-8)  # (J3 locked: not recorded there)
        after = traj.t > FB_RELEASE
        assert np.all(j3[after] < J3_LATCH) and j1[after][0] < j1_l and np.all(np.diff(j1[after][:5]) < 0)
    # at the release: no pending guard, the latch listed leaving, read within round-off of its value
    assert [x[:2] for x in listed] == [(None, ["latch"])] * 2
    assert all(abs(x[2]) <= 4.5e-16 for x in listed)


def test_a_loop_latch_pushed_closed_at_its_release_latches_again_at_once(tmp_path):
    """The contrast, by hand: with the spring's rest beyond the latch (the crank's load 0.6 - 0.2 j1_l
    less gravity's share is positive at the latch) the loads push J3 into the latch when the timer lets it go:
    it latches again at the same instant, with no impulse (h-release's rule: at rest and pushed
    closed), and stays latched."""
    assert crank_load(latch_crank(), value=0.6, stiff=0.2) > 0.05
    traj = pcmm.simulate(pcmm.load_scene(sprung_four_bar(tmp_path, 1.0, value=0.6, stiff=0.2)))
    assert [(e["transition"], e["t"]) for e in traj.events][1:] == [("release", FB_RELEASE), ("latch", FB_RELEASE)]
    again = traj.events[2]
    assert again["impulse"]["normal"] == 0.0 and again["kinetic_energy_before"] == again["kinetic_energy_change"] == 0.0
    j1 = traj.series("q", "J1")
    assert np.ptp(j1[traj.t >= traj.events[0]["t"]]) < 1e-9


# ---- a release's own guard (no contact) at its value where the run starts ----------------------------
# The hanging four-bar of tests/test_release_events.py (its crank spring to the driven arm), started at
# rest in 'swing' at crank angle PHI0 with a release to 'open' (the cut joint F let go) whose guard is
# the coupler-rocker angle at its value there: the run's first instant sits on the guard.  The closure
# solve puts J3 there within an ulp or two of the value, on either side (+4.4e-16 compiled, -8.9e-16
# Python at PHI0 = -0.3).
def released_four_bar(folder: Path, phi0: float, direction: str, t_end: float) -> Path:
    from test_release_events import CUT_F, FOUR_BAR_URDF, hanging_four_bar, j3_of
    doc = hanging_four_bar({"swing": {"urdf": "p.urdf", "cut_joints": CUT_F}, "open": {"urdf": "p.urdf"}},
                           phi0, t_end,
                           [{"name": "let go", "type": "release", "from": "swing", "to": "open",
                             "guard": {"type": "coordinate", "measure": {"between": ["coupler", "rocker"]},
                                       "value": j3_of(phi0), "direction": direction}}])
    return write_scene(folder, doc, {"p.urdf": FOUR_BAR_URDF})


def j3_start_acceleration_sign(phi0: float) -> int:
    """The sign of J3'' at the start, by hand: the loop starts at rest, so J3'' = (dJ3/dphi1) phi1''
    and phi1'' has the sign of the crank's load -V'(phi0) - K phi0 (the spring to the arm, at
    theta5(0) = 0; V gravity's potential along the loop)."""
    from test_release_events import K as K_ARM
    from test_release_events import dV, j3_of
    slope = (j3_of(phi0 + 1e-6) - j3_of(phi0 - 1e-6)) / 2e-6
    return int(np.sign(slope * (-dV(phi0) - K_ARM * phi0)))


@pytest.mark.parametrize("compiled", ["1", "0"])
@pytest.mark.parametrize("phi0", [-0.3, -0.6, -0.9])
def test_a_release_at_its_value_at_the_start_fires_there_when_the_loads_carry_it_over(tmp_path, monkeypatch,
                                                                                      compiled, phi0):
    """Started at rest on the release's guard with the loads accelerating J3 to its fired side, the
    release fires at the start (within the 1e-6 s the acceleration takes to carry J3 beyond an ulp of
    round-off), whatever t_end and compiled or not.  Before, the plain guard read the start by
    round-off: on the fired side the crossing was missed (no release at -0.3, decreasing; at -0.6,
    increasing, only where J3 came back through its value 0.49 s later), exactly at 0.0 it fired."""
    sign = j3_start_acceleration_sign(phi0)
    direction = "increasing" if sign > 0 else "decreasing"
    monkeypatch.setenv("PCMM_COMPILED", compiled)
    for t_end in (0.3, 0.6):
        traj = pcmm.simulate(pcmm.load_scene(released_four_bar(tmp_path / f"{t_end}", phi0, direction, t_end)))
        assert all(v.startswith("compiled" if compiled == "1" else "python")
                   for v in traj.stats["evaluations"].values()), traj.stats["evaluations"]
        assert [e["transition"] for e in traj.events] == ["release"], (phi0, direction, t_end, traj.events)
        assert traj.events[0]["t"] < 1e-6


@pytest.mark.parametrize("compiled", ["1", "0"])
@pytest.mark.parametrize("phi0", [-0.3, -0.6, -0.9])
def test_a_release_at_its_value_at_the_start_waits_when_the_loads_carry_it_away(tmp_path, monkeypatch,
                                                                              compiled, phi0):
    """The other direction: the loads carry J3 away from the guard's fired side, so the start is no
    crossing and the release waits for J3 to come back through its value: not before 0.3 s here (J3
    has moved by more than 1e-7 rad at the first step, far beyond round-off), and at one time
    whatever t_end, compiled and Python alike."""
    sign = j3_start_acceleration_sign(phi0)
    direction = "decreasing" if sign > 0 else "increasing"
    monkeypatch.setenv("PCMM_COMPILED", compiled)
    seen = []
    for t_end in (0.3, 0.6, 1.0):
        traj = pcmm.simulate(pcmm.load_scene(released_four_bar(tmp_path / f"{t_end}", phi0, direction, t_end)))
        assert all(e["t"] > 0.3 for e in traj.events), (phi0, direction, t_end, traj.events)
        seen.append([(e["transition"], round(e["t"], 9)) for e in traj.events])
    assert seen[0] == [] and seen[1] == [x for x in seen[2] if x[1] <= 0.6]


@pytest.mark.parametrize("compiled", ["1", "0"])
def test_the_loop_latch_is_one_release_even_watched_plain(tmp_path, monkeypatch, compiled):
    """Which reading protects the latch: with the re-arming undone (left_at_value returning the plain
    guards) the release is still one event here, because the closure solve leaves J3 at or past the
    latch's value (+2.2e-16 compiled, 0.0 Python), never below it, and J3 then moves away: no sign
    change in the guard's direction for the scans to take.  The re-arming is what makes that hold
    whichever side round-off puts the start on (h-release's four-bar read it -2.2e-16)."""
    monkeypatch.setenv("PCMM_COMPILED", compiled)
    monkeypatch.setattr(loop, "left_at_value", lambda cfg, guards, leaving, t: list(guards))
    traj = pcmm.simulate(pcmm.load_scene(sprung_four_bar(tmp_path, 1.2)))
    assert [(e["transition"], e["t"]) for e in traj.events][1:] == [("release", FB_RELEASE)]
