"""A re-read segment stays on the run's own assembly branch (PartitionedCoordinates._trail_start,
_continued).  A closed loop's series are re-solved lazily at the recorded steps (and at dense
instants) from the neighbouring recorded step; across a long step (a force-free parallelogram
turns 0.9 rad in one step) a Newton solve started at the step itself landed 2 pi away or on the
anti-parallelogram branch (theta_D != theta_A), on the Python and the compiled path alike.

The parallelogram four-bar (tests/builders.parallelogram) started on its parallelogram branch
stays on it until a change point (theta = pi): there, by its geometry (crank and rocker of equal
length a on pivots b apart, coupler b), theta_D = theta_A and the coupler's absolute angle is 0 —
the invariant every sample is checked against, with the crank's angle continuous (no 2 pi jump:
no sample moves by more than the recorded rate allows over the sample spacing)."""
from __future__ import annotations

import re

import builders
import numpy as np
import pytest

import pcmm
from pcmm.errors import SimulationError
from pcmm.model import compiled


def _assert_path(mode):
    """The compiled loop really ran where asked (a stale extension falls back to Python silently)."""
    assert (compiled.trees_built() > 0) == (mode == "1")


def _assert_on_parallelogram_branch(run, omega):
    crank, rocker, coupler = (run.series("theta", n) for n in ("crank", "rocker", "coupler"))
    t = run.t
    np.testing.assert_allclose(rocker, crank, rtol=0, atol=1e-9)
    np.testing.assert_allclose(coupler, 0.0, rtol=0, atol=1e-9)
    # force free, no gravity: the crank turns at its initial rate (kinetic energy is conserved and on
    # this branch the crank's rate alone sets it), so theta_A = theta0 + omega t at every sample
    np.testing.assert_allclose(crank, crank[0] + omega * (t - t[0]), rtol=0, atol=1e-7)


@pytest.mark.parametrize("mode", ["0", "1"])
def test_a_run_stopped_at_its_change_point_is_read_on_its_own_branch(tmp_path, monkeypatch, mode):
    """Driven into theta = pi the run stops (singular posture); every sample of every segment of the
    partial run, at its steps and resampled on the dense output, is on the parallelogram branch."""
    monkeypatch.setenv(compiled.ENV, mode)
    # with the extension, stepped by the compiled segment loop ("auto"): the check below reads the crank's
    # rate (theta0 + omega t), which it changed near the change point (2 -> 2.16 rad/s from t = 0.964 s) until
    # a rejected step's retry started its solves from the accepted state (tests/test_loop_turns.py)
    compiled.forget_trees()
    path = builders.parallelogram(tmp_path, 0.5, 2.0, t_end=2.0)
    with pytest.raises(SimulationError, match="singular") as stop:
        pcmm.simulate(pcmm.load_scene(path))
    partial = stop.value.partial
    _assert_path(mode)
    assert max(np.diff(partial.t)) * 2.0 > 10 * 0.05, "the case: a step far longer than one warm-start prediction"
    _assert_on_parallelogram_branch(partial, 2.0)
    _assert_on_parallelogram_branch(partial.resampled(0.01), 2.0)


@pytest.mark.parametrize("mode", ["0", "1"])
def test_a_run_far_from_its_change_point_is_read_on_its_own_branch(tmp_path, monkeypatch, mode):
    """The crank turns from 0.3 to 2.3 rad (the change point at pi is never reached) in long steps."""
    monkeypatch.setenv(compiled.ENV, mode)
    compiled.forget_trees()
    path = builders.parallelogram(tmp_path, 0.3, 2.0, t_end=1.0)
    run = pcmm.simulate(pcmm.load_scene(path))
    _assert_path(mode)
    assert max(np.diff(run.t)) * 2.0 > 10 * 0.05, "the case: a step far longer than one warm-start prediction"
    _assert_on_parallelogram_branch(run, 2.0)
    _assert_on_parallelogram_branch(run.resampled(0.01), 2.0)


