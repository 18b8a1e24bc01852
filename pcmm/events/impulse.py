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

A point contact with friction (``ContactSpec.friction``) adds its tangential row J_t: the
impulse (P_t, P_n) is then Routh's process on the 2 x 2 Delassus matrix
``[J_t; J_n] W_eff [J_t; J_n]^T`` (:mod:`pcmm.events.friction`), and ``dv_f = W_eff [J_t; J_n]^T P``.

The impulse carried by every joint of the tree comes from a second route:
RNEA on a gravity-free copy of the tree with zero velocity, the velocity jump
as acceleration and the contact impulse as an external force.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from .._scipy import lapack
from ..model.configuration import Configuration
from .contact import contact_point, contact_state, impact_kind, joint_stop_row, normal_row
from .cutting import cut
from .friction import AmbiguousImpact, FrictionalImpulse, routh
from .impulse_compiled import (NO_IMPULSE, CompiledImpulse, compiled_impulse, disagreement, reach, refuse,
                               takes_no_impulse)
from ..errors import SimulationError
from ..model.pinocchio_helpers import cholesky, frame_jacobian, mass_matrix
from ..model.rows import determinate, independent_rows, left_null, solve
from ..scene.spec import ContactSpec

#: NO_IMPULSE (:func:`takes_no_impulse`): the one rule of both solves for 'no impulse along the
#: normal' (defined beside the compiled plan, which this module imports)


@dataclass
class Impulse:
    """Everything one impact produces; vectors in world axes."""

    kind: str  # "stable" (component with frame) or "mobile" (component with component)
    restitution: float | None  # None: a switch without impact (no_impulse)
    normal: np.ndarray  # unit normal, world, from a towards b
    P: float  # normal impulse on b (N s); -P n acts on a
    vn_before: float  # relative normal velocity n . (v_b - v_a) before (< 0: approaching)
    vn_after: float
    v_before: np.ndarray
    v_after: np.ndarray
    ke_before: float  # from the tree's mass matrix at the impact pose
    ke_after: float
    point: np.ndarray  # world (x, y) of b's contact point
    impact: bool = True  # False: a switch without impulse (the paper's comparison runs)
    drive_work: float = 0.0  # the drives' impulsive work: a driven joint keeps its prescribed speed
    cut_impulses: dict[str, list[float]] = field(default_factory=dict)  # on the child, world [fx, fy, mz]
    # loops and drives: per cut joint [fx, fy, mz] on link b from link a (world axes, moment about
    # point_b); per drive "J.drive" the motor's impulse on the joint's child ([0, 0, mz] revolute,
    # the force along the axis prismatic).  Same form as joint_impulses.
    constraint_impulses: dict[str, list[float]] = field(default_factory=dict)
    constraint_rows: dict[str, float] = field(default_factory=dict)  # the multiplier of each row, by label
    contact_impulses: list = field(default_factory=list)  # (link, world point, F, mz): on b, then on a
    joint_impulses: dict[str, list[float]] = field(default_factory=dict)  # every joint, world [fx, fy, mz]
    rnea_residual: np.ndarray | None = None  # generalized impulse the joints' actuators carry
    tangent: np.ndarray | None = None  # frictional contacts: world unit tangent t = (n_y, -n_x)
    P_t: float = 0.0  # frictional contacts: tangential impulse on b along t (N s)
    friction: FrictionalImpulse | None = None  # Routh's process: phases, slip, the works
    # the moving bodies' momenta about the world origin, before and after ([Lx, Ly, H0] each), where
    # the solve had them at hand (the compiled one); else the event record computes them
    momenta: tuple | None = None

    @property
    def vector(self) -> np.ndarray:
        return self.P * self.normal + (0.0 if self.tangent is None else self.P_t * self.tangent)

    @property
    def energy_dissipated(self) -> float:
        """KE- + drive_work - KE+ (>= 0): the drives' work may raise the kinetic energy, never this."""
        return self.ke_before + self.drive_work - self.ke_after


