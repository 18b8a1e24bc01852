"""The event log's generated record builder (pcmm.results.event_log._builder): the same records,
of the same types, as a recursive walk of the layout (_walk) and as the dicts appended."""
from __future__ import annotations

import numpy as np

from pcmm.results import event_log
from pcmm.results.event_log import EventLog


def _records():
    long_text = "a warning longer than SHORT_TEXT characters, kept aside as it is: " + "x" * 60
    yield {"t": 0.25, "name": "floor", "from": "free", "to": "free", "merge": False, "law": None,
           "count": 3, "impulse": {"normal": -2.5, "vector": [0.0, 1.5, np.float64(2.75)]},
           "pair": (1.0, 2), "single": (7.5,), "empty": [], "nested": [[1.0, {"k": 2}], ()],
           "big": 2 ** 60, "warnings": [long_text]}
    yield {"t": 1.0, "x": [float(i) / 7.0 for i in range(50)], 3: "an int key", "flag": True}
    yield [1.0, "name", None, (2, 3.5)]



def _walk(layout, row, pos: int, aside: list):
    """The value of ``layout`` from ``row`` at ``pos``: (value, next position), by a recursive walk of
    the layout (the event log's reader before the generated one: the reference here)."""
    if layout == event_log._F:
        return float(row[pos]), pos + 1
    if layout == event_log._I:
        return int(row[pos]), pos + 1
    if layout == event_log._O:
        return aside[int(row[pos])], pos + 1
    kind = layout[0]
    if kind == event_log._C:
        return layout[1], pos
    if kind == "d":
        out = {}
        for key, sub in zip(layout[1], layout[2]):
            out[key], pos = _walk(sub, row, pos, aside)
        return out, pos
    items = []
    for sub in layout[1]:
        value, pos = _walk(sub, row, pos, aside)
        items.append(value)
    return (items if kind == "l" else tuple(items)), pos


def test_each_record_reads_back_equal_with_the_same_types_and_as_the_general_reader_builds_it():
    """Every record (dict, list and tuple nesting, ints and a 2**60 kept aside, constants, a long
    text kept aside, a one-item tuple, int keys) reads back equal to the one appended, with the
    same container and number types at every leaf, and equal to what _walk makes of the row."""
    records = list(_records())
    log = EventLog(records)

    def types(x):
        if isinstance(x, dict):
            return ("dict", [(type(k).__name__, types(v)) for k, v in x.items()])
        if isinstance(x, (list, tuple)):
            return (type(x).__name__, [types(v) for v in x])
        return type(x).__name__ if not isinstance(x, np.float64) else "float"

    for i, rec in enumerate(records):
        got = log[i]
        assert got == rec and types(got) == types(rec)
        k, row = log._index[0][i]
        table = log._tables[k]
        general = _walk(table.layout, table.row(int(row)), 0, log._aside)[0]
        assert general == got and types(general) == types(got)
    assert list(log) == records and log[1]["x"][3] == 3.0 / 7.0


def test_a_log_taken_to_its_columns_and_back_reads_the_same_records_and_grows():
    """columns() -> from_columns() (the layouts through JSON, as a store chunk keeps them): the
    same records, 600 of them (past two BLOCKs of 256), a record read by index and changed before
    is written back, and the log grows afterwards as any log."""
    import json
    records = [dict(rec, t=float(i)) if isinstance(rec, dict) else rec
               for i in range(200) for rec in _records()]
    log = EventLog(records)
    log[4]["t"] = -1.0  # the run's record, changed after it was read (kept by index)
    records[4] = dict(records[4], t=-1.0)
    layouts, rows, index, aside = log.columns()
    back = EventLog.from_columns(json.loads(json.dumps(layouts)), rows, index, json.loads(json.dumps(aside)))
    assert len(back) == 600 and list(back) == records and back[-1] == records[-1]
    back.append({"t": 1.0, "x": [1.0] * 50, 3: "an int key", "flag": True})
    back.append({"t": 2.0, "new": "layout"})
    assert back[600]["x"] == [1.0] * 50 and back[601] == {"t": 2.0, "new": "layout"} and list(back)[:600] == records


def test_an_interrupt_inside_append_leaves_the_log_as_it_was(monkeypatch):
    """Ctrl-C (or SIGTERM, an interrupt in pcmm.cli) landing inside ``EventLog.append``: the event
    is not counted, every event before it reads back, and the next append works.  The log used to
    count the event before encoding it, so a signal mid-encoding left an index row of garbage and
    the partial run's record died with IndexError (clean-clone CI, test_fs_signals_at_random_moments)."""
    from pcmm.results import event_log
    log = event_log.EventLog([{"t": 0.5, "name": "floor", "impulse": {"normal": 2.0, "vector": [0.0, 2.0]}}])
    real = event_log._Table.append

    def interrupted(self, numbers):
        raise KeyboardInterrupt
    for event in ({"t": 1.0, "name": "floor", "impulse": {"normal": 1.0, "vector": [0.0, 1.0]}},
                  {"t": 1.5, "name": "wall", "P": 3.0}):  # a layout seen before, and a new one
        monkeypatch.setattr(event_log._Table, "append", interrupted)
        try:
            log.append(event)
        except KeyboardInterrupt:
            pass
        monkeypatch.setattr(event_log._Table, "append", real)
        assert len(log) == 1 and log[-1]["t"] == 0.5 and [e["t"] for e in log] == [0.5]
    log.append({"t": 2.0, "name": "wall", "P": 4.0})
    log.append({"t": 2.5, "name": "floor", "impulse": {"normal": 0.5, "vector": [0.0, 0.5]}})
    assert [(e["t"], e["name"]) for e in log] == [(0.5, "floor"), (2.0, "wall"), (2.5, "floor")]
    assert log[1]["P"] == 4.0 and log[2]["impulse"]["vector"] == [0.0, 0.5]
