"""A closed loop's dependent angles stay continuous near a change point: no whole turns, no other
branch (pcmm.model.partitioned._nearest_turns and its C++ twin in pcmm/model/_loops.hpp).

A force-free parallelogram four-bar (tests/builders.parallelogram: crank A and rocker D of length a
on pivots b apart, coupler b) started on its parallelogram branch coasts at its initial rates
(theta_A' = omega, theta_B' = -omega, theta_D' = omega: kinetic energy is conserved and on this branch
the crank's rate alone sets it) until its change point theta = pi, where the run stops (singular
posture).  Near it the dependent block Phi_q[:, D] is nearly singular and a Newton step can be
huge: on main the solve converged to the right posture 2 pi k away (theta_D - theta_A = -1.2e5 rad
at 0.5 rad under "auto"), and the recorded angle series jumped.  Every recorded sample is checked:
consecutive samples (across segment boundaries too, where no time passes) differ by no more than
the rates allow over their spacing, |dq| <= 1.5 max|v| dt + 1e-9, and the posture is the
parallelogram's (theta_D = theta_A, theta_B = -theta_A) to 1e-9, never 2 pi k off it.  The crank's
rate is checked where the compiled stepping changed it (test_a_coasting_parallelogram_keeps_its_speed_...).
"""
from __future__ import annotations

import math

import builders
import numpy as np
import pytest

import pcmm
from pcmm.errors import SimulationError
from pcmm.model import compiled, partitioned
from pcmm.model.mechanism import Mechanism


def _stopped_run(tmp_path, monkeypatch, theta0, mode, stepped):
    """The parallelogram from ``theta0`` at omega = 2 rad/s, run to its change point: the partial run."""
    monkeypatch.setenv(compiled.ENV, mode)
    monkeypatch.setattr(partitioned, "STEP_LOOPS_COMPILED", stepped)
    compiled.forget_trees()
    path = builders.parallelogram(tmp_path, theta0, 2.0, t_end=2.0)
    with pytest.raises(SimulationError, match="singular|degenerates") as stop:
        pcmm.simulate(pcmm.load_scene(path))
    assert (compiled.trees_built() > 0) == (mode == "1"), "the route asked for ran"
    return stop.value.partial


def _samples(run):
    t = np.concatenate([np.asarray(s.t) for s in run.segments])
    q = np.concatenate([np.asarray(s.q) for s in run.segments])
    v = np.concatenate([np.asarray(s.v) for s in run.segments])
    return t, q, v


