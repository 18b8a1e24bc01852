"""Recording a run: each accepted segment's times and integrator states, and everything derived
from them (coordinates, angles, link positions, energies, force elements, constraint and holding
forces), computed when first read.

The series of a segment are computed from that segment alone: in the partition it was integrated
in, from its own start (a loop's Newton solves warm-started there), with the force elements and
the locks (holds) it had.  What the run does afterwards never changes them (issue 22: the holding
moment of a locked stretch depended on how far the run went on).
"""
from __future__ import annotations

import time

import numpy as np

from ..events.holding import Holds
from ..model.configuration import Configuration
from ..results.trajectory import SegmentRecord, Trajectory
from ..signals import deferred
from .dense import dense_states


def record(traj: Trajectory, cfg: Configuration, seg, offsets, q_start, holds: Holds, stepping) -> None:
    """Record an accepted segment (:func:`record_samples`); a Ctrl-C or SIGTERM meanwhile waits
    until it is kept, so an interrupted run never loses the segment it was recording."""
    with deferred() as held:
        record_samples(traj, cfg, seg, offsets, q_start, holds, stepping)
    held.reraise()


def record_samples(traj: Trajectory, cfg: Configuration, seg, offsets, q_start, holds: Holds, stepping) -> None:
    """Keep the segment's times and the integrator's states; everything derived from them is
    computed when first asked for (:meth:`SegmentRecord.deferred`), in the partition and from
    the warm start the segment was integrated with.  ``stepping = (fun, method, opts)`` lets
    the segment be resampled at other times on the dense output of its steps.  The holding
    forces of the locks in force at the time are among the constraint forces (labels
    ``<lock>.hold``); their extremes are ``stats["holding"]``."""
    t0 = time.perf_counter()
    coords, forces = cfg.coords, cfg.forces
    frozen = coords.frozen_state()
    y_full, offsets, q_start = np.array(seg.y, float), dict(offsets), np.array(q_start, float)
    t = np.asarray(seg.t, float).copy()
    n_state = coords.ny  # the partition's state size (the tree's: 2 nv)
    y = y_full[:n_state]  # a contact phase or a flight integrates one more component (its impulse, its work)
    held, holds = holds.labels(), holds.snapshot()
    applied = holds.applied(cfg) if held else None  # the holding forces' elements, as values too
    own_rhs = stepping[0] is coords.rhs  # a tree's right-hand side (a closure over this segment's forces)

    def in_segment_state(work):
        """Run ``work(reader)`` on a reader of this segment's coordinates (its partition, anchors,
        steps and force elements, as values: :meth:`Coordinates.restored`; a later entry may have
        compiled the configuration's forces at other angle offsets); every evaluation reads the
        calling thread's Pinocchio data (:meth:`Configuration.workspace`), so the series may be
        read from another thread while the run goes on."""
        with coords.restored(frozen, q_start, (t, y), forces) as reader:  # accepted: nothing here stops anything
            return work(reader)

    def derive():
        def work(reader):
            return with_holds(cfg, holds, t, derived_series(cfg, reader, t, y, offsets, forces), applied)
        return in_segment_state(work)

    def resample(times):
        def work(reader):
            fun, method, opts = stepping
            if getattr(fun, "__self__", None) is coords:  # rhs or rhs_with_power: the reader's own
                fun = getattr(reader, fun.__name__)
            elif not coords.constrained and own_rhs:
                fun = reader.fresh_rhs()
            states = dense_states(t, y_full, times, (fun, method, opts))[:n_state]
            # the dense steps left the loop's warm starts at the segment's end: the series are
            # solved from its start onwards, as the recorded ones are (from the end, a loop's
            # Newton solve at the start could land on another assembly)
            reader.seed(q_start)
            return with_holds(cfg, holds, times, derived_series(cfg, reader, times, states, offsets, forces), applied)
        return in_segment_state(work)
    coord_names = []
    for name in cfg.joint_names:
        sl = cfg.joint_slice[name]
        coord_names += [name] if sl.stop - sl.start == 1 else [f"{name}.x", f"{name}.y", f"{name}.theta"]
    names = dict(coordinates=coord_names, links=list(cfg.links), force_names=list(forces.names),
                 constraint_labels=list(coords.labels) + held)
    # the name lists are the same for every segment of a configuration (and its locks): one copy
    # per run, not one per segment (a bouncing run has one segment per impact)
    names = traj.shared_names.setdefault((cfg.name, *(tuple(v) for v in names.values())), names)
    traj.segments.append(SegmentRecord.deferred(derive, t, resample=resample, configuration=cfg.name, **names))
    traj.stats["constraint_drift_max"] = max(traj.stats["constraint_drift_max"], getattr(coords, "max_residual", 0.0))
    traj.stats["record_s"] += time.perf_counter() - t0


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
    for i in range(len(t)):
        q = series["q"][i]  # the series' rates are world-axes for a planar joint: back to Pinocchio's v
        out[i] = list(holds.forces(cfg, t[i], q, cfg.velocity(q, series["v"][i]), applied).values())
    return out


def derived_series(cfg: Configuration, coords, t, y, offsets, forces) -> dict:
    """Coordinates, angles, positions, energies, force elements and constraint forces at the
    recorded states of one segment, read by ``coords`` (a reader of the segment: :meth:`Coordinates.restored`),
    with the segment's force elements ``forces`` (a value: the configuration's may have been
    compiled again since, at other angle offsets)."""
    n = len(t)
    nv, nl = cfg.nv, len(cfg.links)
    Q, V = np.empty((n, nv)), np.empty((n, nv))
    xy = np.empty((n, nl, 2))
    ke, pe = np.empty(n), np.empty(n)
    ff = np.empty((n, len(forces.names)))
    m = len(coords.labels)
    lam = np.empty((n, m))
    for i in range(n):
        q, v = coords.unpack(t[i], y[:, i])
        Q[i], V[i] = q, cfg.qdot(q, v)  # the coordinates' rates: a planar joint's x', y' in world axes
        xy[i] = cfg.link_poses(q)[:, :2]
        ke[i] = cfg.kinetic_energy(q, v)
        pe[i] = cfg.potential_energy(q, forces)
        ff[i] = forces.element_values(q, v)
        if m:
            lam[i] = coords.accelerations(t[i], q, v)[1]
    off = np.array([offsets.get(link, 0.0) for link in cfg.links])
    return dict(q=Q, v=V, theta=Q @ cfg.A.T + cfg.b + off, omega=V @ cfg.A.T, xy=xy, kinetic=ke, potential=pe,
                forces=ff, constraint_forces=lam)
