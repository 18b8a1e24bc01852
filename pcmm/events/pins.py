"""A struck point pinned where it lands (issue 24, items 2 and 3): the ``pin`` transition.

A point of link b strikes the frame (the transition's point contact) and stays there: the run
continues in the target configuration, whose revolute cut joint ``point_a = "entry"`` holds b's
point at the place of the strike (its anchor, set now: :meth:`ClosureRows.set_anchors`).  The
strike is plastic and does not slip.

**The impulse is solved with every constraint of the target at once** (the paper's Eqs. 29/42 with
the target's constraint Jacobian, not one normal followed by a projection): with M the tree's mass
matrix (the target has the same tree), A the target's rows (its cut joints, the new anchored one
among them, and its drives) and the rows of the unilateral contacts kept closed,

    M (v+ - v-) = A^T lam,   A v+ = b   (b = 0 for a cut joint, f'(t) for a drive),

so ``lam = (A M^-1 A^T)^-1 (b - A v-)`` and ``v+ = v- + M^-1 A^T lam``; ``lam`` of a revolute cut
joint is its impulse on b (world x, y).

**Simultaneous contacts.**  Every cut joint of the source held by compression only (a ``contact``
with a normal) and absent from the target is a closed unilateral contact at the strike.  Each is
either kept (its normal impulse P_n >= 0, its normal velocity after 0) or released (no impulse,
normal velocity after >= 0): a complementarity problem, solved exactly by enumerating the 2^k
active sets (k is small) and keeping those that satisfy every inequality.  Exactly one must; none
or several stop the run with a message.  The old foot of a rimless wheel leaves *because* the new
foot's impulse separates it: holding it too would need a tensile impulse (design_24.md section 2.3).
A kept contact must be in the target (else the scene's ``to`` is wrong, and the message says so).

**Double support.**  A point held by compression only in the source *and* in the target (the other
foot of a walker that lands) is in the same complementarity: held (its cut joint's rows kept, its
normal impulse n . lam >= 0) or lifted (its rows left out, its normal velocity after >= 0).  Where
the strike lifts it (holding it would pull: a walker's trailing foot), the run enters the target's
configuration without its cut joint (:meth:`~pcmm.scene.spec.SceneSpec.lift_off_target`, as a
force lift-off does), solved again from there; without one it stops and says which to add.
A bounce, a merge or contacts struck at once (pcmm.events.transitions) that would pull such a point
stop the run instead, naming it (:func:`check_held_points_push`): their solves do not release it.
(tests/test_double_support.py: a compass walker, against the momentum balances by hand.)

The new pin's impulse (P_t, P_n) along the contact's tangent t = (n_y, -n_x) and normal must lie in
its friction cone when a finite ``friction`` is given, else the strike would slip (the message gives
the friction it needs, |P_t| / P_n).  Where the target's rows are redundant (a pin on a pendulum: two
rows for one coordinate) the velocity after is unique but the impulse's split among the rows is not:
the cone is then tested over every split (:func:`_inside_cone`), not over the minimum-norm one, and
a target that cannot hold the rows at all is refused by its entry ("the cut joints are redundant").
"""
from __future__ import annotations

import itertools
import math

import numpy as np

from ..errors import SimulationError
from ..model.configuration import Configuration
from ..model.pinocchio_helpers import frame_jacobian
from ..scene.spec import PinSpec
from .contact import contact_state
from .entry import enter
from .friction import AmbiguousImpact, routh
from .momentum import check_struck_point_momentum, struck_point_only
from .records import event_record
from .impulse import Impulse, _inverse_mass, constraint_impulses, joint_impulses, loop_point_impulses, tangent_of

SIGN_TOL = 1e-10  # relative: an impulse or a normal speed this small (x the scale) counts as zero


def _rows_of(cfg: Configuration, spec, k: int):
    """(world normal n, J_rel (2 x nv)) of the source's cut joint ``spec`` (index k) at the current
    kinematics: b's point relative to a's."""
    cl = cfg.coords.closure
    Jb = frame_jacobian(cfg.model, cfg.data, cl.frames_b[k])[:2]
    Ja = frame_jacobian(cfg.model, cfg.data, cl.frames_a[k])[:2]
    n = cfg.data.oMf[cl.links_a[k]].rotation[:2, :2] @ np.asarray(spec.normal, float)
    return n / np.linalg.norm(n), Jb - Ja


