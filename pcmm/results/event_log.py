"""The events of a run, kept compactly: columns of numbers, one table per record layout.

A run of many impacts keeps one event record (:class:`pcmm.events.EventRecord`) per impact;
as nested dicts of Python floats such a record takes ~3 kB, which a run of 1e6 bounces cannot
afford (issue 26).  :class:`EventLog` keeps each record as its *layout* -- the nested keys,
the containers, and the text, flags and ``None`` that repeat from one event to the next
(transition names, configurations, kinds) -- shared by every event of that layout, and a row
of its numbers in a float64 table of that layout, appended in blocks.  The rare rich values
(warning messages, anything else that is neither a number nor a short text) are kept aside
as they are.  Reading an event builds the same dict again: the same keys in the same order,
the same numbers (a float64 holds a float exactly, and an integer below 2**53), the same types.

The log is a sequence of dicts (``len``, indexing, slices, iteration, ``==`` with a list) and
grows by :meth:`EventLog.append`; a record is encoded when appended, so changing the dict
afterwards does not change the log.  A record read by its index (``log[i]``) is the run's
record: ``log[0]["t"] = ...`` changes it, as it did when events were a list (the last
``READ_KEPT`` read are kept as dicts; one pushed out is written back when it was changed).
Iterating, and a slice, build each record afresh and keep none of them (a summary of a long
run reads every event once), except those kept.
"""
from __future__ import annotations

import functools

import numpy as np

from .segment_log import RecordSequence

BLOCK = 256  # rows of a layout's table allocated at once
READ_KEPT = 64  # records read by index kept as dicts (a run reads its last ones after each event)
FLATTENERS = 8  # layouts whose generated readers are tried before the general encoder (_flattener)
SHORT_TEXT = 48  # texts up to this length are part of the layout (names repeat); longer ones are kept aside
_EXACT_INT = 2 ** 53

# the layout's leaves: a number of the row (float or int), a constant of the layout, a value kept aside
_F, _I, _C, _O = "f", "i", "c", "o"


def _layout(obj, numbers: list, aside: list):
    """The hashable layout of ``obj``; its numbers appended to ``numbers``, its rich values to ``aside``.
    (Dispatched on the exact type, the common ones first, a container's float items read in its
    own loop: a record is appended at every event.)"""
    kind = type(obj)
    if kind is float or kind is np.float64:
        numbers.append(obj)
        return _F
    if kind is dict:
        return ("d", tuple(obj), _items(obj.values(), numbers, aside))
    if kind is list:
        return ("l", _items(obj, numbers, aside))
    if kind is str:
        if len(obj) <= SHORT_TEXT:
            return (_C, obj)
    elif kind is bool or obj is None:
        return (_C, obj)
    elif kind is int:
        if -_EXACT_INT < obj < _EXACT_INT:
            numbers.append(obj)
            return _I
    elif kind is tuple:
        return ("t", _items(obj, numbers, aside))
    elif isinstance(obj, np.float64):
        numbers.append(obj)
        return _F
    numbers.append(len(aside))  # a message, an array, anything else: kept as it is
    aside.append(obj)
    return _O


def _items(values, numbers: list, aside: list) -> tuple:
    """The layouts of a container's ``values`` (:func:`_layout` of each; a float's here)."""
    out = []
    for v in values:
        if type(v) is float:
            numbers.append(v)
            out.append(_F)
        else:
            out.append(_layout(v, numbers, aside))
    return tuple(out)


