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
    cache[joints] = (new, new.createData(), jmap, copies, cut_ids, {})  # {}: the cut joints' complements
    return cache[joints]


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


def cut(cfg: Configuration, q: np.ndarray, joints: tuple[str, ...]) -> CutSystem:
    """The cut system of ``cfg`` at pose ``q`` with ``joints`` released."""
    model, data = cfg.model, cfg.data
    joints = tuple(joints)
    qp = cfg.to_pin(q)
    pin.computeJointJacobians(model, data, qp)  # placements (oMi, liMi) and the tree's Jacobians in one pass
    new, new_data, jmap, copies, cut_ids, known = _structure(cfg, joints)
    q_parts = []
    for jid in range(1, model.njoints):
        if jid in cut_ids:
            new.jointPlacements[jmap[jid]] = data.oMi[jid]  # the planar joint starts at the child's pose
            q_parts.append(np.array([0.0, 0.0, 1.0, 0.0]))
        else:
            j = model.joints[jid]
            q_parts.append(qp[j.idx_q:j.idx_q + j.nq])
    for name in joints:
        fr = new.frames[copies[name]]
        fr.placement = data.liMi[cfg.joint_id[name]]
        new.frames[copies[name]] = fr
    q_f = np.concatenate(q_parts) if q_parts else np.zeros(0)
    pin.computeJointJacobians(new, new_data, q_f)
    pin.updateFramePlacements(new, new_data)
    # T: tree velocity -> cut-system velocity
    T = np.zeros((new.nv, model.nv))
    for jid in range(1, model.njoints):
        nj = new.joints[jmap[jid]]
        if jid in cut_ids:
            Jl = joint_jacobian(model, data, jid, LOCAL)
            T[nj.idx_v:nj.idx_v + 3] = Jl[_PLANAR_ROWS]
        else:
            j = model.joints[jid]
            T[nj.idx_v:nj.idx_v + nj.nv, j.idx_v:j.idx_v + j.nv] = np.eye(j.nv)
    rows, owner, dirs, rots = [], [], [], {}
    for name in joints:
        jid = cfg.joint_id[name]
        child = joint_jacobian(new, new_data, jmap[jid], LOCAL)[_PLANAR_ROWS]
        parent = frame_jacobian(new, new_data, copies[name], LOCAL)[_PLANAR_ROWS]
        jm = model.joints[jid]
        N = _forbidden(model, jid, qp[jm.idx_q:jm.idx_q + jm.nq], known)
        for k in range(N.shape[1]):
            rows.append(N[:, k] @ (child - parent))
            owner.append(name)
            dirs.append(N[:, k])
        rots[name] = data.oMi[jid].rotation[:2, :2].copy()
    J_cut = np.array(rows).reshape(len(rows), new.nv)
    return CutSystem(new, new_data, q_f, T, J_cut, owner, dirs, rots)
