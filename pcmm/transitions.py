"""Configuration transformations: what happens when a guard fires.

Transition types form a registry (``TRANSITIONS``); each handler takes the
run context, the configuration, the transition and the pre-impact state, and
returns an :class:`Outcome`: the next configuration and its state, plus the
event record for the summary.

* ``latch``: the metamorphic joint locks on contact.  The impact is perfectly
  plastic in the locked direction (e = 0), then the run continues in the next
  configuration's URDF.
* ``stop``: a unilateral stop with Newton's restitution e; the configuration
  does not change and the bodies separate.  When the impacts accumulate
  (post-impact normal speed or interval below the accumulation tolerances) the
  last impact is made perfectly plastic and the bodies merge into
  ``merge_to``.

Without impact (the paper's comparison runs) a transformation switches
configuration with no impulse: surviving joints keep their velocities, locked
ones drop theirs.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .configuration import Configuration, Mechanism
from .errors import SimulationError
from .impulse import Impulse, contact_state, impact_kind, solve_impulse
from .scene import TransitionSpec

POSE_TOL = 1e-9
RESTING_FACTOR = 100.0  # a guard crossing at a separating speed below 100 x the accumulation speed is rest


@dataclass
class Context:
    mechanism: Mechanism
    impact: bool
    accumulation_speed: float
    accumulation_interval: float
    forced_speed: float | None = None  # given for the run (CLI, RunOptions): wins over every transition's
    forced_interval: float | None = None
    last_impact: dict[str, float] = field(default_factory=dict)

    def tolerances(self, tr: TransitionSpec) -> tuple[float, float]:
        """(speed, interval) for a stop: the run's explicit value, else the transition's, else the scene's."""
        def pick(forced, own, default):
            return forced if forced is not None else own if own is not None else default
        return (pick(self.forced_speed, tr.accumulation_speed, self.accumulation_speed),
                pick(self.forced_interval, tr.accumulation_interval, self.accumulation_interval))


@dataclass
class Outcome:
    configuration: str
    q: np.ndarray
    v: np.ndarray
    event: dict
    angle_offsets: dict[str, float]
    merged_from: tuple | None = None  # stop-merge: (source configuration, transition, locked joint values)


# ---- state mapping -----------------------------------------------------------------------
def switch(src: Configuration, dst: Configuration, t: float, q: np.ndarray, v: np.ndarray,
           known: dict | None = None):
    """Map (q, v) of ``src`` onto ``dst`` by joint name and check the common links' poses.

    Joints ``dst`` has and ``src`` lacks take their value from ``known`` (at rest),
    else from the links' poses.  Returns (q, v, dropped velocities {joint: v},
    angle offsets {link: 2 pi k}).
    """
    q_new = dst.neutral()
    v_new = np.zeros(dst.nv)
    missing = []
    for name in dst.joint_names:
        if name in src.joint_slice:
            q_new[dst.joint_slice[name]] = q[src.joint_slice[name]]
            v_new[dst.joint_slice[name]] = v[src.joint_slice[name]]
        elif known and name in known:
            q_new[dst.joint_slice[name]] = known[name]
        else:
            missing.append(name)
    if missing:
        q_new, v_new = _joints_from_poses(src, dst, q, v, q_new, v_new, missing)
    dropped = {n: float(v[src.joint_slice[n]][0]) for n in src.joint_names
               if n not in dst.joint_slice and src.joint_slice[n].stop - src.joint_slice[n].start == 1}
    q_new, v_new = dst.coords.project(t, q_new, v_new)
    poses_src = src.link_poses(q)
    poses_dst = dst.link_poses(q_new)
    offsets = {}
    problems = []
    for link in dst.links:
        if link not in src.link_index:
            continue
        a, b = poses_src[src.link_index[link]], poses_dst[dst.link_index[link]]
        dtheta = a[2] - b[2]
        k = np.round(dtheta / (2 * np.pi))
        dpos = np.linalg.norm(a[:2] - b[:2])
        dang = abs(dtheta - 2 * np.pi * k)
        if dpos > POSE_TOL or dang > POSE_TOL:
            problems.append(f"link '{link}' is at (x, y, theta) = ({a[0]:.9g}, {a[1]:.9g}, {a[2]:.9g}) in "
                            f"'{src.name}' ({src.spec.urdf.name}) but at ({b[0]:.9g}, {b[1]:.9g}, {b[2]:.9g}) "
                            f"in '{dst.name}' ({dst.spec.urdf.name}): position differs by {dpos:.3g} m, "
                            f"angle by {dang:.3g} rad (allowed {POSE_TOL:g})")
        offsets[link] = float(2 * np.pi * k)
    if problems:
        raise SimulationError([f"t = {t:.9g} s, switching '{src.name}' -> '{dst.name}': {p}" for p in problems]
                              + ["the two URDFs must place every shared link identically at the switch "
                                 "(check the fixed joint's origin in the merged configuration)"])
    return q_new, v_new, dropped, offsets


