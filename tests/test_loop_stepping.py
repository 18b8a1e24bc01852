"""Closed loops stepped by the compiled segment loop (pcmm/model/_segment_loop.hpp over the compiled
loop of pcmm/model/_loops.hpp, scipy's DOP853 stepping in C++, the loop's guards scanned there too)
against pcmm's DOP853 stepping them in Python over the same compiled right-hand side (the reference,
``partitioned.STEP_LOOPS_COMPILED = False``): the same events in number, order and kind, their times
and the segments' ends within the Python run's own sensitivity to one ulp of its initial rate; a call
the loop declines (a conditioning check firing) taken by the Python evaluation, with the Python
route's outcome; the flights' dense outputs handed to the audit; ``PCMM_COMPILED=0`` still Python."""
from __future__ import annotations

import math

import builders
import numpy as np
import pytest
from builders import ROOT

import pcmm
from pcmm.errors import SimulationError
from pcmm.model import compiled, partitioned
from pcmm.ode import integrators

EXAMPLES = ROOT / "examples"
needs_extension = pytest.mark.skipif(
    not compiled.enabled() or not hasattr(getattr(compiled._tree_dynamics, "SegmentLoop", None), "fallbacks"),
    reason=f"the compiled loop stepping is not here: {compiled.why_not() or 'an extension built before it'}")

class _Spy:
    """The compiled segment loops a run makes (compiled.segment_loop), by owner kind, and the fallbacks
    each took."""

    def __init__(self, monkeypatch):
        self.loops = []
        real = compiled.segment_loop

        def made(owner, *args, **options):
            loop = real(owner, *args, **options)
            self.loops.append((type(owner).__name__, options, loop))
            return loop
        monkeypatch.setattr(compiled, "segment_loop", made)

    def over_loops(self):
        return [(options, loop) for kind, options, loop in self.loops if kind == "Loop"]


def _run(path, stepped: bool, monkeypatch, **options):
    monkeypatch.setattr(partitioned, "STEP_LOOPS_COMPILED", stepped)
    return pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(**options))


def _within_nudge(fast, slow, nudged_path, monkeypatch, **options):
    """fast and slow within 1e-12 s / 1e-10 (builders.RUN_FLOORS), or within ten times what the
    Python-stepped run itself moves when its initial rate is nudged by one ulp (``nudged_path``), event
    by event."""
    apart = builders.run_differences(fast, slow)
    if builders.within_floors(apart):
        return apart
    own = builders.run_differences(_run(nudged_path, False, monkeypatch, **options), slow)
    builders.assert_within_nudge(apart, own, "the Python-stepped run")
    return apart


@needs_extension
def test_a_four_bar_striking_its_stop_is_stepped_in_cpp(tmp_path, monkeypatch):
    """A torque-driven four-bar whose rocker strikes a stop, bounces and merges: its loop segments are
    stepped by the compiled loop over the compiled Loop (before: pcmm's DOP853 in Python; no segment
    loop over a Loop was made), the flights with their work appended and their dense outputs kept, and
    the run is the Python-stepped run within its own round-off sensitivity."""
    path = builders.four_bar_rocker_stop(tmp_path, e=0.5, rocker_stop=1.6, torque=1.0, t_end=2.0)
    spy = _Spy(monkeypatch)
    fast = _run(path, True, monkeypatch)
    made = spy.over_loops()
    assert made, "no compiled segment loop stepped the loop"
    assert any(options.get("power") and options.get("keep_dense") for options, _ in made), "the flights"
    assert any(options.get("solved") for options, _ in made), "the loop's guards scanned in C++"
    assert len(fast.events) >= 3
    spy.loops.clear()
    slow = _run(path, False, monkeypatch)
    assert not spy.over_loops()
    nudged = builders.nudged_scene(tmp_path, path, "[initial.v]\nA = 0.0\n", "[initial.v]\nA = 2.220446049250313e-16\n")
    _within_nudge(fast, slow, nudged, monkeypatch)


@needs_extension
def test_a_slider_crank_striking_its_stop_is_stepped_in_cpp(tmp_path, monkeypatch):
    """A torque-driven slider-crank whose slider strikes a stop on its guide and bounces (the guard on the
    slider's coordinate, a dependent one: read from the loop's solution): stepped by the compiled loop,
    the same events as pcmm's DOP853 stepping in Python, within that run's one-ulp sensitivity."""
    path = builders.slider_crank_stop(tmp_path, e=0.5, t_end=1.5)
    spy = _Spy(monkeypatch)
    fast = _run(path, True, monkeypatch)
    made = spy.over_loops()
    assert made and any(options.get("solved") for options, _ in made)
    slow = _run(path, False, monkeypatch)
    assert len(fast.events) == len(slow.events) == 4
    _within_nudge(fast, slow, builders.nudged_scene(tmp_path, path, "[initial.v]\nA = 0.0\n", "[initial.v]\nA = 2.220446049250313e-16\n"),
                  monkeypatch)


@needs_extension
@pytest.mark.parametrize("name, events", [("double_folded.toml", 47), ("double_folded_cycle.toml", 144),
                                          ("andrews.toml", 0)])
