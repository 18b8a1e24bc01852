"""The compiled right-hand side of closed loops (pcmm/model/_loops.hpp, PartitionedCoordinates._compiled_loop)
against the Python evaluation it replaces: the Newton solve of the dependent coordinates from the same
warm starts, the dependent rates and the KKT accelerations, at random states of every loop
configuration of the shipped examples and of a drawn four-bar; whole runs against PCMM_COMPILED=0."""
from __future__ import annotations

import copy
import math
import shutil

import builders
import numpy as np
import pytest
from builders import ROOT

import pcmm
from pcmm.errors import SimulationError
from pcmm.model import compiled, partitioned
from pcmm.model.mechanism import Mechanism

EXAMPLES = ROOT / "examples"
needs_extension = pytest.mark.skipif(not compiled.enabled() or not hasattr(compiled._tree_dynamics, "Loop"),
                                     reason=f"the compiled loops are not here: {compiled.why_not()}")


def _loop_starts(scene, traj):
    """{configuration with loops: [(t, q, v) at the start of each of its segments]} of a run."""
    out = {}
    mech = Mechanism(scene)
    for seg in traj.segments:
        coords = mech[seg.configuration].coords
        if coords.constrained and coords.closure.size:
            out.setdefault(seg.configuration, []).append((float(seg.t[0]), seg.q[0].copy(), seg.v[0].copy()))
    return out


def _python_twin(coords):
    """A copy of ``coords`` that evaluates in Python only (its own warm starts)."""
    twin = copy.copy(coords)
    twin._loop, twin._loop_held, twin._loop_refused = None, None, "the reference"
    twin._trail = None
    twin.checking = False
    return twin


def _compare_at_random_states(scene, starts, rng, n=12):
    """At each start: the configuration partitioned and seeded there (pack), then ``n`` random
    states near it, evaluated one after the other by the compiled loop and by a Python twin (the
    same sequence of warm starts on both sides); returns the largest relative difference."""
    mech = Mechanism(scene)
    worst = 0.0
    for name, points in starts.items():
        coords = mech[name].coords
        for t0, q0, v0 in points[:3]:
            y0 = coords.pack(t0, q0, v0)
            coords.checking = False
            twin = _python_twin(coords)
            twin.seed(q0)
            k = len(coords.I)
            for _ in range(n):
                y = y0 + np.concatenate([rng.uniform(-2e-3, 2e-3, k), rng.uniform(-0.2, 0.2, k)])
                t = t0 + rng.uniform(0.0, 1e-2)
                got = coords.rhs(t, y)
                assert coords._loop is not None and coords.evaluations == "compiled", coords.evaluations
                want = twin._python_rhs(t, y)
                worst = max(worst, float(np.max(np.abs(got - want), initial=0.0)) / (1.0 + float(np.max(np.abs(want), initial=0.0))))
                w = np.append(y, 0.0)
                got, want = coords.rhs_with_power(t, w), twin._python_rhs_with_power(t, w)
                worst = max(worst, float(np.max(np.abs(got - want))) / (1.0 + float(np.max(np.abs(want)))))
                q, v = coords.unpack(t, y)  # the compiled solve closes the loop (the Python binding's rows)
                phi, Jq = coords.loop_rows(q)
                assert np.max(np.abs(phi)) < 1e-12 and np.max(np.abs(Jq @ v), initial=0.0) < 1e-9
                # the singularity guard's rate: central differences 1e-7 apart of determinants whose
                # rows agree to round-off, so they agree to about 1e-16 / 1e-7
                fast, slow = coords.singularity_guard().rate(t, y, None), twin.singularity_guard().rate(t, y, None)
                assert abs(fast - slow) <= 1e-7 * (1.0 + abs(slow)), (fast, slow)
                # a segment reader's rows and accelerations (the audit's powers, the lazy series): compiled
                with coords.restored(coords.frozen_state(), q0) as reader:
                    got = (*reader.accelerations(t, q, v), *reader.rows(t, q, v))
                    assert reader._reader_kkt(t, q, v) is not None, reader.evaluations
                want = (*twin.accelerations(t, q, v), *twin.rows(t, q, v))
                for g, w in zip(got, want):
                    worst = max(worst, float(np.max(np.abs(g - w), initial=0.0)) / (1.0 + float(np.max(np.abs(w), initial=0.0))))
    return worst