def _point_rows(cfg: Configuration, q, contact) -> np.ndarray:
    """J_b - J_a (2 x nv, world x, y) of the contact's two points at ``q``."""
    cfg.kinematics(q)
    pa, pb = cfg.point(contact.a, contact.point_a), cfg.point(contact.b, contact.point_b)
    return cfg.point_jacobian(pb) - cfg.point_jacobian(pa)


def closed_unilateral(cfg: Configuration, dst: Configuration):
    """The source's cut joints held by compression only that the target does not have:
    [(spec, world normal, normal row)] at the current kinematics of ``cfg``."""
    if not getattr(cfg.coords, "constrained", False):
        return []
    kept = {s.name for s in (dst.spec.cut_joints if dst is not None else ())}
    out = []
    for k, s in enumerate(cfg.coords.closure.specs):
        if s.normal is not None and s.name not in kept:
            n, J = _rows_of(cfg, s, k)
            out.append((s, n, n @ J))
    return out


def held_in_both(cfg: Configuration, dst: Configuration, struck: str):
    """The source's cut joints held by compression only that the target holds too (a foot in
    double support), but the struck one: [(spec, world normal, normal row)] at the current
    kinematics of ``cfg``.  Holding one through the strike must take a compressive impulse."""
    if not getattr(cfg.coords, "constrained", False):
        return []
    also = {s.name for s in (dst.spec.cut_joints if dst is not None else ()) if s.normal is not None} - {struck}
    out = []
    for k, s in enumerate(cfg.coords.closure.specs):
        if s.normal is not None and s.name in also:
            n, J = _rows_of(cfg, s, k)
            out.append((s, n, n @ J))
    return out


def check_held_points_push(cfg: Configuration, q, imp: Impulse, where: str) -> None:
    """An impact of ``cfg`` (a bounce, a merge, contacts at once) must not pull a point ``cfg``
    holds by compression only (a cut joint with a contact normal): such a point would leave the
    surface in the same impact, which only a pin strike resolves (:func:`pin_strike`).  Raises
    naming the point and its impulse instead of applying a tensile one."""
    if not getattr(cfg.coords, "constrained", False) or not imp.constraint_impulses:
        return
    closure = cfg.coords.closure
    if all(s.normal is None for s in closure.specs):  # no point held by compression only (drives alone, say)
        return
    cfg.kinematics(q)
    forces = [imp.constraint_impulses.get(s.name) for s in closure.specs]
    scale = max([abs(imp.P)] + [float(np.hypot(F[0], F[1])) for F in forces if F is not None])
    for k, (s, F) in enumerate(zip(closure.specs, forces)):
        if s.normal is None or F is None:
            continue
        n = cfg.data.oMf[closure.links_a[k]].rotation[:2, :2] @ np.asarray(s.normal, float)
        P = float(n @ np.asarray(F[:2], float)) / float(np.linalg.norm(n))
        if P < -SIGN_TOL * scale:
            raise SimulationError(f"{where}: the impact would pull the point held by '{s.name}' (normal impulse "
                                  f"{P:.6g} N s; it is held by compression only), so the point would leave the "
                                  "surface in this impact; pcmm releases a held point within an impact only at a "
                                  "pin strike, not at a bounce or a merge, and does not apply a tensile impulse to "
                                  f"it (a cut joint '{s.name}' without a contact normal may pull)")


def _released_target(scene, target: str, lifted: list[str]) -> str | None:
    """The configuration like ``target`` without the cut joints ``lifted`` (the one each lifts off
    into by itself, :meth:`~pcmm.scene.spec.SceneSpec.lift_off_target`), or None."""
    for name in lifted:
        target = scene.lift_off_target(target, name)
        if target is None:
            return None
    return target


def anchor_where_entered(dst: Configuration, q: np.ndarray) -> dict[str, np.ndarray]:
    """Anchor every cut joint of ``dst`` anchored at entry where b's point is at ``q`` (what a pin
    into ``dst`` does; for checks that enter ``dst`` at a guard's posture)."""
    if not getattr(dst.coords, "constrained", False) or not dst.coords.closure.anchored:
        return {}
    dst.kinematics(q)
    return dst.coords.closure.set_anchors(dst.data)