@functools.lru_cache(maxsize=256)  # per layout, for every log of the process (a study's runs share them)
def _flattener(layout):
    """``record -> its numbers`` (a list, in :func:`_layout`'s order) for a record of exactly
    ``layout``, None for any other record; or None where ``layout`` keeps values aside (those are
    encoded by :func:`_layout`).  It is straight-line code generated from the layout: every
    container's type, length and keys, every constant and every number's type are checked as
    :func:`_layout` classifies them, and the numbers read without a call per value (a run of
    bounces appends one record of the same layout per impact: 226 function calls each by
    :func:`_layout` for three_bar_cycle's)."""
    consts: list = []
    lines: list = []
    numbers: list = []
    count = [0]

    def new_var() -> str:
        count[0] += 1
        return f"x{count[0]}"

    def const(value) -> str:
        consts.append(value)
        return f"K[{len(consts) - 1}]"

    def emit(node, var: str) -> bool:
        if node == _F:
            lines.append(f"if type({var}) is not float and not isinstance({var}, F64): return None")
            numbers.append(var)
            return True
        if node == _I:
            lines.append(f"if type({var}) is not int or not -E < {var} < E: return None")
            numbers.append(var)
            return True
        if node == _O:
            return False
        kind = node[0]
        if kind == _C:
            value = node[1]
            if value is None or type(value) is bool:
                lines.append(f"if {var} is not {value!r}: return None")
            else:
                lines.append(f"if type({var}) is not str or {var} != {const(value)}: return None")
            return True
        subs = node[2] if kind == "d" else node[1]
        names = [new_var() for _ in subs]
        container = {"d": "dict", "l": "list", "t": "tuple"}[kind]
        lines.append(f"if type({var}) is not {container} or len({var}) != {len(subs)}: return None")
        if kind == "d":
            lines.append(f"if tuple({var}) != {const(node[1])}: return None")
        if subs:
            lines.append(f"{', '.join(names)}, = {var}{'.values()' if kind == 'd' else ''}")
        return all(emit(sub, name) for sub, name in zip(subs, names))
    if not emit(layout, "x0"):
        return None
    body = "\n    ".join(lines + [f"return [{', '.join(numbers)}]"])
    scope = {"K": tuple(consts), "F64": np.float64, "E": _EXACT_INT}
    exec(f"def flat(x0):\n    {body}\n", scope)  # noqa: S102 - code generated from a layout above, no input text
    return scope["flat"]


@functools.lru_cache(maxsize=256)  # per layout, for every log of the process
def _builder(layout):
    """``(row, aside) -> the record`` of ``layout`` from its numbers ``row`` (a list of floats):
    the record a recursive walk of the layout builds, by straight-line code generated from the
    layout -- one dict or list display per container, no call per value (a store writes, and a
    summary reads, every event of a run: the walk made 75 calls for a bouncing ball's record;
    tests/test_event_log_builder.py keeps it as the reference)."""
    consts: list = []
    pos = [0]

    def const(value) -> str:
        consts.append(value)
        return f"K[{len(consts) - 1}]"

    def expr(node) -> str:
        if node == _F or node == _I or node == _O:
            i = pos[0]
            pos[0] += 1
            return f"r[{i}]" if node == _F else f"int(r[{i}])" if node == _I else f"A[int(r[{i}])]"
        kind = node[0]
        if kind == _C:
            return const(node[1])
        if kind == "d":
            return "{" + ", ".join(f"{const(key)}: {expr(sub)}" for key, sub in zip(node[1], node[2])) + "}"
        items = [expr(sub) for sub in node[1]]
        return f"[{', '.join(items)}]" if kind == "l" else f"({', '.join(items)}{',' if len(items) == 1 else ''})"
    body = expr(layout)
    scope = {"K": tuple(consts)}
    exec(f"def build(r, A):\n    return {body}\n", scope)  # noqa: S102 - code generated from a layout, no input text
    return scope["build"]