def test_the_examples_are_the_python_stepped_runs(tmp_path, monkeypatch, name, events):
    """Example 2 (47 impacts, a macro-impact and a merge), its working cycle (144 events) and Andrews'
    squeezer (seven bodies, five loops, point springs; its scene names DOP853, the Python stepping, so it
    runs under "auto" here): the same events and segments as pcmm's DOP853 stepping in Python, within the Python run's one-ulp sensitivity; the compiled loop stepped every loop
    segment it was given, and the Loop declined no evaluation."""
    path = EXAMPLES / name
    spy = _Spy(monkeypatch)
    fast = _run(path, True, monkeypatch, method="auto")  # andrews.toml names DOP853: the Python stepping
    made = spy.over_loops()
    assert made
    assert sum(loop.fallbacks() for _, loop in made) == 0
    spy.loops.clear()
    slow = _run(path, False, monkeypatch, method="auto")
    assert not spy.over_loops()
    assert len(fast.events) == len(slow.events) == events
    apart = _within_nudge(fast, slow, builders.nudged_scene(tmp_path, path, *builders.EXAMPLE_NUDGES[name]), monkeypatch, method="auto")
    if not events:  # one segment to the end: its final state
        assert apart["q"].max() < 1e-8 and apart["v"].max() < 1e-7


@needs_extension
def test_the_audit_reads_the_loop_steps_dense_output(monkeypatch):
    """Each flight's audit reads the dense output the compiled loop formed as it accepted each step:
    no step of Example 2 is taken again for it, and the audit's residuals are the Python-stepped run's
    to round-off."""
    retaken = []
    real = integrators._dop853_dense
    monkeypatch.setattr(integrators, "_dop853_dense", lambda *a: retaken.append(a[1]) or real(*a))
    path = EXAMPLES / "double_folded.toml"
    fast = _run(path, True, monkeypatch)
    assert retaken == []
    slow = _run(path, False, monkeypatch)
    (a,), (b,) = fast.stats["macro_impacts"], slow.stats["macro_impacts"]
    assert a["flights"] == b["flights"] > 10
    assert abs(a["flight_energy_residual_max"] - b["flight_energy_residual_max"]) <= 1e-12


@needs_extension
def test_a_declined_evaluation_is_taken_by_python(tmp_path, monkeypatch):
    """A parallelogram four-bar coasting (no force, no gravity) into its change point: there the compiled
    loop's conditioning check declines evaluations inside the compiled segment loop, whose fallback (the
    Python evaluation) decides as in the Python route: new partitions, then a stop near the change point
    with a message naming it.  (Coasting, the step-size control reads round-off only, so the two routes'
    steps part from the second step on, as the Python route's own do for a start 1e-8 rad away: the
    outcome is compared, not the instants.)  Before the stop at a stalled partition (run/loop.py), the
    compiled route repeated a new partition at t = 1.3106 s for ever.  From 0.6741 rad (one declined
    evaluation): from 0.45 and 0.5 rad the compiled run now declines none (a rejected step's retry starts its
    solves from the accepted state, tests/test_loop_turns.py; a new partition restarts from the run's own
    solution)."""
    theta0 = 0.6741
    path = builders.parallelogram(tmp_path, theta0, 2.0, t_end=2.0)
    change_point = (np.pi - theta0) / 2.0  # theta = pi
    spy = _Spy(monkeypatch)
    with pytest.raises(SimulationError, match="singular|change point") as fast:
        _run(path, True, monkeypatch)
    made = spy.over_loops()
    assert made and sum(loop.fallbacks() for _, loop in made) >= 1
    with pytest.raises(SimulationError, match="singular|change point") as slow:
        _run(path, False, monkeypatch)
    for stop in (fast.value.partial, slow.value.partial):
        assert 1.1 < stop.segments[-1].t[-1] <= change_point
        for seg in stop.segments:
            assert np.all(np.diff(seg.t) >= 0)
            for q in seg.q:  # every recorded posture on the parallelogram branch: rocker parallel to the crank
                assert abs(math.remainder(q[2] - q[0], 2 * math.pi)) < 1e-9


@needs_extension
def test_the_named_method_dop853_steps_in_python(tmp_path, monkeypatch):
    """A scene that names DOP853 gets pcmm's DOP853 stepping in Python, the reference (only "auto" gives
    loops the compiled stepping)."""
    path = builders.four_bar_rocker_stop(tmp_path, e=0.5, rocker_stop=1.6, torque=1.0, t_end=0.3)
    spy = _Spy(monkeypatch)
    _run(path, True, monkeypatch, method="DOP853")
    assert not spy.over_loops()
    _run(path, True, monkeypatch, method="auto")
    assert spy.over_loops()


@needs_extension
def test_without_the_compiled_evaluations_python_steps(tmp_path, monkeypatch):
    """PCMM_COMPILED=0: no compiled segment loop is made; the loops are evaluated and stepped in Python."""
    monkeypatch.setenv(compiled.ENV, "0")
    path = builders.four_bar_rocker_stop(tmp_path, e=0.5, rocker_stop=1.45, torque=1.0, t_end=0.5)
    spy = _Spy(monkeypatch)
    traj = _run(path, True, monkeypatch)
    assert spy.loops == []
    assert all(said.startswith("python") for said in traj.stats["evaluations"].values())
