"""A run streamed to a folder as it goes: chunks of segments and events, appended, each whole.

``pcmm run SCENE --store DIR`` (``pcmm.simulate(..., store=DIR)``) writes::

    DIR/run.json            the run's header, when it starts: scene, impact, views
    DIR/chunk-000000.npz    the next segments (their series, derived when the chunk is written)
    DIR/chunk-000001.npz    and the events since the chunk before, ...
    DIR/end.json            when the run ends (completed or stopped): status, message, stats

Each file is written under a temporary name and then renamed (:func:`pcmm.files.atomic_write`),
so a run killed at any instant -- even by SIGKILL -- leaves every chunk it had written whole and
readable, and none half written.  The run keeps in memory only the segments and events of the
chunk it is filling: a long run's memory does not grow with its steps or events.

:func:`read_store` reads a folder back as a :class:`~pcmm.results.trajectory.Trajectory`
(``Trajectory.load(DIR)``) whose segments and events are read from the chunks when asked for,
one chunk in memory at a time.  A folder without ``end.json`` is a run that was killed: it
reads as a partial run up to its last chunk.

A chunk's segments are grouped by their name lists (configuration, coordinates, links, force
elements, constraint rows): each group's series are concatenated (``g<k>_<series>``), and the
header (the array ``header``, JSON as UTF-8 bytes; a numpy string in chunks written before) lists
the segments in order with their group and samples, the groups' names, and the number of the
chunk's events.  The events are kept as the run's :class:`~pcmm.results.event_log.EventLog`
keeps them: ``event_layouts`` (JSON as UTF-8 bytes: each layout of record, and the values kept
aside), ``event_rows<j>`` (float64, the numbers of the events of layout ``j``, a row each) and
``event_index`` (int64, the layout and row of each event) -- no event is turned into a dict to be
written, and they are read only when asked for (a pass over a run's segments reads none).  Chunks
written before keep them as JSON: the array ``events``, or the header's ``events``.
"""
from __future__ import annotations

import bisect
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import UsageError
from ..files import atomic_write
from .event_log import EventLog
from .segment import SegmentRecord
from .segment_log import RecordSequence, SegmentLog

FORMAT = "pcmm-store-1"
SERIES = ("t", "q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces")
NAMES = ("coordinates", "links", "force_names", "constraint_labels")
CHUNK_SAMPLES = 50_000  # a chunk is written once the pending segments hold this many samples
CHUNK_RECORDS = 2_000  # ... or this many segments or events
#: the last events (and segments) of the chunks written that a run keeps in memory: what its own
#: checks read back of its past -- the zero-time-cycle check reads the last 64 events
#: (pcmm.run.actions.ZERO_TIME_CYCLE) -- so that no chunk is read again while the run goes on
RECENT = 64


def chunk_path(folder: Path, k: int) -> Path:
    return folder / f"chunk-{k:06d}.npz"


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, Sequence):
        return list(o)
    raise TypeError(f"not JSON serializable: {type(o)}")


def _dumps(obj) -> str:
    return json.dumps(obj, default=_json_default)


def write_json(path: Path, obj) -> None:
    atomic_write(path, lambda f: f.write(_dumps(obj)), force=True)


def _json_array(header) -> np.ndarray:
    """A chunk's header as the bytes of its JSON in UTF-8: a numpy string array would hold 4 bytes
    a character (UTF-32), and the events' JSON is most of a chunk (a bouncing ball's 2,000 events:
    9.4 MB that way, 2.4 MB this)."""
    return np.frombuffer(_dumps(header).encode(), dtype=np.uint8)


def _open(path: Path):
    """A chunk file opened for reading (every read of a chunk goes through here)."""
    return np.load(path, allow_pickle=False)


def _read_header(z) -> dict:
    """A chunk's header: UTF-8 bytes, or (chunks written before) a numpy string."""
    a = z["header"]
    return json.loads(a.tobytes().decode() if a.dtype == np.uint8 else str(a[()]))