def impact_with_rows(M: np.ndarray, name: str, v: np.ndarray, A: np.ndarray, b: np.ndarray):
    """(v+, lam, redundant) of ``M (v+ - v-) = A^T lam``, ``A v+ = b`` (the Schur complement; a
    redundant set of rows gets the minimum-norm multipliers, the velocity is unique either way, and
    ``redundant`` says the split of the impulse among the rows is not)."""
    W = _inverse_mass(M, name)  # M^-1 by its Cholesky factor
    if A.shape[0] == 0:
        return v.copy(), np.zeros(0)
    S = A @ W @ A.T
    lam, _, rank, _ = np.linalg.lstsq(S, b - A @ v, rcond=1e-13)
    return v + W @ A.T @ lam, lam, rank < A.shape[0]


def _free_splits(A: np.ndarray, i: int) -> np.ndarray:
    """The directions (2 x r) in which the impulse of the pin whose rows are ``i, i + 1`` of ``A``
    may change without changing the velocity after: its rows of a basis of the null space of A^T
    (``M (v+ - v-) = A^T lam`` fixes lam only up to that space when the rows are redundant)."""
    U, sv, _ = np.linalg.svd(A)
    rank = int(np.sum(sv > 1e-13 * max(sv.max(initial=0.0), 1e-300)))
    return U[i:i + 2, rank:]


def _inside_cone(F: np.ndarray, K: np.ndarray, n: np.ndarray, tang: np.ndarray, mu: float) -> bool:
    """Whether some impulse F + K z (z free) lies in the friction cone |t . F| <= mu n . F: two
    half-spaces g_k . z <= c_k, which meet unless g_2 = -alpha g_1 (alpha > 0) with c_1 + c_2 / alpha < 0
    (or a zero g_k with c_k < 0). K with no columns: F itself, the impulse being unique."""
    tol = 1e-12 * max(float(np.linalg.norm(F)), 1e-300)
    kt, kn = tang @ K, n @ K
    Ft, Fn = float(tang @ F), float(n @ F)
    g = [kt - mu * kn, -kt - mu * kn]
    c = [mu * Fn - Ft + tol, mu * Fn + Ft + tol]
    scale = max(float(np.abs(K).max(initial=0.0)), 1e-300)
    zero = [float(np.linalg.norm(gk)) <= 1e-12 * scale for gk in g]
    if any(z and ck < 0 for z, ck in zip(zero, c)):
        return False
    if any(zero):
        return True
    cross = g[0] @ g[1] / (np.linalg.norm(g[0]) * np.linalg.norm(g[1]))
    if cross > -1 + 1e-12:  # not anti-parallel: the half-spaces meet
        return True
    alpha = float(np.linalg.norm(g[1]) / np.linalg.norm(g[0]))
    return c[0] + c[1] / alpha >= 0


