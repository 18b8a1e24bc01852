"""Simultaneous contacts (issue 24, item 3): every point contact closed at an impact in one
complementarity solve, normal and tangential.

When a stop's guard fires, every other ``stop`` of the configuration whose point contact is
closed at that instant (its gap within the pose tolerance, whatever its normal velocity) takes
part in the same impact.  With J the contacts' rows in (t, n) pairs (t = (n_y, -n_x)), W_eff the
configuration's effective inverse inertia (its loops' and drives' rows eliminated, the paper's
Eq. 25 without a cut) and u = J v the contact velocities, the impulse P (on each b) gives

    u+ = u- + D P,   D = J W_eff J^T (the contacts' Delassus matrix),   v+ = v- + W_eff J^T P,

and each contact i is in one of its modes (Newton's restitution e_i on the normal, Coulomb's mu_i
on the tangent, the velocity-level law of Stewart and Trinkle 1996 / Anitescu and Potra 1997):

* separate: P_n = P_t = 0, and u_n+ >= -e u_n^- (taken as 0 for a contact that does not approach);
* stick:    u_n+ = -e min(u_n-, 0), u_t+ = 0, P_n >= 0, |P_t| <= mu P_n;
* slide s:  u_n+ = -e min(u_n-, 0), P_t = -s mu P_n, P_n >= 0, s u_t+ >= 0 (it slips along s t after);
* a frictionless contact holds with P_t = 0 instead of stick or slide; "stick" (mu = inf) never slides.

Newton's law per contact only: a contact with friction, restitution > 0 and ``restitution_law``
Poisson's or Stronge's (whose one-contact outcome, Routh's process, differs from Newton's) is
refused here, naming it, rather than silently given Newton's outcome.

The solve enumerates every combination of modes (4^k for k contacts: two or three contacts are
what a planar mechanism meets), solves each combination's linear equations (least squares: the
rows of two contacts on one body may be dependent) and keeps those that satisfy every
inequality.  The velocity after must be the same for all of them (else the rigid-body law is
ambiguous here and the run stops, listing them); the impulse may not be (two points sticking on
one body share their tangential impulse in any proportion): the least-norm one is reported and
the event says so.  None: the law has no solution here (a Painleve case), and the run stops.

Pinocchio 4.1's contact solvers (``PGSConstraintSolver``, ``ADMMConstraintSolver``) solve the
plastic version of this problem iteratively, to a tolerance, on three-dimensional cones built from
its constraint models; the enumeration here is exact to round-off, takes Newton's restitution per
contact and returns every solution (so it can tell an ambiguous impact), so pcmm uses it.  (The
tests check it against the modes enumerated by hand, not against those solvers.)
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from .contact_faults import POSE_TOL

SEPARATE, STICK, SLIDE_POS, SLIDE_NEG, HOLD = "separate", "stick", "slide+", "slide-", "hold"
TOL = 1e-10  # relative: a residual, an impulse or a velocity this small (x its scale) counts as zero


class NoConsistentOutcome(Exception):
    """The complementarity problem has no solution, or solutions with different velocities."""


@dataclass
class ContactsSolution:
    P: np.ndarray  # (2k,) impulses on b: (P_t, P_n) per contact
    u_after: np.ndarray  # (2k,) contact velocities after: (u_t, u_n) per contact
    modes: tuple[str, ...]  # per contact
    unique_impulse: bool  # False: other impulses give the same velocity (the least-norm one is P)
    alternatives: list  # every admissible (modes, P)


def modes_of(mu: float | None) -> tuple[str, ...]:
    if mu is None:
        return (SEPARATE, HOLD)
    if math.isinf(mu):
        return (SEPARATE, STICK)
    return (SEPARATE, STICK, SLIDE_POS, SLIDE_NEG)


def _equations(D, u, modes, e, mu):
    """(A, b) with A P = b the equalities of one combination of modes."""
    k = len(modes)
    A, b = np.zeros((2 * k, 2 * k)), np.zeros(2 * k)
    for i, m in enumerate(modes):
        it, i_n = 2 * i, 2 * i + 1
        target_n = -e[i] * min(u[i_n], 0.0)
        if m == SEPARATE:
            A[it, it] = A[i_n, i_n] = 1.0
            continue
        A[i_n], b[i_n] = D[i_n], target_n - u[i_n]  # u_n+ = target
        if m == STICK:
            A[it], b[it] = D[it], -u[it]  # u_t+ = 0
        elif m == HOLD:
            A[it, it] = 1.0  # P_t = 0
        else:
            s = 1.0 if m == SLIDE_POS else -1.0
            A[it, it], A[it, i_n] = 1.0, s * mu[i]  # P_t + s mu P_n = 0
    return A, b


def _admissible(modes, P, u_after, u, e, mu, tol_P, tol_u) -> bool:
    for i, m in enumerate(modes):
        Pt, Pn = P[2 * i], P[2 * i + 1]
        ut, un = u_after[2 * i], u_after[2 * i + 1]
        if m == SEPARATE:
            if un < -e[i] * min(u[2 * i + 1], 0.0) - tol_u:
                return False
            continue
        if Pn < -tol_P:
            return False
        if m == STICK and not math.isinf(mu[i]) and abs(Pt) > mu[i] * Pn + tol_P:
            return False
        if m in (SLIDE_POS, SLIDE_NEG) and (1.0 if m == SLIDE_POS else -1.0) * ut < -tol_u:
            return False
    return True


def solve_contacts(D: np.ndarray, u: np.ndarray, e, mu) -> ContactsSolution:
    """The impulse of k simultaneous contacts (module text): ``D`` (2k x 2k) and ``u`` (2k,) in
    (t, n) pairs, ``e`` and ``mu`` per contact (mu None: frictionless, inf: no slip)."""
    k = len(e)
    scale_u = max(float(np.max(np.abs(u))), 1e-300)
    scale_D = max(float(np.max(np.abs(D))), 1e-300)
    tol_u, tol_P = TOL * scale_u, TOL * scale_u / scale_D
    found = []
    for modes in itertools.product(*(modes_of(m) for m in mu)):
        A, b = _equations(D, u, modes, e, mu)
        P, _, rank, _ = np.linalg.lstsq(A, b, rcond=1e-13)
        if np.linalg.norm(A @ P - b) > TOL * max(float(np.linalg.norm(b)), scale_u):
            continue  # the equalities have no solution
        u_after = u + D @ P
        if _admissible(modes, P, u_after, u, e, mu, tol_P, tol_u):
            found.append((modes, P, u_after, rank < 2 * k))
    if not found:
        raise NoConsistentOutcome("no combination of the modes (separate, stick, slide) satisfies every contact's "
                                  "law: the rigid-body impact has no solution here (a Painleve case)")
    ref = found[0][2]
    if any(np.max(np.abs(f[2] - ref)) > 1e3 * tol_u for f in found[1:]):
        raise NoConsistentOutcome("several outcomes with different velocities satisfy the contacts' laws ("
                                  + "; ".join(f"{', '.join(m)}: contact velocities after {np.round(ua, 9).tolist()}"
                                              for m, _, ua, _ in found) + "): the rigid-body impact is ambiguous here")
    modes, P, u_after, family = min(found, key=lambda f: float(np.linalg.norm(f[1])))
    # not unique: another admissible combination, or this one's equations admit a family of impulses
    unique = not family and all(np.max(np.abs(f[1] - P)) <= 1e3 * tol_P for f in found)
    return ContactsSolution(P, u_after, modes, unique, [(m, p) for m, p, _, _ in found])


# ---- the impact of a configuration's closed contacts -------------------------------------------
def joins_simultaneous(s) -> bool:
    """Can the stop ``s`` close at once with another and share its impact (:func:`closed_with`)?  A
    ``stop`` of a point contact resolved by an impulse without a cut; never a joint stop, which is
    decided by the transition alone (a bounce at a joint stop asks nothing more)."""
    return s.type == "stop" and s.contact is not None and s.contact.joint is None and not s.cut \
        and getattr(s, "law", "impulse") == "impulse"


def closed_with(cfg, tr, q) -> list:
    """The other ``stop`` transitions of ``cfg`` whose point contact is closed at ``q`` (gap within
    the pose tolerance) and that an impulse resolves without a cut: they take part in the impact
    of ``tr`` (itself such a stop).  Empty when ``tr`` is not one (:func:`joins_simultaneous`),
    answered from the transition alone."""
    if not joins_simultaneous(tr):
        return []
    others = [s for s in cfg.scene.transitions_from(cfg.name) if s is not tr and joins_simultaneous(s)]
    if not others:
        return []
    cfg.kinematics(q)  # once: the gaps n . (p_b - p_a) read the placements
    out = []
    for other in others:
        c = other.contact
        n = cfg.rotation(c.a) @ np.asarray(c.normal, float)
        gap = float(n @ (cfg.point_position(cfg.point(c.b, c.point_b)) - cfg.point_position(cfg.point(c.a, c.point_a))))
        if abs(gap) <= POSE_TOL * float(np.linalg.norm(n)):
            out.append(other)
    return out


def simultaneous_impact(cfg, trs: list, t, q, v):
    """The impact of the stops ``trs`` (the one that fired first) closed at once: one solve
    (:func:`solve_contacts`).  Returns (Impulse of ``trs[0]`` with every contact's effect, the
    record's ``simultaneous`` block {transition: its contact's outcome}, warnings)."""
    from ..errors import SimulationError
    from .contact import contact_point, contact_state, impact_kind
    from .impulse import Impulse, _inverse_mass, constraint_impulses, joint_impulses, loop_point_impulses, tangent_of

    where = f"t = {t:.9g} s, transitions {', '.join(repr(s.name) for s in trs)} (contacts closed at once)"
    rows, normals, points = [], [], []
    for s in trs:
        n, _, _, _ = contact_state(cfg, q, v, s.contact)
        pa, pb = cfg.point(s.contact.a, s.contact.point_a), cfg.point(s.contact.b, s.contact.point_b)
        J_rel = cfg.point_jacobian(pb) - cfg.point_jacobian(pa)
        rows += [tangent_of(n) @ J_rel, n @ J_rel]
        normals.append(n)
        points.append((cfg.point_position(pa), cfg.point_position(pb)))
    J = np.vstack(rows)
    cfg.kinematics(q, v)
    M = cfg.mass_matrix(q)
    W = _inverse_mass(M, cfg.name)  # M^-1 by its Cholesky factor
    G = cfg.coords.equality(t, cfg.model, cfg.data)
    if G.shape[0]:
        WGt = W @ G.T
        S = G @ WGt
        W_eff = W - WGt @ np.linalg.lstsq(S, WGt.T, rcond=1e-13)[0]  # Eq. 25, no joint cut
    else:
        W_eff = W
    D, u = J @ W_eff @ J.T, J @ v
    e = [float(s.restitution) for s in trs]
    mu = [s.contact.friction for s in trs]
    other_law = [s for s, ei, mi in zip(trs, e, mu) if s.contact.restitution_law != "newton" and ei > 0
                 and mi is not None and mi > 0]
    if other_law:  # the laws differ only with friction and e > 0 (one contact: Routh's process, friction.py)
        raise SimulationError(
            f"{where}: the contacts closed at once are solved with Newton's restitution per contact (the velocity-level "
            "law, module pcmm.events.simultaneous), but "
            + ", ".join(f"'{s.name}' names restitution_law = \"{s.contact.restitution_law}\"" for s in other_law)
            + " with friction and restitution > 0, whose outcome differs from Newton's and has no simultaneous "
            "form here; use restitution_law = \"newton\" for these contacts, or move them so that they do not "
            "close at the same instant")
    try:
        sol = solve_contacts(D, u, e, mu)
    except NoConsistentOutcome as exc:
        raise SimulationError(f"{where}: {exc}") from None
    P = sol.P
    v_after = v + W_eff @ J.T @ P
    ke0, ke1 = float(0.5 * v @ M @ v), float(0.5 * v_after @ M @ v_after)
    mult = -np.linalg.lstsq(S, G @ W @ J.T @ P, rcond=1e-13)[0] if G.shape[0] else np.zeros(0)
    by_label = {lab: float(x) for lab, x in zip(cfg.coords.labels, mult)}
    drive_work = sum(m * float(v[cfg.joint_slice[lab[:-6]]][0]) for lab, m in by_label.items() if lab.endswith(".drive"))
    if ke1 - ke0 - drive_work > 1e-9 * max(ke0, 1e-300):
        raise SimulationError(f"{where}: the velocity-level law of the contacts ({', '.join(sol.modes)}) creates "
                              f"energy here: kinetic energy {ke0:.9g} -> {ke1:.9g} J; give smaller restitutions")
    block, point_impulses = {}, []
    for i, s in enumerate(trs):
        n, tang = normals[i], tangent_of(normals[i])
        F = P[2 * i + 1] * n + P[2 * i] * tang
        pos_a, pos_b = points[i]
        point_impulses += [(s.contact.b, pos_b, F, 0.0), (s.contact.a, pos_a, -F, 0.0)]
        block[s.name] = {"mode": sol.modes[i], "restitution": e[i],
                         "friction": None if mu[i] is None else ("stick" if math.isinf(mu[i]) else mu[i]),
                         "impulse": {"normal": float(P[2 * i + 1]), "tangential": float(P[2 * i]),
                                     "vector": [float(F[0]), float(F[1])]},
                         "normal_velocity": {"before": float(u[2 * i + 1]), "after": float(sol.u_after[2 * i + 1])},
                         "slip": {"before": float(u[2 * i]), "after": float(sol.u_after[2 * i])},
                         "contact_point": [float(x) for x in pos_b]}
    n0 = normals[0]
    imp = Impulse(kind=impact_kind(cfg, trs[0].contact), restitution=e[0], normal=n0, P=float(P[1]),
                  vn_before=float(u[1]), vn_after=float(sol.u_after[1]), v_before=v.copy(), v_after=v_after,
                  ke_before=ke0, ke_after=ke1, point=contact_point(cfg, trs[0].contact),
                  tangent=tangent_of(n0), P_t=float(P[0]))
    imp.drive_work = drive_work
    imp.constraint_rows = by_label
    cfg.kinematics(q)
    loop = loop_point_impulses(cfg, by_label)
    imp.constraint_impulses = constraint_impulses(cfg, by_label, loop)
    imp.contact_impulses = point_impulses[:2]
    imp.joint_impulses, imp.rnea_residual = joint_impulses(cfg, q, v_after - v, point_impulses + loop)
    warnings = [] if sol.unique_impulse else [(
        f"{where}: the velocity after is unique but the impulses are not ({len(sol.alternatives)} admissible "
        "splits, e.g. two points sticking on one body share their tangential impulse in any proportion); the "
        "least-norm split is reported")]
    return imp, block, warnings
