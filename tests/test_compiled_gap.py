"""A tree's contact gap guard read in C++ (pcmm/model/_guard_eval.hpp): the compiled segment loop
scans it and the compiled locator locates it, so a bouncing tree's flight comes back to Python only
at the steps where the gap may close.  It must be the Python guard (pcmm.events.guards._gap: value
and rate, plain and re-armed) at hypothesis-drawn states of drawn trees with drawn point contacts,
and the runs it drives must be the runs with the Python guard (events to 1e-12 s, states to 1e-10)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from builders import (
    EXAMPLES,
    Bar,
    G,
    ball,
    base_doc,
    chain_urdf,
    stop,
    write_scene,
)
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import pcmm
from pcmm.errors import SimulationError
from pcmm.events import contact as contacts
from pcmm.events.guards import UNFIRED, make_guard
from pcmm.model import compiled
from pcmm.model.mechanism import Mechanism
from pcmm.ode import integrators

td = compiled._tree_dynamics
pytestmark = pytest.mark.skipif(td is None or not hasattr(td, "guard_value") or not compiled.enabled(),
                                reason=f"the compiled contact gap is not built or is off: {compiled.why_not()}")


def _chain_scene(folder, bars, contact, q, v, e=0.8, t_end=1.0, g=G, solver=None):
    """A chain (``bars``: joints J1..Jn, links link1..n) with one stop whose guard is the gap of
    ``contact`` (decreasing), merging nowhere (each strike a bounce)."""
    tr = stop("hit", "c1", e, {"type": "gap", "value": 0.0, "direction": "decreasing"}, contact)
    doc = base_doc("gap_chain", "c1", {"c1": "chain.urdf"}, q, v, g=g, t_end=t_end, solver=solver, transitions=[tr])
    return write_scene(folder, doc, {"chain.urdf": chain_urdf(bars)})


def _two_link_hit(folder, t_end=2.0, e=0.7):
    """Two bars on J1 (frame) and J2 (link 1's tip), gravity: link 2's tip strikes a point of link 1
    (x = 0.2 along it) from above, the normal fixed in link 1 (it turns with it: the rate's w_a term)."""
    bars = [Bar(0.5, 1.0), Bar(0.4, 0.6)]
    contact = {"a": "link1", "point_a": [0.2, 0.0], "b": "link2", "point_b": [0.4, 0.0], "normal": [0.0, 1.0]}
    return _chain_scene(folder, bars, contact, {"J1": 0.3, "J2": 2.2}, {"J1": 1.0, "J2": -2.0}, e=e, t_end=t_end)


def _pendulum_floor(folder, t_end=2.0, e=0.9):
    """A bar on J1 whose tip strikes a floor at y = -0.3 (a gap between the frame and the tip)."""
    contact = {"a": "frame", "point_a": [0.0, -0.3], "b": "link1", "point_b": [0.6, 0.0], "normal": [0.0, 1.0]}
    return _chain_scene(folder, [Bar(0.6, 1.5)], contact, {"J1": 0.2}, {"J1": 0.0}, e=e, t_end=t_end)


def _runs(path, flag, monkeypatch, t_end=None):
    monkeypatch.setattr(contacts, "COMPILED_CONTACTS", flag)
    scene = pcmm.load_scene(path)
    return pcmm.simulate(scene, pcmm.RunOptions(t_end=t_end)) if t_end is not None else pcmm.simulate(scene)


def _states(traj):
    return np.concatenate([np.hstack([s.q, s.v]) for s in traj.segments])


def _differences(a, b, slowest=0.0):
    """How far run ``a`` is from run ``b``, up to the first strike slower than ``slowest`` (m/s) in ``b``:
    (the largest difference of the event times, of the velocities after each event, and of the states at
    the samples of the same time (to 1e-12 s) in the same segment; the number of such samples).  The
    events must have the same names in the same order.  (A last-bit difference of the restart state after a
    bounce may move the next steps: the step-size control reads an error estimate that nearly cancels;
    so samples are compared where their times agree.)"""
    slow = [k for k, ev in enumerate(b.events) if abs(ev["normal_velocity"]["before"]) < slowest]
    k = slow[0] if slow else len(b.events)
    ea, eb = list(a.events)[:k], list(b.events)[:k]
    assert [ev["name"] for ev in ea] == [ev["name"] for ev in eb] and len(a.events) >= k
    dt = max((abs(x["t"] - y["t"]) for x, y in zip(ea, eb)), default=0.0)
    dv = max((np.max(np.abs(np.array(list(x["v_after"].values())) - np.array(list(y["v_after"].values()))))
              for x, y in zip(ea, eb)), default=0.0)
    dy, matched = 0.0, 0
    for sa, sb in zip(list(a.segments)[:k + 1], list(b.segments)[:k + 1]):
        ya, yb = np.hstack([sa.q, sa.v]), np.hstack([sb.q, sb.v])
        at = np.clip(np.searchsorted(sb.t, sa.t - 1e-12), 0, len(sb.t) - 1)
        same = np.abs(sb.t[at] - sa.t) <= 1e-12
        if same.any():
            dy = max(dy, float(np.max(np.abs(ya[same] - yb[at[same]]))))
            matched += int(same.sum())
    return dt, dv, dy, matched


def _same_run(a, b, t_tol=1e-12, y_tol=1e-10):
    """The same events (names, times to ``t_tol``, velocities after each to ``y_tol``) and the same states
    (to ``y_tol``) at the samples of the same time, the end's included."""
    dt, dv, dy, matched = _differences(a, b)
    assert dt <= t_tol and dv <= y_tol and dy <= y_tol and matched >= 2
    assert a.t[-1] == b.t[-1] and np.max(np.abs(_states(a)[-1] - _states(b)[-1])) <= y_tol


# ---- the guard at a state ---------------------------------------------------------------------
JOINTS = st.sampled_from(["revolute", "revolute", "prismatic_x", "prismatic_y"])


@st.composite
def trees_with_contacts(draw):
    """1-3 joints (revolute, or prismatic along x or y), bars of drawn lengths and yaws; a contact
    between link a (the frame or a link) and a later link b, at drawn points with a drawn normal."""
    n = draw(st.integers(1, 3))
    bars = []
    for _ in range(n):
        kind = draw(JOINTS)
        axis = {"revolute": (0.0, 0.0, 1.0), "prismatic_x": (1.0, 0.0, 0.0), "prismatic_y": (0.0, 1.0, 0.0)}[kind]
        bars.append(Bar(draw(st.floats(0.2, 1.5)), draw(st.floats(0.3, 3.0)), yaw=draw(st.floats(-1.5, 1.5)),
                        joint="revolute" if kind == "revolute" else "prismatic", axis=axis))
    a = draw(st.integers(0, n - 1))
    b = draw(st.integers(a + 1, n))
    point = st.lists(st.floats(-1.0, 1.0), min_size=2, max_size=2)
    angle = draw(st.floats(-math.pi, math.pi))
    scale = draw(st.floats(0.5, 3.0))  # the normal need not be a unit vector: the guard normalises it
    contact = {"a": "frame" if a == 0 else f"link{a}", "point_a": draw(point), "b": f"link{b}",
               "point_b": draw(point), "normal": [scale * math.cos(angle), scale * math.sin(angle)]}
    value = draw(st.floats(-0.2, 0.2))
    states = draw(st.lists(st.lists(st.floats(-3.0, 3.0), min_size=2 * n, max_size=2 * n), min_size=1, max_size=4))
    return bars, contact, value, states


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(trees_with_contacts())
def test_the_compiled_gap_is_the_python_gap_at_drawn_states(tmp_path_factory, data):
    """guard_value(description, y) and normal_speed(description, y) against the Python contact's gap,
    gap rate and normal speed (contact_state and gap_rate through Pinocchio's Python binding), at drawn
    states of drawn trees and contacts: the same to round-off of the terms (1e-12 of the points'
    distances and speeds); the guard and pcmm.events.contact.normal_speed read the compiled ones."""
    bars, contact, value, states = data
    n = len(bars)
    folder = tmp_path_factory.mktemp("gap")
    tr = stop("hit", "c1", 0.5, {"type": "gap", "value": value, "direction": "decreasing"}, contact)
    doc = base_doc("drawn", "c1", {"c1": "chain.urdf"}, {f"J{k}": 0.0 for k in range(1, n + 1)},
                   {f"J{k}": 0.0 for k in range(1, n + 1)}, transitions=[tr])
    scene = pcmm.load_scene(write_scene(folder, doc, {"chain.urdf": chain_urdf(bars)}))
    cfg = Mechanism(scene)["c1"]
    guard = make_guard(cfg, scene.transitions[0])
    assert guard.evaluator is not None, compiled.why_not()
    desc, rearm, _ = guard.evaluator
    assert desc[0] == "gap" and not rearm
    for y in states:
        y = np.asarray(y, float)
        got_value, got_rate = td.guard_value(desc, y)
        size = 1.0 + float(np.sum(np.abs(y)))
        q, v = y[:n], y[n:]
        _, gap, vn, _ = contacts.contact_state(cfg, q, v, scene.transitions[0].contact)
        assert got_value == pytest.approx(gap - value, abs=1e-12 * size)
        assert got_rate == pytest.approx(contacts.gap_rate(cfg, q, v, scene.transitions[0].contact),
                                         abs=1e-12 * size * size)
        assert td.normal_speed(desc, y) == pytest.approx(vn, abs=1e-12 * size * size)
        assert contacts.normal_speed(cfg, q, v, scene.transitions[0].contact) == td.normal_speed(desc, y)


def test_only_a_trees_point_contact_is_compiled(tmp_path, monkeypatch):
    """A tree's point contact is compiled (plain, and re-armed after a bounce); a configuration with a
    planar joint and a cut joint keeps the Python guard; with COMPILED_CONTACTS off none is compiled."""
    scene = pcmm.load_scene(ball(tmp_path / "b", 0.8))
    cfg = Mechanism(scene)["free"]
    assert make_guard(cfg, scene.transitions[0]).evaluator is not None
    assert make_guard(cfg, scene.transitions[0], rearm=True).evaluator[1:] == (True, UNFIRED)
    monkeypatch.setattr(contacts, "COMPILED_CONTACTS", False)
    assert make_guard(cfg, scene.transitions[0]).evaluator is None
    monkeypatch.setattr(contacts, "COMPILED_CONTACTS", True)
    walking = pcmm.load_scene(EXAMPLES / "compass_gait.toml")  # a planar hip, a foot pinned by a cut joint
    walker = Mechanism(walking)[walking.initial_configuration]
    gaps = [tr for tr in walking.transitions if tr.guard.type == "gap" and tr.source == walker.name]
    assert gaps and all(make_guard(walker, tr).evaluator is None for tr in gaps)


# ---- the loop scans it, the locator locates it ----------------------------------------------------
def test_a_bouncing_ball_hands_python_only_the_steps_near_a_bounce(tmp_path, monkeypatch):
    """A ball bouncing 20 times (e = 1): with the compiled gap the loop hands Python a few steps per
    bounce, not every step (before, a gap guard made every accepted step a candidate: 6.3 per bounce)."""
    path = ball(tmp_path, 1.0, t_end=20 * 2 * math.sqrt(2 / G) - math.sqrt(2 / G) + 0.1)
    accepted = []
    real = integrators._Stepper.accept

    def counting(self, *args, **kw):
        accepted.append(args[2])
        return real(self, *args, **kw)
    monkeypatch.setattr(integrators._Stepper, "accept", counting)
    compiled_run = _runs(path, True, monkeypatch)
    handed = len(accepted)
    accepted.clear()
    python_run = _runs(path, False, monkeypatch)
    assert len(compiled_run.events) == len(python_run.events) == 20
    assert len(accepted) == python_run.stats["steps"]  # every step through the Python scanner
    assert handed <= 3 * 20, (handed, len(accepted))
    _same_run(compiled_run, python_run)


@pytest.mark.parametrize("build", [
    lambda p: ball(p, 0.9, t_end=3.0),                  # bounces, then accumulates and merges
    lambda p: ball(p, 1.0, h=0.3, t_end=4.0),           # a prismatic joint, 36 bounces
    _pendulum_floor,                                    # a revolute joint's tip on a floor
    _two_link_hit,                                      # a mobile contact: the normal turns with link 1
], ids=["ball_merges", "ball_elastic", "pendulum_floor", "two_link_mobile"])
def test_runs_are_the_runs_with_the_python_gap(tmp_path, monkeypatch, build):
    """The same events (names, order, times to 1e-12 s) and every recorded state to 1e-10 as with the
    Python gap guard, and the compiled route taken (the steps handed to Python are fewer)."""
    path = build(tmp_path)
    compiled_run = _runs(path, True, monkeypatch)
    python_run = _runs(path, False, monkeypatch)
    assert len(python_run.events) >= 2
    _same_run(compiled_run, python_run)


@st.composite
def falling_trees(draw):
    """1-2 joints (revolute, or prismatic along y) under gravity, the last link's tip (or a point on it)
    striking a floor through the frame's point (0, -depth) whose normal leans by up to 0.4 rad, with a
    drawn restitution; drawn initial coordinates and rates."""
    n = draw(st.integers(1, 2))
    bars = []
    for _ in range(n):
        prismatic = draw(st.booleans())
        bars.append(Bar(draw(st.floats(0.3, 1.0)), draw(st.floats(0.5, 2.0)), yaw=draw(st.floats(-1.0, 1.0)),
                        joint="prismatic" if prismatic else "revolute",
                        axis=(0.0, 1.0, 0.0) if prismatic else (0.0, 0.0, 1.0)))
    lean = draw(st.floats(-0.4, 0.4))
    contact = {"a": "frame", "point_a": [0.0, -draw(st.floats(0.2, 1.5))], "b": f"link{n}",
               "point_b": [draw(st.floats(0.1, 1.0)) * bars[-1].length, 0.0],
               "normal": [-math.sin(lean), math.cos(lean)]}
    q = {f"J{k}": draw(st.floats(-0.5, 0.5)) for k in range(1, n + 1)}
    v = {f"J{k}": draw(st.floats(-1.0, 1.0)) for k in range(1, n + 1)}
    return bars, contact, q, v, draw(st.floats(0.3, 1.0))


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(falling_trees())
def test_drawn_trees_striking_a_floor_run_as_with_the_python_gap(tmp_path_factory, monkeypatch, drawn):
    """Drawn trees falling onto a drawn floor, 1.5 s: the run with the compiled gap is the run with the
    Python gap (events to 1e-12 s, velocities and states to 1e-10), or where the mechanism itself
    amplifies round-off more than that (a double pendulum whipping its tip at 37 rad/s, stacked sliders
    whose strikes double a time difference at each), within ten times what a nudge of the initial
    coordinate by one ulp of max(1, |q|) does to the Python run; up to the first strike slower than 1 mm/s, where an accumulation
    begins (a run without merge_to then ends in an error: its partial run).  Measured on a leaning floor:
    the accumulation carries a 2e-16 s difference past 1e-12 s near 2.5e-4 m/s."""
    bars, contact, q, v, e = drawn
    folder = tmp_path_factory.mktemp("fall")
    path = _chain_scene(folder / "plain", bars, contact, q, v, e=e, t_end=1.5)
    nudged = _chain_scene(folder / "nudged", bars, contact, {**q, "J1": q["J1"] + math.ulp(max(1.0, abs(q["J1"])))}, v,
                          e=e, t_end=1.5)
    scene = pcmm.load_scene(path)
    cfg = Mechanism(scene)["c1"]
    y0 = cfg.coords.pack(0.0, np.array(list(q.values())), np.array(list(v.values())))
    guard = make_guard(cfg, scene.transitions[0])
    if guard(0.0, y0) <= 1e-3:  # the tip starts on or below the floor: not a flight
        event("starts on the floor")
        return
    runs = []
    for p, flag in ((path, True), (path, False), (nudged, False)):
        try:
            runs.append(_runs(p, flag, monkeypatch))
        except SimulationError as exc:  # the strikes accumulate (no merge_to): the run up to there
            runs.append(exc.partial)
    compiled_run, python_run, nudged_run = runs
    got = _differences(compiled_run, python_run, slowest=1e-3)
    try:
        spread = _differences(nudged_run, python_run, slowest=1e-3)
    except AssertionError:  # the nudge changes the events themselves: this mechanism decides nothing here
        spread = (math.inf,) * 3
    event("within the strict bounds" if got[0] <= 1e-12 and max(got[1:3]) <= 1e-10 else
          "within the nudge's spread" if math.isfinite(spread[0]) else "the nudge changes the events")
    assert got[3] >= 2
    assert got[0] <= max(1e-12, 10 * spread[0])
    assert got[1] <= max(1e-10, 10 * spread[1]) and got[2] <= max(1e-10, 10 * spread[2])


def test_a_loop_refuses_an_evaluator_that_does_not_read_its_state(tmp_path):
    """The compiled segment loop takes an evaluated guard only over a tree of the evaluator's size (a
    contact gap reads the state's q and v): another tree, or a guard index it does not have, is refused
    with a message naming it (the integrators then hand every step to Python)."""
    scene = pcmm.load_scene(ball(tmp_path, 0.8))
    desc = make_guard(Mechanism(scene)["free"], scene.transitions[0]).evaluator[0]
    two = td.Tree()  # two prismatic joints: not the ball's state
    for j in (1, 2):
        two.add_joint("JointModelPY", j - 1, np.eye(3), np.zeros(3), np.zeros(3), 0.0)
        two.set_inertia(j, 1.0, np.zeros(3), 0.1 * np.eye(3))
    two.finalize(np.array([0.0, -G, 0.0]), np.zeros(2), np.zeros((2, 4)))
    guards_of_one = (np.zeros((1, 4)), np.zeros(1), np.zeros(1), -np.ones(1))
    y0 = np.array([1.0, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="does not read this tree's state"):
        td.SegmentLoop(two, 0.0, y0, 1.0, 1e-10, 1e-12, 0.0, 1000, 0.04, *guards_of_one, False,
                       evaluated=[(0, desc, 0.0)])
    with pytest.raises(ValueError, match="guard 3 is not an unclaimed guard"):
        td.SegmentLoop(two, 0.0, y0, 1.0, 1e-10, 1e-12, 0.0, 1000, 0.04, *guards_of_one, False,
                       evaluated=[(3, desc, 0.0)])
    with pytest.raises(ValueError, match="unknown kind 'spring'"):
        td.guard_value(("spring", two), y0)


def test_a_loop_that_refuses_the_evaluated_guards_gets_every_step_to_python(tmp_path, monkeypatch):
    """Where a compiled loop refuses the evaluated guards (integrators._segment_loop), the segment is
    still stepped by it with every step handed to the Python scanner: the same run."""
    path = ball(tmp_path, 0.8, t_end=2.0)
    python_run = _runs(path, False, monkeypatch)
    refused, stepped = [], []
    make = td.SegmentLoop

    def refusing(*args, **options):  # every compiled loop is made by this type (registered per tree)
        if "evaluated" in options:
            refused.append(options["evaluated"])
            raise ValueError("evaluated: not this loop's")
        stepped.append(args[13])  # every_step
        return make(*args, **options)
    monkeypatch.setattr(td, "SegmentLoop", refusing)
    # the registry the run fills with it is a copy, dropped after the test (later tests get the real type)
    monkeypatch.setattr(integrators, "SEGMENT_LOOPS", dict(integrators.SEGMENT_LOOPS))
    compiled_run = _runs(path, True, monkeypatch)
    assert refused and len(stepped) == len(refused) and all(stepped)
    _same_run(compiled_run, python_run)
