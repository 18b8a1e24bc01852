"""The series derived from a recorded segment's states: coordinates and their rates, link angles and
positions, kinetic and potential energy, force elements and constraint forces.

Two routes give the same numbers:

* :func:`per_sample_series`, the reference and the fallback: one sample at a time, each through the
  configuration's own evaluations (``coords.unpack``, ``cfg.link_poses``, ``cfg.kinetic_energy``,
  ``cfg.potential_energy``, ``forces.element_values``, ``coords.accelerations``).  It serves every
  configuration: loops (whose Newton solves go sample after sample from the segment's start),
  planar joints, point springs, and every run with ``PCMM_COMPILED=0``.
* :func:`whole_segment_series`, where the segment's coordinates come out of its states without a
  solve (``coords.unpack_many``: a tree, or drives without a loop) and the configuration has
  neither a planar joint nor a point spring: the link positions, kinetic energy and gravity
  potential of every sample in one compiled pass (:func:`pcmm.model.compiled.series`, Pinocchio's
  forward kinematics, ``computeKineticEnergy`` and ``computePotentialEnergy``: what the reference's
  Python calls compute) and the rest as array expressions of the same formulas (the linear force
  elements' ``f = value - k (C q + d - rest) - c C q'``, their energy ``k x^2 / 2``, the angles
  ``A q + b``), and a drive's moments (rows that depend on time alone) in one compiled KKT solve
  (:func:`pcmm.model.compiled.multipliers`, checked against ``coords.accelerations``).

A stored run derives each chunk's series on its writer's thread while the run waits
(:mod:`pcmm.results.store`): there the per-sample route was 82 % of writing a chunk.
``tests/test_series.py`` holds the two routes equal (to 1e-12 relative) on every example and on
mechanisms of its own.
"""
from __future__ import annotations

import threading

import numpy as np

from ..model import compiled
from ..model.configuration import Configuration


def derived_series(cfg: Configuration, coords, t, y, offsets, forces) -> dict:
    """Coordinates, angles, positions, energies, force elements and constraint forces at the
    recorded states ``y`` (a column each) of one segment at times ``t``, read by ``coords`` (a reader
    of the segment: :meth:`Coordinates.restored`), with the segment's force elements ``forces`` (a
    value: the configuration's may have been compiled again since, at other angle offsets) and the
    run's angle offsets ``offsets`` {link: 2 pi k}: :func:`whole_segment_series` where it applies,
    else :func:`per_sample_series`."""
    whole = whole_segment_series(cfg, coords, t, y, offsets, forces)
    return whole if whole is not None else per_sample_series(cfg, coords, t, y, offsets, forces)


def per_sample_series(cfg: Configuration, coords, t, y, offsets, forces) -> dict:
    """:func:`derived_series` one sample at a time through the configuration's own evaluations: the
    reference, and the route of every configuration :func:`whole_segment_series` declines."""
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
    return _with_angles(cfg, offsets, dict(q=Q, v=V, xy=xy, kinetic=ke, potential=pe, forces=ff,
                                           constraint_forces=lam))


def whole_segment_series(cfg: Configuration, coords, t, y, offsets, forces) -> dict | None:
    """:func:`derived_series` over the whole segment at once, or None where it does not apply (a
    loop's coordinates need their Newton solves, a planar joint's rates are not its velocities, a
    point spring is not linear in ``q``, nothing moves, or there is no compiled tree:
    :func:`pcmm.model.compiled.why_not`)."""
    n = len(t)
    if n == 0 or cfg.nv == 0 or cfg.has_planar or forces.points is not None:
        return None
    many = getattr(coords, "unpack_many", None)
    if many is None:
        return None
    tree = _series_tree(cfg)
    if tree is None:
        return None
    states = many(np.asarray(t, float), y)
    if states is None:  # a loop: its coordinates are Newton solves
        return None
    Q, V = np.ascontiguousarray(states[0].T), np.ascontiguousarray(states[1].T)  # a sample a row
    xy, ke, gravity = compiled.series(tree, Q, V)
    x = Q @ forces.C.T + forces.d - forces.rest  # each linear element's measure from its rest value
    m = len(coords.labels)
    lam = _multipliers(coords, tree, t, Q, V, forces) if m else np.empty((n, 0))
    return _with_angles(cfg, offsets, dict(
        q=Q, v=V, xy=xy, kinetic=ke,
        # Configuration.potential_energy: gravity (with the bodies welded to the frame) plus the springs'
        potential=(gravity + cfg._welded_energy) + 0.5 * np.sum(forces.k * x * x, axis=1),
        forces=forces.f0 - forces.k * x - forces.c * (V @ forces.C.T),  # ForceField.element_values
        constraint_forces=lam))


