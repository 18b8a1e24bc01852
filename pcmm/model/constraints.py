"""Closed loops and driven coordinates: which coordinates a configuration integrates in.

A tree without loops or drives integrates ``y = [q, v]`` (:mod:`pcmm.model.tree`); loops (cut
joints) and drives integrate the independent coordinates by generalized coordinate partitioning
(:mod:`pcmm.model.partitioned`) on the constraint rows of :mod:`pcmm.model.rows`.  This module is
their one door: :func:`coordinates_for` picks the strategy; outside ``model/`` both are seen only
through the :class:`~pcmm.model.coordinates.Coordinates` protocol.
"""
from __future__ import annotations

import numpy as np

from .configuration import Configuration
from .coordinates import Coordinates
from .partitioned import NEWTON_TOL, SINGULAR_COND, PartitionedCoordinates
from .rows import ClosureRows, Drives, constrained_accelerations, determinate, indeterminate, left_null, solve
from .tree import TreeCoordinates

__all__ = ["coordinates_for", "constrained_accelerations", "determinate", "indeterminate", "left_null", "solve", "NEWTON_TOL", "SINGULAR_COND"]


def coordinates_for(cfg: Configuration) -> Coordinates:
    """The coordinate strategy a configuration needs: plain tree, or partitioned."""
    scene = cfg.scene
    specs = cfg.spec.cut_joints
    drives = scene.drives_in(cfg.name)
    if not specs and not drives:
        return TreeCoordinates(cfg)
    closure = ClosureRows(
        specs=specs,
        frames_a=tuple(cfg.point(s.a, s.point_a).frame_id for s in specs),
        frames_b=tuple(cfg.point(s.b, s.point_b).frame_id for s in specs),
        links_a=tuple(cfg.link_frame[s.a] for s in specs),
        links_b=tuple(cfg.link_frame[s.b] for s in specs))
    dr = Drives(joints=tuple(d.joint for d in drives),
                index=tuple(cfg.joint_slice[d.joint].start for d in drives),
                coefficients=tuple(np.array(d.coefficients) for d in drives))
    return PartitionedCoordinates(cfg, closure, dr)
