"""The event log's generated record builder (pcmm.results.event_log._builder): the same records,
of the same types, as the general reader _build and as the dicts appended."""
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


def test_each_record_reads_back_equal_with_the_same_types_and_as_the_general_reader_builds_it():
    """Every record (dict, list and tuple nesting, ints and a 2**60 kept aside, constants, a long
    text kept aside, a one-item tuple, int keys) reads back equal to the one appended, with the
    same container and number types at every leaf, and equal to what _build makes of the row."""
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
        general = event_log._build(table.layout, table.row(int(row)), 0, log._aside)[0]
        assert general == got and types(general) == types(got)
    assert list(log) == records and log[1]["x"][3] == 3.0 / 7.0