def _joints_from_poses(src, dst, q, v, q_new, v_new, names):
    """Values of joints that ``src`` does not have (e.g. a released latch): from the links' poses."""
    poses = src.link_poses(q)
    omega = src.A @ v
    for name in names:
        uj = dst.spec.info.joints[name]
        if uj.type != "revolute" or uj.parent not in src.link_index or uj.child not in src.link_index:
            raise SimulationError(f"switching '{src.name}' -> '{dst.name}': joint '{name}' appears and "
                                  "pcmm can only derive a new revolute joint's angle from its links' poses")
        ip, ic = src.link_index[uj.parent], src.link_index[uj.child]
        q_new[dst.joint_slice[name]] = poses[ic, 2] - poses[ip, 2] - uj.rpy[2]
        v_new[dst.joint_slice[name]] = omega[ic] - omega[ip]
    return q_new, v_new


# ---- event records -------------------------------------------------------------------
def _by_link(cfg: Configuration, v):
    return {link: float(w) for link, w in zip(cfg.links, cfg.A @ v)}


def event_dict(cfg: Configuration, tr: TransitionSpec, t, *, transition, to, restitution, merge, impact,
               P, normal, point, vn, v, ke, v_after_named=None, **extra) -> dict:
    """One event of the summary (the schema lives here only): ``vn``, ``v`` and ``ke`` are
    (before, after) pairs, velocities in ``cfg``'s coordinates; ``extra`` adds keys."""
    v_before, v_after = v
    return {
        "t": float(t), "name": tr.name, "kind": impact_kind(cfg, tr.contact), "transition": transition,
        "from": cfg.name, "to": to, "restitution": restitution, "merge": merge, "impact": impact,
        "impulse": {"normal": float(P), "vector": [float(P * c) + 0.0 for c in normal[:2]]},
        "normal": [float(normal[0]), float(normal[1])], "contact_point": [float(point[0]), float(point[1])],
        "normal_velocity": {"before": float(vn[0]), "after": float(vn[1])},
        "omega_before": _by_link(cfg, v_before), "omega_after": _by_link(cfg, v_after),
        "v_before": cfg.by_joint(v_before),
        "v_after": cfg.by_joint(v_after) if v_after_named is None else v_after_named,
        "joint_impulses": {}, "kinetic_energy_before": float(ke[0]), "kinetic_energy_after": float(ke[1]),
        **extra,
    }


def event_record(cfg: Configuration, tr: TransitionSpec, t, target, merge, imp: Impulse | None,
                 q, v_before, v_after, contact_point, transition_type=None) -> dict:
    """The event of an impact resolved by an impulse (or of a switch without impact)."""
    M = cfg.mass_matrix(q)
    ke = (float(0.5 * v_before @ M @ v_before), float(0.5 * v_after @ M @ v_after))
    common = dict(transition=transition_type or tr.type, to=target, merge=merge, point=contact_point,
                  v=(v_before, v_after), ke=ke)
    if imp is None:
        n, _, vn_b, Jn = contact_state(cfg, q, v_before, tr.contact)
        return event_dict(cfg, tr, t, restitution=None, impact=False, P=0.0, normal=n,
                          vn=(vn_b, float(Jn @ v_after)), **common)
    # A driven joint keeps its prescribed speed through the impact: its motor's impulsive
    # moment does work (mu q'), so the kinetic energy may rise by that much; what never
    # rises is KE_before + drive_work - KE_after (the energy the impact dissipates).
    drive_work = sum(mu * float(v_before[cfg.joint_slice[lab[:-6]]][0])
                     for lab, mu in imp.constraint_impulses.items() if lab.endswith(".drive"))
    return event_dict(cfg, tr, t, restitution=imp.restitution, impact=True, P=imp.P, normal=imp.normal,
                      vn=(imp.vn_before, imp.vn_after), **common,
                      joint_impulses=imp.joint_impulses, cut_impulses=imp.cut_impulses,
                      constraint_impulses=imp.constraint_impulses, drive_work=drive_work,
                      energy_dissipated=ke[0] + drive_work - ke[1])


def _contact_point(cfg, tr):
    return cfg.point_position(cfg.point(tr.contact.b, tr.contact.point_b))