def _assert_continuous_on_its_branch(run, theta0):
    t, q, v = _samples(run)
    dq, dt = np.abs(np.diff(q, axis=0)), np.diff(t)
    allowed = 1.5 * np.maximum(np.abs(v[1:]), np.abs(v[:-1])) * dt[:, None] + 1e-9
    worst = int(np.argmax(np.max(dq - allowed, axis=1)))
    assert np.all(dq <= allowed), (f"the angles jump between t = {t[worst]:.9g} and {t[worst + 1]:.9g} s: "
                                   f"{q[worst]} -> {q[worst + 1]}")
    # the parallelogram branch: the rocker parallel to the crank, the coupler horizontal (not 2 pi k off)
    np.testing.assert_allclose(q[:, 2], q[:, 0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(q[:, 1], -q[:, 0], rtol=0, atol=1e-9)
    assert abs(q[0, 0] - theta0) < 1e-12


def _start(k):
    """The k-th of 30 starting angles from 0.31 to 1.19 rad (the survey of docs/performance.md)."""
    return float(np.linspace(0.31, 1.19, 30)[k])


# (start, PCMM_COMPILED, loops stepped in C++): what main recorded there
CASES = [
    (0.5, "1", True),         # "auto", the compiled segment loop: theta_D - theta_A = -1.2e5 rad (whole turns)
    (_start(3), "1", True),   # 0.401: 2 pi off
    (_start(13), "1", True),  # 0.705: 6 pi off
    (_start(20), "1", True),  # 0.917: another assembly from t = 0.26 s (a new partition's start)
    (_start(29), "1", True),  # 1.19: 2 pi off
    (_start(17), "1", False), # 0.826, stepped in Python over the compiled loop: 4 pi off
    (_start(26), "1", False), # 1.099: 7.7e4 rad off
    (_start(28), "1", False), # 1.160: another assembly, 44 rad off
    (0.4, "0", False),        # all in Python: another assembly from t = 1.086 s, the crank 12 rad off
    (_start(20), "0", False), # 0.917: another assembly from t = 0.27 s
    (_start(12), "0", False), # 0.674: its series could not be read (a recorded step passes the change point)
    (_start(26), "0", False), # 1.099: nor these (a read at the singular posture)
]
# Each part of the fix is needed by some of these: without the compiled solve's whole turns 0.5, 0.705 (auto)
# and 1.160 (Python-stepped) fail; without the Python solve's, 0.674 and 1.099 (all in Python); without the
# new partition's start read along its segment (run/loop.py _at_last_step), 0.705 and 0.917 (auto), 0.4 and
# 0.917 (all in Python).


@pytest.mark.parametrize(("theta0", "mode", "stepped"), CASES)
def test_a_run_stopped_at_its_change_point_keeps_its_angles_continuous(tmp_path, monkeypatch, theta0, mode, stepped):
    run = _stopped_run(tmp_path, monkeypatch, theta0, mode, stepped)
    _assert_continuous_on_its_branch(run, theta0)


def test_the_angles_kept_within_a_half_turn_are_the_revolute_ones_not_driven(tmp_path):
    """Only a revolute coordinate is periodic in the closure rows; a prismatic one is not, nor a driven
    angle (its row q_j - f(t)).  The slider-crank's P is a length; the parallelogram's three angles all
    turn."""
    assert Mechanism(pcmm.load_scene(builders.parallelogram(tmp_path / "pg", 0.5, 2.0)))["c"].coords.turns == [0, 1, 2]
    coords = Mechanism(pcmm.load_scene(builders.slider_crank_stop(tmp_path / "sc", 0.5)))["free"].coords
    assert coords.cfg.joint_names == ["A", "B", "P"]
    assert coords.turns == [0, 1]


def test_nearest_turns_moves_only_the_named_angles_by_whole_turns():
    """q and q + 2 pi k are one posture for a revolute angle: each named angle comes back to within pi
    of the start (7.5 turns away: 8 turns back, -0.5 turn left; exactly the multiple of 2 pi taken), the
    others are untouched, and an angle within pi of its start is not moved by a single bit."""
    start = np.array([0.3, -1.0, 0.25, 5.0])
    q = start + np.array([7.5 * 2 * math.pi + 0.1, 0.7, -3 * 2 * math.pi, 40.0])
    out = q.copy()
    partitioned._nearest_turns(out, start, [0, 1, 2])
    assert out[0] == q[0] - 8 * partitioned.TWO_PI
    assert abs(out[0] - start[0]) <= math.pi
    assert out[1] == q[1]  # within pi already: the same bits
    assert out[2] == q[2] + 3 * partitioned.TWO_PI
    assert abs(out[2] - start[2]) < 1e-14
    assert out[3] == q[3]  # not named (a prismatic or driven coordinate): never moved


# the starts where the compiled stepping ("auto") changed the crank's speed on main (survey, 8 of 30):
# 0.8866 rad by 0.119 rad/s from t = 0.800 s, 0.5224 by 0.077 from 1.06 s, 0.7045 by 0.074: a rejected
# step's retry warm-started from that step's stages, past the change point, on the other assembly
# (docs/performance.md); and two of them stepped in Python over the compiled loop (which kept their speed)
@pytest.mark.parametrize(("theta0", "mode", "stepped"), [
    (_start(19), "1", True), (_start(7), "1", True), (_start(13), "1", True),
    (_start(19), "1", False), (_start(7), "1", False)])
def test_a_coasting_parallelogram_keeps_its_speed_up_to_its_change_point(tmp_path, monkeypatch, theta0, mode, stepped):
    """Force-free, the parallelogram's kinetic energy is conserved and on its branch the crank's rate
    alone sets it: every recorded sample has |theta_A'| = omega = 2 rad/s (to 1e-6) and theta_A =
    theta0 + omega t (to 1e-6), the closed form, whatever stops the run near the change point; and its
    angles stay continuous on the parallelogram branch."""
    monkeypatch.setenv(compiled.ENV, mode)
    monkeypatch.setattr(partitioned, "STEP_LOOPS_COMPILED", stepped)
    compiled.forget_trees()
    path = builders.parallelogram(tmp_path, theta0, 2.0, t_end=2.0)
    try:
        run = pcmm.simulate(pcmm.load_scene(path))
    except SimulationError as stop:
        run = stop.partial
    assert (compiled.trees_built() > 0) == (mode == "1"), "the route asked for ran"
    t, q, v = _samples(run)
    assert t[-1] > 0.9 * (math.pi - theta0) / 2.0, "the run reached the change point's neighbourhood"
    worst = int(np.argmax(np.abs(np.abs(v[:, 0]) - 2.0)))
    assert abs(abs(v[worst, 0]) - 2.0) <= 1e-6, f"the crank's rate is {v[worst, 0]!r} rad/s at t = {t[worst]:.9g} s"
    np.testing.assert_allclose(q[:, 0], theta0 + 2.0 * t, rtol=0, atol=1e-6)
    _assert_continuous_on_its_branch(run, theta0)


# the starts whose run went past, or jumped at, the change point on main (survey): under "auto" 0.583
# and 0.613 rad had a step accepted across it - the step's guards were read again at its start
# (integrators._guards_at_start), solved from the step's stages, past the change point, on the other
# assembly, (3.155, -3.148, 3.135) for (3.135, -3.135, 3.135), where the singularity guard has the end's
# sign - and their series could not be read ("passes a singular posture"); with the start read on the
# accepted state's solution, 0.613's event was located on the other assembly by solves warm-started
# from past the change point, and the next segment started there (3.213, -3.177, 3.106) for (3.106,
# -3.106, 3.106).  Stepped in Python over the compiled loop, 0.705 and 1.19 rad jumped to the other
# assembly the same way at a new partition's event before it (t = 0.980 and 0.945 s): the next segment
# started on the located event's solution, on the other assembly (run/loop.py _at_event).
@pytest.mark.parametrize(("k", "stepped"), [(9, True), (10, True), (13, False), (29, False)])
def test_a_run_stops_before_its_change_point_on_its_branch(tmp_path, monkeypatch, k, stepped):
    """The run stops before its change point (never past it, within 0.1 rad of it), every recorded
    sample on the parallelogram branch and on the closed form theta0 + omega t."""
    theta0 = _start(k)
    run = _stopped_run(tmp_path, monkeypatch, theta0, "1", stepped)
    _assert_continuous_on_its_branch(run, theta0)
    t, q, _ = _samples(run)
    np.testing.assert_allclose(q[:, 0], theta0 + 2.0 * t, rtol=0, atol=1e-6)
    assert math.pi - 0.1 < q[-1, 0] < math.pi, f"the run stopped at theta = {q[-1, 0]!r}"
