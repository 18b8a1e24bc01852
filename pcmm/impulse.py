"""Impulse solving by joint cutting (paper section 3, Eqs. 21-43).

At a configuration transformation the metamorphic joint(s) are cut (module
:mod:`pcmm.cutting`), giving the system f with inertia ``M_f`` and the cut
joints' constraint rows ``J_cut``; loops and drives of the configuration add
their own ideal-constraint rows.  With ``G`` all those rows and
``W = M_f^-1``, eliminating the constraint impulses gives the effective
inverse inertia of the cut system (the inverse of the paper's ``M_f``, Eq. 25;
for a mobile impact the sum over f1 and f2, Eqs. 39 and 42):

    W_eff = W - W G^T (G W G^T)^-1 G W

Newton's restitution law on the contact normal (Eq. 21) then gives the
impulse ``P = -(1 + e) (J_n W_eff J_n^T)^-1 J_n v_f^-`` (Eqs. 29, 42), the
velocity jump ``dv_f = W_eff J_n^T P`` (Eqs. 24, 30, 35, 38, 43) and the
cut joints' impulsive reactions ``-(G W G^T)^-1 G W J_n^T P``.

The impulse carried by every joint of the tree comes from a second route:
RNEA on a gravity-free copy of the tree with zero velocity, the velocity jump
as acceleration and the contact impulse as an external force.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin
import scipy.linalg as sla

from .configuration import LWA, Configuration, cholesky, frame_jacobian, mass_matrix
from .cutting import cut
from .errors import SimulationError
from .scene import ContactSpec


@dataclass
class Impulse:
    """Everything one impact produces; vectors in world axes."""

    kind: str  # "stable" (component with frame) or "mobile" (component with component)
    restitution: float
    normal: np.ndarray  # unit normal, world, from a towards b
    P: float  # normal impulse on b (N s); -P n acts on a
    vn_before: float  # relative normal velocity n . (v_b - v_a) before (< 0: approaching)
    vn_after: float
    v_before: np.ndarray
    v_after: np.ndarray
    ke_before: float
    ke_after: float
    cut_impulses: dict[str, list[float]] = field(default_factory=dict)  # on the child, world [fx, fy, mz]
    constraint_impulses: dict[str, float] = field(default_factory=dict)  # loops and drives, by row label
    joint_impulses: dict[str, list[float]] = field(default_factory=dict)  # every joint, world [fx, fy, mz]
    rnea_residual: np.ndarray | None = None  # generalized impulse the joints' actuators carry

    @property
    def vector(self) -> np.ndarray:
        return self.P * self.normal


def _normal_row(cfg: Configuration, contact: ContactSpec):
    """(points a and b, world normal n from a to b, J_n = n^T (J_b - J_a)); kinematics must be
    computed on the configuration's data."""
    pa, pb = cfg.point(contact.a, contact.point_a), cfg.point(contact.b, contact.point_b)
    n = cfg.rotation(contact.a) @ np.asarray(contact.normal, dtype=float)
    n /= np.linalg.norm(n)
    return pa, pb, n, n @ (cfg.point_jacobian(pb) - cfg.point_jacobian(pa))


def contact_state(cfg: Configuration, q, v, contact: ContactSpec):
    """(normal, gap, vn, J_n) at (q, v): n in world from a to b, gap = n . (p_b - p_a)."""
    cfg.kinematics(q, v)
    pa, pb, n, Jn = _normal_row(cfg, contact)
    gap = float(n @ (cfg.point_position(pb) - cfg.point_position(pa)))
    return n, gap, float(Jn @ v), Jn


def gap_rate(cfg: Configuration, q, v, contact: ContactSpec) -> float:
    """d/dt of the gap n . (p_b - p_a) at (q, v): the points' normal relative velocity plus
    the turn of the normal with link a, n' = w_a z x n (n is fixed in a)."""
    cfg.kinematics(q, v)
    pa, pb, n, Jn = _normal_row(cfg, contact)
    w_a = pin.getFrameVelocity(cfg.model, cfg.data, cfg.link_frame[contact.a], LWA).angular[2]
    r = cfg.point_position(pb) - cfg.point_position(pa)
    return float(Jn @ v + w_a * (n[0] * r[1] - n[1] * r[0]))


