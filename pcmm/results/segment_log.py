"""The segments of a run, kept compactly: each segment's integrator states in shared blocks.

A bouncing run records one segment per impact.  Kept as one :class:`SegmentRecord` each, with
its own arrays and the closures that derive its series, a segment costs ~5 kB before a single
sample (issue 26).  :class:`SegmentLog` keeps, per segment, one row of integers (its context,
where its numbers lie, how many samples) and its numbers -- the warm start ``q_start``, the
times and the integrator's states -- appended to float64 blocks shared by every segment.  What
the segments of one stay have in common (the configuration, its name lists, and the
*context* that derives the series: partition, force elements, locks, angle offsets, stepping)
is kept once and shared by every segment it is the same for.

Reading ``log[i]`` gives the :class:`SegmentRecord` of that segment (made once, then the same
object), whose series are derived when first read, as a run's segments always were.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .segment import SegmentRecord

DATA_BLOCK = 1 << 16  # floats of a data block (512 kB); a longer segment gets a block of its own
ROW_BLOCK = 1024  # segment rows allocated at once
_ROW = 6  # context, data block, offset, samples, state rows, q_start length


class RecordSequence(Sequence):
    """What a run's record sequences (segments, events, a store's) share with a list: ``+`` with
    a list or another sequence gives a plain list, and an index is checked as a list's is."""

    def __add__(self, other):
        return [*self, *other]

    def __radd__(self, other):
        return [*other, *self]

    def _position(self, i, what: str) -> int:
        """Index ``i`` (negative from the end) as a position in ``range(len(self))``, or IndexError."""
        n = len(self)
        i = int(i)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"{what} index out of range")
        return i


class SegmentLog(RecordSequence):
    """The segments of a run, in order; grows by :meth:`add`.

    ``context`` objects (one per stay whose segments share it) give ``derive(t, y, q_start)``,
    the segment's series as a dict of arrays, and ``resample(t, y, q_start, times)``, the same at
    other times; equal contexts (``==``) in a row of the same configuration are kept once."""

    def __init__(self):
        self._contexts: list[tuple] = []  # (configuration, names, context)
        self._last: dict[str, int] = {}  # configuration -> its latest context
        self._names: dict = {}  # the name lists, one copy per configuration and set of names
        self._rows: list[np.ndarray] = []
        self._data: list[np.ndarray] = []
        self._fill = 0  # floats used in the last data block
        self._n = 0
        self.total_samples = 0
        self._records: dict[int, object] = {}  # the segments read so far (same object every time)

    # ---- growing --------------------------------------------------------------------------
    def context_id(self, configuration: str, names: dict, context, keep=None) -> int:
        """The id of ``context`` (the latest one of ``configuration`` when equal to it); the name
        lists are kept once per configuration and set of names, whatever the context.  ``keep``:
        ``context -> the context kept`` where it is new (a context may refer to what the run
        changes later, and be compared as it is: only a kept one needs its own copy).  Name lists that
        are the very ones the latest context of ``configuration`` holds are those kept (the recording
        hands the same lists while their sources are equal): they are not looked up again."""
        k = self._last.get(configuration)
        if k is None or self._contexts[k][1] is not names:
            names = self._names.setdefault((configuration, *(tuple(v) for v in names.values())), names)
        if k is not None:
            conf, known_names, known = self._contexts[k]
            if known_names is names and known == context:
                return k
        self._contexts.append((configuration, names, context if keep is None else keep(context)))
        self._last[configuration] = len(self._contexts) - 1
        return len(self._contexts) - 1

    def add(self, context: int, t: np.ndarray, y: np.ndarray, q_start: np.ndarray) -> None:
        """Keep a segment: its times ``t`` (n,), the integrator's states ``y`` (rows, n) and the
        coordinates ``q_start`` it started from, under the context ``context`` (:meth:`context_id`)."""
        n, rows, nq = t.size, y.shape[0], q_start.size
        size = nq + n + rows * n
        if not self._data or self._fill + size > self._data[-1].size:
            self._data.append(np.empty(max(DATA_BLOCK, size)))
            self._fill = 0
        block = self._data[-1]
        at = self._fill
        block[at:at + nq] = q_start
        block[at + nq:at + nq + n] = t
        block[at + nq + n:at + size] = y.reshape(-1)
        self._fill += size
        if self._n == len(self._rows) * ROW_BLOCK:
            self._rows.append(np.empty((ROW_BLOCK, _ROW), np.int64))
        self._rows[-1][self._n % ROW_BLOCK] = (context, len(self._data) - 1, at, n, rows, nq)
        self._n += 1
        self.total_samples += n

    # ---- reading --------------------------------------------------------------------------
    def _row(self, i: int):
        return self._rows[i // ROW_BLOCK][i % ROW_BLOCK]

    def arrays(self, i: int):
        """(t, y, q_start) of segment ``i``: views of the blocks (read-only)."""
        k, b, at, n, rows, nq = self._row(i).tolist()  # Python ints
        block = self._data[b]
        q_start, t = block[at:at + nq], block[at + nq:at + nq + n]
        y = block[at + nq + n:at + nq + n + rows * n].reshape(rows, n)
        for a in (q_start, t, y):
            a.flags.writeable = False
        return t, y, q_start

    def configuration(self, i: int) -> str:
        return self._contexts[int(self._row(i)[0])][0]

    def samples(self, i: int) -> int:
        return int(self._row(i)[3])

    def times(self) -> np.ndarray:
        """Every sample time, segment after segment (what ``Trajectory.t`` is), without making records."""
        return np.concatenate([self.arrays(i)[0] for i in range(self._n)]) if self._n else np.zeros(0)

    def configurations(self) -> list[str]:
        """The configuration of every sample (``Trajectory.configuration_at``), without making records."""
        return [self.configuration(i) for i in range(self._n) for _ in range(self.samples(i))]

    def _record(self, i: int):
        rec = self._records.get(i)
        if rec is None:
            k = int(self._row(i)[0])
            configuration, names, context = self._contexts[k]
            t, y, q_start = self.arrays(i)
            rec = SegmentRecord.deferred(lambda: context.derive(t, y, q_start), t.copy(),
                                         resample=lambda times: context.resample(t, y, q_start, times),
                                         configuration=configuration, **names)
            self._records[i] = rec
        return rec

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self._record(j) for j in range(*i.indices(self._n))]
        return self._record(self._position(i, "segment"))

    def __iter__(self):
        for i in range(self._n):
            yield self._record(i)

    def __reduce__(self):  # pickled (sent to another process) as its records, series and all
        return (list, (list(self),))

    def __deepcopy__(self, memo):
        import copy
        return copy.deepcopy(list(self), memo)  # a plain list of copied records

    def __repr__(self) -> str:
        return f"<SegmentLog of {self._n} segments>"
