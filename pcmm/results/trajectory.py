"""Run results: segments (one per stay in a configuration), events and stats.

A :class:`Trajectory` saves to one NPZ file (arrays plus a JSON header) and
loads back without the scene; it exports CSV with one column per named
quantity and units in the header.  Files are written atomically (temporary
file, then rename) so an interrupted write never leaves half a file.

The file also records what the views need (:attr:`Trajectory.views`): each
visited configuration's URDF text and joints (name, type, parent, child) and
each force element's target.  ``pcmm replay`` and ``pcmm plot`` read only
that, so a saved run replays and plots after its scene and URDFs are gone.
Files of the first format (``pcmm-trajectory-1``, without views) still load;
their views are read from the scene file they name while it exists.
"""
from __future__ import annotations

import csv
import json
import math
import os
import tomllib
import xml.etree.ElementTree as ET
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import SimulationError, UsageError
from ..files import atomic_write
from .event_log import EventLog
from .segment import SegmentRecord
from .segment_log import SegmentLog

FORMAT = "pcmm-trajectory-2"
_FORMATS = ("pcmm-trajectory-1", FORMAT)
_ARRAYS = ("t", "q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces")


class RunStats(dict):
    """A run's statistics; the entries given as functions (``RunStats(d, holding=f)``) are
    computed the first time they are read, however they are read (item, ``get``, iteration,
    ``items``, JSON, pickle): they derive from series that are themselves computed on demand."""

    def __init__(self, data=(), **deferred):
        super().__init__(data)
        for key in deferred:
            super().__setitem__(key, None)
        self._deferred = dict(deferred)

    def defer(self, key: str, fn) -> None:
        """Make ``key``'s value ``fn()``, computed the first time it is read."""
        super().__setitem__(key, None)
        self._deferred[key] = fn

    def _settle(self, key=None):
        for k in ([key] if key is not None else list(self._deferred)):
            fn = self._deferred.pop(k, None)
            if fn is not None:
                super().__setitem__(k, fn())

    def __getitem__(self, key):
        self._settle(key) if key in self._deferred else None
        return super().__getitem__(key)

    def get(self, key, default=None):
        self._settle(key) if key in self._deferred else None
        return super().get(key, default)

    def __iter__(self):
        self._settle()
        return super().__iter__()

    def items(self):
        self._settle()
        return super().items()

    def values(self):
        self._settle()
        return super().values()

    def copy(self):
        self._settle()
        return dict(super().items())

    def __repr__(self):
        self._settle()
        return super().__repr__()

    def __reduce__(self):
        self._settle()
        return (dict, (dict(super().items()),))


def _extend(ext: dict, col: np.ndarray, t: np.ndarray) -> None:
    """Widen the extremes ``ext`` ({min, t_min, max, t_max}) by the samples ``col`` at ``t``; NaN
    samples (a statically indeterminate force) are left out and counted (``indeterminate_samples``)."""
    loose = np.isnan(col)
    if loose.any():
        ext["indeterminate_samples"] = ext.get("indeterminate_samples", 0) + int(np.count_nonzero(loose))
        col, t = col[~loose], t[~loose]
    if not col.size:
        return
    i_lo, i_hi = int(np.argmin(col)), int(np.argmax(col))
    if col[i_lo] < ext["min"]:
        ext["min"], ext["t_min"] = float(col[i_lo]), float(t[i_lo])
    if col[i_hi] > ext["max"]:
        ext["max"], ext["t_max"] = float(col[i_hi]), float(t[i_hi])


def stance_forces(traj: "Trajectory", s: SegmentRecord) -> dict:
    """{cut joint: (F_n, F_t)} of every point ``s``'s configuration holds by compression only (a cut
    joint with a contact normal: a pinned foot's stance): the force on b along the contact's world
    normal n (> 0 pushing) and tangent t = (n_y, -n_x), from the recorded ``<cut joint>.fx``, ``.fy``
    and link a's angle (the normal is given in a's frame).  Empty without the run's views."""
    out = {}
    for j in _stance_joints(traj, s):
        labels = (f"{j['name']}.fx", f"{j['name']}.fy")
        F = s.constraint_forces[:, [s.constraint_labels.index(x) for x in labels]]
        angle = s.theta[:, s.links.index(j["a"])] if j["a"] in s.links else np.zeros(len(s.t))
        c, si = np.cos(angle), np.sin(angle)
        nx, ny = c * j["normal"][0] - si * j["normal"][1], si * j["normal"][0] + c * j["normal"][1]
        norm = np.hypot(nx, ny)
        nx, ny = nx / norm, ny / norm
        out[j["name"]] = (nx * F[:, 0] + ny * F[:, 1], ny * F[:, 0] - nx * F[:, 1])
    return out


def _stance_joints(traj: Trajectory, s: SegmentRecord) -> list[dict]:
    """The cut joints of ``s``'s configuration with a contact normal whose forces ``s`` records
    (what :func:`stance_forces` reads)."""
    view = ((traj.views or {}).get("configurations") or {}).get(s.configuration) or {}
    return [j for j in view.get("cut_joints") or ()
            if j.get("normal") is not None and all(x in s.constraint_labels for x in (f"{j['name']}.fx", f"{j['name']}.fy"))]


