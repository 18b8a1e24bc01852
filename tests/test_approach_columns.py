"""The closest approach at a run's end reads its events' columns, not their records (issue 26).

A run of a million bounces built every event record twice at its end (~23.5 us each) to find when
each watched transition last fired.  :func:`pcmm.run.approach.firings` reads each layout's ``t``
and ``t_end`` columns instead; the reference is the same reading of the records themselves
(:func:`pcmm.run.approach._firings_of_records`), and the records built are counted.
"""
from __future__ import annotations

import math

import builders
import pytest

from pcmm.results.event_log import EventLog
from pcmm.run import approach

LONG = "a transition named at such a length that its name is kept aside, not in the layout"


def _events() -> list[dict]:
    """Events of several layouts, one transition's spread over two of them and interleaved with
    another's (its last in the log's order is not its latest), a contact law's ``t_end`` (0.0, a
    number, None), an integer instant, a name kept aside, an event with no name, a record that is
    not a plain dict (kept aside whole)."""
    return [
        {"t": 0.5, "name": "floor", "impulse": {"normal": 2.0}},
        {"t": 0.75, "name": "wall", "t_end": 0.0, "x": [1.0, 2.0]},
        {"t": 1.0, "name": "wall", "t_end": 1.25, "x": [3.0, 4.0]},
        Record({"t": 2.75, "name": "wall"}),  # not a plain dict: kept aside whole
        {"t": 1.5, "name": "floor", "impulse": {"normal": 1.0}},
        {"t": 2, "name": "floor", "impulse": {"normal": 0.5}},  # an integer instant: its own layout
        {"t": 2.5, "name": "wall", "t_end": None, "x": [5.0, 6.0]},
        {"t": 2.25, "name": "floor", "impulse": {"normal": 0.25}},  # out of time order: last, not latest
        {"t": 3.0, "name": LONG},
        {"t": 3.5, "warning": "no name"},
        {"t": 0.1, "name": "wall", "t_end": 0.2, "x": [7.0, 8.0]},
    ]


class Record(dict):
    """An event record of a dict's own type (the log keeps it aside, as it is)."""


def test_firings_from_the_columns_equal_those_from_the_records():
    names = {"floor", "wall", LONG, "absent"}
    log = EventLog(_events())
    want = approach._firings_of_records(_events(), names)
    # by hand: floor's latest 2.25 (not its last layout's), wall's t_end where not 0/None
    assert want["floor"] == approach.Firing(2.25, 2.25, 2.25)
    assert want["wall"] == approach.Firing(2.75, 0.2, 2.75)
    assert want[LONG] == approach.Firing(3.0, 3.0, 3.0) and "absent" not in want
    got = approach.firings(log, names)
    assert got == want
    assert {k: [type(x) for x in (f.latest, f.last, f.t_max)] for k, f in got.items()} == \
        {k: [type(x) for x in (f.latest, f.last, f.t_max)] for k, f in want.items()}


def test_firings_of_a_log_split_in_parts_equal_those_of_the_whole():
    """A store's events come as its chunks' logs, then those not yet written."""
    class Parts(list):
        def logs(self):
            return [EventLog(_events()[:4]), EventLog(_events()[4:7]), _events()[7:]]
    names = {"floor", "wall", LONG}
    assert approach.firings(Parts(_events()), names) == approach._firings_of_records(_events(), names)


def _counting(monkeypatch) -> list:
    built = []
    real = EventLog._event

    def event(self, i):
        built.append(i)
        return real(self, i)
    monkeypatch.setattr(EventLog, "_event", event)
    return built


@pytest.mark.parametrize("stored", [False, True])
def test_a_2000_bounce_run_ends_without_building_its_event_records(tmp_path, monkeypatch, stored):
    """The ball (e = 1, never merged) bounces 2,000 times; its end's closest approach (the floor's
    guard since it last fired) builds no event record, in memory or read from a store's chunks,
    and equals the record found by reading every event record."""
    import pcmm
    from pcmm.model.mechanism import Mechanism
    period = 2.0 * math.sqrt(2.0 * 1.0 / builders.G)  # h = 1 m, falling from rest
    scene = pcmm.load_scene(builders.ball(tmp_path, 1.0, t_end=(2000 - 0.25) * period, merge=False,
                                          solver={"max_events": 10_000}))
    traj = pcmm.simulate(scene, store=tmp_path / "store") if stored else pcmm.simulate(scene)
    assert len(traj.events) == 2000
    cfg = Mechanism(scene)["free"]
    built = _counting(monkeypatch)
    got = approach.closest_approach(scene, cfg, traj)
    assert built == []
    monkeypatch.setattr(approach, "firings", lambda events, names: approach._firings_of_records(events, names))
    want = approach.closest_approach(scene, cfg, traj)
    assert len(built) == 2000  # the reference reads every record
    assert got == want and len(got) == 1 and got[0]["last_fired"] == traj.events[-1]["t"]
