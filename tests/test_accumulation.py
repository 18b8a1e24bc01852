"""Impact accumulation that converges: no energy enters when a guard re-arms after a bounce.

Between two impacts at one stop of a one-degree-of-freedom mechanism under constant loads
(gravity, a constant torque) the flight starts and ends at the same posture, so the work of
the loads is zero and each approach speed equals the previous rebound speed; the speeds form
the geometric series v_k = e^(k-1) v_1 and the impacts accumulate in finite time.  These
tests check that on two closed loops (a torque-driven slider-crank whose slider strikes a
stop on its guide, a four-bar whose rocker strikes a stop) and on a tree (the bouncing ball),
and they check the flight-energy audit of ``stats["macro_impacts"]``.

Double precision bounds the equality: a contact point known to a few ulp (delta x) under a
normal acceleration a changes the approach speed by a delta x / v.  So the speeds agree to
1e-9 relative plus that round-off term, which is below 1e-9 relative for v > 1e-3 m/s here.
The tests also put back the old re-arming (a restart shifted 1e-12 m into the stop) and
check that they catch it.
"""
from __future__ import annotations

import dataclasses
import importlib
import math
from pathlib import Path

import numpy as np
import pytest

import builders
import pcmm
import pcmm.events.guards

SIMULATE = importlib.import_module("pcmm.run.loop")  # the module (pcmm.simulate is also the function)

E = 0.7
SLIDER_CRANK = dict(a=0.1, b=0.3, m_crank=0.5, m_rod=0.8, m_slider=2.0, torque=2.0, theta_stop=-1.0)


def _slider_crank_normal_acceleration() -> float:
    """The slider's acceleration at rest at the stop posture, from the slider-crank's own
    Lagrangian in the crank angle (written out here, no pcmm): M(th) th'' = tau - V'(th) at
    th' = 0, with M the kinetic-energy coefficient of the crank, the rod and the slider, and
    x'' = x'(th) th''."""
    p = SLIDER_CRANK
    a, b, g = p["a"], p["b"], builders.G

    def geometry(th):
        phi = math.asin(-a * math.sin(th) / b)  # the rod's absolute angle (slider on y = 0)
        crank_c = np.array([a / 2 * math.cos(th), a / 2 * math.sin(th)])
        rod_c = np.array([a * math.cos(th) + b / 2 * math.cos(phi), a * math.sin(th) + b / 2 * math.sin(phi)])
        x = a * math.cos(th) + b * math.cos(phi)
        return phi, crank_c, rod_c, x

    def d(f, th, h=1e-5):
        return (np.asarray(f(th + h)) - np.asarray(f(th - h))) / (2 * h)
    th = p["theta_stop"]
    dphi = d(lambda u: geometry(u)[0], th)
    dcrank = d(lambda u: geometry(u)[1], th)
    drod = d(lambda u: geometry(u)[2], th)
    dx = d(lambda u: geometry(u)[3], th)
    M = (p["m_crank"] * dcrank @ dcrank + p["m_crank"] * a * a / 12
         + p["m_rod"] * drod @ drod + p["m_rod"] * b * b / 12 * dphi ** 2 + p["m_slider"] * dx ** 2)
    dV = g * (p["m_crank"] * dcrank[1] + p["m_rod"] * drod[1]) - p["torque"]
    return float(dx * (-dV / M))


def _run(path, **options):
    try:
        return pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(**options))
    except pcmm.SimulationError as exc:  # a shifted guard may never merge: keep what it did
        return exc.partial


def _speeds(traj):
    """(approach speeds, rebound speeds) of the impacts, in order."""
    approach = np.array([-e["normal_velocity"]["before"] for e in traj.events if e["impact"]])
    rebound = np.array([e["normal_velocity"]["after"] for e in traj.events if e["impact"]])
    return approach, rebound