def contact_row(cfg: Configuration, q, v, contact: ContactSpec):
    """(J_n, bias) of the contact's normal row: ``d/dt (J_n v) = J_n a + bias``."""
    qp = cfg.to_pin(q)
    pin.forwardKinematics(cfg.model, cfg.data, qp, v, np.zeros(cfg.nv))
    pin.computeJointJacobians(cfg.model, cfg.data, qp)
    pin.updateFramePlacements(cfg.model, cfg.data)
    pa, pb, n, Jn = _normal_row(cfg, contact)
    acc = (pin.getFrameClassicalAcceleration(cfg.model, cfg.data, pb.frame_id, LWA).linear[:2]
           - pin.getFrameClassicalAcceleration(cfg.model, cfg.data, pa.frame_id, LWA).linear[:2])
    w_a = pin.getFrameVelocity(cfg.model, cfg.data, cfg.link_frame[contact.a], LWA).angular[2]
    vrel = (pin.getFrameVelocity(cfg.model, cfg.data, pb.frame_id, LWA).linear[:2]
            - pin.getFrameVelocity(cfg.model, cfg.data, pa.frame_id, LWA).linear[:2])
    ndot = w_a * np.array([-n[1], n[0]])
    return Jn, float(n @ acc + ndot @ vrel)


def impact_kind(cfg: Configuration, contact: ContactSpec) -> str:
    return "stable" if cfg.root in (contact.a, contact.b) else "mobile"


def solve_impulse(cfg: Configuration, t: float, q: np.ndarray, v: np.ndarray, contact: ContactSpec,
                  restitution: float, cut_joints: tuple[str, ...]) -> Impulse:
    """Solve the stable or mobile impulse at (t, q, v) by cutting ``cut_joints``."""
    n, _, vn, _ = contact_state(cfg, q, v, contact)
    pa = cfg.point(contact.a, contact.point_a)
    pb = cfg.point(contact.b, contact.point_b)
    pos_a, pos_b = cfg.point_position(pa), cfg.point_position(pb)
    cs = cut(cfg, q, cut_joints)
    v_f = cs.T @ v
    M_f = mass_matrix(cs.model, cs.data, cs.q)
    J_n = (n @ (frame_jacobian(cs.model, cs.data, pb.frame_id)[:2]
                - frame_jacobian(cs.model, cs.data, pa.frame_id)[:2]))[None, :]
    G = np.vstack([cs.J_cut, cfg.coords.equality(t, cs.model, cs.data)])
    chol = cholesky(M_f, cfg.name)
    W = sla.cho_solve(chol, np.eye(M_f.shape[0]))
    if G.shape[0]:
        WGt = W @ G.T
        S = G @ WGt
        W_eff = W - WGt @ np.linalg.solve(S, WGt.T)  # inverse of the paper's M_f, Eq. 25
    else:
        W_eff = W
    denom = J_n @ W_eff @ J_n.T  # Eq. 29 / 42 denominator: n^T J M_f^-1 J^T n
    if not np.all(np.isfinite(denom)) or denom[0, 0] <= 1e-14 * np.trace(W_eff):
        raise SimulationError(
            f"t = {t:.9g} s: the contact {contact.a}/{contact.b} cannot take an impulse along its normal "
            "(the normal is orthogonal to every allowed motion); check the contact normal and cut joints")
    P = -(1.0 + restitution) * np.linalg.solve(denom, J_n @ v_f)  # Eqs. 29, 42
    dv_f = W_eff @ J_n.T @ P  # Eqs. 24, 38 (and 35 with its sign)
    v_f_after = v_f + dv_f  # Eqs. 30, 43
    mult = -np.linalg.solve(S, G @ W @ J_n.T @ P) if G.shape[0] else np.zeros(0)
    v_after, res, *_ = np.linalg.lstsq(cs.T, v_f_after, rcond=None)
    if np.linalg.norm(cs.T @ v_after - v_f_after) > 1e-8 * max(1.0, np.linalg.norm(v_f_after)):
        raise SimulationError(f"t = {t:.9g} s: the cut system's post-impact velocity does not reassemble "
                              "the tree (internal error in joint cutting)")
    M = cfg.mass_matrix(q)
    out = Impulse(
        kind=impact_kind(cfg, contact), restitution=restitution, normal=n, P=float(P[0]),
        vn_before=vn, vn_after=float((J_n @ v_f_after)[0]), v_before=v.copy(), v_after=v_after,
        ke_before=float(0.5 * v @ M @ v), ke_after=float(0.5 * v_after @ M @ v_after))
    k = 0
    for name in cut_joints:
        F = np.zeros(3)
        while k < len(cs.row_owner) and cs.row_owner[k] == name:
            F += mult[k] * cs.row_dirs[k]
            k += 1
        out.cut_impulses[name] = [*(cs.child_rotation[name] @ F[:2]), float(F[2])]
    labels = cfg.coords.labels
    out.constraint_impulses = {lab: float(val) for lab, val in zip(labels, mult[len(cs.row_owner):])}
    point_impulses = [(contact.b, pos_b, out.vector, 0.0), (contact.a, pos_a, -out.vector, 0.0)]
    point_impulses += loop_point_impulses(cfg, out.constraint_impulses)
    out.joint_impulses, out.rnea_residual = joint_impulses(cfg, q, v_after - v, point_impulses)
    return out