def _runs(path):
    """(the scene, its run with the compiled loops)."""
    scene = pcmm.load_scene(path)
    return scene, pcmm.simulate(scene)


@needs_extension
@pytest.mark.parametrize("name", ["double_folded.toml", "double_folded_cycle.toml", "andrews.toml"])
def test_every_loop_configuration_of_the_examples_at_random_states(name):
    scene = pcmm.load_scene(EXAMPLES / name)
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=min(scene.t_end, 3.5)))
    starts = _loop_starts(scene, traj)
    assert starts, "the example visits a configuration with loops"
    assert _compare_at_random_states(scene, starts, np.random.default_rng(7)) < 1e-10


@needs_extension
def test_a_drawn_four_bar_at_random_states(tmp_path):
    """A four-bar turned by a torque whose rocker strikes a stop and merges (a zero-DOF loop after),
    drawn: the crank's start, the torque and the stop."""
    rng = np.random.default_rng(11)
    for _ in range(3):
        path = builders.four_bar_rocker_stop(tmp_path, e=0.5, rocker_stop=float(rng.uniform(1.2, 1.6)),
                                             torque=float(rng.uniform(0.5, 2.0)), theta0=float(rng.uniform(0.8, 1.2)),
                                             t_end=1.0)
        scene, traj = _runs(path)
        starts = _loop_starts(scene, traj)
        assert set(traj.stats["evaluations"].values()) == {"compiled"}
        assert _compare_at_random_states(scene, starts, rng) < 1e-10


@pytest.mark.slow  # each example run whole, compiled and in Python (double_folded_cycle: 19.5 s)
@needs_extension
@pytest.mark.parametrize("name", ["double_folded.toml", "double_folded_cycle.toml", "andrews.toml"])
def test_whole_runs_are_the_python_runs(tmp_path, monkeypatch, name):
    """The same events to 1e-12 s and the same segment ends to 1e-10 as with the Python evaluations,
    or, where the Python run itself moves by more when nudged by round-off (the late bounces of a
    macro-impact, rebounding at 1e-6 m/s), within ten times that."""
    compiled.forget_trees()
    scene, fast = _runs(EXAMPLES / name)
    for cfg, said in fast.stats["evaluations"].items():
        coords = Mechanism(scene)[cfg].coords
        if coords.constrained and coords.closure.size:
            assert said == "compiled", (cfg, said)
    monkeypatch.setenv(compiled.ENV, "0")
    slow = pcmm.simulate(pcmm.load_scene(EXAMPLES / name))
    apart = builders.run_differences(fast, slow)
    if builders.within_floors(apart):
        return
    # each scene's initial rate nudged by one machine epsilon: the reference against itself (its own
    # round-off sensitivity; tests/test_compiled_properties.py: the same bound)
    nudged = pcmm.simulate(pcmm.load_scene(builders.nudged_scene(tmp_path, EXAMPLES / name,
                                                                 *builders.EXAMPLE_NUDGES[name])))
    builders.assert_within_nudge(apart, builders.run_differences(nudged, slow))