def _series_violations(traj, a_n, ulp_x, rel=1e-9, ulps=16):
    """Impacts k whose approach speed differs from impact k-1's rebound speed by more than
    ``rel`` relative plus round-off: a contact point known to ``ulp_x`` shifts the speed by
    ``a_n ulp_x / v``, and an instant known to ulp(t) (the dense output is evaluated at
    (t - t_step) / h) by ``a_n ulp(t)``; ``ulps`` of each."""
    approach, rebound = _speeds(traj)
    va, vr = approach[1:], rebound[:-1]
    t = np.array([e["t"] for e in traj.events if e["impact"]])[1:]
    allowed = rel * vr + ulps * a_n * (ulp_x / vr + np.spacing(t))
    return np.flatnonzero(np.abs(va - vr) > allowed) + 1


def _old_shifted_make_guard(shift=1e-12):
    """pcmm 0.1's re-arming: the restarted guard shifted ``shift`` into the stop, armed only
    once the gap had opened by more than that."""
    plain = pcmm.events.guards.make_guard

    def make_guard(cfg, tr, rearm=False, **kw):
        g_raw = plain(cfg, tr, **kw)
        if not rearm:
            return g_raw
        d = tr.guard.direction
        state = {"armed": False, "offset": None}

        def value(t, y):
            val = g_raw(t, y)
            if state["offset"] is None:
                state["offset"] = d * (max(0.0, d * val) + shift)
            if not state["armed"] and val * d < -shift:
                state["armed"] = True
            return val if state["armed"] else val - state["offset"]
        # the raw guard's other evaluations (an event grid's values, its affine, linear, evaluated and compiled
        # scans) read it unshifted: without them the run evaluates the planted guard through value
        others = {f.name: None for f in dataclasses.fields(g_raw)
                  if f.name in ("many", "affine", "linear", "holding", "loop_scan", "evaluator")}
        return dataclasses.replace(g_raw, value=value, **others)
    return make_guard


def _plant_old_rearming(monkeypatch):
    """pcmm 0.1's re-arming in the run: its shifted guard, built anew at every bounce.  The run takes
    a bounce's guards again for the next bounce at the same stop (pcmm.run.loop._guards: its own
    re-armed guard is a function of the state alone); this one keeps its state for one flight, so it
    is not taken again (taken again, it shifted the first flight only and both checks passed)."""
    monkeypatch.setattr(SIMULATE, "make_guard", _old_shifted_make_guard())
    built = SIMULATE._guards

    def every_bounce(*args, **kw):
        kw.pop("kept", None)
        return built(*args[:7], **kw)  # without the run's kept guards (its eighth argument)
    monkeypatch.setattr(SIMULATE, "_guards", every_bounce)


@pytest.fixture(scope="module")
def slider_crank(tmp_path_factory):
    p = SLIDER_CRANK
    path = builders.slider_crank_stop(tmp_path_factory.mktemp("sc"), E, torque=p["torque"], theta_stop=p["theta_stop"],
                                a=p["a"], b=p["b"], t_end=1.5)
    return path, _run(path, accumulation_speed=1e-6)


def test_slider_crank_approach_speed_is_the_previous_rebound_speed(slider_crank):
    _, traj = slider_crank
    a_n = _slider_crank_normal_acceleration()
    assert 3.0 < a_n < 10.0  # the torque presses the slider onto the stop
    x_stop = traj.events[0]["contact_point"][0]
    approach, rebound = _speeds(traj)
    assert len(approach) > 30 and traj.events[-1]["merge"]
    assert rebound[:-1] == pytest.approx(E * approach[:-1], rel=1e-12)  # Newton's law at each impact
    assert _series_violations(traj, a_n, np.spacing(x_stop)).size == 0
    # above 1e-3 m/s the round-off term is below 1e-9 relative: the plain 1e-9 holds there
    fast = rebound[:-1] > 1e-3
    assert fast.sum() >= 15
    assert np.all(np.abs(approach[1:][fast] / rebound[:-1][fast] - 1) < 1e-9)


