"""Recording a run: each accepted segment's times and integrator states, and everything derived
from them (coordinates, angles, link positions, energies, force elements, constraint and holding
forces), computed when first read.

The series of a segment are computed from that segment alone: in the partition it was integrated
in, from its own start (a loop's Newton solves warm-started there), with the force elements and
the locks (holds) it had.  What the run does afterwards never changes them (issue 22: the holding
moment of a locked stretch depended on how far the run went on).
"""
from __future__ import annotations

import dataclasses
import functools
import time
import weakref

import numpy as np

from ..events.holding import Holds
from ..model.configuration import Configuration
from ..results.segment_log import SegmentLog
from ..results.trajectory import SegmentRecord, Trajectory
from ..signals import deferred
from . import series as segment_series
from .dense import dense_states


def record(traj: Trajectory, cfg: Configuration, seg, offsets, q_start, holds: Holds, stepping) -> None:
    """Record an accepted segment (:func:`record_samples`); a Ctrl-C or SIGTERM meanwhile waits
    until it is kept, so an interrupted run never loses the segment it was recording."""
    with deferred() as held:
        record_samples(traj, cfg, seg, offsets, q_start, holds, stepping)
    held.reraise()


def record_samples(traj: Trajectory, cfg: Configuration, seg, offsets, q_start, holds: Holds, stepping) -> None:
    """Keep the segment's times and the integrator's states; everything derived from them is
    computed when first asked for (:class:`SegmentContext`), in the partition and from the warm
    start the segment was integrated with.  ``stepping = (fun, method, opts)`` lets the segment
    be resampled at other times on the dense output of its steps.  The holding forces of the
    locks in force at the time are among the constraint forces (labels ``<lock>.hold``); their
    extremes are ``stats["holding"]``.

    A run's :class:`~pcmm.results.segment_log.SegmentLog` keeps the numbers in shared blocks and
    the context once for every segment it is the same for (a bouncing run: one context, a
    segment per impact); a trajectory whose segments are a plain list gets a record."""
    t0 = time.perf_counter()
    coords = cfg.coords
    t, y_full = np.asarray(seg.t, float), np.asarray(seg.y, float)
    held = holds.labels()
    # the run's own offsets and locks, compared as they are now; a context the log keeps gets copies
    context = SegmentContext(cfg, coords.frozen_state(), offsets, holds,
                             holds.applied(cfg) if held else None, cfg.forces, stepping,
                             own_rhs=stepping[0] is coords.rhs,  # a tree's rhs: a closure over these forces
                             n_state=coords.ny)  # the partition's state size (a flight's y has one more row)
    log = filling(traj)
    names = _names(log, cfg, coords, held)
    q_start = np.array(q_start, float)
    if isinstance(log, SegmentLog):
        log.add(log.context_id(cfg.name, names, context, SegmentContext.kept), t, y_full, q_start)
    else:  # one copy of the name lists per configuration, as the log keeps them
        context = context.kept()
        names = traj.shared_names.setdefault((cfg.name, *(tuple(v) for v in names.values())), names)
        t, y_full = t.copy(), y_full.copy()
        traj.segments.append(SegmentRecord.deferred(
            lambda: context.derive(t, y_full, q_start), t,
            resample=lambda times: context.resample(t, y_full, q_start, times), configuration=cfg.name, **names))
    traj.stats["constraint_drift_max"] = max(traj.stats["constraint_drift_max"], getattr(coords, "max_residual", 0.0))
    traj.stats["record_s"] += time.perf_counter() - t0


#: {a run's SegmentLog: {configuration: (force names, constraint labels, holds' labels, the name lists)}}:
#: the name lists handed to the log last, per configuration (the log keeps one copy of equal ones)
_NAMES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _names(log, cfg: Configuration, coords, held: list) -> dict:
    """The name lists of a segment of ``cfg`` (its coordinates, links, force elements and constraint
    labels with the holds' ``held``): those made for ``log``'s last segment of ``cfg`` where the values
    they are made from are equal (made again at every segment, they were equal lists; the log keeps the
    first of equal ones), else new ones."""
    forces, labels = cfg.forces.names, coords.labels
    kept = _NAMES.get(log) if isinstance(log, SegmentLog) else None
    last = None if kept is None else kept.get(cfg)
    if last is not None and last[0] == tuple(forces) and last[1] == tuple(labels) and last[2] == held:
        return last[3]
    coord_names = []
    for name in cfg.joint_names:
        sl = cfg.joint_slice[name]
        coord_names += [name] if sl.stop - sl.start == 1 else [f"{name}.x", f"{name}.y", f"{name}.theta"]
    names = dict(coordinates=coord_names, links=list(cfg.links), force_names=list(forces),
                 constraint_labels=list(labels) + held)
    if isinstance(log, SegmentLog):
        if kept is None:
            kept = _NAMES[log] = weakref.WeakKeyDictionary()
        kept[cfg] = (tuple(forces), tuple(labels), list(held), names)
    return names