def derive_series(segments) -> int:
    """Derive the series of a run's segments kept in memory (its :class:`SegmentLog`) not yet read,
    as a store's writer does a chunk's (:func:`pcmm.results.store.derive_together`: one call for each
    run of consecutive segments of one tree context, each segment's series views of that call's
    arrays, no copy), before they are first read; a segment that already derived its series, a
    constrained configuration's, and any other sequence of segments (a store's, a list) are left to
    derive when read, segment by segment.  Returns the calls made."""
    if not isinstance(segments, SegmentLog):
        return 0
    from .store import derive_together  # (the store reads trajectories back)
    return derive_together(segments, copies=0)


def holding_extremes(traj: "Trajectory", segments=None, known=None) -> dict:
    """{lock: {min, t_min, max, t_max}} of every holding force or moment (constraint forces labelled
    ``<lock>.hold``): what a designer sizes a latch by; and beside them {cut joint: {"normal": {...},
    "tangential": {...}}} of every point held by compression only (a pinned foot's stance force,
    :func:`stance_forces`), what a designer sizes the contact's friction by.  The extremes are the
    force's along the run, not its largest recorded sample: around the extreme sample (and every
    local extreme sample near it, :mod:`pcmm.results.peaks`) the force is evaluated on the run's
    dense output between the steps (the path of :meth:`Trajectory.resampled`) and its extreme there
    taken, with its time; a trajectory without dense output (loaded from a file, a store's chunks
    read back) gives its samples' extremes.  A force the rows leave statically indeterminate (NaN:
    redundant rows, :func:`pcmm.model.rows.determinate`) is left out of the extremes and counted
    (``indeterminate_samples``); held indeterminate throughout, its extremes are None (no number is
    any split's).  ``segments``: those to read (a store's chunk as it is written), else the run's;
    ``known``: the extremes of the run's earlier parts (:func:`merged_extremes` of the chunks written
    before): a sample is refined only where it could reach beyond them too."""
    from .peaks import MARGIN, MOST, local_extremes, refine
    out: dict = {}
    derived = segments is not None
    segments = traj.segments if segments is None else segments
    candidates: dict = {}  # (ext's id) -> [(sign * value, segment index, sample index)]
    columns: dict = {}  # (ext's id) -> (ext, column of a record, the earlier parts' extremes of it)

    def consider(ext, col, t, si, column, before):
        _extend(ext, col, t)
        key = id(ext)
        columns.setdefault(key, (ext, column, before))
        for sign in (1.0, -1.0):
            kept = candidates.setdefault((key, sign), [])
            kept += [(sign * float(col[i]), si, int(i)) for i in local_extremes(col, sign)]
            if len(kept) > 8 * MOST:  # a long run: only the highest can be within the margin
                kept.sort(reverse=True)
                del kept[4 * MOST:]

    for si, s in enumerate(segments):
        if not derived and (any(x.endswith(".hold") for x in s.constraint_labels) or _stance_joints(traj, s)):
            derived = traj._derive_grouped() >= 0  # the first series read: every run of one context at once
        for name, parts in stance_forces(traj, s).items():
            entry = out.setdefault(name, {part: {"min": math.inf, "t_min": None, "max": -math.inf, "t_max": None}
                                          for part in ("normal", "tangential")})
            for p, (part, col) in enumerate(zip(("normal", "tangential"), parts)):
                consider(entry[part], col, s.t, si, lambda rec, name=name, p=p: stance_forces(traj, rec)[name][p],
                         ((known or {}).get(name) or {}).get(part))
        for k, label in enumerate(s.constraint_labels):
            if not label.endswith(".hold"):
                continue
            ext = out.setdefault(label, {"min": math.inf, "t_min": None, "max": -math.inf, "t_max": None})
            consider(ext, s.constraint_forces[:, k], s.t, si,
                     lambda rec, label=label: rec.constraint_forces[:, rec.constraint_labels.index(label)],
                     (known or {}).get(label))
    jobs: dict = {}  # segment index -> [(sample index, sign, column, ext)]
    for (key, sign), kept in candidates.items():
        ext, column, before = columns[key]
        if ext["t_min"] is None:
            continue
        lo, hi = ext["min"], ext["max"]
        if before and before.get("min") is not None:  # the run's extremes so far: beat those too
            lo, hi = min(lo, before["min"]), max(hi, before["max"])
        top, span = (hi if sign > 0 else -lo), hi - lo
        kept = sorted(c for c in kept if c[0] >= top - MARGIN * span)[::-1][:MOST]
        for _, si, i in kept:
            jobs.setdefault(si, []).append((i, sign, column, ext))
    for si, todo in sorted(jobs.items()):
        for (i, sign, _, ext), found in zip(todo, refine(segments[si], [j[:3] for j in todo])):
            if found is None:
                continue
            value, t = found
            if sign > 0 and value > ext["max"]:
                ext["max"], ext["t_max"] = value, t
            elif sign < 0 and value < ext["min"]:
                ext["min"], ext["t_min"] = value, t
    for entry in out.values():
        for ext in (entry,) if "t_min" in entry else entry.values():
            if ext["t_min"] is None:  # indeterminate at every sample
                ext["min"] = ext["max"] = None
    return out