def test_slider_crank_impact_count_and_merge_time_follow_the_geometric_series(slider_crank):
    _, traj = slider_crank
    approach, rebound = _speeds(traj)
    v1, acc = approach[0], 1e-6
    # merged at the first impact whose rebound e^k v1 is at most the accumulation speed
    k = math.log(acc / v1) / math.log(E)
    assert abs(k - round(k)) > 0.05  # not on the edge, where round-off could decide
    assert len(approach) == math.ceil(k)
    # once the flights are short the slider moves under its constant acceleration a_n at the
    # stop: each flight lasts 2 r / a_n, and the rest of the series after impact K sums to
    # 2 r_K (1 - e^M) / (a_n (1 - e)) for the M flights left
    a_n = _slider_crank_normal_acceleration()
    times = np.array([e["t"] for e in traj.events if e["impact"]])
    K = int(np.argmax(rebound < 1e-4))
    M = len(times) - 1 - K
    predicted = 2 * rebound[K] * (1 - E ** M) / (a_n * (1 - E))
    assert times[-1] - times[K] == pytest.approx(predicted, rel=2e-4)


def test_slider_crank_flight_energy_audit(slider_crank):
    _, traj = slider_crank
    (macro,) = traj.stats["macro_impacts"]
    assert macro["merged"] and macro["impacts"] == sum(e["impact"] for e in traj.events)
    assert macro["flights"] == macro["impacts"] - 1 and macro["flights_resolved"] >= 15
    assert macro["flight_energy_relative_max"] < 1e-8
    assert macro["guard_residual_max"] < 1e-15  # each impact where the slider meets the stop


def test_slider_crank_catches_the_old_shifted_rearming(slider_crank, monkeypatch):
    """Putting back pcmm 0.1's 1e-12 m shift breaks both checks: energy enters each flight."""
    path, _ = slider_crank
    _plant_old_rearming(monkeypatch)
    traj = _run(path, accumulation_speed=1e-6, max_events=200)
    x_stop = traj.events[0]["contact_point"][0]
    assert _series_violations(traj, _slider_crank_normal_acceleration(), np.spacing(x_stop)).size > 0
    assert traj.stats["macro_impacts"][0]["guard_residual_max"] > 1e-11


@pytest.fixture(scope="module")
def four_bar(tmp_path_factory):
    path = builders.four_bar_rocker_stop(tmp_path_factory.mktemp("fb"), E, 2.2, torque=5.0, t_end=1.5)
    return path, _run(path, accumulation_speed=1e-6)


def _estimated_normal_acceleration(traj):
    """The tip's normal acceleration at the stop from the last flights (2 r / T): it only
    sizes the round-off allowance of the speed check."""
    _, rebound = _speeds(traj)
    times = np.array([e["t"] for e in traj.events if e["impact"]])
    return float(np.max(2 * rebound[-6:-1] / np.diff(times)[-5:]))


def test_four_bar_rocker_stop_accumulates_as_the_series(four_bar):
    _, traj = four_bar
    approach, rebound = _speeds(traj)
    assert len(approach) > 30 and traj.events[-1]["merge"] and traj.segments[-1].configuration == "locked"
    assert rebound[:-1] == pytest.approx(E * approach[:-1], rel=1e-12)
    # the tip (rocker length 0.25 m) is known to a few ulp of the rocker angle, 2.2 rad
    ulp_tip = 0.25 * np.spacing(2.2)
    assert _series_violations(traj, _estimated_normal_acceleration(traj), ulp_tip).size == 0
    k = math.log(1e-6 / approach[0]) / math.log(E)
    assert abs(k - round(k)) > 0.05 and len(approach) == math.ceil(k)
    (macro,) = traj.stats["macro_impacts"]
    assert macro["flight_energy_relative_max"] < 1e-8 and macro["guard_residual_max"] < 1e-14


def test_four_bar_catches_the_old_shifted_rearming(four_bar, monkeypatch):
    path, good = four_bar
    _plant_old_rearming(monkeypatch)
    traj = _run(path, accumulation_speed=1e-6, max_events=200)
    assert traj.stats["macro_impacts"][0]["guard_residual_max"] > 1e-11
    assert _series_violations(traj, _estimated_normal_acceleration(good), 0.25 * np.spacing(2.2)).size > 0