def filling(traj: Trajectory):
    """The segments the run is filling: the trajectory's, or those of the chunk not yet written
    when the run streams to a store (:mod:`pcmm.results.store`)."""
    return getattr(traj.segments, "tail", traj.segments)


def recorded_steps(traj: Trajectory, seg, q_start):
    """``() -> (t, y, q_start)`` of the segment just recorded (``seg``, started from ``q_start``),
    to be read before the run goes on (the flight audit, at once): where the run's
    :class:`SegmentLog` keeps it, the very arrays it copied into its blocks (no copy; the same
    values as :meth:`SegmentLog.arrays` reads back, without forming its read-only views at every
    flight), else copies of them."""
    log = filling(traj)
    if isinstance(log, SegmentLog):
        steps = (np.ascontiguousarray(seg.t, float), np.ascontiguousarray(seg.y, float),
                 np.ascontiguousarray(q_start, float))
        return lambda: steps
    kept = (np.array(seg.t, float), np.array(seg.y, float), np.array(q_start, float))
    return lambda: kept


class SegmentContext:
    """What the series of a segment are derived with, as values kept when it was recorded: the
    configuration, its coordinates' partition and anchors (``frozen``, :meth:`Coordinates.restored`;
    a later entry may hold them elsewhere), the angle offsets, the locks in force and the force
    elements they hold with (``applied``, :meth:`Holds.applied`), the force elements (a later entry
    may compile them at other angle offsets) and the stepping ``(fun, method, opts)`` of its dense
    output.  The segments of one stay share it (``==``: the same values)."""

    __slots__ = ("cfg", "frozen", "offsets", "holds", "applied", "forces", "stepping", "own_rhs", "n_state")

    def __init__(self, cfg, frozen, offsets, holds, applied, forces, stepping, own_rhs=False, n_state=None):
        self.cfg, self.frozen, self.offsets, self.holds = cfg, frozen, offsets, holds
        self.applied, self.forces, self.stepping, self.own_rhs = applied, forces, stepping, own_rhs
        self.n_state = cfg.coords.ny if n_state is None else n_state

    def __eq__(self, other) -> bool:
        if not isinstance(other, SegmentContext):
            return NotImplemented
        return (self.cfg is other.cfg and self.own_rhs == other.own_rhs and self.n_state == other.n_state
                and self.forces is other.forces and _same(self.frozen, other.frozen)
                and self.offsets == other.offsets and _same_holds(self.holds, other.holds)
                and _same(self.applied, other.applied)
                and _same_stepping(self.stepping, other.stepping))

    __hash__ = None

    def kept(self) -> "SegmentContext":
        """This context with copies of what the run changes later (its angle offsets, its locks:
        :meth:`Holds.snapshot`), as a recorded segment keeps it; made only where the log keeps a new
        context, which the run's own offsets and locks are compared as they are (``==``)."""
        self.offsets, self.holds = dict(self.offsets), self.holds.snapshot()
        return self

    def _reading(self, t, y, q_start, work):
        """Run ``work(reader)`` on a reader of the segment's coordinates (its partition, anchors,
        steps and force elements, as values: :meth:`Coordinates.restored`); every evaluation reads
        the calling thread's Pinocchio data (:meth:`Configuration.workspace`), so the series may be
        read from another thread while the run goes on."""
        n_state = self.n_state  # a contact phase or a flight integrates one more component
        with self.cfg.coords.restored(self.frozen, q_start, (t, y[:n_state]), self.forces) as reader:
            return work(reader)

    def derive(self, t, y, q_start) -> dict:
        """The series of the segment at its own steps ``t`` (states ``y``, started from ``q_start``)."""
        cfg, n_state = self.cfg, self.n_state
        return self._reading(t, y, q_start, lambda reader: with_holds(
            cfg, self.holds, t, derived_series(cfg, reader, t, y[:n_state], self.offsets, self.forces), self.applied))

    def resample(self, t, y, q_start, times) -> dict:
        """The series of the segment at ``times``, on the dense output of its steps."""
        cfg, coords, n_state = self.cfg, self.cfg.coords, self.n_state

        def work(reader):
            fun, method, opts = self.stepping
            if getattr(fun, "__self__", None) is coords:  # rhs or rhs_with_power: the reader's own
                fun = getattr(reader, fun.__name__)
            elif not coords.constrained and self.own_rhs:
                fun = reader.fresh_rhs()
            states = dense_states(t, y, times, (fun, method, opts))[:n_state]
            # the dense steps left the loop's warm starts at the segment's end: the series are
            # solved from its start onwards, as the recorded ones are (from the end, a loop's
            # Newton solve at the start could land on another assembly)
            reader.seed(q_start)
            return with_holds(cfg, self.holds, times, derived_series(cfg, reader, times, states, self.offsets,
                                                                     self.forces), self.applied)
        return self._reading(t, y, q_start, work)


