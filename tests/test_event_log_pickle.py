"""An event log pickles (a process pool sends a run's result back): its generated readers of the
layouts last appended (event_log._flattener, code made by exec) stay behind, and the copy reads,
appends and encodes as the original does."""
from __future__ import annotations

import pickle

from pcmm.results.event_log import EventLog


def _bounce(t: float, p: float) -> dict:
    return {"t": t, "name": "floor", "impulse": {"normal": p, "vector": [0.0, p]}, "merged": False}


def test_an_event_log_survives_a_pickle_round_trip_and_appends_after_it():
    log = EventLog([_bounce(0.5, 2.0), _bounce(1.5, 1.0)])  # the second record is read by a generated reader
    assert log._flat, "the case: a generated reader is held"
    copy = pickle.loads(pickle.dumps(log))  # before: PicklingError (function flat ... on __main__)
    assert list(copy) == list(log)
    copy.append(_bounce(2.25, 0.5))
    log.append(_bounce(2.25, 0.5))
    assert list(copy) == list(log) and copy[-1]["impulse"]["vector"] == [0.0, 0.5]
    assert copy._flat and len(copy._tables) == len(log._tables) == 1  # the same layout, its reader made again