@needs_extension
def test_it_steps_aside_with_the_reason_where_it_disagrees(monkeypatch):
    """A compiled loop that is not the Python evaluation (its drive law off by 1e-6 rad, a
    defect planted for the test) is refused by the probe check: the loops run in Python, the
    stats say why, and the run is the Python run to the bit."""
    compiled.forget_trees()
    real = compiled.loop

    def planted(tree, driven, laws, springs=()):
        laws = tuple(((law[0][0] + 1e-6, *law[0][1:]), law[1], law[2]) for law in laws)
        return real(tree, driven, laws, springs)
    monkeypatch.setattr(compiled, "loop", planted)
    traj = pcmm.simulate(pcmm.load_scene(EXAMPLES / "double_folded.toml"), pcmm.RunOptions(t_end=0.5))
    said = traj.stats["evaluations"]["config1"]
    assert said.startswith("python: it disagrees with the Python loop right-hand side, dependent (0, 1, 2) by "), said
    monkeypatch.undo()
    compiled.forget_trees()
    monkeypatch.setenv(compiled.ENV, "0")
    slow = pcmm.simulate(pcmm.load_scene(EXAMPLES / "double_folded.toml"), pcmm.RunOptions(t_end=0.5))
    np.testing.assert_array_equal(traj.segments[-1].q, slow.segments[-1].q)
    np.testing.assert_array_equal(traj.segments[-1].v, slow.segments[-1].v)


@needs_extension
def test_a_second_scene_on_the_same_model_with_another_drive_is_checked_again(tmp_path, monkeypatch):
    """Two scenes on one URDF in one process (as a study runs them) share the Pinocchio model and
    so its compiled loop tree (same cut joint, force elements, gravity): what differs is the crank's
    drive law, which the compiled loop carries besides its tree.  The first scene's probe check
    must not stand for the second's: with the second's compiled loop off by 1e-6 rad in its drive
    (a defect planted for the test), the probe check refuses it, and the run says why."""
    compiled.forget_trees()
    first = pcmm.simulate(pcmm.load_scene(EXAMPLES / "double_folded.toml"), pcmm.RunOptions(t_end=0.2))
    assert first.stats["evaluations"]["config1"] == "compiled", first.stats["evaluations"]
    # the same example with the crank accelerating: theta1 = pi + (pi/5) t + 0.45 t^2
    (tmp_path / "scenes").mkdir()
    shutil.copytree(ROOT / "urdf", tmp_path / "urdf")
    law = "coefficients = [3.141592653589793, 0.6283185307179586]"
    text = (EXAMPLES / "double_folded.toml").read_text()
    assert text.count(law) == 1
    second = tmp_path / "scenes" / "double_folded_accelerating.toml"
    second.write_text(text.replace(law, "coefficients = [3.141592653589793, 0.6283185307179586, 0.45]"))
    real = compiled.loop

    def planted(tree, driven, laws, springs=()):
        laws = tuple(((law[0][0] + 1e-6, *law[0][1:]), law[1], law[2]) for law in laws)
        return real(tree, driven, laws, springs)
    monkeypatch.setattr(compiled, "loop", planted)
    traj = pcmm.simulate(pcmm.load_scene(second), pcmm.RunOptions(t_end=0.2))
    said = traj.stats["evaluations"]["config1"]
    assert said.startswith("python: it disagrees with the Python loop right-hand side, dependent (0, 1, 2) by "), said


@needs_extension
def test_a_loop_whose_power_disagreed_is_checked_again_on_the_next_scene(monkeypatch):
    """A compiled loop whose right-hand side agrees but whose right-hand side with power does not
    (its power off by 1e-6 W, a defect planted for the test) is refused; the next scene on the same
    model and drives must not take the right-hand side's pass for both: it is refused too."""
    compiled.forget_trees()
    real = compiled.loop

    class Planted:
        def __init__(self, loop):
            self._loop = loop

        def __getattr__(self, name):
            return getattr(self._loop, name)

        def rhs_with_power(self, t, y):
            out = self._loop.rhs_with_power(t, y)
            return None if out is None else out + np.eye(1, len(out), len(out) - 1)[0] * 1e-6

    monkeypatch.setattr(compiled, "loop", lambda *args: Planted(real(*args)))
    for _ in range(2):
        traj = pcmm.simulate(pcmm.load_scene(EXAMPLES / "double_folded.toml"), pcmm.RunOptions(t_end=0.2))
        said = traj.stats["evaluations"]["config1"]
        assert said.startswith("python: it disagrees with the Python loop right-hand side, dependent (0, 1, 2) "
                               "with power by "), said