def merged_extremes(parts) -> dict:
    """The extremes of a run from those of its parts (:func:`holding_extremes` of each chunk of a
    store, in time order): the lowest minimum and highest maximum with their times (the earlier of
    equal ones), the indeterminate samples summed, None where every part's is None."""
    out: dict = {}

    def merge(into, ext):
        if ext.get("indeterminate_samples"):
            into["indeterminate_samples"] = into.get("indeterminate_samples", 0) + ext["indeterminate_samples"]
        if ext["min"] is not None and (into["min"] is None or ext["min"] < into["min"]):
            into["min"], into["t_min"] = ext["min"], ext["t_min"]
        if ext["max"] is not None and (into["max"] is None or ext["max"] > into["max"]):
            into["max"], into["t_max"] = ext["max"], ext["t_max"]

    blank = {"min": None, "t_min": None, "max": None, "t_max": None}
    for part in parts:
        for name, entry in part.items():
            if "t_min" in entry:
                merge(out.setdefault(name, dict(blank)), entry)
            else:
                kept = out.setdefault(name, {k: dict(blank) for k in entry})
                for k, ext in entry.items():
                    merge(kept.setdefault(k, dict(blank)), ext)
    return out


@dataclass
class Trajectory:
    """The result of a run: one :class:`SegmentRecord` per stay in a configuration, the events
    and the stats.

    Attributes
    ----------
    scene : str
        Path of the scene file the run read.
    scene_name : str
    impact : bool
        ``False`` for the comparison run without impact (the paper's Figs. 6-9).
    segments : list of SegmentRecord
    events : list of dict
        One :class:`pcmm.events.EventRecord` per transformation, in time order.
    stats : dict
        ``steps``, ``rhs_evals``, ``wall_s``, ``constraint_drift_max``, ...
    status : str
        ``"complete"``, or ``"partial"`` for a run stopped by an error or Ctrl-C.
    message : str
        Why a partial run stopped.

    Examples
    --------
    >>> import pcmm
    >>> traj = pcmm.simulate(pcmm.load_scene("examples/three_bar.toml"), pcmm.RunOptions(t_end=0.2))
    >>> [s.configuration for s in traj.segments], traj.status
    (['config1', 'config2'], 'complete')
    """

    scene: str  # path of the scene file
    scene_name: str
    impact: bool  # False: the comparison run without impact (Figs. 6-9)
    segments: list[SegmentRecord] = field(default_factory=list)
    #: a sequence of dicts, kept compactly as columns (:class:`~pcmm.results.event_log.EventLog`)
    events: list[dict] = field(default_factory=EventLog)
    stats: dict = field(default_factory=dict)
    status: str = "complete"  # or "partial"
    message: str = ""
    #: What the replay and the figures need, recorded at run time (see :func:`record_views`):
    #: ``{"configurations": {name: {"urdf": text, "joints": {joint: {"type", "parent", "child"}}}},
    #: "forces": {name: {"on": {"kind", "name"}}}}``.
    views: dict = field(default_factory=dict)
    #: The segments' name lists (coordinates, links, force elements, constraint labels), one copy per
    #: configuration and set of locks, shared by its segments while the run records them (memory:
    #: a bouncing run has one segment per impact). Not saved: the segments carry the lists.
    shared_names: dict = field(default_factory=dict, repr=False, compare=False)
    #: The file this trajectory was loaded from (not saved), for messages.
    source: str | None = field(default=None, compare=False)

    # ---- access -----------------------------------------------------------------------
    @property
    def t(self) -> np.ndarray:
        """Every sample time of the run, segment after segment (s).

        Examples
        --------
        >>> import pcmm
        >>> traj = pcmm.simulate(pcmm.load_scene("examples/three_bar.toml"), pcmm.RunOptions(t_end=0.2))
        >>> float(traj.t[0]), float(traj.t[-1])
        (0.0, 0.2)
        """
        if hasattr(self.segments, "times"):  # a run's SegmentLog: without making a record per segment
            return self.segments.times()
        return np.concatenate([s.t for s in self.segments]) if self.segments else np.zeros(0)

    @property
    def links(self) -> list[str]:
        """Every link of the run, in order of first appearance.

        Examples
        --------
        >>> import pcmm
        >>> pcmm.simulate(pcmm.load_scene("examples/three_bar.toml"), pcmm.RunOptions(t_end=0.2)).links
        ['frame', 'link1', 'link2', 'link3']
        """
        out: list[str] = []
        for s in self.segments:
            out += [n for n in s.links if n not in out]
        return out

    def series(self, quantity: str, name: str | None = None) -> np.ndarray:
        """A quantity over the whole run, one value per sample of :attr:`t`.

        Parameters
        ----------
        quantity : str
            ``theta``/``omega``/``xy`` (by link), ``q``/``v`` (by coordinate), ``forces``
            (by force name), ``constraint_forces`` (by row label), ``kinetic``/``potential``
            (no name).
        name : str, optional
            The link, coordinate, force or row.

        Returns
        -------
        numpy.ndarray
            NaN where a segment lacks ``name`` (a joint that a configuration locks).

        Examples
        --------
        After the latch, joint O3 no longer exists; the absolute angles go on.

        >>> import numpy as np, pcmm
        >>> traj = pcmm.simulate(pcmm.load_scene("examples/three_bar.toml"), pcmm.RunOptions(t_end=0.2))
        >>> q3 = traj.series("q", "O3")
        >>> bool(np.isnan(q3[-1])), bool(np.isnan(q3[0]))
        (True, False)
        >>> traj.series("theta", "link3").shape == traj.t.shape
        True
        """
        names_of = {"theta": "links", "omega": "links", "xy": "links", "q": "coordinates",
                    "v": "coordinates", "forces": "force_names", "constraint_forces": "constraint_labels"}
        unnamed = ("kinetic", "potential")
        if quantity not in names_of and quantity not in unnamed:
            raise UsageError(f"series: no quantity {quantity!r}; the quantities are "
                             f"{', '.join([*names_of, *unnamed])}; the sample times are the attribute .t")
        if quantity in unnamed and name is not None:
            raise UsageError(f"series: {quantity!r} is the whole mechanism's: give no name (got {name!r})")
        if quantity in names_of:
            known = list(dict.fromkeys(n for s in self.segments for n in getattr(s, names_of[quantity])))
            if name not in known:
                what = {"links": "link", "coordinates": "coordinate", "force_names": "force",
                        "constraint_labels": "constraint row"}[names_of[quantity]]
                head = f"series: {quantity!r} needs a {what}" if name is None else f"series: no {what} {name!r} in this run"
                raise UsageError(f"{head}; the run's {what}s: {', '.join(known) or '(none)'}")
        parts = []
        self._derive_grouped()
        for s in self.segments:
            arr = getattr(s, quantity)
            if quantity in names_of:
                names = getattr(s, names_of[quantity])
                if name in names:
                    parts.append(arr[:, names.index(name)])
                else:
                    parts.append(np.full((len(s.t),) + arr.shape[2:], np.nan))
            else:
                parts.append(arr)
        return np.concatenate(parts) if parts else np.zeros(0)

    def _derive_grouped(self) -> int:
        """Derive the series of the segments not yet read, a run of one tree context in one call
        (:func:`derive_series`), once for the segments there are: read again, the segments are
        not walked again (a walk of 1,000 segments costs ~2 ms, most of a series read after the
        first).  Returns the calls made."""
        segments = self.segments
        if not isinstance(segments, SegmentLog):
            return 0
        # the mark is the log's own, not the trajectory's: a read that derives while the trajectory
        # is pickled (its stats' holding extremes) must not grow the __dict__ pickle is walking
        if segments.__dict__.get("_walked") == len(segments):
            return 0
        calls = derive_series(segments)
        segments.__dict__["_walked"] = len(segments)
        return calls

    def resampled(self, dt: float) -> "Trajectory":
        """The run at times 0, dt, 2 dt, ... (and at every segment's ends, so events keep their
        instants), on the integrator's dense output instead of its steps: curves between long
        steps follow the solution, not a polygon."""
        if not (dt > 0 and np.isfinite(dt)):
            raise UsageError(f"dt = {dt!r}: must be a number > 0")
        from ..viz.dense import segment_times  # the views' grid: one rule for --dt and the figures
        segs = [s.resampled(segment_times(float(s.t[0]), float(s.t[-1]), dt)) for s in self.segments]
        return Trajectory(scene=self.scene, scene_name=self.scene_name, impact=self.impact, segments=segs,
                          events=self.events, stats=self.stats, status=self.status, message=self.message,
                          views=self.views)

    def configuration_at(self) -> list[str]:
        """The configuration of every sample of :attr:`t`.

        Examples
        --------
        >>> import pcmm
        >>> c = pcmm.simulate(pcmm.load_scene("examples/three_bar.toml"), pcmm.RunOptions(t_end=0.2)).configuration_at()
        >>> c[0], c[-1]
        ('config1', 'config2')
        """
        if hasattr(self.segments, "configurations"):  # a run's SegmentLog: without making records
            return self.segments.configurations()
        return [s.configuration for s in self.segments for _ in s.t]

    def visited(self) -> list[str]:
        """The configurations the run stays in, in order of first visit."""
        return list(dict.fromkeys(s.configuration for s in self.segments))

    def configuration_views(self) -> dict[str, dict]:
        """``{configuration: {"urdf": text, "joints": {...}}}`` for every visited configuration.

        Raises :class:`UsageError` naming the trajectory file when a configuration's
        view is not recorded (a first-format file whose scene file is gone)."""
        views = self.views.get("configurations", {})
        missing = [c for c in self.visited() if c not in views]
        if missing:
            why = ("it was written by an earlier pcmm version (format pcmm-trajectory-1)" if self.source
                   else "its views were not recorded")
            raise UsageError(
                f"{self.source or 'trajectory'}: holds no geometry for configuration(s) {missing}: {why}, "
                f"and its scene file {self.scene} is not found; run the scene again with this version "
                "('pcmm run SCENE --out FILE') to get a file that replays on its own")
        return {c: views[c] for c in self.visited()}

    # ---- notebook views -------------------------------------------------------------------
    def show(self, *others: "Trajectory", fps: float = 60, height: int = 520, layout: str = "overlay",
             view: str = "run"):
        """The offline replay page, inline in Jupyter (an ``<iframe srcdoc>``, no server).

        ``others`` are overlaid (the second a faint ghost) or ``layout="side"`` by side, each in its
        own colour (e.g. the run without impact); ``view`` is ``run``, ``configuration`` or ``follow``."""
        from ..viz.replay import Inline  # the views read a run's record alone: they sit below it
        return Inline(self, *others, fps=fps, height=height, layout=layout, view=view)

    def plot(self, compare: "Trajectory | None" = None, impulse_sign: str = "body_b") -> dict:
        """The paper's figure set as matplotlib figures, ``{file stem: Figure}``."""
        from ..viz.plots import figures
        return figures(self, compare=compare, impulse_sign=impulse_sign)

    # ---- files ------------------------------------------------------------------------
    def save(self, path: str | Path, force: bool = True) -> Path:
        """Write the trajectory to one NPZ file, atomically; :meth:`load` reads it back.  The file
        holds what the replay and the figures need (each visited configuration's URDF text and
        joints), so it stands alone without its scene.

        Parameters
        ----------
        path : str or pathlib.Path
        force : bool
            Overwrite an existing file (else :class:`~pcmm.errors.UsageError`).

        Examples
        --------
        >>> import os, tempfile, pcmm
        >>> traj = pcmm.simulate(pcmm.load_scene("examples/three_bar.toml"), pcmm.RunOptions(t_end=0.2))
        >>> path = traj.save(os.path.join(tempfile.mkdtemp(), "run.npz"))
        >>> back = pcmm.Trajectory.load(path)
        >>> back.events[0]["t"] == traj.events[0]["t"], len(back.t) == len(traj.t)
        (True, True)
        """
        self._derive_grouped()
        visited = self.visited()
        views = {"configurations": {c: v for c, v in self.views.get("configurations", {}).items() if c in visited},
                 "forces": self.views.get("forces", {}), "transitions": self.views.get("transitions", [])}
        header = {"format": FORMAT, "scene": self.scene, "scene_name": self.scene_name,
                  "impact": self.impact, "events": list(self.events), "stats": self.stats,
                  "status": self.status, "message": self.message, "views": views,
                  "segments": [{"configuration": s.configuration, "coordinates": s.coordinates,
                                "links": s.links, "force_names": s.force_names,
                                "constraint_labels": s.constraint_labels} for s in self.segments]}
        arrays = {"header": np.array(json.dumps(header, default=_json_default))}
        for i, s in enumerate(self.segments):
            for a in _ARRAYS:
                arrays[f"s{i}_{a}"] = getattr(s, a)

        def write(f):
            np.savez_compressed(f, **arrays)
        return atomic_write(path, write, force=force, binary=True)

    @classmethod
    def load(cls, path: str | Path) -> "Trajectory":
        """Read a trajectory written by :meth:`save` (no scene or model needed), or the folder a run
        streamed to (``pcmm run --store DIR``, :mod:`pcmm.results.store`): its segments and events
        are then read from its chunks when asked for, and a run killed midway reads as a partial
        run up to the last chunk it wrote.

        Raises
        ------
        UsageError
            The file is missing, truncated, empty or foreign, or its arrays do not fit its header.
        """
        path = Path(path)
        if path.is_dir() and (path / "run.json").is_file():  # a store: read lazily, chunk by chunk
            from .store import read_store
            traj = cls(**read_store(path))
            traj.source = str(path)
            return traj
        what = f"{path}: not a pcmm trajectory file (.npz written by 'pcmm run --out')"
        try:
            with np.load(path, allow_pickle=False) as z:
                header = json.loads(str(z["header"][()]))
                if not isinstance(header, dict) or header.get("format") not in _FORMATS:
                    fmt = header.get("format") if isinstance(header, dict) else None
                    raise ValueError(f"format {fmt!r} is not one of {', '.join(_FORMATS)}"
                                     + (" (written by a newer pcmm?)" if str(fmt or "")
                                        .startswith("pcmm-trajectory-") else ""))
                segs = []
                for i, meta in enumerate(header["segments"]):
                    segs.append(_segment(meta, {a: np.asarray(z[f"s{i}_{a}"]) for a in _ARRAYS}, i))
                traj = cls(scene=_text(header["scene"]), scene_name=_text(header["scene_name"]),
                           impact=bool(header["impact"]), segments=segs, events=header["events"],
                           stats=dict(header["stats"]), status=_text(header["status"]),
                           message=_text(header["message"]))
        except FileNotFoundError:
            raise UsageError(f"{path}: trajectory file not found") from None
        except IsADirectoryError:
            raise UsageError(f"{path}: is a folder, not a trajectory file") from None
        except (OSError, EOFError, ValueError, KeyError, TypeError, IndexError, AttributeError, ArithmeticError,
                MemoryError, zipfile.BadZipFile, zlib.error, RecursionError) as exc:
            raise UsageError(f"{what}: {type(exc).__name__}: {exc}") from None
        if not isinstance(traj.events, list) or any(not isinstance(e, dict) for e in traj.events):
            raise UsageError(f"{what}: its events are not records")
        traj.events = EventLog(traj.events)
        views = header.get("views")
        traj.views = views if isinstance(views, dict) and views else legacy_views(traj.scene)
        traj.source = str(path)
        return traj

    def to_csv(self, path: str | Path, force: bool = True) -> Path:
        """Write one CSV row per sample: ``t``, ``configuration``, then every named quantity,
        units in the header; atomically.  ``v_<joint>`` is the rate of ``q_<joint>``: for a URDF
        ``planar`` joint ``P`` the columns ``v_P.x``, ``v_P.y`` are its origin's velocity in world
        axes (``[m/s in world axes]``), not Pinocchio's body-frame velocity.

        Examples
        --------
        >>> import os, tempfile, pcmm
        >>> traj = pcmm.simulate(pcmm.load_scene("examples/three_bar.toml"), pcmm.RunOptions(t_end=0.2))
        >>> path = traj.to_csv(os.path.join(tempfile.mkdtemp(), "run.csv"))
        >>> path.read_text().splitlines()[0].split(",")[:4]
        ['t [s]', 'configuration', 'theta_frame [rad]', 'omega_frame [rad/s]']
        """
        cols: list[tuple[str, np.ndarray]] = [("t [s]", self.t)]
        for link in self.links:
            cols.append((f"theta_{link} [rad]", self.series("theta", link)))
            cols.append((f"omega_{link} [rad/s]", self.series("omega", link)))
            xy = self.series("xy", link)
            cols.append((f"x_{link} [m]", xy[:, 0]))
            cols.append((f"y_{link} [m]", xy[:, 1]))
        coords = []
        for s in self.segments:
            coords += [c for c in s.coordinates if c not in coords]
        types = {j: d["type"] for view in self.views.get("configurations", {}).values()  # where it moves
                 for j, d in (view.get("joints") or {}).items()
                 if isinstance(d, dict) and d.get("type") in ("revolute", "prismatic")}
        planar = {j for view in self.views.get("configurations", {}).values()
                  for j, d in (view.get("joints") or {}).items() if isinstance(d, dict) and d.get("type") == "planar"}
        for c in coords:  # a revolute joint's coordinate is an angle, a prismatic one's a length
            q_unit, v_unit = {"revolute": ("rad", "rad/s"), "prismatic": ("m", "m/s")}.get(
                types.get(c), ("rad|m", "rad/s|m/s"))
            joint, _, part = c.rpartition(".")
            if joint in planar and part in ("x", "y", "theta"):  # a planar joint's rates are world-frame
                q_unit, v_unit = ("rad", "rad/s") if part == "theta" else ("m", "m/s in world axes")
            cols.append((f"q_{c} [{q_unit}]", self.series("q", c)))
            cols.append((f"v_{c} [{v_unit}]", self.series("v", c)))
        forces = self.views.get("forces", {})
        for name in dict.fromkeys(n for s in self.segments for n in s.force_names):
            on = (forces.get(name) or {}).get("on") or {}
            unit = "N" if on.get("kind") == "joint" and types.get(on.get("name")) == "prismatic" else \
                "N m" if on.get("kind") == "link" or types.get(on.get("name")) == "revolute" else "N m|N"
            cols.append((f"force_{name} [{unit}]", self.series("forces", name)))
        for name in dict.fromkeys(n for s in self.segments for n in s.constraint_labels):
            cols.append((f"constraint_{name} [{constraint_unit(name, types)}]", self.series("constraint_forces", name)))
        cols.append(("kinetic_energy [J]", self.series("kinetic")))
        cols.append(("potential_energy [J]", self.series("potential")))
        config = self.configuration_at()

        def write(f):
            out = csv.writer(f, lineterminator="\n")
            out.writerow([spreadsheet_text(h) for h in ["t [s]", "configuration"] + [c[0] for c in cols[1:]]])
            data = np.column_stack([c[1] for c in cols]) if cols else np.zeros((0, 0))
            for i, row in enumerate(data):
                out.writerow([repr(float(row[0])), spreadsheet_text(config[i])]
                             + ["" if np.isnan(x) else repr(float(x)) for x in row[1:]])
        return atomic_write(path, write, force=force)