class _Table:
    """The rows of one layout: float64 blocks of BLOCK rows."""

    __slots__ = ("layout", "width", "blocks", "n")

    def __init__(self, layout, width: int):
        self.layout, self.width, self.blocks, self.n = layout, width, [], 0

    def append(self, numbers: list) -> int:
        if self.n == len(self.blocks) * BLOCK:
            self.blocks.append(np.empty((BLOCK, self.width)))
        self.blocks[-1][self.n % BLOCK] = numbers
        self.n += 1
        return self.n - 1

    def row(self, i: int) -> np.ndarray:
        return self.blocks[i // BLOCK][i % BLOCK]


class EventLog(RecordSequence):
    """The events of a run: a sequence of event records (dicts) kept as columns of numbers.

    Examples
    --------
    >>> log = EventLog([{"t": 0.5, "name": "floor", "impulse": {"normal": 2.0, "vector": [0.0, 2.0]}}])
    >>> log.append({"t": 1.5, "name": "floor", "impulse": {"normal": 1.0, "vector": [0.0, 1.0]}})
    >>> len(log), log[-1]["impulse"]["vector"], [e["t"] for e in log]
    (2, [0.0, 1.0], [0.5, 1.5])
    """

    def __init__(self, events=()):
        self._tables: list[_Table] = []
        self._by_layout: dict = {}
        self._index: list[np.ndarray] = []  # blocks of (table, row) per event
        self._n = 0
        self._aside: list = []
        self._flat: list = []  # (table index, flattener) of the layouts last appended, the latest first
        self._templates: dict = {}  # id(template) -> (template, table index) of records given as numbers
        # the records last read by index (the same dict while kept here; changed, written back when dropped)
        self._read: dict[int, dict] = {}
        for e in events:
            self.append(e)

    def __getstate__(self) -> dict:
        """Pickled without the generated readers of :attr:`_flat` (code made by exec has no
        importable name; a process pool pickles a run's result): the copy makes its own, from
        :func:`_flattener`, at its next append."""
        return {**self.__dict__, "_flat": [], "_templates": {}}

    def append(self, event) -> None:
        """Keep ``event`` (encoded now: later changes to the dict are not seen)."""
        if self._n == len(self._index) * BLOCK:
            self._index.append(np.empty((BLOCK, 2), np.int64))
        self._encode(self._n, event)
        self._n += 1  # counted once kept whole: a Ctrl-C inside _encode leaves the log as it was

    def _encode(self, i: int, event) -> None:
        log_row = getattr(event, "log_row", None)
        if log_row is not None:  # a record given as its numbers over a record of its layout
            k, numbers = self._row_of(*log_row())
            if k is not None:
                row = self._tables[k].append(numbers)
                self._index[i // BLOCK][i % BLOCK] = (k, row)
                return
            event = event.record()
        for k, flat in self._flat:  # a layout seen lately: its generated reader (_flattener)
            numbers = flat(event)
            if numbers is not None:
                break
        else:
            numbers = []
            layout = _layout(event, numbers, self._aside)
            k = self._by_layout.get(layout)
            if k is None:
                k = self._new_table(layout, len(numbers))
            flat = _flattener(layout)
            if flat is not None:
                self._flat = [(k, flat)] + [f for f in self._flat if f[0] != k][:FLATTENERS - 1]
        row = self._tables[k].append(numbers)
        self._index[i // BLOCK][i % BLOCK] = (k, row)

    def _new_table(self, layout, width: int) -> int:
        """A table for a layout first seen: made, then found by its layout (an interrupt between the
        two leaves an unused table, never a layout that points past the tables)."""
        self._tables.append(_Table(layout, width))
        k = self._by_layout[layout] = len(self._tables) - 1
        return k

    def _row_of(self, template, numbers):
        """(table, numbers) of a record given as ``numbers`` (in the order :func:`_layout` reads them)
        over ``template``, a record of its layout: the template's layout is found once (kept by
        identity, with it); (None, None) where that layout keeps values aside or has another width."""
        templates = self.__dict__.setdefault("_templates", {})  # (a log pickled before it had them)
        known = templates.get(id(template))
        if known is None or known[0] is not template:
            width: list = []
            aside: list = []
            layout = _layout(template, width, aside)
            k = None
            if not aside:
                k = self._by_layout.get(layout)
                if k is None:
                    k = self._new_table(layout, len(width))
            known = templates[id(template)] = (template, k, len(width))
        if known[1] is None or len(numbers) != known[2]:
            return None, None
        return known[1], numbers

    def extend(self, events) -> None:
        for e in events:
            self.append(e)

    def _event(self, i: int):
        k, row = self._index[i // BLOCK][i % BLOCK]
        table = self._tables[k]
        return _builder(table.layout)(table.row(int(row)).tolist(), self._aside)

    def __len__(self) -> int:
        return self._n

    def time(self, i: int) -> float:
        """Event ``i``'s ``"t"`` without building its record where its layout starts with it (every
        event record's does): the run's zero-time-cycle check reads it at every event."""
        i = self._position(i, "event")
        kept = self._read.get(i)
        if kept is not None:
            return kept["t"]
        k, row = self._index[i // BLOCK][i % BLOCK]
        table = self._tables[k]
        layout = table.layout
        if type(layout) is tuple and layout[0] == "d" and layout[1][:1] == ("t",) and layout[2][0] == _F:
            return float(table.row(int(row))[0])
        return self._event(i)["t"]

    def _kept(self, i: int):
        """Record ``i``, the same dict while it is among the last READ_KEPT read by index; the
        one it pushes out is written back if it was changed meanwhile (as a list's would stay)."""
        read = self._read
        record = read.pop(i, None)
        if record is None:
            record = self._event(i)
            if len(read) >= READ_KEPT:
                j = next(iter(read))
                dropped = read.pop(j)
                if dropped != self._event(j):
                    self._encode(j, dropped)
        read[i] = record  # the latest last
        return record

    def __getitem__(self, i):
        if isinstance(i, slice):  # as iterating: built afresh, not kept
            return [self._read.get(j) or self._event(j) for j in range(*i.indices(self._n))]
        return self._kept(self._position(i, "event"))

    def __iter__(self):
        read = self._read
        for i in range(self._n):
            record = read.get(i)
            yield record if record is not None else self._event(i)

    def __eq__(self, other):
        if isinstance(other, (EventLog, list, tuple)):
            return len(self) == len(other) and all(a == b for a, b in zip(self, other))
        return NotImplemented

    def __repr__(self) -> str:
        return repr(list(self))

    def columns(self) -> tuple[list, list[np.ndarray], np.ndarray, list]:
        """The log as its columns: (the layouts, in JSON's terms: nested lists; each layout's rows, a
        float64 array of them; the (layout, row) of every event, an int64 array; the values kept
        aside) -- what :meth:`from_columns` takes back.  Records read by index and changed since are
        written back first."""
        for i, record in list(self._read.items()):
            if record != self._event(i):
                self._encode(i, record)
        rows = [np.concatenate(t.blocks)[:t.n] if t.blocks else np.empty((0, t.width)) for t in self._tables]
        index = np.concatenate(self._index)[:self._n] if self._index else np.empty((0, 2), np.int64)
        return [t.layout for t in self._tables], rows, index, list(self._aside)

    @classmethod
    def from_columns(cls, layouts: list, rows: list[np.ndarray], index: np.ndarray, aside: list) -> EventLog:
        """The log of :meth:`columns` (its layouts as tuples again, or as read back from JSON)."""
        def hashable(node):
            return tuple(hashable(x) for x in node) if isinstance(node, (list, tuple)) else node

        def blocks(a: np.ndarray, dtype) -> list[np.ndarray]:  # BLOCK rows each, as appended
            out = []
            for j in range(0, len(a), BLOCK):
                block = np.empty((BLOCK, a.shape[1]), dtype)
                block[:len(a) - j] = a[j:j + BLOCK]
                out.append(block)
            return out
        log = cls()
        for layout, table_rows in zip(layouts, rows):
            layout = hashable(layout)
            table = _Table(layout, table_rows.shape[1])
            table.blocks, table.n = blocks(table_rows, float), len(table_rows)
            log._by_layout.setdefault(layout, len(log._tables))
            log._tables.append(table)
        log._index, log._n = blocks(np.asarray(index).reshape(-1, 2), np.int64), len(index)
        log._aside = list(aside)
        return log

    def nbytes(self) -> int:
        """Bytes of the number tables and the index (the layouts and the values kept aside not counted)."""
        return sum(b.nbytes for t in self._tables for b in t.blocks) + sum(b.nbytes for b in self._index)
