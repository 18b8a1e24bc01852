"""Joint cutting: the multibody system f of paper section 2.2.

Cutting a joint releases the subtree it carries: the cut joint is replaced by a
free planar joint rooted at the frame (3 DOF), so the subtree becomes a
separate tree (the paper's f1 / f2), and the released constraint comes back
as rows ``J_cut v_f = 0`` whose multipliers are the cut joint's constraint
force (paper Eqs. 6, 15).  At the impact pose every joint frame of the cut
model coincides with the tree's, so each link, contact point and cut-joint
point keeps its frame index and local placement.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..model.configuration import Configuration
from ..model.pinocchio_helpers import LOCAL, frame_jacobian, joint_jacobian

_PLANAR_ROWS = [0, 1, 5]  # vx, vy, wz of a spatial velocity
_PLANAR_INDEX = np.array(_PLANAR_ROWS)  # the same rows as an index array (cheaper to apply)


@dataclass
class CutSystem:
    """The cut system f at one pose.

    ``T`` maps the tree's velocity to f's (``v_f = T v``); ``J_cut`` (rows)
    and ``N`` (one block per cut joint) give the cut-joint constraint in each
    child's frame; ``row_owner[k]`` names the cut joint of row ``k``.
    """

    model: pin.Model
    data: pin.Data
    q: np.ndarray
    T: np.ndarray
    J_cut: np.ndarray
    row_owner: list[str]
    row_dirs: list[np.ndarray]  # per row: (fx, fy, mz) direction in the child's frame
    child_rotation: dict[str, np.ndarray]


def _complement(S_planar: np.ndarray) -> np.ndarray:
    """Orthonormal basis (3 x k) of the planar motions a joint forbids."""
    if S_planar.size == 0:
        return np.eye(3)
    u, s, _ = np.linalg.svd(S_planar.reshape(3, -1), full_matrices=True)
    rank = int(np.sum(s > 1e-12))
    return u[:, rank:]


def _structure(cfg: Configuration, joints: tuple[str, ...]):
    """The cut model's topology, built once per configuration and cut set; the pose-dependent
    placements (the planar joints' and the parent-side copies') are set at each impact."""
    cache = cfg.cut_models
    if joints in cache:
        return cache[joints]
    model = cfg.model
    cut_ids = {cfg.joint_id[n] for n in joints}
    new = pin.Model()
    new.name = model.name + "_cut"
    new.gravity = model.gravity
    jmap = {0: 0}
    for jid in range(1, model.njoints):
        if jid in cut_ids:
            jm, parent, placement = pin.JointModelPlanar(), 0, pin.SE3.Identity()
        else:
            jm, parent, placement = model.joints[jid], jmap[model.parents[jid]], model.jointPlacements[jid]
        jmap[jid] = new.addJoint(parent, jm, placement, model.names[jid])
        new.appendBodyToJoint(jmap[jid], model.inertias[jid], pin.SE3.Identity())
    for fr in list(model.frames)[1:]:
        new.addFrame(pin.Frame(fr.name, jmap[fr.parentJoint], fr.parentFrame, fr.placement, fr.type), False)
    # parent-side copies of each cut child frame, to express the relative velocity
    copies = {name: new.addFrame(pin.Frame(f"pcmm:cut:{name}:parent", jmap[model.parents[cfg.joint_id[name]]], 0,
                                           pin.SE3.Identity(), pin.FrameType.OP_FRAME), False)
              for name in joints}
    cache[joints] = (new, new.createData(), jmap, copies, cut_ids, {},  # {}: the cut joints' complements
                     _layout(model, new, jmap, cut_ids))
    return cache[joints]


@dataclass(frozen=True)
class _Layout:
    """Where each joint of the tree sits in the cut model, fixed by the topology: the cut
    model's q with the planar joints at their origin and the kept joints' entries to copy,
    and T (tree velocity -> cut-system velocity) with the kept joints' identity blocks, the
    cut joints' three rows left to fill at each pose."""

    q0: np.ndarray
    q_from: np.ndarray  # entries of the tree's (Pinocchio) q copied into the cut model's q ...
    q_to: np.ndarray  # ... at these entries
    T0: np.ndarray
    planar_rows: tuple  # (tree joint id, first row of its planar joint in T)