def constraint_unit(label: str, joint_types: dict[str, str]) -> str:
    """The unit of a constraint-force series from its label: a cut joint's force components
    (``.fx``, ``.fy``, ``.fn``) in N, its moment (``.mz``) in N m; a drive's or a lock's
    (``<joint>.drive``, ``<joint>.hold``) by its joint's type; "N|N m" where the label does not
    tell (the hold of a stop-merge: a normal force, or a joint stop's moment)."""
    what, _, part = label.rpartition(".")
    if part in ("fx", "fy", "fn"):
        return "N"
    if part == "mz":
        return "N m"
    if part in ("drive", "hold"):
        return {"revolute": "N m", "prismatic": "N"}.get(joint_types.get(what), "N|N m")
    return "N|N m"


def _text(x) -> str:
    if not isinstance(x, str):
        raise TypeError(f"expected text, found {type(x).__name__}")
    return x


def _segment(meta: dict, arrays: dict, i: int) -> SegmentRecord:
    """One segment read back, its arrays checked against the names in its header."""
    names = {k: [_text(n) for n in meta[k]] for k in ("coordinates", "links", "force_names", "constraint_labels")}
    t = arrays["t"]
    n = t.shape[0] if t.ndim == 1 else -1
    if n < 1 or not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise ValueError(f"segment {i}: its times are not a finite, non-decreasing series")
    shapes = {"q": (n, len(names["coordinates"])), "v": (n, len(names["coordinates"])),
              "theta": (n, len(names["links"])), "omega": (n, len(names["links"])),
              "xy": (n, len(names["links"]), 2), "kinetic": (n,), "potential": (n,),
              "forces": (n, len(names["force_names"])), "constraint_forces": (n, len(names["constraint_labels"]))}
    for a, shape in shapes.items():
        if arrays[a].shape != shape or arrays[a].dtype.kind not in "fi":
            raise ValueError(f"segment {i}: array '{a}' has shape {arrays[a].shape} ({arrays[a].dtype}), "
                             f"expected {shape} numbers")
    return SegmentRecord(configuration=_text(meta["configuration"]), **names,
                         **{a: arrays[a].astype(float) for a in _ARRAYS})