def _inverse_mass(M: np.ndarray, configuration: str) -> np.ndarray:
    """``M^-1`` by its Cholesky factor: LAPACK's potrf and potrs called directly, the very calls
    ``scipy.linalg.cho_factor`` / ``cho_solve`` make (same bits) without their checks' overhead,
    which dominates for the few coordinates of a mechanism (and without importing scipy.linalg,
    0.3 s at start-up: :mod:`pcmm._scipy`)."""
    if M.shape[0] == 0:
        return np.zeros((0, 0))
    la = lapack()
    c, info = la.dpotrf(M, lower=False, overwrite_a=False, clean=False)
    if info == 0 and np.isfinite(c).all():
        W, info = la.dpotrs(c, np.eye(M.shape[0]), lower=False, overwrite_b=True)
        if info == 0:
            return W
    import scipy.linalg as sla  # the checked route, for its clear error
    return sla.cho_solve(cholesky(M, configuration), np.eye(M.shape[0]))


_GELSD_WORK: dict[tuple[int, int], tuple[int, int]] = {}


def _least_squares(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.lstsq(A, b, rcond=None)[0]`` for a vector ``b``: LAPACK's dgelsd with numpy's
    default cut-off (eps max(m, n)) called directly (the same routine and workspace: the same
    bits), without numpy's wrapper, which costs as much as the solve at this size."""
    m, n = A.shape
    if m == 0 or n == 0 or m < n:
        return np.linalg.lstsq(A, b, rcond=None)[0]
    if (m, n) not in _GELSD_WORK:
        work, iwork, info = lapack().dgelsd_lwork(m, n, 1, -1)
        _GELSD_WORK[(m, n)] = (int(work), int(iwork)) if info == 0 else None
    sizes = _GELSD_WORK[(m, n)]
    if sizes is None:
        return np.linalg.lstsq(A, b, rcond=None)[0]
    x, _, _, info = lapack().dgelsd(A, b, sizes[0], sizes[1], cond=np.finfo(float).eps * max(m, n))
    if info != 0:
        return np.linalg.lstsq(A, b, rcond=None)[0]
    return x[:n]


def tangent_of(n: np.ndarray) -> np.ndarray:
    """The contact tangent: the normal turned by -90 degrees, t = (n_y, -n_x)."""
    return np.array([n[1], -n[0]])


@dataclass(frozen=True)
class _Plan:
    """What an impulse solve at one contact with one set of cut joints needs that no event changes:
    the cut joints split into the tree's (cut here, :mod:`pcmm.events.cutting`) and the loops' (already
    rows of ``G``), the contact's frames and its constant row, the drives' rows among the multipliers
    (their impulsive work).  Built at the first impact, kept with the configuration's model
    (``Configuration.impulse_models``) under everything it reads."""

    contact: ContactSpec
    cut_joints: tuple[str, ...]  # tree joints cut at the impact
    cut_loops: tuple[str, ...]  # loop cut joints among the transition's cut (their rows are in G)
    stop: bool  # a joint stop (its own coordinate's row), else a point contact
    frictional: bool
    prismatic: bool  # a prismatic joint stop
    kind: str  # "stable" or "mobile"
    frame_a: int  # link frames of a and b
    frame_b: int
    Jn_tree: np.ndarray | None  # a joint stop's row in the tree: -s e_j (constant)
    drive_rows: tuple[tuple[int, int], ...]  # (multiplier index among the constraint rows, joint velocity index)


def _plan(cfg: Configuration, contact: ContactSpec, cut_joints: tuple[str, ...]) -> _Plan:
    labels = tuple(cfg.coords.labels)
    loop_cuts = tuple(s.name for s in cfg.spec.cut_joints)
    key = ("plan", id(contact), tuple(cut_joints), labels, loop_cuts)  # the contact by identity: its hash
    kept = cfg.impulse_models  # walks all its fields, and a plan holds the contact it was made for
    plan = kept.get(key)
    if plan is not None and plan.contact is contact:
        return plan
    Jn = None
    if contact.joint is not None:
        Jn = np.zeros(cfg.nv)
        Jn[cfg.joint_slice[contact.joint].start] = -contact.stop_sign
    plan = kept[key] = _Plan(
        contact=contact, cut_joints=tuple(j for j in cut_joints if j not in loop_cuts),
        cut_loops=tuple(j for j in cut_joints if j in loop_cuts),
        stop=contact.joint is not None,
        frictional=contact.joint is None and contact.friction is not None,
        prismatic=contact.joint is not None and cfg.spec.info.joints[contact.joint].type == "prismatic",
        kind=impact_kind(cfg, contact), frame_a=cfg.link_frame[contact.a], frame_b=cfg.link_frame[contact.b],
        Jn_tree=Jn,
        drive_rows=tuple((i, cfg.joint_slice[lab[:-6]].start) for i, lab in enumerate(labels) if lab.endswith(".drive")))
    return plan


def solve_impulse(cfg: Configuration, t: float, q: np.ndarray, v: np.ndarray, contact: ContactSpec,
                  restitution: float, cut_joints: tuple[str, ...], name: str | None = None) -> Impulse:
    """Solve the stable or mobile impulse at (t, q, v) by cutting ``cut_joints``; a point contact
    with ``friction`` takes a two-dimensional impulse (Routh's process).  ``name`` (the
    transition) goes into the messages.

    Compiled where the contact's plan takes it (:mod:`pcmm.events.impulse_compiled`: rows of revolute
    loop cut joints and drives, a joint stop or a frictionless point contact), checked against
    :func:`solve_impulse_python` at the plan's first impact; else that Python solve."""
    plan = _plan(cfg, contact, cut_joints)
    # redundant rows (pcmm.model.partitioned): the Python solve keeps an independent set of them
    fast = None if cfg.coords.redundant else compiled_impulse(cfg, plan)
    if fast is not None:
        out = _compiled_solve(cfg, plan, fast, q, v, restitution)
        if out is not None and fast.checked:
            return out
        if out is not None:  # the plan's first impact: the two solves must agree
            reference = solve_impulse_python(cfg, t, q, v, contact, restitution, cut_joints, name)
            why = disagreement(out, reference)
            if why is None:
                fast.checked = True
                return out
            refuse(cfg, plan, why)
            return reference
    return solve_impulse_python(cfg, t, q, v, contact, restitution, cut_joints, name)


def _compiled_solve(cfg: Configuration, plan: _Plan, fast: CompiledImpulse, q, v, restitution) -> Impulse | None:
    """The :class:`Impulse` of ``fast``'s compiled solve (pcmm/model/_impulse.hpp); None where it
    takes no impulse along the normal (the Python solve then says why).  An :class:`ArrayImpulse`:
    the joints', cut joints' and rows' impulses are kept as the solve's arrays, their dicts formed
    when first read (a bounce's record reads the arrays: :func:`pcmm.events.records.bounce_record`)."""
    got = fast.plan.solve(q, v, restitution)
    if got is None:
        return None
    v_after, (P, vn_before, vn_after, ke_before, ke_after, drive_work), n, point, pos_a, pos_b, mu, cut, joints, tau, \
        momenta, loop_points = got
    out = ArrayImpulse(kind=plan.kind, restitution=restitution, normal=n, P=P, vn_before=vn_before, vn_after=vn_after,
                       v_before=v.copy(), v_after=v_after, ke_before=ke_before, ke_after=ke_after, point=point,
                       drive_work=drive_work, rnea_residual=tau, momenta=momenta)
    d = out.__dict__
    del d["cut_impulses"], d["constraint_rows"], d["joint_impulses"], d["contact_impulses"]  # (_FORMED: when read)
    out.arrays = (cut, mu, joints)
    out.solved = (fast, plan, pos_a, pos_b)
    labels = fast.row_labels
    if fast.loop_cuts:  # each loop cut joint's impulse on b at its point, the opposite on a (loop_point_impulses' form)
        loop = []
        for k, s in enumerate(fast.loop_cuts):
            F = mu[2 * k:2 * k + 2]
            loop += [(s.b, loop_points[k, 2:], F, 0.0), (s.a, loop_points[k, :2], -F, -0.0)]
        out.constraint_impulses = constraint_impulses(cfg, out.constraint_rows, loop)
        for name in plan.cut_loops:  # on b from a, world axes, like a tree joint's cut impulse
            out.cut_impulses[name] = list(out.constraint_impulses[name])
    elif not labels:
        out.constraint_impulses = {}
    elif _revolute_drives(cfg, labels):  # constraint_impulses' [0, 0, mu] of each drive (a revolute joint's)
        out.constraint_impulses = {lab: [0.0, 0.0, m] for lab, m in zip(labels, mu.tolist())}
    else:
        out.constraint_impulses = constraint_impulses(cfg, out.constraint_rows, [])
    return out


def _revolute_drives(cfg: Configuration, labels: tuple[str, ...]) -> bool:
    """Are the drives of ``labels`` (each "J.drive") all on revolute joints?  Decided once per model."""
    key = ("revolute drives", labels)
    kept = cfg.impulse_models.get(key)
    if kept is None:
        kept = cfg.impulse_models[key] = all(
            cfg.spec.info.joints[lab[:-len(".drive")]].type != "prismatic" for lab in labels)
    return kept


def _contact_impulses(imp: ArrayImpulse) -> list:
    """The contact's impulses on b and on a, (link, world point, F, mz), of a compiled solve."""
    _, plan, pos_a, pos_b = imp.solved
    contact, P, n = plan.contact, imp.P, imp.normal
    if not plan.stop:
        return [(contact.b, pos_b, P * n, 0.0), (contact.a, pos_a, -P * n, 0.0)]
    if plan.prismatic:
        return [(contact.b, pos_b, P * n, 0.0), (contact.a, pos_b, -P * n, 0.0)]
    s_ = contact.stop_sign
    return [(contact.b, pos_b, np.zeros(2), -s_ * P), (contact.a, pos_b, np.zeros(2), s_ * P)]


class ArrayImpulse(Impulse):
    """The :class:`Impulse` of a compiled solve (:func:`_compiled_solve`): its cut joints', drive rows'
    and joints' impulses are the solve's arrays ``arrays = (cut, mu, joints)`` (one row [fx, fy, mz] per
    cut joint and per joint, in ``solved[0]``'s ``cut_names`` and ``joint_names`` order; one multiplier
    per drive row), and ``cut_impulses``, ``constraint_rows``, ``joint_impulses`` and
    ``contact_impulses`` are formed from them when first read (then kept, or replaced when set): the
    same dicts and numbers."""

    arrays: tuple
    solved: tuple  # (CompiledImpulse, _Plan, a's contact point, b's)

    def __getattr__(self, name: str):  # only for a name the instance lacks: one of _FORMED, not yet formed
        form = _FORMED.get(name)
        if form is None:
            raise AttributeError(f"'{type(self).__name__}' object has no attribute '{name}'")
        value = self.__dict__[name] = form(self)
        return value


#: the fields of :class:`ArrayImpulse` formed when first read: {field: how, from the impulse}
_FORMED = {
    "cut_impulses": lambda imp: dict(zip(imp.solved[0].cut_names, imp.arrays[0].tolist())),
    "constraint_rows": lambda imp: dict(zip(imp.solved[0].row_labels, imp.arrays[1].tolist())),
    "joint_impulses": lambda imp: dict(zip(imp.solved[0].joint_names, imp.arrays[2].tolist())),
    "contact_impulses": _contact_impulses,
}


def _no_impulse_cause(cfg: Configuration, G: np.ndarray, cut_joints) -> str:
    """What to check when a contact takes no impulse: with every row of the configuration (its cut
    joints, loops and drives: ``G``, drives last) no coordinate is free, and the drives are what
    fix the last ones, then no impulse can change a velocity and the drives are named; else the
    normal and the cut joints."""
    drives = list(getattr(getattr(cfg.coords, "drives", None), "joints", ()))
    nv = G.shape[1]
    free = nv - (np.linalg.matrix_rank(G) if G.shape[0] else 0)
    without = G[:G.shape[0] - len(drives)]
    free_undriven = nv - (np.linalg.matrix_rank(without) if without.shape[0] else 0)
    if free == 0 and drives and free_undriven > 0:
        named = ", ".join(f"'{j}'" for j in drives)
        return (f"configuration '{cfg.name}' has no free coordinate there: its loops and cut joints leave "
                f"{free_undriven} and the drive{'s' if len(drives) > 1 else ''} on {named} prescribe"
                f"{'' if len(drives) > 1 else 's'} {'them' if free_undriven > 1 else 'it'}, so no impulse can "
                "change a velocity. A driven joint takes the freedom an impact needs: give the struck part a "
                "freedom of its own (e.g. on a spring), or drive it by a motor torque (a `torque` force) instead of a "
                "drive")
    if free == 0:
        return (f"configuration '{cfg.name}' has no free coordinate there (its cut joints and loops fix all "
                f"{nv}), so no impulse can change a velocity; check the cut joints {list(cut_joints)} and loops")
    return "check the contact normal and cut joints"


def solve_impulse_python(cfg: Configuration, t: float, q: np.ndarray, v: np.ndarray, contact: ContactSpec,
                         restitution: float, cut_joints: tuple[str, ...], name: str | None = None) -> Impulse:
    """The impulse by the cut system in Python: the reference, and the solve of every case the
    compiled one does not take.

    One pass of the tree's kinematics serves the contact, the cut and the report; what does not
    change between events is the contact's plan (:func:`_plan`) and the cut model's topology."""
    plan = _plan(cfg, contact, cut_joints)
    data = cfg.data
    cfg.kinematics(q, v)  # placements, frames and joint Jacobians at the impact pose
    if plan.stop:
        if plan.prismatic:
            n, _ = joint_stop_row(cfg, cfg.model, data, contact)
        else:  # joint_stop_row's normal alone: against the child's y axis
            n = -contact.stop_sign * data.oMf[plan.frame_b].rotation[:2, 1].copy()
        vn = float(plan.Jn_tree @ v)
        pos_a = pos_b = data.oMf[plan.frame_b].translation[:2].copy()
    else:
        pa, pb, n, Jn_tree = normal_row(cfg, contact)
        vn = float(Jn_tree @ v)
        pos_a, pos_b = cfg.point_position(pa), cfg.point_position(pb)
    point = contact_point(cfg, contact)  # where the event reports the contact
    frictional = plan.frictional
    tangent = tangent_of(n) if frictional else None
    cut_joints, cut_loops = plan.cut_joints, plan.cut_loops
    cs = cut(cfg, q, cut_joints, kinematics=False)
    v_f = cs.T @ v
    M_f = mass_matrix(cs.model, cs.data, cs.q)
    if not plan.stop:
        J_rel = (frame_jacobian(cs.model, cs.data, pb.frame_id)[:2]
                 - frame_jacobian(cs.model, cs.data, pa.frame_id)[:2])
        J_n = (n @ J_rel)[None, :]
    elif plan.prismatic:
        J_n = joint_stop_row(cfg, cs.model, cs.data, contact)[1][None, :]
    else:  # joint_stop_row's row alone: -s (w_b - w_a)
        J_n = (-contact.stop_sign * (frame_jacobian(cs.model, cs.data, plan.frame_b)[5]
                                     - frame_jacobian(cs.model, cs.data, plan.frame_a)[5]))[None, :]
    G = np.concatenate((cs.J_cut, cfg.coords.equality(t, cs.model, cs.data)))
    try:
        W = _inverse_mass(M_f, cfg.name)
    except SimulationError:
        if not cut_joints:
            raise
        joints = cfg.spec.info.joints
        freed = ", ".join(f"'{joints[j].child}'" for j in cut_joints if j in joints)
        raise SimulationError(
            f"t = {t:.9g} s, transition '{name}': cutting {', '.join(repr(j) for j in cut_joints)} (its `cut`) frees "
            f"{freed}, and the cut system's mass matrix is not positive definite: a body the cut frees has no "
            "inertia along one of its planar freedoms (a point mass, izz = 0, turns freely about its centroid). "
            "Give it a rotational inertia, or, for a joint stop (contact = { joint = ... }), write cut = []: the "
            "stop acts on the joint's own coordinate and the run is the same") from None
    G_all = G
    # redundant but consistent rows (a cut joint given twice, a drive on a joint a lock and a loop fix):
    # the impulse is the same on a maximal independent set of them; their impulsive forces along the
    # rows' left null vectors are indeterminate, reported NaN (below)
    kept = independent_rows(G) if cfg.coords.redundant else None
    if kept is not None:
        G = G[kept]
    if G.shape[0]:
        WGt = W @ G.T
        S = G @ WGt
        W_eff = W - WGt @ solve(S, WGt.T)  # inverse of the paper's M_f, Eq. 25 (dgesv: numpy's solve's bits)
    else:
        W_eff = W
    denom = J_n @ W_eff @ J_n.T  # Eq. 29 / 42 denominator: n^T J M_f^-1 J^T n
    d = float(denom[0, 0])
    M = cfg.mass_matrix(q)
    R = (J_n if plan.stop else J_rel) @ cs.T  # the contact's relative motion, in the tree (NO_IMPULSE)
    reach_ = reach(R @ solve(M, R.T))
    if takes_no_impulse(d, reach_):  # no impulse along n
        raise SimulationError(
            f"t = {t:.9g} s: the contact {contact.a}/{contact.b} cannot take an impulse along its normal "
            f"(the normal is orthogonal to every allowed motion: J W_eff J^T = {d:.3g}, "
            f"{d / reach_ if reach_ > 0 else 0.0:.3g} of what the contact's motion reaches; none at or below "
            f"{NO_IMPULSE:g}); " + _no_impulse_cause(cfg, G, cut_joints))
    fr = None
    if frictional:
        where = f"t = {t:.9g} s, " + (f"transition '{name}'" if name else f"contact {contact.a}/{contact.b}")
        J = np.vstack([tangent @ J_rel, J_n])  # rows (t, n)
        D = J @ W_eff @ J.T  # the contact's Delassus matrix
        vc = J @ v_f
        fr = frictional_impulse(D, vc, contact, restitution, where)
        P = fr.P
    else:
        J = J_n
        # Eqs. 29, 42: LAPACK's dgesv of this 1 x 1 system is the division (the same bits), without its call
        P = -(1.0 + restitution) * ((J_n @ v_f) / d)
    dv_f = W_eff @ J.T @ P  # Eqs. 24, 38 (and 35 with its sign)
    v_f_after = v_f + dv_f  # Eqs. 30, 43
    mult = -solve(S, G @ W @ J.T @ P) if G.shape[0] else np.zeros(0)
    if kept is not None:
        full = np.zeros(G_all.shape[0])
        full[kept] = mult
        mult = full
        work_mult, mult = mult, determinate(G_all, mult)
    else:
        work_mult = mult
    v_after = _least_squares(cs.T, v_f_after)
    if _norm(cs.T @ v_after - v_f_after) > 1e-8 * max(1.0, _norm(v_f_after)):
        raise SimulationError(f"t = {t:.9g} s: the cut system's post-impact velocity does not reassemble "
                              "the tree (internal error in joint cutting)")
    out = Impulse(
        kind=plan.kind, restitution=restitution, normal=n, P=float(P[-1]),
        vn_before=vn, vn_after=float((J_n @ v_f_after)[0]), v_before=v.copy(), v_after=v_after,
        ke_before=float(0.5 * v @ M @ v), ke_after=float(0.5 * v_after @ M @ v_after), point=point,
        tangent=tangent, P_t=float(P[0]) if frictional else 0.0, friction=fr)
    k = 0
    for name in cut_joints:
        F = np.zeros(3)
        while k < len(cs.row_owner) and cs.row_owner[k] == name:
            F += mult[k] * cs.row_dirs[k]
            k += 1
        out.cut_impulses[name] = [*(cs.child_rotation[name] @ F[:2]), float(F[2])]
    rows = mult[len(cs.row_owner):].tolist()
    out.constraint_rows = dict(zip(cfg.coords.labels, rows))
    # A driven joint keeps its prescribed speed through the impact: its motor's impulsive
    # moment does work (mu q'), so the kinetic energy may rise by that much; what never
    # rises is KE_before + drive_work - KE_after (the energy the impact dissipates).
    # (with redundant rows: any split's work, the same for all: a drive whose impulse is indeterminate is at rest)
    out.drive_work = sum(float(work_mult[len(cs.row_owner) + i]) * float(v[j]) for i, j in plan.drive_rows)
    if not plan.stop:
        point_impulses = [(contact.b, pos_b, out.vector, 0.0), (contact.a, pos_a, -out.vector, 0.0)]
    elif plan.prismatic:  # a force along the axis at the child
        point_impulses = [(contact.b, pos_b, out.vector, 0.0), (contact.a, pos_b, -out.vector, 0.0)]
    else:  # a couple: -s P on the child, +s P on the parent
        s_ = contact.stop_sign
        point_impulses = [(contact.b, pos_b, np.zeros(2), -s_ * out.P), (contact.a, pos_b, np.zeros(2), s_ * out.P)]
    out.contact_impulses = list(point_impulses)
    loop = loop_point_impulses(cfg, out.constraint_rows)
    point_impulses += loop
    out.constraint_impulses = constraint_impulses(cfg, out.constraint_rows, loop)
    for name in cut_loops:  # on b from a, world axes, like a tree joint's cut impulse
        out.cut_impulses[name] = list(out.constraint_impulses[name])
    if kept is None:
        out.joint_impulses, out.rnea_residual = joint_impulses(cfg, q, v_after - v, point_impulses)
    else:  # redundant rows: each joint's impulse from one split, NaN where another split changes it
        out.joint_impulses, out.rnea_residual = _determinate_joint_impulses(
            cfg, q, v_after - v, point_impulses[:len(point_impulses) - len(loop)], work_mult, G_all, len(cs.row_owner))
    if fr is not None:
        check_frictional_energy(fr, out, where)
    return out


def _determinate_joint_impulses(cfg: Configuration, q, dv, contact, split, G, first: int):
    """``joint_impulses`` where the rows ``G`` are redundant: from the impulsive multipliers ``split``
    (one solution; the constraint rows' from index ``first`` on), then again with each left null
    vector of ``G`` added (another solution, the same velocities): a joint's component that changes
    is statically indeterminate, NaN; the others are every split's (a joint the redundant rows'
    forces reach only through their resultant)."""
    labels = cfg.coords.labels

    def carried(m):
        return joint_impulses(cfg, q, dv, list(contact) + loop_point_impulses(cfg, dict(zip(labels, m[first:].tolist()))))
    base, residual = carried(split)
    scale = max([1.0] + [abs(x) for f in base.values() for x in f])
    for y in left_null(G).T:
        other, _ = carried(split + scale * y)
        for name, f in base.items():
            base[name] = [x if abs(x - o) <= 1e-9 * scale else math.nan for x, o in zip(f, other[name])]
    return base, residual


def _norm(x: np.ndarray) -> float:
    """``np.linalg.norm`` of a vector, by the same operations (the square root of ``x . x``)."""
    return math.sqrt(float(x.dot(x)))


def frictional_impulse(D: np.ndarray, vc: np.ndarray, contact: ContactSpec, e: float, where: str) -> FrictionalImpulse:
    """Routh's process at a frictional point contact (Delassus matrix ``D``, contact velocity ``vc``
    in (t, n)); refuses a Painleve case and an impact that ends sliding in contact."""
    try:
        fr = routh(D, float(vc[0]), float(vc[1]), contact.friction, e, contact.restitution_law)
    except AmbiguousImpact as exc:
        raise SimulationError(f"{where}, contact {contact.a}/{contact.b}: {exc}") from None
    scale = max(abs(fr.vn_before), abs(fr.slip_before))
    if abs(fr.vn_after) <= 1e-12 * scale and abs(fr.slip_after) > 1e-9 * scale:
        need = np.abs(np.linalg.solve(D, -np.asarray(vc, float)))  # the sticking plastic impulse
        raise SimulationError(
            f"{where}, contact {contact.a}/{contact.b}: the plastic impact ends with the point sliding in contact "
            f"(slip {fr.slip_after:.6g} m/s, phases {fr.phase_text}); pcmm models no sliding contact: a no-slip "
            f"outcome needs friction >= {need[0] / need[1]:.6g} (|P_t| / P_n of the sticking impulse), or give "
            "restitution > 0 so that the point leaves the surface")
    return fr


def check_frictional_energy(fr: FrictionalImpulse, imp: Impulse, where: str) -> None:
    """Newton's kinematic law with friction may create energy when the slip stops or reverses during
    the impact (Kane and Levinson; Stronge 1991): refused with the cause, not a silent gain."""
    gain = imp.ke_after - imp.ke_before - imp.drive_work
    if gain > 1e-9 * max(imp.ke_before, 1e-300):
        cause = (f"Newton's kinematic restitution with friction creates energy here (the slip {fr.slip_before:.6g} m/s "
                 f"stopped or reversed during the impact: phases {fr.phase_text})" if fr.law == "newton" and fr.slip_changed else
                 f"the frictional impact ({fr.law} law, phases {fr.phase_text}) creates energy")
        raise SimulationError(
            f"{where}: {cause}: kinetic energy {imp.ke_before:.9g} -> {imp.ke_after:.9g} J "
            + (f"(no split of the works: {fr.no_split}); use " if fr.no_split is not None else
               f"(normal work {fr.work_normal:.6g} J, friction work {fr.work_tangential:.6g} J); use ")
            + "restitution_law = \"energetic\" (Stronge) or a smaller restitution")


def no_impulse(cfg: Configuration, q: np.ndarray, v_before: np.ndarray, v_after: np.ndarray,
               contact: ContactSpec) -> Impulse:
    """A transformation without impact (the paper's comparison runs): no impulse acts, the
    velocity changes from ``v_before`` to ``v_after`` by the switch alone; the contact's
    kinematics and the kinetic energies are those of the record."""
    n, _, vn, Jn = contact_state(cfg, q, v_before, contact)
    point = contact_point(cfg, contact)
    M = cfg.mass_matrix(q)
    return Impulse(kind=impact_kind(cfg, contact), restitution=None, normal=n, P=0.0, vn_before=vn,
                   vn_after=float(Jn @ v_after), v_before=v_before.copy(), v_after=v_after,
                   ke_before=float(0.5 * v_before @ M @ v_before), ke_after=float(0.5 * v_after @ M @ v_after),
                   point=point, impact=False)


def loop_point_impulses(cfg: Configuration, by_label: dict[str, float]):
    """The loop cut joints' impulses as (link, point, force, moment) on b and, opposite, on a."""
    out = []
    for s, fa, fb in cfg.coords.cut_joint_frames():
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


def constraint_impulses(cfg: Configuration, rows: dict[str, float], loop_points) -> dict[str, list[float]]:
    """Each loop cut joint's impulse as [fx, fy, mz] on its link b (the first of the pair
    :func:`loop_point_impulses` gives), and each drive's as the impulse its motor applies on the
    driven joint's child, in the same [fx, fy, mz] form as the joint impulses."""
    out = {}
    specs = cfg.coords.closure.specs if getattr(cfg.coords, "constrained", False) else ()
    for s, (_, _, F, m) in zip(specs, loop_points[::2]):
        out[s.name] = [float(F[0]), float(F[1]), float(m)]
    for lab, mu in rows.items():
        if not lab.endswith(".drive"):
            continue
        joint = lab[:-len(".drive")]
        uj = cfg.spec.info.joints[joint]
        if uj.type == "prismatic":
            axis = cfg.data.oMi[cfg.joint_id[joint]].rotation[:2, :] @ np.asarray(uj.axis, float)
            axis /= np.linalg.norm(axis)
            out[lab] = [float(mu * axis[0]), float(mu * axis[1]), 0.0]
        else:
            out[lab] = [0.0, 0.0, float(mu)]
    return out


def joint_impulses(cfg: Configuration, q, dv, point_impulses):
    """Impulse carried by every joint: RNEA with zero velocity and gravity,
    ``dv`` as acceleration and the point impulses as external forces.

    Returns ({joint: [fx, fy, mz]} on the child from the parent, world axes,
    moment about the joint centre) and the generalized residual, which is the
    impulse the actuators (drives) supply and is zero on passive joints.
    """
    model = cfg.model
    cache = cfg.impulse_models  # built once per model (createData is costly)
    kept = cache.get("joint_impulses")
    if kept is None:
        m0 = model.copy()
        m0.gravity.linear[:] = 0.0
        fext = pin.StdVec_Force()
        for _ in range(model.njoints):
            fext.append(pin.Force.Zero())
        # each link's joint and each joint's name, read once per model; the external forces' vector,
        # reset where the previous event loaded it
        kept = cache["joint_impulses"] = (m0, m0.createData(), fext,
                                          {link: model.frames[f].parentJoint for link, f in cfg.link_frame.items()},
                                          list(model.names), np.zeros(model.nv), [])
    m0, d0, fext, parent_joint, names, zero_v, loaded = kept
    for jid in loaded:
        fext[jid] = pin.Force.Zero()
    loaded.clear()
    qp = cfg.to_pin(q)
    pin.forwardKinematics(m0, d0, qp)
    for link, p, F, mz in point_impulses:
        jid = parent_joint[link]
        if jid == 0:
            continue
        fx, fy, px, py = float(F[0]), float(F[1]), float(p[0]), float(p[1])
        # the moment about the world origin, p x F + mz, term by term as numpy's cross and sum
        # form it (the same floating-point operations, so the same bits, signed zeros included)
        moment = np.array([py * 0.0 - 0.0 * fy + 0.0, 0.0 * fx - px * 0.0 + 0.0, px * fy - py * fx + mz])
        f_world = pin.Force(np.array([fx, fy, 0.0]), moment)
        fext[jid] = fext[jid] + d0.oMi[jid].actInv(f_world)
        loaded.append(jid)
    tau = pin.rnea(m0, d0, qp, zero_v, dv, fext)
    out = {}
    for jid in range(1, model.njoints):
        f = d0.f[jid]
        R = d0.oMi[jid].rotation
        lin = R @ f.linear
        out[names[jid]] = [float(lin[0]), float(lin[1]), float((R @ f.angular)[2])]
    return out, np.asarray(tau).copy()