def loop_point_impulses(cfg: Configuration, by_label: dict[str, float]):
    """The loop cut joints' impulses as (link, point, force, moment) on b and, opposite, on a."""
    out = []
    if not getattr(cfg.coords, "constrained", False):
        return out
    for s, fa, fb in zip(cfg.coords.closure.specs, cfg.coords.closure.frames_a, cfg.coords.closure.frames_b):
        pa, pb = cfg.data.oMf[fa].translation[:2], cfg.data.oMf[fb].translation[:2]
        if s.type == "prismatic":
            n = cfg.rotation(s.a) @ np.array([-s.axis[1], s.axis[0]]) / np.linalg.norm(s.axis)
            F, m = by_label[f"{s.name}.fn"] * n, by_label[f"{s.name}.mz"]
            out += [(s.b, pb, F, m), (s.a, pb, -F, -m)]
            continue
        F = np.array([by_label[f"{s.name}.fx"], by_label[f"{s.name}.fy"]])
        m = by_label.get(f"{s.name}.mz", 0.0)
        out += [(s.b, pb, F, m), (s.a, pa, -F, -m)]
    return out


def joint_impulses(cfg: Configuration, q, dv, point_impulses):
    """Impulse carried by every joint: RNEA with zero velocity and gravity,
    ``dv`` as acceleration and the point impulses as external forces.

    Returns ({joint: [fx, fy, mz]} on the child from the parent, world axes,
    moment about the joint centre) and the generalized residual, which is the
    impulse the actuators (drives) supply and is zero on passive joints.
    """
    model = cfg.model
    if not hasattr(cfg, "_impulse_model"):
        cfg._impulse_model = model.copy()
        cfg._impulse_model.gravity.linear[:] = 0.0
        cfg._impulse_data = cfg._impulse_model.createData()
    m0, d0 = cfg._impulse_model, cfg._impulse_data
    qp = cfg.to_pin(q)
    pin.forwardKinematics(m0, d0, qp)
    fext = pin.StdVec_Force()
    for _ in range(model.njoints):
        fext.append(pin.Force.Zero())
    for link, p, F, mz in point_impulses:
        jid = model.frames[cfg.link_frame[link]].parentJoint
        if jid == 0:
            continue
        F3 = np.array([F[0], F[1], 0.0])
        p3 = np.array([p[0], p[1], 0.0])
        f_world = pin.Force(F3, np.cross(p3, F3) + np.array([0.0, 0.0, mz]))
        fext[jid] = fext[jid] + d0.oMi[jid].actInv(f_world)
    tau = pin.rnea(m0, d0, qp, np.zeros(model.nv), dv, fext)
    out = {}
    for jid in range(1, model.njoints):
        f = d0.f[jid]
        R = d0.oMi[jid].rotation
        lin = R @ f.linear
        out[model.names[jid]] = [float(lin[0]), float(lin[1]), float((R @ f.angular)[2])]
    return out, np.asarray(tau).copy()