def _merge(ctx: Context, cfg: Configuration, tr: TransitionSpec, target: str, t, q, v, transition_type):
    """Plastic impact (or none without impact), then switch to ``target``."""
    dst = ctx.mechanism[target]
    locked = [n for n in cfg.joint_names if n not in dst.joint_slice]
    if ctx.impact:
        imp = solve_impulse(cfg, t, q, v, tr.contact, 0.0, tr.cut)
        v_after = imp.v_after
    else:  # the paper's comparison: surviving joints keep their velocities, locked ones drop theirs
        imp, v_after = None, v.copy()
        for n in locked:
            v_after[cfg.joint_slice[n]] = 0.0
    if imp is not None:
        scale = max(1.0, float(np.max(np.abs(v))))
        moving = {n: float(v_after[cfg.joint_slice[n]][0]) for n in locked
                  if abs(v_after[cfg.joint_slice[n]][0]) > 1e-8 * scale}
        if moving:
            raise SimulationError(
                f"t = {t:.9g} s, transition '{tr.name}': after the plastic impact the joints that "
                f"'{target}' locks still move ({moving}); the contact normal of the transition does not "
                "act along the locked joint's motion, so the merge would silently drop velocity")
    if tr.guard.type == "coordinate":
        from .guards import guard_value
        residual = abs(guard_value(cfg, tr, t, q, v))
        if residual > POSE_TOL:
            raise SimulationError(
                f"t = {t:.9g} s, transition '{tr.name}': the event was located {residual:.3g} away from "
                f"the guard's value, more than the {POSE_TOL:g} the switch to '{target}' allows: lower "
                "solver.event_tol (--event-tol) or rtol")
    cfg.kinematics(q, v)
    point = _contact_point(cfg, tr)
    record = event_record(cfg, tr, t, target, True, imp, q, v, v_after, point, transition_type)
    q_new, v_new, dropped, offsets = switch(cfg, dst, t, q, v if imp is None else v_after)
    record["dropped_velocities"] = dropped
    merged_from = None
    if transition_type == "stop":
        merged_from = (cfg.name, tr, {n: q[cfg.joint_slice[n]].copy() for n in locked})
    return Outcome(target, q_new, v_new, record, offsets, merged_from)


def handle_latch(ctx: Context, cfg: Configuration, tr: TransitionSpec, t, q, v) -> Outcome:
    return _merge(ctx, cfg, tr, tr.target, t, q, v, "latch")


def handle_stop(ctx: Context, cfg: Configuration, tr: TransitionSpec, t, q, v) -> Outcome:
    if not ctx.impact:
        if tr.merge_to is None:
            raise SimulationError(f"transition '{tr.name}': a run without impact switches configuration at "
                                  "the stop, so the stop needs merge_to (the merged configuration)")
        return _merge(ctx, cfg, tr, tr.merge_to, t, q, v, "stop")
    speed, interval = ctx.tolerances(tr)
    _, _, vn, _ = contact_state(cfg, q, v, tr.contact)
    if vn >= 0:
        # The guard fired while the contact does not approach.  A tiny separating speed is the
        # integrator's resolution at the end of an accumulation (the bounces are shorter than its
        # dense-output error): the bodies rest in contact.  A clear one means a wrong normal.
        if vn > RESTING_FACTOR * speed:
            raise SimulationError(
                f"t = {t:.9g} s, transition '{tr.name}': the guard fired but the contact is separating "
                f"(relative normal velocity {vn:.3g} m/s along the declared normal); the normal "
                "must point from link a towards link b")
        accumulated, rest_speed = True, vn
    else:
        imp = solve_impulse(cfg, t, q, v, tr.contact, tr.restitution, tr.cut)
        last = ctx.last_impact.get(tr.name)
        rest_speed = imp.vn_after
        # impacts at the same instant are a sequential resolution of simultaneous contacts, not an
        # accumulation: only a positive interval counts
        accumulated = abs(imp.vn_after) <= speed or (last is not None and 0 < t - last <= interval)
    ctx.last_impact[tr.name] = t
    if accumulated:
        if tr.merge_to is None:
            raise SimulationError(
                f"t = {t:.9g} s, transition '{tr.name}': the impacts accumulate (post-impact normal speed "
                f"{abs(rest_speed):.3g} m/s) and the bodies come to rest in contact; give the stop a "
                "merge_to configuration so the run can continue with the bodies merged")
        return _merge(ctx, cfg, tr, tr.merge_to, t, q, v, "stop")
    cfg.kinematics(q, v)
    record = event_record(cfg, tr, t, cfg.name, False, imp, q, v, imp.v_after, _contact_point(cfg, tr))
    q_new, v_new = cfg.coords.project(t, q, imp.v_after)
    return Outcome(cfg.name, q_new, v_new, record, {})


def handle_release(ctx: Context, cfg: Configuration, tr: TransitionSpec, t, q, v, release) -> Outcome:
    """Undo a stop-merge whose holding force turns tensile: back to the source configuration."""
    source_name, locked = release
    dst = ctx.mechanism[source_name]
    q_new, v_new, _, offsets = switch(cfg, dst, t, q, v, known=locked)
    dst.kinematics(q_new, v_new)
    n, _, vn, _ = contact_state(dst, q_new, v_new, tr.contact)
    M = cfg.mass_matrix(q)
    ke = float(0.5 * v @ M @ v)
    record = event_dict(cfg, tr, t, transition="release", to=source_name, restitution=None, merge=False,
                        impact=False, P=0.0, normal=n, point=_contact_point(dst, tr), vn=(vn, vn), v=(v, v),
                        ke=(ke, ke), v_after_named=dst.by_joint(v_new))
    return Outcome(source_name, q_new, v_new, record, offsets)


TRANSITIONS = {"latch": handle_latch, "stop": handle_stop}