@pytest.mark.parametrize("mode", ["0", "1"])
@pytest.mark.parametrize("theta1", [2.0, 3.0, 3.14])
def test_a_long_first_step_is_read_on_the_branch_it_starts_on(tmp_path, monkeypatch, mode, theta1):
    """A segment's first step is solved from the segment's start (the seed): a step from theta = 0.5
    to theta1 (up to next to the change point) read back on the parallelogram branch
    (theta_B = -theta1, theta_D = theta1), the branch of its start."""
    monkeypatch.setenv(compiled.ENV, mode)
    from pcmm.model.mechanism import Mechanism
    path = builders.parallelogram(tmp_path, 0.5, 2.0)
    coords = Mechanism(pcmm.load_scene(path))["c"].coords
    q0, v0 = np.array([0.5, -0.5, 0.5]), np.array([2.0, -2.0, 2.0])
    y0 = coords.pack(0.0, q0, v0)  # the independent coordinate: the crank's or the coupler's relative angle
    q1 = np.array([theta1, -theta1, theta1])
    ts, ys = np.array([0.0, (theta1 - 0.5) / 2.0]), np.array([y0, [q1[coords.I[0]], y0[1]]]).T
    with coords.restored(coords.frozen_state(), q0, steps=(ts, ys)) as reader:
        q, _ = reader.unpack(ts[1], ys[:, 1])
    np.testing.assert_allclose(q, q1, rtol=0, atol=1e-9)


@pytest.mark.parametrize("mode", ["0", "1"])
def test_a_step_across_the_change_point_is_refused_not_read_on_a_guessed_branch(tmp_path, monkeypatch, mode):
    """A recorded step from theta = 2.9 to 3.3 passes the change point (theta = pi, where the
    parallelogram and anti-parallelogram branches cross; no accepted segment does, the run stops
    there): the reader says so, naming the instant and the loop's cut joint, rather than return a
    branch (before: the anti-parallelogram's theta_D = 3.062 for theta_A = 3.3, silently)."""
    monkeypatch.setenv(compiled.ENV, mode)
    from pcmm.model.mechanism import Mechanism
    path = builders.parallelogram(tmp_path, 2.9, 2.0)
    coords = Mechanism(pcmm.load_scene(path))["c"].coords
    q0, v0 = np.array([2.9, -2.9, 2.9]), np.array([2.0, -2.0, 2.0])
    y0 = coords.pack(0.0, q0, v0)
    q1 = np.array([3.3, -3.3, 3.3])
    ts, ys = np.array([0.0, 0.2]), np.array([y0, [q1[coords.I[0]], y0[1]]]).T
    with coords.restored(coords.frozen_state(), q0, steps=(ts, ys)) as reader:
        with pytest.raises(SimulationError, match=r"t = 0\.2 s, the loop of cut joint 'C' passes a singular posture"):
            reader.unpack(ts[1], ys[:, 1])


@pytest.mark.parametrize("mode", ["0", "1"])
@pytest.mark.parametrize("theta1", [np.pi, np.pi - 5e-8])
def test_a_read_at_the_change_point_is_refused_not_read_off_the_meeting_point(tmp_path, monkeypatch, mode, theta1):
    """Recorded steps at theta = 2.9, 3.0, 3.1, 3.12 and theta1 at (or 5e-8 before) the change point
    theta = pi, where the parallelogram and anti-parallelogram branches meet and the constraint
    Jacobian loses rank: there the rates of the dependent coordinates are not determined.  The last
    step is short (no continuation: the solve starts from theta = 3.12 carried along its rates).  The
    reader names the instant and the loop's cut joint (before: at theta = pi it returned theta_D
    5.4e-7 off pi and the rates (2, -1.5, 0.5) for the run's (2, -2, 2); 5e-8 before pi, (2, -1.52, 0.56))."""
    monkeypatch.setenv(compiled.ENV, mode)
    compiled.forget_trees()
    from pcmm.model.mechanism import Mechanism
    path = builders.parallelogram(tmp_path, 2.9, 2.0)
    coords = Mechanism(pcmm.load_scene(path))["c"].coords
    q0, v0 = np.array([2.9, -2.9, 2.9]), np.array([2.0, -2.0, 2.0])
    y0 = coords.pack(0.0, q0, v0)
    i = coords.I[0]
    thetas = np.array([2.9, 3.0, 3.1, 3.12, theta1])
    ts = (thetas - 2.9) / 2.0
    ys = np.array([[np.array([th, -th, th])[i], y0[1]] for th in thetas]).T
    with coords.restored(coords.frozen_state(), q0, steps=(ts, ys)) as reader:
        q, v = reader.unpack(ts[3], ys[:, 3])  # theta = 3.12: read on its branch
        np.testing.assert_allclose(q, [3.12, -3.12, 3.12], rtol=0, atol=1e-12)
        np.testing.assert_allclose(v, [2.0, -2.0, 2.0], rtol=0, atol=1e-7)
        _assert_path(mode)
        said = re.escape(f"re-reading a recorded segment at t = {ts[4]:.9g} s, the loop of cut joint 'C' is at a "
                         "singular posture")
        with pytest.raises(SimulationError, match=said):
            reader.unpack(ts[4], ys[:, 4])