def test_bouncing_ball_series_to_1e_8(tmp_path):
    """The tree: the ball's gap is its height, resolved to round-off near zero, so the series
    holds to 1e-9 relative all the way down to an accumulation speed of 1e-8 m/s."""
    h, acc = 1.0, 1e-8
    t1, v1 = math.sqrt(2 * h / builders.G), math.sqrt(2 * builders.G * h)
    traj = _run(builders.ball(tmp_path, E, h=h, t_end=t1 + 2 * v1 / (builders.G * (1 - E)) + 0.5), accumulation_speed=acc)
    approach, rebound = _speeds(traj)
    assert np.all(np.abs(approach[1:] / rebound[:-1] - 1)[rebound[:-1] > 1e-4] < 1e-9)
    assert _series_violations(traj, builders.G, 0.0).size == 0  # the gap is the height: its ulp vanishes at 0
    n_expected = math.ceil(math.log(acc / v1) / math.log(E))
    assert len(approach) == n_expected and traj.events[-1]["merge"]
    # merge time: t1 plus the flights 2 e^k v1 / g of the bounces before the merge
    t_merge = t1 + sum(2 * E ** k * v1 / builders.G for k in range(1, n_expected))
    assert traj.events[-1]["t"] == pytest.approx(t_merge, abs=1e-9)
    (macro,) = traj.stats["macro_impacts"]
    assert macro["flight_energy_relative_max"] < 1e-9


def test_a_stop_without_bounces_has_no_macro_impact_and_example1_latch_none_either():
    traj = pcmm.simulate(pcmm.load_scene(Path(__file__).resolve().parents[1] / "examples" / "three_bar.toml"))
    assert traj.stats["macro_impacts"] == [{
        "transition": "O3 latches", "t_first": traj.events[0]["t"], "t_last": traj.events[0]["t"], "impacts": 1,
        "flights": 0, "merged": True, "guard_residual_max": traj.stats["macro_impacts"][0]["guard_residual_max"],
        "flight_energy_residual_max": 0.0, "flight_energy_relative_max": 0.0, "flights_resolved": 0}]
    assert traj.stats["macro_impacts"][0]["guard_residual_max"] < 1e-12  # rad, at the latch angle pi


def test_example1_stop_variant_flight_energy_at_round_off():
    """Example 1 with its metamorphic joint as an e = 0.8 stop (examples/three_bar_stop.toml):
    every flight between two impacts balances kinetic plus gravity energy against the work of
    the motor, the springs and the damper to round-off, and every impact sits at pi."""
    traj = pcmm.simulate(pcmm.load_scene(Path(__file__).resolve().parents[1] / "examples" / "three_bar_stop.toml"))
    (macro,) = traj.stats["macro_impacts"]
    assert macro["impacts"] >= 1 and macro["flights"] == macro["impacts"]  # the last flight runs to t_end
    assert macro["flight_energy_relative_max"] < 1e-8
    assert macro["guard_residual_max"] < 1e-12