def _layout(model, new, jmap, cut_ids) -> _Layout:
    q0 = np.zeros(new.nq)
    T0 = np.zeros((new.nv, model.nv))
    q_from, q_to, planar = [], [], []
    for jid in range(1, model.njoints):
        nj = new.joints[jmap[jid]]
        if jid in cut_ids:
            q0[nj.idx_q:nj.idx_q + 4] = (0.0, 0.0, 1.0, 0.0)  # x, y, cos, sin: at the child's pose
            planar.append((jid, nj.idx_v))
        else:
            j = model.joints[jid]
            q_from += range(j.idx_q, j.idx_q + j.nq)
            q_to += range(nj.idx_q, nj.idx_q + nj.nq)
            T0[nj.idx_v:nj.idx_v + nj.nv, j.idx_v:j.idx_v + j.nv] = np.eye(j.nv)
    return _Layout(q0, np.array(q_from, dtype=int), np.array(q_to, dtype=int), T0, tuple(planar))


#: joints whose motion subspace S (in the joint's frame) does not depend on q: revolute (RX, RY,
#: RZ, unaligned, unbounded), prismatic (PX, ..., unaligned) and planar
_CONSTANT_S = ("JointModelR", "JointModelP")


def _forbidden(model, jid: int, q_joint: np.ndarray, known: dict) -> np.ndarray:
    """The planar motions joint ``jid`` forbids (:func:`_complement` of its S), computed once per
    configuration and cut set when S does not depend on the pose (``known`` keeps it)."""
    if jid in known:
        return known[jid]
    jm = model.joints[jid]
    jd = jm.createData()
    jm.calc(jd, q_joint)
    N = _complement(np.asarray(jd.S)[_PLANAR_ROWS])
    if jm.shortname().startswith(_CONSTANT_S):
        known[jid] = N
    return N


def forbidden_motions(model, jid: int) -> np.ndarray | None:
    """The planar motions joint ``jid`` forbids (3 x k, the basis :func:`cut` gives its rows) where
    they do not depend on the pose (revolute and prismatic joints), else None."""
    jm = model.joints[jid]
    if not jm.shortname().startswith(_CONSTANT_S):
        return None
    return _forbidden(model, jid, np.zeros(jm.nq), {})


def cut(cfg: Configuration, q: np.ndarray, joints: tuple[str, ...], kinematics: bool = True) -> CutSystem:
    """The cut system of ``cfg`` at pose ``q`` with ``joints`` released.  ``kinematics=False``: the
    tree's placements and joint Jacobians at ``q`` are already on ``cfg.data``
    (:meth:`Configuration.kinematics`), and are not computed again."""
    model, data = cfg.model, cfg.data
    joints = tuple(joints)
    qp = cfg.to_pin(q)
    if kinematics:
        pin.computeJointJacobians(model, data, qp)  # placements (oMi, liMi) and the tree's Jacobians in one pass
    new, new_data, jmap, copies, cut_ids, known, layout = _structure(cfg, joints)
    for jid, _ in layout.planar_rows:
        new.jointPlacements[jmap[jid]] = data.oMi[jid]  # the planar joint starts at the child's pose
    for name in joints:
        fr = new.frames[copies[name]]
        fr.placement = data.liMi[cfg.joint_id[name]]
        new.frames[copies[name]] = fr
    q_f = layout.q0.copy()
    q_f[layout.q_to] = qp[layout.q_from]
    pin.computeJointJacobians(new, new_data, q_f)
    pin.updateFramePlacements(new, new_data)
    # T: tree velocity -> cut-system velocity
    T = layout.T0.copy()
    for jid, row in layout.planar_rows:
        T[row:row + 3] = joint_jacobian(model, data, jid, LOCAL)[_PLANAR_INDEX]
    rows, owner, dirs, rots = [], [], [], {}
    for name in joints:
        jid = cfg.joint_id[name]
        child = joint_jacobian(new, new_data, jmap[jid], LOCAL)[_PLANAR_INDEX]
        parent = frame_jacobian(new, new_data, copies[name], LOCAL)[_PLANAR_INDEX]
        relative = child - parent  # the child's velocity relative to the parent's copy of its frame
        jm = model.joints[jid]
        N = _forbidden(model, jid, qp[jm.idx_q:jm.idx_q + jm.nq], known)
        for k in range(N.shape[1]):
            rows.append(N[:, k] @ relative)
            owner.append(name)
            dirs.append(N[:, k])
        rots[name] = data.oMi[jid].rotation[:2, :2].copy()
    J_cut = np.array(rows).reshape(len(rows), new.nv)
    return CutSystem(new, new_data, q_f, T, J_cut, owner, dirs, rots)
