"""Explicit state (issue 23 item 3): a trajectory's lazy series are read from a second thread while
the first keeps running, and they are the series read alone.

The mechanism (ours): a turnstile bar (L = 0.5 m, 1 kg) on J1, no gravity, turned by a motor
(200 N m) against a torsion spring k (1 N m/rad) that measures the bar's angle as the run's series
give it.  After one full turn from its start angle alpha it strikes a stop (e = 0) and is held
('held': the bar welded at yaw alpha, written on the first 2 pi branch); a timer lets it go again.
Every strike enters 'held' 2 pi further on and every release enters 'turning' 2 pi further on: both
configurations compile their force elements again at new angle offsets on every entry
(Configuration.continue_angles), so a recorded segment's elements differ from its configuration's
current ones as soon as the run has gone on.  The held bar's pin carries, at the arm L of the stop's
contact, the force (motor - k theta) / L (the bar at rest: the elements' moment over the arm).
"""
from __future__ import annotations

import math
import threading
from pathlib import Path

import numpy as np
import pytest

import pcmm
from pcmm.results.segment_log import SegmentLog

from builders import bar_xml, joint_xml, link_xml, robot_xml, scene_doc, stop, write_scene

ALPHA, TORQUE, K, L = 0.5, 200.0, 1.0, 0.5


def turnstile(folder: Path, t_end: float = 1.0, every: float = 0.05) -> Path:
    turning = robot_xml("turning", link_xml("frame"), joint_xml("J1", "revolute", "frame", "link1"), bar_xml("link1", L, 1.0))
    held = robot_xml("held", link_xml("frame"), joint_xml("J1", "fixed", "frame", "link1", yaw=ALPHA), bar_xml("link1", L, 1.0))
    guard = {"type": "coordinate", "measure": {"joint": "J1"}, "value": ALPHA + 2 * math.pi, "direction": "increasing"}
    contact = {"a": "frame", "point_a": [L * math.cos(ALPHA), L * math.sin(ALPHA)], "b": "link1", "point_b": [L, 0.0],
               "normal": [math.sin(ALPHA), -math.cos(ALPHA)]}
    doc = scene_doc({"turning": "turning.urdf", "held": "held.urdf"}, {"J1": ALPHA}, {"J1": 0.0}, gravity=(0.0, 0.0),
                    t_end=t_end, name="turnstile",
                    forces=[{"name": "motor", "type": "linear", "configurations": ["turning"], "on": {"joint": "J1"},
                             "measure": {"joint": "J1"}, "value": TORQUE},
                            {"name": "spring", "type": "spring", "configurations": ["turning"], "on": {"joint": "J1"},
                             "measure": {"link": "link1"}, "k": K}],
                    transitions=[stop("strike", "turning", 0.0, guard, contact, merge_to="held"),
                                 {"name": "let go", "type": "release", "from": "held", "to": "turning",
                                  "guard": {"type": "time", "every": every, "start": 0.0}}])
    return write_scene(folder, doc, {"turning.urdf": turning, "held.urdf": held})


SERIES = ("q", "theta", "forces", "constraint_forces", "potential")


def _series(rec) -> dict:
    return {name: np.array(getattr(rec, name)) for name in SERIES}


def _times(rec) -> np.ndarray:
    return np.linspace(rec.t[0], rec.t[-1], 7)


def _check_hand(rec) -> None:
    """The element values, the potential energy and the held pin's force, from the series' own
    angle (by hand)."""
    theta = rec.theta[:, 1]
    # no gravity: the potential energy is the spring's, k theta^2 / 2, also while held (the lock
    # carries the turning configuration's spring on J1: Holds.held_energy)
    np.testing.assert_allclose(rec.potential, K * theta ** 2 / 2, rtol=1e-12, atol=1e-9)
    if rec.configuration == "turning":
        np.testing.assert_allclose(rec.forces[:, rec.force_names.index("spring")], -K * theta, rtol=0, atol=1e-9)
    else:
        np.testing.assert_allclose(rec.constraint_forces[:, -1], (TORQUE - K * theta) / L, rtol=0, atol=1e-6)