def derive_together(log, copies: int = RECENT) -> int:
    """Derive the series of a chunk's segments (a run's :class:`SegmentLog`) not yet read, one call
    for each run of consecutive segments that share a context reading every sample alone (a tree's:
    ``cfg.coords.constrained`` false, so a sample's series depend on that sample's state and time
    alone, never on a Newton solve warm-started from the sample before); each segment gets its own
    rows (views of the run's arrays, copies for the last :data:`RECENT`, which outlive the chunk).  A bouncing ball's chunk of 2,000 segments is then one derivation instead of
    2,000 (each made its reader of the segment and some twenty small array operations: 57 us a
    bounce).  Every other segment derives its series when read, as before.  Returns the calls made.
    ``copies``: how many of the last segments get copies (0 for a run kept in memory, whose arrays
    all stay: :func:`pcmm.results.trajectory.derive_series`)."""
    if not isinstance(log, SegmentLog):
        return 0
    calls, n, start = 0, len(log), 0
    while start < n:
        k = int(log._row(start)[0])
        end = start + 1
        while end < n and int(log._row(end)[0]) == k:
            end += 1
        calls += _derive_run(log, log._contexts[k][2], range(start, end), copies)
        start = end
    return calls


def _derive_run(log: SegmentLog, context, indices: range, copies: int = RECENT) -> int:
    """:func:`derive_together` for the segments ``indices`` of one context: 1 call, or 0 where it
    does not apply (fewer than two segments not yet read, a constrained configuration, states of
    different sizes)."""
    coords = getattr(getattr(context, "cfg", None), "coords", None)
    if coords is None or getattr(coords, "constrained", True):
        return 0
    todo = [i for i in indices if "_derive" in log[i].__dict__]  # (a segment read already keeps its series)
    if len(todo) < 2:
        return 0
    pieces = [log.arrays(i) for i in todo]
    if len({y.shape[0] for _, y, _ in pieces}) != 1:
        return 0
    whole = context.derive(np.concatenate([t for t, _, _ in pieces]), np.hstack([y for _, y, _ in pieces]),
                           pieces[0][2])
    at, kept = 0, len(log) - copies  # the last RECENT segments outlive the chunk (StoreReader.written): copies
    for i, (t, _, _) in zip(todo, pieces):
        rec, m = log[i], len(t)
        if i < kept:  # views of the run's arrays, dropped with the chunk once it is written
            rec.__dict__.update({name: a[at:at + m] for name, a in whole.items()})
        else:
            rec.__dict__.update({name: a[at:at + m].copy() for name, a in whole.items()})
        del rec.__dict__["_derive"]
        at += m
    return 1


def write_chunk(path: Path, segments: list, events) -> None:
    """One chunk: ``segments`` (records; their series are read now) and ``events`` (an
    :class:`EventLog`, or dicts)."""
    groups: dict[tuple, int] = {}
    parts: dict[int, dict[str, list]] = {}
    metas = []
    for s in segments:
        names = tuple(tuple(getattr(s, n)) for n in NAMES)
        k = groups.setdefault((s.configuration, names), len(groups))
        bucket = parts.setdefault(k, {a: [] for a in SERIES})
        for a in SERIES:
            bucket[a].append(np.asarray(getattr(s, a), float))
        metas.append([k, int(len(s.t))])
    header = {"format": FORMAT, "segments": metas, "event_count": len(events),
              "groups": [{"configuration": conf, **{n: list(v) for n, v in zip(NAMES, names)}}
                         for conf, names in groups]}
    layouts, rows, index, aside = (events if isinstance(events, EventLog) else EventLog(events)).columns()
    arrays = {"header": _json_array(header), "event_layouts": _json_array({"layouts": layouts, "aside": aside}),
              "event_index": index, **{f"event_rows{j}": r for j, r in enumerate(rows)}}
    for k, bucket in parts.items():
        for a, pieces in bucket.items():
            arrays[f"g{k}_{a}"] = np.concatenate(pieces)

    def write(f):
        np.savez(f, **arrays)
    atomic_write(path, write, force=True, binary=True)