def _same(a, b) -> bool:
    """Values equal, arrays element by element (a frozen partition, the holds' force elements).
    (Asked at every segment, for the context it may share with the one before: loops, not
    generators, and the array's own reduction, not numpy's wrappers.)"""
    if a is b:
        return True
    if isinstance(a, dict) and isinstance(b, dict):  # (the frozen partitions: first)
        if a.keys() != b.keys():
            return False
        for k in a:
            if not _same(a[k], b[k]):
                return False
        return True
    if isinstance(a, (int, float, str)) and isinstance(b, (int, float, str)):
        return a == b
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape):
            return False
        if a.dtype == b.dtype and a.dtype.kind in "biu":  # integers (a partition's indices): equal values, equal bytes
            return a.tobytes() == b.tobytes()
        return bool((a == b).all())
    if isinstance(a, (tuple, list)) and isinstance(b, (tuple, list)):
        if type(a) is not type(b) or len(a) != len(b):
            return False
        for x, y in zip(a, b):
            if not _same(x, y):
                return False
        return True
    if type(a) is type(b) and dataclasses.is_dataclass(a) and not isinstance(a, type):
        # (the holds' Applied: a record of values, its reference configuration compared as the same object)
        for name in _field_names(type(a)):
            if not _same(getattr(a, name), getattr(b, name)):
                return False
        return True
    return False  # anything else: the same object only


@functools.lru_cache(maxsize=None)
def _field_names(cls) -> tuple:
    return tuple(f.name for f in dataclasses.fields(cls))


def _same_stepping(a: tuple, b: tuple) -> bool:
    """The same ``(fun, method, opts)``: each the same object, or an equal callable (a bound method)."""
    if len(a) != len(b):
        return False
    for x, y in zip(a, b):
        if x is not y and not (callable(x) and x == y):
            return False
    return True


def _same_holds(a: Holds, b: Holds) -> bool:
    """The same locks in force (the snapshots share everything else with the run's Holds)."""
    if len(a.items) != len(b.items):
        return False
    for x, y in zip(a.items, b.items):
        if x is not y:
            return False
    return True


def with_holds(cfg: Configuration, holds: Holds, t, series: dict, applied=None) -> dict:
    """The series of a segment with locks in force: their holding forces appended to the
    constraint forces, and the energy of the held joints' springs (constant while they are
    held, :meth:`Holds.held_energy`) added to the potential energy.  ``applied`` are the force
    elements the segment held with (:meth:`Holds.applied`)."""
    if holds.items:
        series["constraint_forces"] = np.hstack((series["constraint_forces"], holding_forces(cfg, holds, t, series, applied)))
        series["potential"] = series["potential"] + np.array([holds.held_energy(cfg, q, applied) for q in series["q"]])
    return series


def holding_forces(cfg: Configuration, holds: Holds, t, series: dict, applied=None) -> np.ndarray:
    """(n, holds) holding force or moment of every lock in force, at the segment's own solved
    coordinates ``series["q"], series["v"]`` (those every other series was derived from).  Never
    solved again from the integrator's state: a loop's Newton solve warm-started from wherever
    the coordinates were left (the segment's end, or a later segment's) can land on the other
    assembly, and the series would then depend on what the run did after the segment.
    ``applied`` are the force elements the segment held with (:meth:`Holds.applied`)."""
    out = np.empty((len(t), len(holds.items)))
    if (applied is None or applied.reference is None) and holds.items and holds.reference(cfg) is None:
        out[:] = np.nan  # no configuration to solve them in (the run's warnings say so: Holds.indeterminate_notes)
        return out
    for i in range(len(t)):
        q = series["q"][i]  # the series' rates are world-axes for a planar joint: back to Pinocchio's v
        out[i] = list(holds.forces(cfg, t[i], q, cfg.velocity(q, series["v"][i]), applied).values())
    return out


def derived_series(cfg: Configuration, coords, t, y, offsets, forces) -> dict:
    """The series of one segment at its recorded states (:func:`pcmm.run.series.derived_series`)."""
    return segment_series.derived_series(cfg, coords, t, y, offsets, forces)
