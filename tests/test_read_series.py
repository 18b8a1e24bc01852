"""An in-memory run's series, first read, are derived as a store's writer derives a chunk's: the
segments of one tree context in one call (``store.derive_together`` through
``trajectory.derive_series``), the same bits as each segment derived alone (tests/test_series.py's
reference)."""
from __future__ import annotations

import math

import builders
import numpy as np

import pcmm
from pcmm.results import trajectory
from pcmm.results.trajectory import derive_series, holding_extremes
from test_series import _counted  # derived_series' calls counted (the samples each derives)

KEYS = ("q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces")


def _ball(tmp_path):
    """A ball (e = 1, never merged) over 30 bounces, kept in memory: its first fall, then 30 flights
    of one context."""
    scene = pcmm.load_scene(builders.ball(tmp_path, 1.0, merge=False))
    return pcmm.simulate(scene, pcmm.RunOptions(t_end=29.5 * 2.0 * math.sqrt(2.0 / 9.81)))


def test_an_in_memory_runs_series_first_read_are_derived_in_one_call_a_context(tmp_path, monkeypatch):
    traj = _ball(tmp_path)
    n = len(traj.segments)
    assert n == 31
    alone = [{key: getattr(seg, key) for key in KEYS} for seg in traj.segments]  # one segment at a time
    traj.segments._records.clear()  # the same segments, not yet derived
    calls = _counted(monkeypatch)
    y = traj.series("xy", "ball")
    # the flights in one call; the first fall (its own context) derives its own when read
    assert calls == [sum(len(s["q"]) for s in alone[1:]), len(alone[0]["q"])]
    np.testing.assert_array_equal(y, np.concatenate([s["xy"][:, traj.segments[0].links.index("ball")]
                                                     for s in alone]))
    for mine, seg in zip(alone, traj.segments):
        for key in KEYS:
            np.testing.assert_array_equal(mine[key], getattr(seg, key), err_msg=key)
    # views of the one call's arrays (no copy); read again: nothing derived again
    assert np.shares_memory(traj.segments[1].q, traj.segments[n - 1].q) is False
    assert traj.segments[1].q.base is not None and traj.segments[1].q.base is traj.segments[n - 1].q.base
    walks = []
    monkeypatch.setattr(trajectory, "derive_series", lambda segments: walks.append(1) or derive_series(segments))
    traj.series("kinetic")
    holding_extremes(traj)
    assert len(calls) == 2 and derive_series(traj.segments) == 0
    assert walks == []  # the segments are not walked again for a second read (the same log, as long)


def test_the_ends_holding_extremes_derive_only_where_they_read(tmp_path, monkeypatch):
    """The end of every run reads the holding forces (``.hold`` rows) and stance forces of every
    segment (``holding_extremes``): a ball has neither, so nothing is derived there; Example 1's
    latch holds (``O3.hold`` before it releases, say), and its segments are then derived."""
    traj = _ball(tmp_path)
    traj.segments._records.clear()
    calls = _counted(monkeypatch)
    assert holding_extremes(traj) == {} and calls == []
    cycle = pcmm.simulate(pcmm.load_scene(builders.EXAMPLES / "three_bar_cycle.toml"), pcmm.RunOptions(t_end=1.3))
    want = holding_extremes(cycle)
    assert want  # it holds somewhere
    cycle.segments._records.clear()
    del calls[:]
    assert holding_extremes(cycle) == want and calls


def test_a_list_of_segments_is_left_to_derive_when_read(tmp_path):
    traj = _ball(tmp_path)
    assert derive_series(list(traj.segments)) == 0