def spreadsheet_text(text: str) -> str:
    """A text cell a spreadsheet shows as text: a leading = + - @ (or tab, carriage return)
    would make it a formula, so such a cell starts with an apostrophe (OWASP's rule)."""
    return "'" + text if text[:1] in ("=", "+", "-", "@", "\t", "\r") else text


def non_finite_fields(obj, where: str = "") -> list[str]:
    """The paths (``events[3].impulse.normal``) of every NaN or infinite number in ``obj``."""
    if isinstance(obj, dict):
        return [p for k, v in obj.items() for p in non_finite_fields(v, f"{where}.{k}" if where else str(k))]
    if isinstance(obj, (list, tuple)):
        return [p for i, v in enumerate(obj) for p in non_finite_fields(v, f"{where}[{i}]")]
    if isinstance(obj, np.ndarray):
        return non_finite_fields(obj.tolist(), where)
    if isinstance(obj, (float, np.floating)) and not math.isfinite(obj):
        return [f"{where} = {float(obj)!r}"]
    return []


#: an event's impulses between parts: NaN there is a force the rows leave statically indeterminate
#: (redundant rows: pcmm.events.impulse), written as null; nowhere else
_INDETERMINATE_KEYS = ("constraint_rows", "cut_impulses", "constraint_impulses", "joint_impulses")