def _multipliers(coords, tree, t, Q, V, forces) -> np.ndarray:
    """(n, m) constraint forces (a drive's moment) at the samples: ``M a + h = tau + J^T lam`` with
    rows ``J`` that depend on time alone (``coords.time_rows()``: drives without a loop, bias
    ``-f''(t)``), every sample in one compiled call (checked once per tree and rows against
    ``coords.accelerations``, the Python solve); a sample the compiled solve leaves (NaN), and
    every sample where there is none, by ``coords.accelerations`` itself."""
    n, m = len(t), len(coords.labels)
    lam = np.full((n, m), np.nan)
    rows = coords.time_rows()
    if rows is not None and len(rows[0]) == m and compiled.has_multipliers():
        J, bias_of = rows
        if _multipliers_agree(coords, tree, J, bias_of, forces):
            gamma = np.array([bias_of(ti) for ti in t], float).reshape(n, m)
            lam = compiled.multipliers(tree, Q, V, _generalized(forces, Q, V), J, gamma)
    for i in np.flatnonzero(~np.isfinite(lam).all(axis=1)):
        lam[i] = coords.accelerations(t[i], Q[i], V[i])[1]
    return lam


def _generalized(forces, Q, V) -> np.ndarray:
    """:meth:`ForceField.generalized` at every row of ``Q``, ``V`` (linear elements: no point spring)."""
    return forces.Q0 - Q @ forces.K.T - V @ forces.Dv.T


def _multipliers_agree(coords, tree, J, bias_of, forces) -> bool:
    """Whether the compiled multipliers on ``tree`` with the rows ``J`` equal ``coords.accelerations``
    at probe states and times (asked once per thread, tree and rows)."""
    key = (id(tree), J.tobytes())
    held = _HELD.multipliers.get(key)
    if held is not None and held[0] is tree:
        return held[1]
    nv = J.shape[1]

    def compiled_lam(t, q, v):
        Q, V = q[None, :], v[None, :]
        return compiled.multipliers(tree, Q, V, _generalized(forces, Q, V), J, np.reshape(bias_of(t), (1, -1)))[0]
    probes = [(0.37 * (k + 1), y[:nv], y[nv:2 * nv]) for k, y in enumerate(compiled.probe_states(nv))]
    ok = compiled.agrees(set(), compiled_lam, lambda t, q, v: coords.accelerations(t, q, v)[1], probes,
                         "constraint forces of rows that depend on time alone")
    _HELD.multipliers[key] = (tree, ok)
    return ok


def _with_angles(cfg: Configuration, offsets, series: dict) -> dict:
    """The series with the links' angles ``A q + b`` (plus the run's offsets) and their rates."""
    off = np.array([offsets.get(link, 0.0) for link in cfg.links])
    Q, V = series["q"], series["v"]
    return dict(q=Q, v=V, theta=Q @ cfg.A.T + cfg.b + off, omega=V @ cfg.A.T, xy=series["xy"],
                kinetic=series["kinetic"], potential=series["potential"], forces=series["forces"],
                constraint_forces=series["constraint_forces"])


class _Held(threading.local):
    """This thread's compiled series trees, {id(model): (model, gravity, tree)}: the tree of a
    model looked up once per thread, not at every segment (a bouncing run's chunk derives 2,000)."""

    def __init__(self):
        self.trees: dict = {}
        self.multipliers: dict = {}  # {(id(tree), rows' bytes): (tree, agreed)}


_HELD = _Held()


def _series_tree(cfg: Configuration):
    """The calling thread's compiled tree of ``cfg``'s model with its links' frames (checked against
    :func:`_python_series` once per tree: :func:`pcmm.model.compiled.series_tree`), or None."""
    if not compiled.enabled():
        return None
    model = cfg.model
    gravity = model.gravity.linear.tobytes()  # (a caller may set it: part of the compiled tree's key)
    held = _HELD.trees.get(id(model))
    if held is not None and held[0] is model and held[1] == gravity:
        return held[2]
    frames = [cfg.link_frame[link] for link in cfg.links]
    tree = compiled.series_tree(model, frames, lambda Q, V: _python_series(cfg, Q, V))
    if len(_HELD.trees) >= 32:
        _HELD.trees.pop(next(iter(_HELD.trees)))
    _HELD.trees[id(model)] = (model, gravity, tree)
    return tree


def _python_series(cfg: Configuration, Q, V):
    """(xy, kinetic energy, gravity potential without the welded bodies) sample by sample through the
    configuration's Python evaluations: what the compiled pass must equal."""
    xy = np.array([cfg.link_poses(q)[:, :2] for q in Q]).reshape(len(Q), len(cfg.links), 2)
    ke = np.array([cfg.kinetic_energy(q, v) for q, v in zip(Q, V)])
    gravity = np.array([cfg.gravity_energy(q) - cfg._welded_energy for q in Q])
    return xy, ke, gravity