class _Chunk:
    """A chunk read back: its segments' records and its events."""

    def __init__(self, path: Path):
        with _open(path) as z:
            header = _read_header(z)
            if header.get("format") != FORMAT:
                raise ValueError(f"{path.name}: format {header.get('format')!r}, expected {FORMAT}")
            arrays = {name: np.asarray(z[name]) for name in z.files if name != "header"}
        if "event_index" in arrays:
            self._events = {name: arrays.pop(name) for name in list(arrays) if name.startswith("event_")}
        else:  # chunks written before: the events' JSON, in an array or the header
            self._events = header.get("events", arrays.pop("events", None))
        groups = header["groups"]
        at = [0] * len(groups)
        self.segments = []
        for k, n in header["segments"]:
            g, a0 = groups[k], at[k]
            at[k] += n
            self.segments.append(SegmentRecord(configuration=g["configuration"], **{m: g[m] for m in NAMES},
                                               **{a: arrays[f"g{k}_{a}"][a0:a0 + n] for a in SERIES}))

    @property
    def events(self):
        """The chunk's events (an :class:`EventLog`, made when first asked for)."""
        kept = self._events
        if isinstance(kept, dict):
            self._events = _event_log(kept)
        elif isinstance(kept, np.ndarray):
            self._events = json.loads(kept.tobytes().decode())
        return self._events


def _event_log(arrays) -> EventLog:
    """A chunk's events written as columns (``arrays``: its ``event_*`` arrays, or the open file)."""
    head = json.loads(np.asarray(arrays["event_layouts"]).tobytes().decode())
    rows = [np.asarray(arrays[f"event_rows{j}"]) for j in range(len(head["layouts"]))]
    return EventLog.from_columns(head["layouts"], rows, np.asarray(arrays["event_index"]), head["aside"])


def chunk_events(path: Path):
    """The events of chunk ``path`` alone (its segments' arrays not read), as :attr:`_Chunk.events`."""
    with _open(path) as z:
        if "event_index" in z.files and _read_header(z).get("format") == FORMAT:
            return _event_log(z)
    return _Chunk(path).events