# ---- re-arming with a point contact: a newcomer's telescoping RRP arm (helper-14) --------------------------------------
def _telescoping_arm(folder: Path, point_contact: bool) -> Path:
    """Shoulder and elbow revolute, a prismatic `slide` in the forearm pulled in by a 10 N/m
    spring; the slider's end stop at s = 0.15 m (e = 0.5) as a point contact (gap guard) or as a
    joint stop, merging into the arm with `slide` locked; released when the hold turns tensile."""
    B = builders
    urdf = B.robot_xml(
        "rrp", B.link_xml("frame"), B.joint_xml("shoulder", "revolute", "frame", "upper"),
        B.solid_xml("upper", 0.5, 0.00375, com=(0.15, 0.0)),
        B.joint_xml("elbow", "revolute", "upper", "fore_in", xyz=(0.3, 0.0)),
        B.solid_xml("fore_in", 0.4, 0.0020833333333333333, com=(0.125, 0.0)),
        B.joint_xml("slide", "prismatic", "fore_in", "fore_out", axis=(1.0, 0.0, 0.0)),
        B.solid_xml("fore_out", 0.3, 0.001, com=(0.1, 0.0)))
    if point_contact:
        guard = {"type": "gap", "value": 0.0, "direction": "decreasing"}
        contact = {"a": "fore_in", "point_a": [0.15, 0.0], "b": "fore_out", "point_b": [0.0, 0.0], "normal": [-1.0, 0.0]}
    else:
        guard = {"type": "coordinate", "measure": {"joint": "slide"}, "value": 0.15, "direction": "increasing"}
        contact = {"joint": "slide"}
    spring = {"name": "slide spring", "type": "spring", "on": {"joint": "slide"}, "measure": {"joint": "slide"},
              "k": 10.0, "rest": 0.0, "configurations": ["free"]}
    doc = B.base_doc("rrp", "free", {"free": "rrp.urdf", "locked": {"from": "free", "lock": ["slide"]}},
                     {"shoulder": 0.0, "elbow": 0.0, "slide": 0.05}, {"shoulder": 0.0, "elbow": 0.0, "slide": 0.0},
                     t_end=1.0, forces=[spring],
                     transitions=[B.stop("slide end stop", "free", 0.5, guard, contact, merge_to="locked")])
    return B.write_scene(folder, doc, {"rrp.urdf": urdf})


def test_a_point_contact_keeps_bouncing_where_its_gap_passes_zero_after_a_bounce(tmp_path):
    """The slider's 12th bounce left the gap a hair on the fired side; the re-armed guard read
    |gap|, which dipped back to 0 as the slider moved off, and the step's cubic model took that
    for a crossing: "the guard fired but the contact is separating" at the default rtol.  Now the
    point contact bounces on as the joint stop does: the same events (merge, tensile release)
    within 1e-10 s, and each bounce keeps Newton's law."""
    (tmp_path / "p").mkdir()
    (tmp_path / "j").mkdir()
    point = pcmm.simulate(_telescoping_arm(tmp_path / "p", True))
    joint = pcmm.simulate(_telescoping_arm(tmp_path / "j", False))
    assert [(e["transition"], e["merge"]) for e in point.events] == [(e["transition"], e["merge"]) for e in joint.events]
    assert len(point.events) > 20 and any(e["merge"] for e in point.events)
    assert any(e["transition"] == "release" for e in point.events)
    assert max(abs(a["t"] - b["t"]) for a, b in zip(point.events, joint.events)) < 1e-10
    for e in point.events:
        if e["transition"] == "stop" and not e["merge"]:
            assert e["normal_velocity"]["after"] == pytest.approx(-0.5 * e["normal_velocity"]["before"], rel=1e-9)


def test_the_event_table_keeps_every_transformation_of_a_long_run(tmp_path):
    """46 events: the table shows the first and last 20 and, between them, the merge and the
    tensile release that a newcomer was looking for (they were cut out), and a prismatic joint
    stop's row keeps the header's units (it said rad/s and N m s)."""
    from pcmm.results.summary import event_table
    traj = pcmm.simulate(_telescoping_arm(tmp_path, False), pcmm.RunOptions(t_end=3.0))
    table = event_table(traj)
    assert len(traj.events) > 42
    for e in traj.events:
        if e["merge"] or e["transition"] == "release":
            assert f"{e['t']:13.9f}" in table, e["t"]
    assert "more events (all in the summary JSON)" in table
    assert "joint stop slide (prismatic): vn and P along its axis" in table and "rad/s" not in table


def test_an_arm_on_a_prismatic_joint_stop_is_refused(tmp_path):
    """It was silently ignored (a prismatic stop reports its axial impulse)."""
    path = _telescoping_arm(tmp_path, False)
    text = path.read_text()
    assert text.endswith('[transitions.contact]\njoint = "slide"\n')
    path.write_text(text + "arm = 0.1\n")
    assert "arm = 0.1" in path.read_text()
    with pytest.raises(pcmm.SceneError, match=r"contact.arm: = 0.1: a lever arm belongs to a revolute joint stop"):
        pcmm.load_scene(path)