@pytest.mark.parametrize("name", ["compass_gait.toml", "rimless_wheel.toml"])
def test_loops_on_a_planar_joint_run_in_python_and_say_so(name):
    """The other examples with loops stand on a planar joint (a body's x, y, theta: q' is not v):
    not compiled, and the stats say so."""
    traj = pcmm.simulate(pcmm.load_scene(EXAMPLES / name), pcmm.RunOptions(t_end=0.05))
    assert set(traj.stats["evaluations"].values()) == {"python: not compiled: a planar joint"}


@needs_extension
def test_a_loop_that_cannot_close_is_the_python_message():
    """A state whose independent coordinate the loop cannot reach: the compiled solve declines and
    the Python solve from the same warm start stops the run with its own message."""
    scene = pcmm.load_scene(EXAMPLES / "double_folded.toml")
    coords = Mechanism(scene)["config1"].coords
    t0 = 0.0
    q0 = np.array([math.pi, -3.459398, 1.095, 0.210561])
    v0 = np.zeros(4)
    q, v = coords.project(t0, q0, v0)
    y = coords.pack(t0, q, v)
    assert coords._compiled_loop() is not None, coords.evaluations
    far = y.copy()
    far[0] += 5.0  # the independent coordinate (the slider E, here) 5 m on: no assembly there
    twin = _python_twin(coords)
    twin.checking = True
    twin.seed(q)
    with pytest.raises(SimulationError) as python:
        twin.unpack(0.01, far)
    with pytest.raises(SimulationError) as fast:
        coords.unpack(0.01, far)
    assert str(fast.value) == str(python.value)
    assert "the loop cannot be closed" in str(fast.value)


@pytest.mark.parametrize("mode", ["1", "0"])
def test_the_series_of_a_run_stopped_at_a_singular_posture_read(tmp_path, monkeypatch, mode):
    """A parallelogram four-bar driven into its change point stops there; the partial run's last
    segment ends with its last accepted step recorded twice (the stop's state at the same instant).
    Its series are read as every segment's: each sample closes the loop (a RecursionError before:
    the re-read solve of a step asked for the step itself as its warm start, at a repeated time)."""
    monkeypatch.setenv(compiled.ENV, mode)
    # stepped by pcmm's DOP853 in Python (the case needs its steps: coasting, the step-size control reads
    # round-off, and the compiled loop's steps stop elsewhere near the change point without the repeated
    # instant this case is about, tests/test_loop_stepping.py; its angles no longer jump there either,
    # tests/test_loop_turns.py).  From 0.68 rad: from 0.5 the Python-stepped run stopped with the repeated
    # instant only after its Newton solves had landed whole turns away; from 0.4 it stops without one since
    # the segment after the singularity guard starts on the run's assembly (run/loop.py _at_event)
    monkeypatch.setattr(partitioned, "STEP_LOOPS_COMPILED", False)
    path = builders.parallelogram(tmp_path, 0.68, 2.0, t_end=2.0)
    with pytest.raises(SimulationError, match="singular") as stop:
        pcmm.simulate(pcmm.load_scene(path))
    partial = stop.value.partial
    last = partial.segments[-1]
    assert last.t[-1] == last.t[-2], "the case: a repeated instant at the segment's end"
    scene = pcmm.load_scene(path)
    coords = Mechanism(scene)["c"].coords
    for seg in partial.segments:
        for q in seg.q:
            phi, _ = coords.loop_rows(q)
            assert np.max(np.abs(phi)) < 1e-12
    assert len(partial.series("theta", "crank")) == sum(len(seg.t) for seg in partial.segments)