class StoreReader:
    """The chunks of a store folder: counts read once (from every chunk's header, or given by the
    writer of a chunk), records read one chunk at a time -- but for the last :data:`RECENT` segments
    and events of those written by the run itself (``recent``), kept in memory."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.paths: list[Path] = []
        self.segment_counts: list[int] = []
        self.event_counts: list[int] = []
        self.starts = {"segments": [0], "events": [0]}  # cumulative counts: where each chunk starts
        self._cached: tuple[int, _Chunk] | None = None
        # which ("segments" or "events") -> (the index of the first kept, the records kept)
        self.recent: dict[str, tuple[int, list]] = {}
        self.refresh()

    def refresh(self) -> None:
        """Take in the chunks written since (consecutive numbers from the last one known)."""
        while True:
            path = chunk_path(self.folder, len(self.paths))
            if not path.is_file():
                return
            with _open(path) as z:
                header = _read_header(z)
            events = header["event_count"] if "event_count" in header else len(header["events"])
            self.add(path, len(header["segments"]), events)

    def add(self, path: Path, segments: int, events: int) -> None:
        """Chunk ``path`` holds the next ``segments`` and ``events``."""
        self.paths.append(path)
        self.segment_counts.append(segments)
        self.event_counts.append(events)
        self.starts["segments"].append(self.starts["segments"][-1] + segments)
        self.starts["events"].append(self.starts["events"][-1] + events)

    def written(self, path: Path, segments: list, events: list) -> None:
        """The run wrote chunk ``path`` of ``segments`` and ``events`` (records): counted without
        reading it back, its last :data:`RECENT` of each kept."""
        for which, records in (("segments", segments), ("events", events)):
            end = self.starts[which][-1] + len(records)
            _, kept = self.recent.get(which, (end, []))
            kept = (kept + list(records[-RECENT:]))[-RECENT:]
            self.recent[which] = (end - len(kept), kept)
        self.add(path, len(segments), len(events))

    def record(self, which: str, i: int):
        """Record ``i`` of those written (``which``: "segments" or "events")."""
        first, kept = self.recent.get(which, (0, ()))
        if first <= i < first + len(kept):
            return kept[i - first]
        k = bisect.bisect_right(self.starts[which], i) - 1
        return getattr(self.chunk(k), which)[i - self.starts[which][k]]

    def chunk(self, k: int) -> _Chunk:
        if self._cached is None or self._cached[0] != k:
            self._cached = None  # one chunk in memory at a time
            self._cached = (k, _Chunk(self.paths[k]))
        return self._cached[1]


class _Stored(RecordSequence):
    """The segments (or events) of a store: those in its chunks, then the ones not yet written
    (``tail``, a run's own log while it goes on)."""

    def __init__(self, reader: StoreReader, which: str, tail=()):
        self.reader, self.which, self.tail = reader, which, tail

    def _counts(self) -> list[int]:
        return self.reader.segment_counts if self.which == "segments" else self.reader.event_counts

    def __len__(self) -> int:
        return self.reader.starts[self.which][-1] + len(self.tail)

    def _get(self, i: int):
        starts = self.reader.starts[self.which]
        if i >= starts[-1]:  # not yet written (a run's latest: what it reads while it goes on)
            return self.tail[i - starts[-1]]
        return self.reader.record(self.which, i)

    def time(self, i: int) -> float:
        """Event ``i``'s ``"t"`` (:meth:`EventLog.time` where it is not yet written)."""
        i = self._position(i, self.which[:-1])
        written = self.reader.starts[self.which][-1]
        if i >= written and hasattr(self.tail, "time"):
            return self.tail.time(i - written)
        return self._get(i)["t"]

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self._get(j) for j in range(*i.indices(len(self)))]
        return self._get(self._position(i, self.which[:-1]))

    def append(self, item) -> None:
        """A run's new segment or event: into the chunk being filled."""
        self.tail.append(item)

    def __iter__(self):
        for k in range(len(self._counts())):
            yield from list(getattr(self.reader.chunk(k), self.which))
        yield from self.tail

    def logs(self):
        """The records as their parts, in order: each chunk's (an :class:`EventLog` for events written
        as columns), then those not yet written; one chunk read at a time (a pass over the events'
        columns, :func:`pcmm.run.approach.firings`, builds no record)."""
        for k in range(len(self._counts())):
            cached = self.reader._cached
            if self.which == "events" and not (cached and cached[0] == k):
                yield chunk_events(self.reader.paths[k])  # (not the chunk's segments)
            else:
                yield getattr(self.reader.chunk(k), self.which)
        yield self.tail

    def __eq__(self, other):
        if isinstance(other, (Sequence,)) and not isinstance(other, str):
            return len(self) == len(other) and all(a == b for a, b in zip(self, other))
        return NotImplemented

    def __reduce__(self):  # pickled as the records themselves
        return (list, (list(self),))

    def __repr__(self) -> str:
        return f"<{len(self)} {self.which} stored in {self.reader.folder}>"