def strike_works(M: np.ndarray, name: str, v: np.ndarray, A: np.ndarray, b: np.ndarray, J_c: np.ndarray,
                 P: tuple[float, float], mu: float) -> dict:
    """What the normal and the tangential part of a pin's strike did: Routh's process
    (:func:`pcmm.events.friction.routh`, e = 0; mu infinite: its limit
    :func:`~pcmm.events.friction.stuck_at_once`, as for a stop with no slip) at the struck
    point, whose rows ``J_c`` = [t; n] give the 2 x 2 Delassus matrix D = J_c W_eff J_c^T, W_eff the
    inverse inertia with the other rows ``A`` of the solve held (``A v = b``).  Where Routh's process
    ends at the pin's own impulse ``P`` (P_t, P_n), its exact per-phase works are the energy lost to
    each part (friction's >= 0: it only dissipates).  Where it does not (it ends sliding, a Painleve
    case, the point's rows redundant with the others), there is no such split: only the phases and why."""
    W = _inverse_mass(M, name)
    if A.shape[0]:
        S = A @ W @ A.T
        v = v + W @ A.T @ np.linalg.lstsq(S, b - A @ v, rcond=1e-13)[0]
        W = W - W @ A.T @ np.linalg.pinv(S, rcond=1e-13) @ A @ W
    D = J_c @ W @ J_c.T
    D = 0.5 * (D + D.T)
    vt, vn = (float(x) for x in J_c @ v)
    P = np.asarray(P, float)
    why = None
    if np.linalg.cond(D) > 1e12:
        why = "the struck point's rows are redundant with the other constraints (its Delassus matrix is singular)"
    else:
        try:
            fr = routh(D, vt, vn, mu, 0.0)
        except (AmbiguousImpact, ValueError) as exc:
            why = f"Routh's process has no answer here ({exc})"
        else:
            if fr.no_split is not None:  # no slip, whose process has no answer here
                why = fr.no_split
            elif np.abs(fr.P - P).max() <= 1e-9 * max(float(np.abs(P).max()), 1e-300):
                return {"phases": fr.phase_text,
                        "energy_lost": {"normal": -fr.work_normal, "tangential": -fr.work_tangential}}
            else:
                why = (f"Routh's process from this state ends elsewhere (phases {fr.phase_text}, impulse "
                       f"({fr.P_t:.6g}, {fr.P_n:.6g}) N s, slip after {fr.slip_after:.6g} m/s): the pin holds the "
                       "point where Coulomb's law would not")
    return {"phases": "stick", "energy_lost": None, "energy_split": f"none: {why}"}


def _no_outcome_text(where, cfg: Configuration, tr: PinSpec, struck: str, q, v, n, tang, vn: float,
                     closed: list[str], found: int, tried: list[str], F: np.ndarray) -> list[str]:
    """The refusal of a strike with no consistent outcome (or several): the struck point, how it
    arrives (normal and tangential speeds), and the impulse a pin would need.  ``F`` is the pin's
    impulse with every closed contact held (the last active set tried), on b, world axes."""
    vt = float(tang @ _point_rows(cfg, q, tr.contact) @ v)
    c = tr.contact
    point = f"{c.b}'s point {list(c.point_b)} (the cut joint '{struck}')"
    arrives = (f"it arrives with normal velocity {vn:.6g} m/s and tangential velocity {vt:.6g} m/s "
               f"(along t = ({tang[0] + 0.0:.6g}, {tang[1] + 0.0:.6g}))")
    P_n, P_t = float(n @ F), float(tang @ F)
    if not closed and not found:
        return [f"{where}: {point} cannot be pinned where it strikes {c.a}: {arrives}, and holding it there "
                f"would need the normal impulse {P_n:.6g} N s (tangential {P_t:.6g} N s): {c.a} would pull "
                f"on {c.b}, which a contact cannot. A pin holds a point only where its strike presses it onto the "
                "surface; this strike is too oblique for that (the point would slide or leave): model it as a "
                "`stop` (a bounce, with friction) or change the approach"]
    head = (f"{where}: the strike of {point} on {c.a} ({arrives}) with the closed contacts {closed} has "
            + (f"no consistent outcome: each way of keeping or releasing them needs a contact to pull or to "
               f"sink, as listed (a 'kept' or 'held' point's normal impulse, and the new pin's, must be >= 0; a "
               f"'released' or 'lifted' one's normal velocity after must be >= 0):" if not found else
               f"{found} consistent outcomes (the rigid-body impact is ambiguous here); each way of keeping or "
               "releasing them:"))
    return [head] + tried