@pytest.fixture(scope="module")
def alone(tmp_path_factory):
    """The run and every segment's series (derived, and resampled), all read in this thread."""
    path = turnstile(tmp_path_factory.mktemp("turnstile"))
    traj = pcmm.simulate(pcmm.load_scene(path))
    derived = [_series(s) for s in traj.segments]
    resampled = [_series(s.resampled(_times(s))) for s in traj.segments]
    return path, traj, derived, resampled


def test_every_entry_compiles_the_elements_at_new_offsets(alone):
    _, traj, _, _ = alone
    held = [s for s in traj.segments if s.configuration == "held"]
    assert len(held) >= 6  # a strike per turn: the offsets grow by 2 pi each time
    angles = [s.theta[0, 1] for s in held]
    np.testing.assert_allclose(np.diff(angles), 2 * math.pi, rtol=0, atol=1e-6)
    for s in traj.segments:
        _check_hand(s)


def test_series_read_in_a_second_thread_while_the_run_goes_on(alone, monkeypatch):
    """A second thread reads the lazy series (force elements, holding forces) of every finished
    segment, and resamples them, again and again while the first thread's run goes on entering
    both configurations at new angle offsets: every series equals the one read alone, and so
    does the run's own trajectory.  (Before, a read swapped the configuration's force elements
    for the segment's and back: a recompilation by the run meanwhile was undone, and the run
    recorded its next segments with the elements of an earlier entry.)"""
    path, ref, derived, resampled = alone
    logs: list = []  # the run's segment log, seen at its first segment (each added complete)
    add = SegmentLog.add
    # The reader's turn, by handshake, not by a pause of the run: each segment added waits until
    # a whole pass of the reader has read it (a sleep gave a thread starved on a loaded machine
    # no turn, and the compiled run was done before it read); then the run goes on while the
    # reader's next pass reads and resamples the finished segments again.
    turn = threading.Condition()
    covered = [0]  # the segments the reader's last whole pass read

    def spy(self, *args, **kwargs):
        add(self, *args, **kwargs)
        if not logs:
            logs.append(self)
        if self is logs[0]:
            with turn:
                turn.wait_for(lambda: covered[0] >= len(self) or failed, timeout=120)
    monkeypatch.setattr(SegmentLog, "add", spy)
    done = threading.Event()
    read: dict[int, dict] = {}
    again: list[tuple[int, dict]] = []
    failed: list[BaseException] = []

    def reader():
        try:
            while not done.is_set():
                finished = [logs[0][i] for i in range(len(logs[0]))] if logs else []
                for i, rec in enumerate(finished):  # each complete when added: its values are kept
                    if i not in read:
                        read[i] = _series(rec)
                    again.append((i, _series(rec.resampled(_times(rec)))))
                with turn:
                    covered[0] = len(finished)
                    turn.notify_all()
        except BaseException as exc:  # noqa: BLE001 - reported in the main thread
            failed.append(exc)
            with turn:
                turn.notify_all()
    second = threading.Thread(target=reader)
    second.start()
    try:
        traj = pcmm.simulate(pcmm.load_scene(path))
    finally:
        done.set()
        second.join()
    assert not failed, failed
    assert len(read) == len(ref.segments) and len(again) > len(ref.segments)  # every segment read mid-run
    assert len(traj.segments) == len(ref.segments)
    for i, series in read.items():
        for name in SERIES:
            np.testing.assert_array_equal(series[name], derived[i][name], err_msg=f"segment {i} {name}")
    for i, series in again:
        for name in SERIES:
            np.testing.assert_array_equal(series[name], resampled[i][name], err_msg=f"segment {i} resampled {name}")
    for i, s in enumerate(traj.segments):  # the run itself: as alone
        _check_hand(s)
        for name in SERIES:
            np.testing.assert_array_equal(getattr(s, name), derived[i][name], err_msg=f"run's segment {i} {name}")
