"""The compiled impulse of one contact (``pcmm/model/_impulse.hpp``): whether a contact and cut set
take it, and its plan, built once per (configuration, contact, cut set).

The impulse solve of :mod:`pcmm.events.impulse` (the paper's Eqs. 21-43 on the cut system) costs
some 300-600 us per impact in Python, most of it in thirty-odd small Pinocchio, LAPACK and numpy
calls.  In a tree whose only constraint rows are drives, the cut joint's rows allow exactly the
motions the joint allows, so the same impulse follows from the tree's own mass matrix restricted
by the drive rows, and the cut joint's impulsive reaction from the impulse the joint carries
(RNEA): ``_impulse.hpp`` does that in one compiled call (the header says how, equation by
equation).  Same numbers to round-off, not to the bit.

Taken: a joint stop (revolute or prismatic) or a frictionless point contact - stops, latches,
stop-merges - in a configuration (no planar joint, no armature) whose rows are revolute cut joints'
(closed loops: their closure rows Phi_q among the constraint rows, Eqs. 12 and 25) and drives on
revolute joints that are not cut.  Left to the Python solve, with the reason kept (:func:`reason`):
prismatic and weld cut joints, friction, planar joints, a driven cut joint, ``PCMM_COMPILED=0``, an
extension without it.  Contacts closed at once (:mod:`pcmm.events.simultaneous`) and pin strikes never
come here.

Each plan is checked once against the Python solve, at its first impact
(:func:`pcmm.events.impulse.solve_impulse`): velocities, impulses and energies to
:data:`AGREEMENT`; a plan that disagrees is dropped for the Python solve, with the reason.  A
study's later runs (their own scenes, so their own contacts and plans) take the compiled plan of an
equal contact, cut and rows on the same model, checked already.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..model import compiled
from ..model.configuration import Configuration
from .cutting import forbidden_motions

#: No impulse along the contact's normal where the denominator of Eqs. 29 and 42, J W_eff J^T (the
#: inverse of the mass the contact meets along n, its constraint rows holding), is at most this
#: fraction of the contact's reach: the largest inverse mass its relative motion meets in the tree
#: without constraint rows, the largest eigenvalue of R M^-1 R^T (:func:`reach`; R the rows of the
#: contact's relative motion in the tree: a point contact's two rows of p_b' - p_a', a joint stop's
#: own row).  A row in the span of the constraint rows (a stop on a driven joint) has J W_eff J^T =
#: 0 up to a round-off of some 1e-16 of J M^-1 J^T; a normal orthogonal to every motion of the points
#: has J (and J W_eff J^T) 0 up to some 1e-16 of R (1e-32 of the reach).  Both are refused; a contact
#: is taken while the part of its row that moves is more than 1e-7 of the row (its square 1e-14).  The
#: rule compares the row with what the row itself reaches, never with the tree's other inertias:
#: the earlier rule, a fraction of tr(W_eff), refused a stop on a link carrying a pinned link of
#: inertia 1e-16 kg m^2 (tr(W_eff) ~ 1e16 from that link alone), whose impulse is well defined.
#: One rule for the Python solve (pcmm.events.impulse, which imports it from here) and the compiled
#: one (pcmm/model/_impulse.hpp takes it when its plan is built, and hands such a contact back to the
#: Python solve for the message).
NO_IMPULSE = 1e-14


def reach(K: np.ndarray) -> float:
    """The largest eigenvalue of the 1 x 1 or 2 x 2 symmetric ``K = R M^-1 R^T`` (a closed form: the
    same operations as pcmm/model/_impulse.hpp's)."""
    if K.shape[0] == 1:
        return float(K[0, 0])
    a, b, c = float(K[0, 0]), 0.5 * (float(K[0, 1]) + float(K[1, 0])), float(K[1, 1])
    return 0.5 * (a + c) + math.hypot(0.5 * (a - c), b)


def takes_no_impulse(d: float, reach_: float) -> bool:
    """Whether a contact whose denominator (Eqs. 29, 42) is ``d`` and whose :func:`reach` is
    ``reach_`` takes no impulse along its normal (:data:`NO_IMPULSE`)."""
    return not (math.isfinite(d) and d > NO_IMPULSE * reach_)

#: |compiled - Python| <= AGREEMENT * (1 + scale) at the first impact of each plan, scale the
#: largest magnitude of the quantity's kind (velocities, impulses, energies)
AGREEMENT = 1e-9


@dataclass
class CompiledImpulse:
    """A contact's compiled plan and the names its results are read with."""

    plan: object  # pcmm.model._tree_dynamics.ImpulsePlan
    row_labels: tuple[str, ...]  # the constraint rows' labels, in the plan's order: all of cfg.coords.labels
    cut_names: tuple[str, ...]  # the tree joints cut, in the plan's order
    joint_names: tuple[str, ...]  # every joint of the tree, in Pinocchio's order (RNEA's rows)
    loop_cuts: tuple = ()  # the loop cut joints' specs, in the order of the plan's pairs (their impulses)
    checked: bool = False  # agreed with the Python solve at an impact


def compiled_impulse(cfg: Configuration, plan) -> CompiledImpulse | None:
    """The compiled plan of ``plan`` (an :class:`pcmm.events.impulse._Plan` of ``cfg``), built on
    first use and kept with the configuration's event-path constants; None: the Python solve
    (:func:`reason` says why)."""
    kept = cfg.impulse_models
    key = ("compiled", id(plan))
    held = kept.get(key)
    if held is None or held[0] is not plan:  # the plan is held: its id stays its own
        labels = tuple(cfg.coords.labels)
        # the next run of a study makes its own plans (its scene's contacts): it takes the compiled
        # plan of an equal contact and cut on this model, checked already, instead of a new one
        same = _by_value(plan, labels)
        fast, why = kept.get(same) or _build(cfg, plan)
        if fast is not None or compiled.enabled():  # not a PCMM_COMPILED=0 of the moment
            kept[same] = (fast, why)
        held = kept[key] = [plan, fast, why, labels]
    if held[1] is not None and not compiled.enabled():  # PCMM_COMPILED=0 set since it was built
        return None
    return held[1]


def refuse(cfg: Configuration, plan, why: str) -> None:
    """Drop ``plan``'s compiled solve for the Python one (it disagreed with it), saying why."""
    labels = tuple(cfg.coords.labels)
    cfg.impulse_models[("compiled", id(plan))] = [plan, None, why, labels]
    cfg.impulse_models[_by_value(plan, labels)] = (None, why)


def _by_value(plan, labels: tuple) -> tuple:
    """The key of ``plan``'s compiled solve by what it is made of: the contact and cut joints (by
    value) and the configuration's rows, on the model whose event-path constants hold it."""
    return ("compiled by value", plan.contact, plan.cut_joints, plan.cut_loops, labels)


def reason(cfg: Configuration, plan) -> str | None:
    """Why ``plan`` runs the Python solve (None: compiled, or not asked yet)."""
    if not compiled.enabled():
        return compiled.why_not()
    held = cfg.impulse_models.get(("compiled", id(plan)))
    return None if held is None or held[0] is not plan else held[2]


def reasons(cfg: Configuration) -> dict[str, str]:
    """Every impulse plan of ``cfg`` asked so far: {"contact (cut joints)": "compiled", "compiled,
    not yet checked", or why the Python solve runs it} (a debugging aid).  The model's event-path
    constants are shared by the configurations built on it: only the plans of ``cfg``'s rows."""
    out = {}
    labels = tuple(cfg.coords.labels)
    for key, held in cfg.impulse_models.items():
        if not (isinstance(key, tuple) and key and key[0] == "compiled") or held[3] != labels:
            continue
        plan, fast, why, _ = held
        c = plan.contact
        where = f"joint stop {c.joint}" if c.joint is not None else f"contact {c.a}/{c.b}"
        what = ("compiled" if fast.checked else "compiled, not yet checked") if fast is not None else why
        out[f"{where} (cut {', '.join(plan.cut_joints + plan.cut_loops) or 'none'})"] = what
    return out


def _build(cfg: Configuration, plan) -> tuple[CompiledImpulse | None, str | None]:
    if not compiled.enabled():
        return None, compiled.why_not()
    contact = plan.contact
    if plan.frictional:
        return None, "a frictional point contact (Routh's process) is solved in Python"
    if cfg.has_planar:
        return None, "a planar joint (nq != nv) in the tree: solved in Python"
    labels = tuple(cfg.coords.labels)
    loop_cuts = cfg.coords.cut_joint_frames() if getattr(cfg.coords, "constrained", False) else ()
    if any(s.type != "revolute" for s, _, _ in loop_cuts):
        return None, "prismatic or weld loop cut joints: solved in Python"
    loop_labels = tuple(lab for s, _, _ in loop_cuts for lab in (f"{s.name}.fx", f"{s.name}.fy"))
    if labels[:len(loop_labels)] != loop_labels or any(not lab.endswith(".drive") for lab in labels[len(loop_labels):]):
        return None, f"constraint rows {list(labels)}: not the loops' then the drives' rows; solved in Python"
    drives = tuple(lab[:-len(".drive")] for lab in labels[len(loop_labels):])
    if set(drives) & set(plan.cut_joints):
        return None, "a driven joint is cut: solved in Python"
    if any(cfg.spec.info.joints[j].type == "prismatic" for j in drives):  # its impulse's axis is read from the pose
        return None, "a prismatic drive: solved in Python"
    model = cfg.model
    cuts = []
    for name in plan.cut_joints:
        N = forbidden_motions(model, cfg.joint_id[name])
        if N is None:
            return None, f"cut joint {name!r}: its forbidden motions depend on the pose; solved in Python"
        cuts.append((cfg.joint_id[name], np.ascontiguousarray(N)))
    frames = [plan.frame_a, plan.frame_b]
    if plan.stop:
        kind = 1 if plan.prismatic else 0
        stop_v = cfg.joint_slice[contact.joint].start
        vec = np.asarray(cfg.spec.info.joints[contact.joint].axis, float) if plan.prismatic else np.zeros(3)
        pa = pb = None
    else:
        kind, stop_v = 2, 0
        pa = cfg.point(contact.a, contact.point_a).frame_id
        pb = cfg.point(contact.b, contact.point_b).frame_id
        frames += [pa, pb]
        vec = np.array([float(contact.normal[0]), float(contact.normal[1]), 0.0])
    if vec.shape != (3,):
        return None, f"the contact's axis {vec.tolist()} is not three numbers: solved in Python"
    built = compiled.impulse_tree(model, frames, [(fa, fb) for _, fa, fb in loop_cuts])
    if built is None:
        return None, compiled.why_not()
    tree, index, _ = built
    try:
        fast = compiled._tree_dynamics.ImpulsePlan(
            tree, kind, stop_v, float(contact.stop_sign) if plan.stop else 1.0,
            float(contact.arm or 0.0) if plan.stop else 0.0, vec, index[plan.frame_a], index[plan.frame_b],
            index[pa] if pa is not None else 0, index[pb] if pb is not None else 0,
            [cfg.joint_slice[j].start for j in drives], cuts, NO_IMPULSE)
    except (TypeError, ValueError) as exc:
        return None, f"the compiled impulse plan could not be built: {exc}"
    return CompiledImpulse(fast, labels, tuple(plan.cut_joints), tuple(cfg.joint_names),
                           tuple(s for s, _, _ in loop_cuts)), None


def disagreement(fast, reference) -> str | None:
    """Where the compiled impulse ``fast`` and the Python solve's ``reference`` (two
    :class:`pcmm.events.impulse.Impulse`) differ beyond round-off, else None."""
    def far(what, a, b, scale):
        a, b = np.asarray(a, float), np.asarray(b, float)
        if a.shape != b.shape:
            return f"{what}: shape {a.shape} against {b.shape}"
        if not np.all(np.abs(a - b) <= AGREEMENT * (1.0 + scale)):
            return f"{what} by {float(np.max(np.abs(a - b))):.3g}"
        return None
    v_scale = float(np.max(np.abs(np.concatenate([reference.v_before, reference.v_after]))))
    p_scale = max([abs(reference.P)] + [abs(x) for f in reference.joint_impulses.values() for x in f])
    e_scale = max(abs(reference.ke_before), abs(reference.ke_after))
    checks = [("v_after", fast.v_after, reference.v_after, v_scale),
              ("the normal impulse", fast.P, reference.P, p_scale),
              ("the normal", fast.normal, reference.normal, 1.0),
              ("the contact point", fast.point, reference.point, float(np.max(np.abs(reference.point)))),
              ("the kinetic energies", [fast.ke_before, fast.ke_after, fast.drive_work],
               [reference.ke_before, reference.ke_after, reference.drive_work], e_scale),
              ("the normal velocities", [fast.vn_before, fast.vn_after], [reference.vn_before, reference.vn_after],
               v_scale)]
    for group in ("joint_impulses", "cut_impulses", "constraint_impulses", "constraint_rows"):
        a, b = getattr(fast, group), getattr(reference, group)
        if a.keys() != b.keys():
            return f"{group}: {sorted(a)} against {sorted(b)}"
        checks += [(f"{group}[{k!r}]", a[k], b[k], p_scale) for k in b]
    checks.append(("rnea_residual", fast.rnea_residual, reference.rnea_residual, p_scale))
    for what, a, b, scale in checks:
        found = far(what, a, b, scale)
        if found:
            return f"the compiled impulse disagrees with the Python solve: {found}"
    return None