def pin_strike(ctx, cfg: Configuration, tr: PinSpec, t, q, v, target: str | None = None):
    """Pin b's point where it strikes, with every constraint of the target at once (module text):
    (target, q, v, event) of the run's outcome.  ``target``: the configuration entered, when not the
    transition's own (the one without the points the strike lifts, :func:`_released_target`)."""
    target = target or tr.target
    where = f"t = {t:.9g} s, transition '{tr.name}'"
    dst = ctx.mechanism.enter(target, cfg, q)
    if list(dst.joint_names) != list(cfg.joint_names):
        raise SimulationError(f"{where}: a pin keeps the tree and adds a cut joint, but '{target}' has the "
                              f"joints {list(dst.joint_names)} and '{cfg.name}' {list(cfg.joint_names)}: give both "
                              "configurations the same URDF")
    n, _, vn, Jn = contact_state(cfg, q, v, tr.contact)
    scale = max(1.0, float(np.max(np.abs(v)))) if v.size else 1.0
    if vn >= 0:
        raise SimulationError(f"{where}: the guard fired but b's point does not approach the surface "
                              f"(normal velocity {vn:.3g} m/s): the normal must point from link a towards link b")
    pb = cfg.point_position(cfg.point(tr.contact.b, tr.contact.point_b))
    tang = tangent_of(n)
    unilateral = closed_unilateral(cfg, dst)
    # the target's anchors: the struck cut joint at b's point now; those the source also holds stay put
    struck = [s for s in dst.spec.cut_joints if s.anchor_at_entry and s.b == tr.contact.b
              and tuple(s.point_b) == tuple(tr.contact.point_b)][0]
    keep = {}
    if getattr(cfg.coords, "constrained", False):
        for k, s in enumerate(cfg.coords.closure.specs):
            if k in cfg.coords.closure.anchors and s.name != struck.name:
                keep[s.name] = cfg.coords.closure.anchors[k]
    dst.kinematics(q, v)
    anchors = dst.coords.closure.set_anchors(dst.data, keep) if getattr(dst.coords, "constrained", False) else {}
    A_dst = dst.coords.equality(t, dst.model, dst.data)
    b_dst = np.zeros(A_dst.shape[0])
    if dst.coords.drives.size:
        b_dst[dst.coords.closure.size:] = dst.coords.drives.values(t)[1]
    M = cfg.mass_matrix(q)
    labels = dst.coords.labels
    row_of = {lab: i for i, lab in enumerate(labels)}
    i_struck = row_of[f"{struck.name}.fx"]
    both = held_in_both(cfg, dst, struck.name)
    solutions, tried = [], []
    for held in itertools.product((False, True), repeat=len(unilateral) + len(both)):
        held_u, held_b = held[:len(unilateral)], held[len(unilateral):]
        # a point held in both configurations and lifted by the strike: its cut joint's rows left out
        kept = [i for i in range(A_dst.shape[0]) if not any(
            not h and labels[i] in (f"{s.name}.fx", f"{s.name}.fy") for (s, _, _), h in zip(both, held_b))]
        rows = [u[2] for u, h in zip(unilateral, held_u) if h]
        A = np.vstack([A_dst[kept]] + [r[None, :] for r in rows])
        b = np.concatenate([b_dst[kept], np.zeros(len(rows))])
        v_plus, lam_kept, redundant = impact_with_rows(M, cfg.name, v, A, b)
        lam = np.zeros(A_dst.shape[0])  # the target's rows' multipliers (zero on a lifted point's)
        lam[kept] = lam_kept[:len(kept)]
        lam_u = iter(lam_kept[len(kept):])
        text, ok = [], True
        for (s, _, row), h in zip(unilateral, held_u):
            if h:
                P = float(next(lam_u))
                ok &= P >= -SIGN_TOL * scale
                text.append(f"{s.name} kept (normal impulse {P:.6g} N s)")
            else:
                vn_after = float(row @ v_plus)
                ok &= vn_after >= -SIGN_TOL * scale
                text.append(f"{s.name} released (normal velocity after {vn_after:.6g} m/s)")
        for (s, nu, row), h in zip(both, held_b):
            if h:
                P = float(nu @ lam[row_of[f"{s.name}.fx"]:row_of[f"{s.name}.fx"] + 2])
                ok &= P >= -SIGN_TOL * scale
                text.append(f"{s.name} held (normal impulse {P:.6g} N s)")
            else:
                vn_after = float(row @ v_plus)
                ok &= vn_after >= -SIGN_TOL * scale
                text.append(f"{s.name} lifted (normal velocity after {vn_after:.6g} m/s)")
        F = lam[i_struck:i_struck + 2]
        ok &= float(n @ F) >= -SIGN_TOL * scale
        tried.append("; ".join(text + [f"the new pin's normal impulse {float(n @ F):.6g} N s"]))
        if ok:
            solutions.append((held, v_plus, lam, redundant, A, kept))
    if len(solutions) != 1:
        raise SimulationError(_no_outcome_text(where, cfg, tr, struck.name, q, v, n, tang, vn,
                                               [u[0].name for u in unilateral + both], len(solutions), tried,
                                               lam[i_struck:i_struck + 2]))
    held, v_plus, lam, redundant, A, kept = solutions[0]
    lifted = [u[0].name for u, h in zip(both, held[len(unilateral):]) if not h]
    if lifted:  # a foot in double support that the strike would pull: it leaves at the strike
        released_into = _released_target(ctx.mechanism.scene, target, lifted)
        if released_into is None:
            pulls = tried[-1]  # every point held: the impulses the target alone would apply
            raise SimulationError(f"{where}: the point(s) held by {lifted} in both '{cfg.name}' and '{target}' "
                                  f"would be pulled by the strike if held ({pulls}), so they leave the surface "
                                  f"at the strike, and the scene has no configuration to release them into: add "
                                  f"one with the same URDF and drives and the cut joints of '{target}' without "
                                  f"{' and '.join(repr(x) for x in lifted)} (pcmm releases them into it by itself)")
        return pin_strike(ctx, cfg, tr, t, q, v, target=released_into)
    stays = [u[0].name for u, h in zip(unilateral, held) if h]
    if stays:
        raise SimulationError(f"{where}: the contact(s) {stays} stay closed through the strike (their impulse is "
                              f"compressive), but '{target}' does not hold them: name a target configuration "
                              "that keeps them")
    F = lam[i_struck:i_struck + 2]
    P_n, P_t = float(n @ F), float(tang @ F)
    mu = tr.contact.friction if tr.contact.friction is not None else struck.friction
    free = _free_splits(A, kept.index(i_struck)) if redundant else np.zeros((2, 0))
    if mu is not None and not math.isinf(mu) and not _inside_cone(F, free, n, tang, mu):
        split = (f"; the constraints of '{target}' are redundant, so the impulse's split among its cut joints is "
                 "not unique, and no split puts it inside the cone" if redundant else "")
        raise SimulationError(f"{where}: the pinned point would slip: its impulse needs friction >= "
                              f"{abs(P_t) / P_n:.6g} (|P_t| / P_n, P_t = {P_t:.6g}, P_n = {P_n:.6g} N s) and the "
                              f"contact has mu = {mu:g}{split}; pcmm models no sliding contact")
    # entered like every switch: the target's constraints checked at the post-impact state (entry.enter)
    entry = enter(cfg, dst, t, q, v_plus, what=f"pin '{tr.name}'", anchored=True)
    q_new, v_new = entry.q, entry.v
    # the stance that begins now: each point held by compression only must push, inside its cone
    # (the guards of the stance watch it from here on: PartitionedCoordinates.contact_guards)
    lifting = {cj for src, cj, _ in ctx.mechanism.scene.lift_offs() if src == target}
    for name, (Fn, Ft) in dst.coords.contact_forces(t, q_new, v_new).items():
        spec = next(s for s in dst.spec.cut_joints if s.name == name)
        scale_F = max(abs(Fn), abs(Ft), 1e-300)
        if Fn < -1e-12 * scale_F and name in lifting:
            continue  # it lifts off by itself at once, before any step (pcmm.run.loop._pending)
        if Fn < -1e-12 * scale_F:
            raise SimulationError(f"{where}: right after the strike the point held by '{name}' would be pulled "
                                  f"(normal force {Fn:.6g} N): it lifts off at once, which '{target}' cannot hold; "
                                  f"add a configuration with the same URDF and drives and the cut joints of "
                                  f"'{target}' but '{name}' (pcmm releases the point into it by itself)")
        if spec.friction is not None and math.isfinite(spec.friction) and abs(Ft) > spec.friction * Fn * (1 + 1e-12):
            raise SimulationError(f"{where}: right after the strike the point held by '{name}' would slip: its "
                                  f"force needs friction >= {abs(Ft) / Fn:.6g} (|F_t| / F_n, F_t = {Ft:.6g}, "
                                  f"F_n = {Fn:.6g} N) and the cut joint has mu = {spec.friction:g}; pcmm models no "
                                  "sliding contact")
    by_label = {lab: float(x) for lab, x in zip(labels, lam[:len(labels)])}
    ke0, ke1 = float(0.5 * v @ M @ v), float(0.5 * v_plus @ M @ v_plus)
    imp = Impulse(kind="stable", restitution=0.0, normal=n, P=P_n, vn_before=vn, vn_after=float(Jn @ v_plus),
                  v_before=v.copy(), v_after=v_plus, ke_before=ke0, ke_after=ke1, point=pb, tangent=tang, P_t=P_t)
    dst.kinematics(q)
    loop = loop_point_impulses(dst, by_label)
    imp.constraint_rows = by_label
    imp.constraint_impulses = constraint_impulses(dst, by_label, loop)
    for s, _, _ in unilateral:  # released: no impulse
        imp.constraint_impulses[s.name] = [0.0, 0.0, 0.0]
    imp.contact_impulses = [(tr.contact.b, pb, F.copy(), 0.0), (tr.contact.a, pb, -F.copy(), 0.0)]
    imp.drive_work = sum(mu_ * float(v[cfg.joint_slice[lab[:-6]]][0])
                         for lab, mu_ in by_label.items() if lab.endswith(".drive"))
    imp.joint_impulses, imp.rnea_residual = joint_impulses(cfg, q, v_plus - v, loop)
    record = event_record(cfg, tr, t, target, True, imp, "pin", q=q)
    if struck_point_only(cfg, dst, struck.name) is None:  # H about the struck point must be conserved
        check_struck_point_momentum(cfg, tr, t, q, v, v_plus, pb)
    record["tangent"] = [float(tang[0]), float(tang[1])]
    record["impulse"]["tangential"] = P_t
    record["impulse"]["vector"] = [float(F[0]), float(F[1])]
    record["anchor"] = {name: [float(x) for x in A] for name, A in anchors.items()}
    # what each part of the strike did: Routh's process at b's point from the same state (e = 0, the
    # other rows of the solve held), whose per-phase works are exact, as for a frictional stop
    J_rel = np.vstack([tang @ _point_rows(cfg, q, tr.contact), Jn])
    (vt0, _), (vt1, _) = J_rel @ v, J_rel @ v_plus
    struck_at = kept.index(i_struck)
    others = [i for i in range(A.shape[0]) if i not in (struck_at, struck_at + 1)]
    b_all = np.concatenate([b_dst[kept], np.zeros(A.shape[0] - len(kept))])
    works = strike_works(M, cfg.name, v, A[others], b_all[others], J_rel, (P_t, P_n), math.inf if mu is None else mu)
    if "ends elsewhere" in works.get("energy_split", ""):  # the pin is not Coulomb's outcome: said, not silent
        record.setdefault("warnings", []).append(
            f"{where}: the pin holds the struck point with the impulse ({P_t:.6g}, {P_n:.6g}) N s, inside the friction "
            f"cone, but Coulomb's law from this state would not stick: {works['energy_split'][len('none: '):]}; "
            "the run goes on pinned (what a pin models), and no split of the energy lost is given")
    record["friction"] = {"mu": "stick" if mu is None or math.isinf(mu) else mu, "law": "pin",
                          "phases": works.pop("phases"), "impulse": {"normal": P_n, "tangential": P_t},
                          "slip": {"before": float(vt0), "after": float(vt1)}, **works}
    released = {}
    for (s, nu, row) in unilateral:
        released[s.name] = {"normal_velocity_after": float(row @ v_plus), "impulse": 0.0}
    record["released"] = released
    if not ctx.impact and not ctx.pinned_without_impact:  # the comparison run: said once, not silent
        ctx.pinned_without_impact = True
        record.setdefault("warnings", []).append(
            f"{where}: a pin has no switch without impulse (b's point must stop where it lands), so this run "
            "without impact takes the plastic impulse at every pin, as the run with impact does: the two runs "
            "differ only through their other transitions")
    if redundant:
        record.setdefault("warnings", []).append(
            f"{where}: the constraints of '{target}' at the strike are redundant (two points pinned on one "
            "rigid body, say): the velocity after is unique, but how the impulse splits among the cut joints is "
            "not; the minimum-norm split is reported")
    return target, q_new, v_new, record