def _indeterminate_as_null(obj):
    """``obj`` (a summary) with the NaN of its events' impulses between parts written as None (JSON
    null): statically indeterminate, which a velocity, an energy or an impulse on the contact never is
    (a NaN there still refuses the summary, :func:`dumps_json_finite`)."""
    if not isinstance(obj, dict) or not isinstance(obj.get("events"), list):
        return obj

    def null(x):
        if isinstance(x, dict):
            return {k: null(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [null(v) for v in x]
        return None if isinstance(x, (float, np.floating)) and math.isnan(x) else x
    events = [dict(e, **{k: null(e[k]) for k in _INDETERMINATE_KEYS if k in e}) if isinstance(e, dict) else e
              for e in obj["events"]]
    return dict(obj, events=events)


def dumps_json_finite(obj, what: str) -> str:
    """JSON text of ``obj``, refusing NaN and infinities (which are not JSON): a result that
    overflowed is an error naming the fields, never ``Infinity`` in a file.  An event's impulse
    between parts that the rows leave statically indeterminate (NaN) is written as null."""
    obj = _indeterminate_as_null(obj)
    bad = non_finite_fields(obj)
    if bad:
        shown = ", ".join(bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        raise SimulationError(f"{what}: not written: the run produced numbers that are not finite "
                              f"({shown}); the model or its values overflowed")
    return json.dumps(obj, indent=2, default=_json_default, allow_nan=False)
# ---- what the views need ---------------------------------------------------------------------
_JOINTS_PARSED: dict[str, dict[str, dict]] = {}  # {URDF text: its joints}: parsed once per process
_JOINTS_PARSED_MAX = 64


def urdf_joints(urdf_text: str) -> dict[str, dict]:
    """``{joint: {"type", "parent", "child"}}`` of a URDF's text (no validation: the scene did it).

    Every run records its scene's views, and parsing a URDF's XML (about 0.2 ms for Example 1's)
    was a tenth of Example 1's whole run: a text is parsed once per process, and each call
    returns a new copy of its joints (a run's views are its own to change)."""
    parsed = _JOINTS_PARSED.get(urdf_text)
    if parsed is None:
        parsed = {}
        for j in ET.fromstring(urdf_text).findall("joint"):
            parent, child = j.find("parent"), j.find("child")
            parsed[j.get("name")] = {"type": j.get("type"), "parent": parent.get("link") if parent is not None else None,
                                     "child": child.get("link") if child is not None else None}
        if len(_JOINTS_PARSED) >= _JOINTS_PARSED_MAX:
            _JOINTS_PARSED.pop(next(iter(_JOINTS_PARSED)))
        _JOINTS_PARSED[urdf_text] = parsed
    return {name: dict(joint) for name, joint in parsed.items()}


_URDF_TEXTS: dict[str, tuple[tuple[int, int], str]] = {}  # {path: ((mtime_ns, size), text)} read once while unchanged


def _view(urdf_path) -> dict:
    """A URDF file's view: its text as the file now has it (read again once its modification time
    or size changes; every run records its scene's views) and its joints."""
    path = os.fspath(urdf_path)
    st = os.stat(path)
    stamp = (st.st_mtime_ns, st.st_size)
    kept = _URDF_TEXTS.get(path)
    if kept is None or kept[0] != stamp:
        if len(_URDF_TEXTS) >= _JOINTS_PARSED_MAX:
            _URDF_TEXTS.pop(next(iter(_URDF_TEXTS)))
        kept = _URDF_TEXTS[path] = (stamp, Path(path).read_text(encoding="utf-8"))
    return {"urdf": kept[1], "joints": urdf_joints(kept[1])}


def _configuration_view(c) -> dict:
    """A configuration's view: its URDF text and joints, the cut joints that close its loops, and
    the joints a derived configuration locks (its recorded URDF is the root one, where they move)."""
    view = _view(c.urdf)
    view["cut_joints"] = [{"name": j.name, "type": j.type, "a": j.a, "point_a": list(j.point_a), "b": j.b,
                           "point_b": list(j.point_b), "axis": list(j.axis) if j.axis else None,
                           "anchor_at_entry": bool(getattr(j, "anchor_at_entry", False)),
                           "normal": list(j.normal) if getattr(j, "normal", None) is not None else None}
                          for j in getattr(c, "cut_joints", ())]
    derivation = getattr(c, "derivation", None)
    view["locked"] = list(derivation.lock) if derivation is not None else []
    return view


def guard_text(g) -> str:
    """A transition's guard as the graph writes it on its edge (``O3 ↑ 3.1416``)."""
    arrow = "↑" if g.direction > 0 else "↓"
    if g.type == "time":
        return f"t = {g.at:g} s" if g.at is not None else f"t = {g.start:g} + k·{g.every:g} s"
    if g.type == "reaction":
        return f"reaction of {g.of} {arrow} {g.value:g}"
    if g.type == "entry":
        return "on entry"
    what = {"joint": lambda n: n[0], "link": lambda n: f"θ({n[0]})",
            "between": lambda n: f"θ({n[1]}) − θ({n[0]})"}.get(g.measure.kind, lambda n: ",".join(n))(
                g.measure.names) if g.measure is not None else g.type
    return f"{what if g.type != 'gap' else 'gap'} {arrow} {g.value:.5g}"


def _transition_view(tr, unmerge_default: bool) -> dict:
    """A transition as the views draw it: the graph's edges and the sketch's stops."""
    c = tr.contact
    merge_to = getattr(tr, "merge_to", None)
    unmerge = getattr(tr, "unmerge", None)
    return {"name": tr.name, "type": tr.type, "from": tr.source, "to": getattr(tr, "target", None),
            "merge_to": merge_to, "unmerge": bool(unmerge_default if unmerge is None else unmerge) and merge_to is not None,
            "restitution": getattr(tr, "restitution", None), "cut": list(tr.cut), "guard": guard_text(tr.guard),
            "contact": None if c is None else {
                "a": c.a, "b": c.b, "point_a": list(c.point_a) if c.point_a else None,
                "point_b": list(c.point_b) if c.point_b else None, "normal": list(c.normal) if c.normal else None,
                "joint": c.joint, "stop_value": c.stop_value, "stop_sign": c.stop_sign}}


def record_views(scene) -> dict:
    """The views of a scene (its data model, duck-typed: ``configurations[name].urdf``,
    ``forces[i].name`` / ``.on.kind`` / ``.on.name``, ``transitions``), recorded when a run starts."""
    unmerge = bool(getattr(getattr(scene, "solver", None), "unmerge", True))
    return {"configurations": {name: _configuration_view(c) for name, c in scene.configurations.items()},
            "forces": {f.name: ({"on": {"kind": f.on.kind, "name": f.on.name}} if f.on is not None else
                                {"on": None, "points": [f.points.a, f.points.b]})
                       for f in scene.forces},
            "transitions": [_transition_view(tr, unmerge) for tr in getattr(scene, "transitions", ())]
            + [_lift_off_view(*x) for x in (scene.lift_offs() if hasattr(scene, "lift_offs") else ())]}


def _lift_off_view(source: str, cut_joint: str, target: str) -> dict:
    """A pinned point's lift-off that pcmm adds by itself (:meth:`pcmm.scene.spec.Scene.lift_offs`),
    drawn as the release it is (the event's name, ``lift-off <cut joint>``)."""
    return {"name": f"lift-off {cut_joint}", "type": "release", "from": source, "to": target, "merge_to": None,
            "unmerge": False, "restitution": None, "cut": [], "guard": f"normal force of {cut_joint} ↓ 0",
            "contact": None}


def legacy_views(scene_path: str) -> dict:
    """Views for a first-format file, read from the scene TOML it names while that exists
    (only ``[configurations.*].urdf`` and ``[[forces]]`` targets; nothing is validated or run)."""
    path = Path(scene_path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
        confs = {}
        for name, c in data.get("configurations", {}).items():
            with_path = (path.parent / c["urdf"])
            if with_path.is_file():
                confs[name] = {**_view(with_path), "locked": [],
                               "cut_joints": [{"name": j.get("name"), "type": j.get("type"), "a": j.get("a"),
                                               "point_a": list(j.get("point_a", ())), "b": j.get("b"),
                                               "point_b": list(j.get("point_b", ())), "axis": j.get("axis")}
                                              for j in c.get("cut_joints", [])]}
        forces = {}
        for f in data.get("forces", []):
            on = f.get("on", {})
            kind = next(iter(on), None)
            forces[f["name"]] = {"on": {"kind": kind, "name": on.get(kind)}}
        return {"configurations": confs, "forces": forces}
    except (OSError, ValueError, KeyError, TypeError, AttributeError, ET.ParseError):
        return {}


def _json_default(o):
    if isinstance(o, EventLog):
        return list(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    raise TypeError(f"not JSON serializable: {type(o)}")


def dumps_json(obj) -> str:
    return json.dumps(obj, indent=2, default=_json_default)