@pytest.mark.parametrize("mode", ["0", "1"])
@pytest.mark.parametrize("theta1", [3.1416, 3.142, 3.145])
def test_a_read_just_past_the_change_point_is_refused(tmp_path, monkeypatch, mode, theta1):
    """Recorded steps at theta = 2.9, 3.0 and theta1, 7.3e-6 to 3.4e-3 past the change point: the
    continuation from theta = 3.0 crosses it (the dependent block's determinant changes sign) and the
    reader says so.  Before, the continuation stopped PREDICT_MAX (0.05) short of the read and never
    saw the crossing: the reads came back on the anti-parallelogram (theta_D = 3.1399 for
    theta_A = 3.145, rates (2, -1, -1) for the parallelogram's (2, -2, 2))."""
    monkeypatch.setenv(compiled.ENV, mode)
    from pcmm.model.mechanism import Mechanism
    path = builders.parallelogram(tmp_path, 2.9, 2.0)
    coords = Mechanism(pcmm.load_scene(path))["c"].coords
    q0, v0 = np.array([2.9, -2.9, 2.9]), np.array([2.0, -2.0, 2.0])
    y0 = coords.pack(0.0, q0, v0)
    i = coords.I[0]
    thetas = np.array([2.9, 3.0, theta1])
    ts = (thetas - 2.9) / 2.0
    ys = np.array([[np.array([th, -th, th])[i], y0[1]] for th in thetas]).T
    with coords.restored(coords.frozen_state(), q0, steps=(ts, ys)) as reader:
        said = re.escape(f"re-reading a recorded segment at t = {ts[2]:.9g} s, the loop of cut joint 'C' passes a "
                         "singular posture")
        with pytest.raises(SimulationError, match=said):
            reader.unpack(ts[2], ys[:, 2])


@pytest.mark.parametrize("mode", ["0", "1"])
def test_a_long_first_step_onto_the_change_point_is_refused_naming_the_loop(tmp_path, monkeypatch, mode):
    """A segment's first step from theta = 0.5 to theta = pi exactly: the Newton solve from the
    segment's start does not converge there; the continuation from the start is what answers, and
    the reader names the instant and the loop's cut joint (before: "the loop cannot be closed ... a
    pcmm defect: please report it", from the failed solve)."""
    monkeypatch.setenv(compiled.ENV, mode)
    from pcmm.model.mechanism import Mechanism
    path = builders.parallelogram(tmp_path, 0.5, 2.0)
    coords = Mechanism(pcmm.load_scene(path))["c"].coords
    q0, v0 = np.array([0.5, -0.5, 0.5]), np.array([2.0, -2.0, 2.0])
    y0 = coords.pack(0.0, q0, v0)
    q1 = np.array([np.pi, -np.pi, np.pi])
    ts, ys = np.array([0.0, (np.pi - 0.5) / 2.0]), np.array([y0, [q1[coords.I[0]], y0[1]]]).T
    with coords.restored(coords.frozen_state(), q0, steps=(ts, ys)) as reader:
        said = re.escape(f"re-reading a recorded segment at t = {ts[1]:.9g} s, the loop of cut joint 'C' ")
        with pytest.raises(SimulationError, match=said) as error:
            reader.unpack(ts[1], ys[:, 1])
    assert "pcmm defect" not in str(error.value)
