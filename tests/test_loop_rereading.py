"""A loop's segments re-read after the run: saved series, resampled series, dense output.

A run keeps a segment as its accepted steps; the loop's dependent coordinates are solved again
when its series are first read (``--out``, ``--csv``) or when it is resampled on the dense
output (``--dt``), where the solver asks for instants in any order and far apart.  Each Newton
solve must start from the accepted step at or before its instant, as it did in the run: started
from the last instant solved, a crank several turns on lands on another assembly or none.

The mechanism: a Grashof crank-rocker without gravity driven by a constant crank torque tau from
rest, its crank spinning up through many turns (and its coupler-rocker angle through its extremes
every turn).  With no other force, the kinetic energy is the motor's work, ``T(t) = tau (A(t) -
A(0))`` (conservation of energy, exact): every re-read sample is held to it.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import pcmm
from builders import bar_xml, joint_xml, link_xml, robot_xml, scene_doc, write_scene
from pcmm.cli import main as cli_main

A, B, C, D = 0.12, 0.33, 0.27, 0.31  # crank, coupler, rocker, frame (m): Grashof, crank the shortest


def crank_rocker(folder: Path, torque: float, t_end: float, gravity=(0.0, 0.0)) -> Path:
    urdf = robot_xml("crank_rocker", link_xml("frame"),
                     joint_xml("A", "revolute", "frame", "crank"), bar_xml("crank", A, 0.8),
                     joint_xml("B", "revolute", "crank", "coupler", xyz=(A, 0.0)), bar_xml("coupler", B, 1.7),
                     joint_xml("D", "revolute", "frame", "rocker", xyz=(D, 0.0)), bar_xml("rocker", C, 1.2))
    cut = {"name": "C", "type": "revolute", "a": "coupler", "point_a": [B, 0.0], "b": "rocker", "point_b": [C, 0.0]}
    doc = scene_doc({"open": "cr.urdf"}, {"A": 1.0, "B": 0.5, "D": 2.0}, {"A": 0.0, "B": 0.0, "D": 0.0},
                    gravity=gravity, t_end=t_end, cut_joints={"open": [cut]}, independent=["A"], name="crank_rocker",
                    forces=[{"name": "motor", "type": "linear", "on": {"joint": "A"}, "measure": {"joint": "A"},
                             "value": torque}])
    return write_scene(folder, doc, {"cr.urdf": urdf})


def assert_energy_is_the_motors_work(traj, torque):
    crank = traj.series("q", "A")
    work = torque * (crank - crank[0])
    kinetic = traj.series("kinetic")
    assert np.max(np.abs(kinetic - work)) < 1e-7 * max(1.0, float(np.max(work)))


@pytest.mark.parametrize("torque, t_end", [(8.0, 0.5), (4.0, 1.0), (8.0, 0.31)])
def test_resampled_crank_rocker_keeps_its_assembly_and_energy(tmp_path, torque, t_end):
    traj = pcmm.simulate(pcmm.load_scene(crank_rocker(tmp_path, torque, t_end)))
    assert traj.status == "complete", traj.message
    crank = traj.series("q", "A")
    assert crank[-1] - crank[0] > 4 * math.pi  # many turns: the re-read instants lie far apart
    assert_energy_is_the_motors_work(traj, torque)
    fine = traj.resampled(0.01)
    assert_energy_is_the_motors_work(fine, torque)
    # the same assembly as the recorded steps: a Grashof crank-rocker's transmission angle (rocker
    # against coupler) never reaches 0 or pi, so its sine keeps one sign on one assembly
    for run in (traj, fine):
        sine = np.sin(run.series("theta", "rocker") - run.series("theta", "coupler"))
        assert np.all(sine > 0.1) or np.all(sine < -0.1)
    # and the same turn: no 2 pi k jump of the rocker against the recorded steps (the crank's is
    # ruled out by the energy above); 0.05 rad allows for the curvature between two steps
    t, rocker = traj.t, traj.series("theta", "rocker")
    assert np.max(np.abs(fine.series("theta", "rocker") - np.interp(fine.t, t, rocker))) < 0.05


def test_cli_saves_and_resamples_the_crank_rocker(tmp_path, capsys):
    path = crank_rocker(tmp_path, 8.0, 0.5)
    out, csv = tmp_path / "t.npz", tmp_path / "t.csv"
    rc = cli_main(["run", str(path), "--out", str(out), "--csv", str(csv), "--dt", "0.01", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 0, err
    saved = pcmm.Trajectory.load(out)
    assert_energy_is_the_motors_work(saved, 8.0)
    rows = np.genfromtxt(csv, delimiter=",", names=True)
    assert len(rows) == 51  # 0, 0.01, ..., 0.5


def test_a_loop_that_cannot_be_closed_names_the_stop_time_and_the_conditioning(tmp_path, monkeypatch):
    """A Newton solve sent from a warm start far from the assembly (here on purpose, past
    t = 0.3 s; the first that does not converge) fails at a trial instant of a step: the message gives that instant, the run's true
    stop (its last accepted step, the partial result's end) and the Jacobian's condition number."""
    from pcmm.model import partitioned
    solve = partitioned.PartitionedCoordinates._solve_dependent

    def far_start(self, t, qI, guess):
        return solve(self, t, qI, guess + 2.0 if t > 0.3 and self.checking else guess)
    monkeypatch.setattr(partitioned.PartitionedCoordinates, "_solve_dependent", far_start)
    # the far start is planted in the Python solve: the compiled loop's solves (pcmm/model/_loops.hpp)
    # hand their failures to it, from their own warm start (tests/test_compiled_loops.py)
    monkeypatch.setenv("PCMM_COMPILED", "0")
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(pcmm.load_scene(crank_rocker(tmp_path, 1.0, 1.0, gravity=(0.0, -9.81))))
    partial = info.value.partial
    stop = float(partial.t[-1])
    message = str(info.value)
    assert 0.0 < stop
    assert f"the run stopped at t = {stop:.9g} s, its last accepted step" in message
    trial = float(message.split("cannot be closed at t = ")[1].split(" s")[0])
    assert trial > max(stop, 0.3) and f"(t = {trial:.9g} s was a trial instant" in message
    assert "condition number is" in message and "well conditioned" in message


def test_lazy_series_read_from_a_second_thread_while_the_first_runs(tmp_path):
    """A trajectory's series are computed when first read; reading them in another thread while
    the first one integrates a run of the same configuration (its Pinocchio data, its loop's
    partition and warm starts busy) gives exactly the series read alone, and leaves the run's
    result exactly what it is alone: each thread evaluates on its own Data
    (``Configuration.workspace``) and the reader of a segment is a copy of the coordinates."""
    import threading

    path = crank_rocker(tmp_path, 8.0, 0.5)
    alone = pcmm.simulate(pcmm.load_scene(path))
    expected = {(k, n): alone.series(k, n) for k, n in (("q", "D"), ("theta", "rocker"), ("constraint_forces", "C.fx"))}
    baseline = pcmm.simulate(pcmm.load_scene(path))  # to be read while the next run goes on
    read, errors = {}, []
    started, finished, paused_at = threading.Event(), threading.Event(), []

    def reader():
        started.wait()
        try:
            for k, n in expected:
                read[(k, n)] = baseline.series(k, n)
            read["fine"] = baseline.resampled(0.01).series("q", "D")
        except Exception as exc:  # noqa: BLE001 - reported by the main thread
            errors.append(exc)
        finally:
            finished.set()

    def progress(t):
        # the reads happen while this run is mid-way, for certain: at its first report the run waits
        # for them (before, a run done before the second thread got its turn passed without a race)
        if not started.is_set():
            paused_at.append(t)
            started.set()
            finished.wait(timeout=120)

    th = threading.Thread(target=reader)
    th.start()
    during = pcmm.simulate(pcmm.load_scene(path), progress=progress)
    started.set()  # (a run that never reported: the reads after it, and paused_at says so)
    th.join()
    assert not errors, errors
    assert paused_at and paused_at[0] < during.t[-1]  # read while the run was mid-way
    for (k, n), values in expected.items():
        np.testing.assert_array_equal(read[(k, n)], values)
        np.testing.assert_array_equal(during.series(k, n), values)
    np.testing.assert_array_equal(read["fine"], alone.resampled(0.01).series("q", "D"))