class StoreWriter:
    """Writes a run's record into ``folder`` as it goes (see the module)."""

    def __init__(self, folder: str | Path, chunk_samples: int = CHUNK_SAMPLES, chunk_records: int = CHUNK_RECORDS):
        self.folder = Path(folder)
        self.chunk_samples, self.chunk_records = chunk_samples, chunk_records
        self.reader: StoreReader | None = None
        self.chunks = 0
        self._aside = None  # the thread that writes the chunks while the run goes on
        #: ``extremes_of(segments) -> dict``, given by the run: a chunk's holding extremes, refined on its
        #: segments' dense output as it is written (read back from the files, they have none), kept in
        #: :attr:`extremes` (the run's ``stats["holding"]`` merges them)
        self.extremes_of = None
        self.extremes: list[dict] = []

    def aside(self, work):
        """``work()`` on a thread of its own, waited for: every evaluation of the series it derives
        writes that thread's Pinocchio data (:meth:`Configuration.workspace`), never the data the
        run's own thread integrates with (a run kept in memory derives its series after it ends)."""
        if self._aside is None:
            from concurrent.futures import ThreadPoolExecutor
            self._aside = ThreadPoolExecutor(1, thread_name_prefix="pcmm-store")
        return self._aside.submit(work).result()

    def start(self, traj) -> None:
        """Open the folder (created; it must not hold a store already) and write the header."""
        if self.folder.exists() and not self.folder.is_dir():
            raise UsageError(f"--store {self.folder}: is a file; give a folder (created if missing)")
        if self.folder.is_dir() and any(self.folder.iterdir()):
            raise UsageError(f"--store {self.folder}: the folder is not empty; give a new or an empty folder "
                             "(a store is one run's record)")
        self.folder.mkdir(parents=True, exist_ok=True)
        write_json(self.folder / "run.json", {"format": FORMAT, "scene": traj.scene, "scene_name": traj.scene_name,
                                              "impact": traj.impact, "views": traj.views})
        self.reader = StoreReader(self.folder)
        traj.segments = _Stored(self.reader, "segments", SegmentLog())  # the run fills the tails
        traj.events = _Stored(self.reader, "events", EventLog())

    def pending(self, traj) -> tuple[list, list]:
        segs, events = traj.segments, traj.events
        return (segs.tail if isinstance(segs, _Stored) else segs), (events.tail if isinstance(events, _Stored) else events)

    def due(self, traj) -> bool:
        """Is the chunk being filled full?"""
        segs, events = self.pending(traj)
        if len(segs) >= self.chunk_records or len(events) >= self.chunk_records:
            return True
        return getattr(segs, "total_samples", 0) >= self.chunk_samples

    def flush(self, traj, more: bool = True) -> None:
        """Write the pending segments and events as the next chunk; the trajectory then reads them
        from it, and goes on filling empty logs (``more``) or none."""
        segs, events = self.pending(traj)
        if len(segs) or len(events):
            path = chunk_path(self.folder, self.chunks)
            derive_together(segs)
            if self.extremes_of is not None:  # while the segments have their dense output
                self.extremes.append(self.extremes_of(segs))
            segs = list(segs)
            write_chunk(path, segs, events)
            self.chunks += 1
            self.reader.written(path, segs, events)  # not read back
        traj.segments = _Stored(self.reader, "segments", SegmentLog() if more else ())
        traj.events = _Stored(self.reader, "events", EventLog() if more else ())

    def end(self, traj) -> None:
        """The run ended (completed or stopped): its last chunk and its end record."""
        if self._aside is not None:
            self._aside.shutdown()
            self._aside = None
        self.flush(traj, more=False)
        stats = dict(traj.stats.items()) if hasattr(traj.stats, "items") else dict(traj.stats)
        write_json(self.folder / "end.json", {"status": traj.status, "message": traj.message, "stats": stats})


def read_store(folder: str | Path) -> dict:
    """The run stored in ``folder``: the fields of its :class:`~pcmm.results.trajectory.Trajectory`
    (``Trajectory.load(folder)``), whose segments and events are read from its chunks when asked
    for.  Raises :class:`UsageError` for a folder that holds no store."""
    folder = Path(folder)
    what = f"{folder}: not a pcmm store (a folder written by 'pcmm run --store')"
    try:
        head = json.loads((folder / "run.json").read_text(encoding="utf-8"))
        if not isinstance(head, dict) or head.get("format") != FORMAT:
            raise ValueError(f"format {head.get('format') if isinstance(head, dict) else None!r}, expected {FORMAT}")
        reader = StoreReader(folder)
        end_path = folder / "end.json"
        end = json.loads(end_path.read_text(encoding="utf-8")) if end_path.is_file() else None
    except FileNotFoundError:
        raise UsageError(f"{what}: it has no run.json") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UsageError(f"{what}: {type(exc).__name__}: {exc}") from None
    segments, events = _Stored(reader, "segments"), _Stored(reader, "events")
    if end is None:
        last = segments[-1].t[-1] if len(segments) else 0.0
        status, stats = "partial", {}
        message = (f"{folder}: the run stopped without ending its store (killed?): it holds its first "
                   f"{len(reader.paths)} chunks, to t = {float(last):.6g} s")
    else:
        status, message, stats = end["status"], end["message"], end["stats"]
    return dict(scene=head["scene"], scene_name=head["scene_name"], impact=bool(head["impact"]),
                segments=segments, events=events, stats=stats, status=status, message=message,
                views=head.get("views") or {})
