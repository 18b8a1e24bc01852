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
* ``release``: a transformation that frees locked joints and goes to a configuration with
  more freedom.  It carries no impulse (paper section 2.2): the freed joints take the values
  and rates the links' poses and velocities give them, so every body's position and
  velocity is continuous (checked, like the poses at any switch) and the kinetic energy is
  unchanged (checked).  A stop-merge held by compression only is released the same way
  when its holding force would turn tensile (:func:`unmerge`).

Without impact (the paper's comparison runs) a transformation switches
configuration with no impulse: surviving joints keep their velocities, locked
ones drop theirs.

Every handler enters its target through :func:`pcmm.events.entry.enter` (via :func:`switch`), which checks the
target's constraints at the post-impact state and stops the run where they do not hold: a new
transition kind is one entry of ``TRANSITIONS`` whose handler does the same.
"""
from __future__ import annotations

import math

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from ..model.configuration import Configuration
from ..model.mechanism import Mechanism
from ..model.pinocchio_helpers import LWA
from ..errors import SimulationError
from .contact import contact_state, normal_speed
from .contact_faults import POSE_TOL, contact_findings
from .records import (BounceRecord, adopt_compiled_bounce, bounce_record, by_link, check_energy, compiled_bounce,
                      event_record, solve_bounce)
from .guards import describe_guard, guard_value, make_guard
from .entry import (VELOCITY_ROUNDOFF, Entry, bounce_projection, enter, enter_bounce, joints_from_poses,  # noqa: F401 - re-exported
                    map_state, pose_mismatches)
from .friction import law_normal_velocity
from .impulse import Impulse, no_impulse, solve_impulse
from .pins import check_held_points_push, pin_strike
from .simultaneous import closed_with, simultaneous_impact
from ..scene.spec import GuardSpec, LatchSpec, ReleaseSpec, StopSpec, TransitionSpec

#: a contact's normal speed (m/s; rad/s at a joint stop) that is rest, not separation: the run loop reads
#: a segment's start with the same bound (pcmm.run.loop._pending)
AT_REST_SPEED = 1e-12


@dataclass
class Context:
    mechanism: Mechanism
    impact: bool
    accumulation_speed: float
    accumulation_interval: float
    forced_speed: float | None = None  # given for the run (CLI, RunOptions): wins over every transition's
    forced_interval: float | None = None
    last_impact: dict[str, float] = field(default_factory=dict)
    pinned_without_impact: bool = False  # a pin of a run without impact was said (:func:`pins.pin_strike`)

    def tolerances(self, tr: StopSpec) -> tuple[float, float]:
        """(speed, interval) for a stop: the run's explicit value, else the transition's, else the scene's."""
        speed, interval = self.forced_speed, self.forced_interval  # (asked at every bounce: no helper made per call)
        if speed is None:
            speed = tr.accumulation_speed if tr.accumulation_speed is not None else self.accumulation_speed
        if interval is None:
            interval = tr.accumulation_interval if tr.accumulation_interval is not None else self.accumulation_interval
        return speed, interval


@dataclass
class Outcome:
    configuration: str
    q: np.ndarray
    v: np.ndarray
    event: dict | BounceRecord  # a bounce's record may be kept as its numbers (read-only)
    angle_offsets: dict[str, float]
    locks: str | None = None  # the switch locked joints: "latch" or "merge" (a stop's accumulation)


# ---- state mapping -----------------------------------------------------------------------
def switch(src: Configuration, dst: Configuration, t: float, q: np.ndarray, v: np.ndarray,
           known: dict | None = None, what: str = "switch", reset: bool = False):
    """Map (q, v) of ``src`` onto ``dst`` (:func:`enter`).  Returns (q, v, dropped velocities
    {joint: v}, angle offsets {link: 2 pi k})."""
    entry = enter(src, dst, t, q, v, known=known, what=what, reset=reset)
    return entry.q, entry.v, entry.dropped, entry.offsets


def _check_continuity(src, dst, t, q, v, q_new, v_new, what: str) -> tuple[float, float]:
    """Every shared body's velocity (and so the kinetic energy) is the same before and after a
    switch without impulse; returns (largest velocity difference, kinetic energy change)."""
    before, after = src.link_velocities(q, v), dst.link_velocities(q_new, v_new)
    scale = max(1.0, float(np.max(np.abs(before))) if before.size else 1.0)
    worst = 0.0
    for link in dst.links:
        if link in src.link_index:
            worst = max(worst, float(np.max(np.abs(before[src.link_index[link]] - after[dst.link_index[link]]))))
    ke0, ke1 = src.kinetic_energy(q, v), dst.kinetic_energy(q_new, v_new)
    if worst > 1e-9 * scale or abs(ke1 - ke0) > 1e-9 * max(ke0, 1e-12):
        raise SimulationError(
            f"t = {t:.9g} s, {what} '{src.name}' -> '{dst.name}': a transformation without impulse must keep every "
            f"body's velocity, but a link's velocity changes by {worst:.3g} and the kinetic energy from {ke0:.9g} "
            f"to {ke1:.9g} J; the freed joints' rates could not be derived from the links (check that "
            f"'{dst.name}' has the same links as '{src.name}')")
    return worst, ke1 - ke0


def check_latch_compressive(tr: TransitionSpec, t, imp: Impulse, v) -> None:
    """A latch locks by a compressive impulse along its contact normal.  A tensile one means the
    declared normal points the wrong way (from b towards a); the merge would pull the bodies."""
    scale = max(1.0, float(np.max(np.abs(v)))) if len(v) else 1.0
    if imp.P < 0 and imp.vn_before > 1e-9 * scale:
        n = tr.contact.normal
        raise SimulationError(
            f"t = {t:.9g} s, transition '{tr.name}': the latch's impulse comes out tensile (P = {imp.P:.6g} N s "
            f"along the declared normal ({n[0]:g}, {n[1]:g}) in link '{tr.contact.a}''s frame; normal "
            f"velocity {imp.vn_before:.3g} m/s, separating): the normal must point from link a "
            f"('{tr.contact.a}') towards link b ('{tr.contact.b}'); flip its sign")


#: Newton's law at a bounce holds "to round-off" within this x |vn-| (the examples: below 5e-16)
RESTITUTION_ROUNDOFF = 1e-9


def check_restitution(tr: TransitionSpec, t, imp: Impulse) -> None:
    """A bounce obeys its restitution law along its normal, to round-off, with vn+ the normal speed
    of the velocity the run goes on with (``imp.v_after``, not the law's formula): frictionless,
    Newton's vn+ = -e vn- (Eq. 21); a frictional contact, the end of Routh's process its law names
    where that has a closed form (:func:`pcmm.events.friction.law_normal_velocity`: Newton's -e vn-
    at any mu; Poisson's and Stronge's with no slip -e v_n1)."""
    if imp.restitution is None:
        return
    if imp.friction is None:
        check_restitution_law(tr, t, imp.restitution, imp.vn_before, imp.vn_after, imp.v_before)
        return
    named = law_normal_velocity(imp.friction, imp.restitution)
    if named is not None:
        check_restitution_law(tr, t, imp.restitution, imp.vn_before, imp.vn_after, imp.v_before, *named)


def check_restitution_law(tr: TransitionSpec, t, e: float, vn_before: float, vn_after: float, v_before,
                          expected: float | None = None, law: str | None = None) -> None:
    """:func:`check_restitution` on the numbers themselves: ``vn_after = expected`` to round-off
    (by default Newton's -e vn_before; ``law`` its text), ``v_before`` the velocity before, whose size
    scales the floor of a vanishing ``vn_before``."""
    if expected is None:
        expected, law = -e * vn_before, f"Newton's restitution law (Eq. 21), e = {e:g}"
    off = abs(vn_after - expected)
    if off <= RESTITUTION_ROUNDOFF * abs(vn_before) or off <= RESTITUTION_ROUNDOFF * VELOCITY_ROUNDOFF * max(
            1.0, float(np.abs(v_before).max(initial=0.0))):
        return
    raise SimulationError(
        f"t = {t:.9g} s, transition '{tr.name}': the bounce breaks {law}: normal velocity {vn_before:.9g} m/s "
        f"before and {vn_after:.9g} after, where the law gives {expected:.9g} (off by {off:.3g}); the impulse "
        "solve is wrong here")


def _contact_faults(cfg: Configuration, tr: TransitionSpec, q, otherwise: str) -> list[str]:
    """What is wrong with the contact at ``q`` (:func:`pcmm.contact_faults.contact_findings`: the points
    or the normal, whichever is at fault), else ``otherwise``."""
    return [f"transition '{tr.name}', {f.field}: {f.text}" for f in contact_findings(cfg, tr, q)] or [otherwise]


def _merge(ctx: Context, cfg: Configuration, tr: TransitionSpec, target: str, t, q, v, transition_type):
    """Plastic impact (or none without impact), then switch to ``target``."""
    dst = ctx.mechanism.enter(target, cfg, q)  # a derived configuration locks the values at this instant
    locked = [n for n in cfg.joint_names if n not in dst.joint_slice]
    if ctx.impact:
        imp = solve_impulse(cfg, t, q, v, tr.contact, 0.0, tr.cut, name=tr.name)
        v_after = imp.v_after
    else:  # the paper's comparison: surviving joints keep their velocities, locked ones drop theirs
        v_after = v.copy()
        for n in locked:
            v_after[cfg.joint_slice[n]] = 0.0
        imp = no_impulse(cfg, q, v, v_after, tr.contact)
    if imp.impact and transition_type == "latch":
        check_latch_compressive(tr, t, imp, v)
    if imp.impact:
        check_held_points_push(cfg, q, imp, f"t = {t:.9g} s, transition '{tr.name}'")
    if imp.impact:
        scale = max(1.0, float(np.max(np.abs(v))))
        moving = {n: float(v_after[cfg.joint_slice[n]][0]) for n in locked
                  if abs(v_after[cfg.joint_slice[n]][0]) > 1e-8 * scale}
        if moving:
            raise SimulationError(
                [f"t = {t:.9g} s, transition '{tr.name}': after the plastic impact the joints that "
                 f"'{target}' locks still move ({moving}), so the merge would silently drop velocity"]
                + _contact_faults(cfg, tr, q, "the contact impulse does not act along the locked joint's motion "
                                  "(check cut and the contact)"))
    if tr.guard.type == "coordinate":
        residual = abs(guard_value(cfg, tr, t, q, v))
        if residual > POSE_TOL:
            raise SimulationError(
                f"t = {t:.9g} s, transition '{tr.name}': the event was located {residual:.3g} away from "
                f"the guard's value, more than the {POSE_TOL:g} the switch to '{target}' allows: lower "
                "solver.event_tol (--event-tol) or rtol")
    q_new, v_new, dropped, offsets = switch(cfg, dst, t, q, v if not imp.impact else v_after,
                                            what=f"{transition_type} '{tr.name}'", reset=not imp.impact)
    if not imp.impact:  # the record shows the velocities the run goes on with (projected onto the target)
        scale = max(1.0, float(np.max(np.abs(v)))) if len(v) else 1.0
        for n in dst.joint_names:
            if n in cfg.joint_slice:
                v_after[cfg.joint_slice[n]] = v_new[dst.joint_slice[n]]
                before = v[cfg.joint_slice[n]]
                if np.max(np.abs(v_new[dst.joint_slice[n]] - before)) > VELOCITY_ROUNDOFF * scale:
                    # a kept joint whose velocity the reset changed (closing a loop without impulse):
                    # named with the velocity it had, like the locked ones
                    dropped[n] = float(before[0]) if before.size == 1 else [float(x) for x in before]
        imp = no_impulse(cfg, q, v, v_after, tr.contact)
    record = event_record(cfg, tr, t, target, True, imp, transition_type, q=q)
    record["dropped_velocities"] = dropped
    if not imp.impact:
        _report_reset(record, cfg, dst, t, tr, q, v, q_new, v_new, imp)
    return Outcome(target, q_new, v_new, record, offsets, "merge" if transition_type == "stop" else "latch")


def _report_reset(record, src: Configuration, dst: Configuration, t, tr: TransitionSpec, q, v, q_new, v_new,
                  imp) -> None:
    """A switch without impulse keeps the velocities of the joints its target keeps, unless the
    target's constraints (a loop the merge closes, a drive) do not admit them: they are then
    projected onto those constraints (:func:`pcmm.events.entry.enter`).  Besides their value
    before in ``dropped_velocities`` (with the locked joints'), every velocity so changed is in
    ``changed_velocities`` ({joint: [rate before, rate after]}, the coordinates' rates as the
    series record them) and in a warning with the kinetic energy before and after."""
    before, after = src.qdot(q, v), dst.qdot(q_new, v_new)
    scale = max(1.0, float(np.max(np.abs(before)))) if len(before) else 1.0
    changed = {}
    for n in dst.joint_names:
        if n not in src.joint_slice:
            continue
        b, a = before[src.joint_slice[n]], after[dst.joint_slice[n]]
        if float(np.max(np.abs(a - b))) > VELOCITY_ROUNDOFF * scale:
            changed[n] = [float(b[0]), float(a[0])] if len(b) == 1 else [b.tolist(), a.tolist()]
    record["changed_velocities"] = changed
    if not changed:
        return
    listed = ", ".join(f"{n}' {b:.6g} -> {a:.6g}" if not isinstance(b, list) else f"{n}' {b} -> {a}"
                       for n, (b, a) in changed.items())
    record.setdefault("warnings", []).append(
        f"t = {t:.9g} s, transition '{tr.name}' without impact: '{dst.name}' does not admit the velocities kept "
        f"from '{src.name}', so the switch changes {listed} (projected onto its constraints; locked: "
        f"{', '.join(n for n in record.get('dropped_velocities') or {} if n not in changed) or 'none'}); "
        "the kinetic energy goes from "
        f"{imp.ke_before:.6g} to {imp.ke_after:.6g} J ({imp.ke_after - imp.ke_before:+.3g} J)")


def handle_latch(ctx: Context, cfg: Configuration, tr: LatchSpec, t, q, v) -> Outcome:
    return _merge(ctx, cfg, tr, tr.target, t, q, v, "latch")


def handle_stop(ctx: Context, cfg: Configuration, tr: StopSpec, t, q, v) -> Outcome:
    if not ctx.impact:
        if tr.merge_to is None:
            raise SimulationError(f"transition '{tr.name}': a run without impact switches configuration at "
                                  "the stop, so the stop needs merge_to (the merged configuration)")
        return _merge(ctx, cfg, tr, tr.merge_to, t, q, v, "stop")
    speed, interval = ctx.tolerances(tr)
    # the whole bounce in one compiled call where the stop's bounces have given the Python route's bits
    # (records.adopt_compiled_bounce); else the impulse solved (compiled or in Python), the rest below
    fast = compiled_bounce(cfg, tr)
    got = None
    if fast is not None and tr.contact.joint is not None:
        # a joint stop's approach speed is the call's vn_before, -s v_j: normal_speed's number (its row
        # has one entry); a stop that does not approach goes the general way below, with normal_speed's
        got = solve_bounce(fast, t, q, v, tr.restitution)
        if got is not None and not got[4][1] < 0:
            got = None
    vn = got[4][1] if got is not None else normal_speed(cfg, q, v, tr.contact)  # (a joint stop's without a kinematics pass)
    together = closed_with(cfg, tr, q)
    if together and min([vn] + [contact_state(cfg, q, v, s.contact)[2] for s in together]) < 0:
        # other contacts closed at this instant, one of them approaching: one solve with them all
        return _simultaneous(ctx, cfg, [tr] + together, t, q, v)
    if vn >= 0:
        # The guard fired while the contact does not approach.  At rest (pushed closed, or at the apex
        # of a bounce too small to open the contact) the bodies merge with no impulse.  A separating
        # rate is never an impact nor merged, however small: a crossing where the contact separates
        # is round-off or an inaccurate step (the four-bar's joint stop, let go at its value, was
        # merged 2.4e-6 s later at +1.0e-10 rad/s), or a wrong normal.
        if vn > AT_REST_SPEED:
            raise SimulationError(_separating_with_faults(cfg, tr, t, q, v, vn))
        accumulated, rest_speed = True, vn
    else:
        if got is None and fast is not None and tr.contact.joint is None:  # a point contact's, after its normal_speed
            got = solve_bounce(fast, t, q, v, tr.restitution)
        if got is None:
            imp = solve_impulse(cfg, t, q, v, tr.contact, tr.restitution, tr.cut, name=tr.name)
            rest_speed = imp.vn_after
        else:
            rest_speed = got[4][2]  # vn_after
        last = ctx.last_impact.get(tr.name)
        # impacts at the same instant are a sequential resolution of simultaneous contacts, not an
        # accumulation: only a positive interval counts
        accumulated = abs(rest_speed) <= speed or (last is not None and 0 < t - last <= interval)
    ctx.last_impact[tr.name] = t
    if accumulated:
        if tr.merge_to is None:
            raise SimulationError(
                f"t = {t:.9g} s, transition '{tr.name}': the impacts accumulate (post-impact normal speed "
                f"{abs(rest_speed):.3g} m/s) and the bodies come to rest in contact; give the stop a "
                "merge_to configuration so the run can continue with the bodies merged")
        return _merge(ctx, cfg, tr, tr.merge_to, t, q, v, "stop")
    if got is not None:
        return _compiled_bounce(cfg, tr, fast, t, q, v, got)
    check_held_points_push(cfg, q, imp, f"t = {t:.9g} s, transition '{tr.name}'")
    check_restitution(tr, t, imp)
    record = bounce_record(cfg, tr, t, imp, q)  # event_record's, as its numbers where the impulse has them
    # no switch: the configuration stays; the state after the impulse (Eq. 43) projected and checked
    q_new, v_new, _ = enter_bounce(cfg, t, q, imp.v_after, what=f"bounce at '{tr.name}'")
    if getattr(imp, "solved", None) is not None:  # the compiled bounce, asked once per stop: the same bits?
        adopt_compiled_bounce(cfg, tr, t, q, v, imp, record, q_new, v_new, bounce_projection(cfg))
    return Outcome(cfg.name, q_new, v_new, record, {})


def _compiled_bounce(cfg: Configuration, tr: StopSpec, plan, t, q, v, got) -> Outcome:
    """A bounce from the compiled call's ``got`` (``BouncePlan.solve``: the impulse, the record's numbers
    and the state projected onto the drives), with the checks of the Python route on its numbers:
    Newton's law (:func:`check_restitution_law`), the energy (:func:`check_energy`) and the drive rows at the
    post-impact velocity, whose residual the call measured: beyond :data:`VELOCITY_ROUNDOFF`, or where the
    projection moved the posture, the Python entry (:func:`enter_bounce`) checks them and says what is
    wrong.  No held point can be pulled: the compiled bounce is taken only without loops (no point held
    by compression only, :func:`check_held_points_push`)."""
    numbers, q_new, v_new, v_after, (P, vn_before, vn_after, ke_before, ke_after, drive_work), moved, residual = got
    check_restitution_law(tr, t, tr.restitution, vn_before, vn_after, v)
    check_energy(tr, t, (ke_before, ke_after), drive_work)
    if moved or residual > VELOCITY_ROUNDOFF:
        q_new, v_new, _ = enter_bounce(cfg, t, q, v_after, what=f"bounce at '{tr.name}'")
    return Outcome(cfg.name, q_new, v_new, BounceRecord(plan, numbers), {})


def _simultaneous(ctx: Context, cfg: Configuration, trs: list, t, q, v) -> Outcome:
    """Stops whose contacts are closed at once bounce together (:mod:`pcmm.events.simultaneous`)."""
    imp, block, warnings = simultaneous_impact(cfg, trs, t, q, v)
    check_held_points_push(cfg, q, imp, f"t = {t:.9g} s, transitions {', '.join(repr(s.name) for s in trs)}")
    for s in trs:
        ctx.last_impact[s.name] = t
    record = event_record(cfg, trs[0], t, cfg.name, False, imp, q=q)
    record["impulse"]["tangential"] = imp.P_t
    record["impulse"]["vector"] = [float(x) for x in imp.vector]
    record["tangent"] = [float(imp.tangent[0]), float(imp.tangent[1])]
    record["simultaneous"] = block
    if warnings:
        record.setdefault("warnings", []).extend(warnings)
    q_new, v_new, _, _ = switch(cfg, cfg, t, q, imp.v_after, what=f"bounce at {', '.join(repr(s.name) for s in trs)}")
    return Outcome(cfg.name, q_new, v_new, record, {})


def _separating(cfg: Configuration, tr: TransitionSpec, t, q, v, vn) -> str:
    """Why a guard fired while its contact separates.  If the guard really moves towards its
    firing side there, the declared normal contradicts the guard: the normal is wrong.  If it
    moves away, the crossing is an artefact of an inaccurate step (typically fixed-step RK4
    at a step beyond its stability limit, whose state then oscillates wildly): the step is."""
    head = (f"t = {t:.9g} s, {describe_guard(tr)}: the guard fired but the contact is separating "
            f"(relative normal velocity {vn:.3g} {_speed_unit(cfg, tr.contact)} "
            "along the declared normal)")
    try:
        # the guard's own rate at the state (a joint stop's: the joint's rate); a difference of its
        # values along q' reads round-off where the rate is tiny (+1.0e-10 rad/s: 0, and blamed the normal)
        rate = make_guard(cfg, tr).rate(t, cfg.coords.pack(t, q, v), None)
        if rate is None:
            qd = cfg.qdot(q, v)
            eps = 1e-7 / max(1.0, float(np.max(np.abs(qd)))) if qd.size else 0.0
            rate = (guard_value(cfg, tr, t, q + eps * qd, v) - guard_value(cfg, tr, t, q - eps * qd, v)) / (2 * eps)
    except Exception:  # noqa: BLE001 - the diagnosis is a hint; never let it mask the error itself
        rate = None
    if rate is not None and rate * tr.guard.direction < 0:
        return (f"{head}, and the guard itself is moving away from its value (rate {rate:.3g}/s), so the "
                "crossing comes from round-off in its value or an inaccurate step, not from the normal (a "
                "separating contact is never struck nor merged); where the integration is unstable or too "
                "coarse, with RK4 lower solver.step (--step), else tighten rtol")
    return f"{head}; the normal must point from link a towards link b"


def _speed_unit(cfg: Configuration, contact) -> str:
    """A contact's normal speed unit: rad/s at a revolute joint stop (the joint's rate), else m/s."""
    if contact.joint is not None and cfg.spec.info.joints[contact.joint].type != "prismatic":
        return "rad/s"
    return "m/s"


def _separating_with_faults(cfg: Configuration, tr: TransitionSpec, t, q, v, vn) -> list[str]:
    """:func:`_separating`'s diagnosis; where it blames the normal, what the contact check finds
    at fault (the points or the normal)."""
    text = _separating(cfg, tr, t, q, v, vn)
    if not text.endswith("the normal must point from link a towards link b"):
        return [text]
    head = text[:text.rindex(";")]
    return [head] + _contact_faults(cfg, tr, q, "the normal must point from link a towards link b")


def _release_event(cfg: Configuration, dst: Configuration, tr: TransitionSpec, t, q, v, q_new, v_new,
                   freed, continuity, cause: str) -> dict:
    """The event of a transformation without impulse that frees joints."""
    ke = cfg.kinetic_energy(q, v)
    dst.kinematics(q_new, v_new)
    child = dst.spec.info.joints[freed[0]].child if freed else dst.links[0]
    point = dst.data.oMf[dst.link_frame[child]].translation[:2]
    return {
        "t": float(t), "name": tr.name, "kind": "release", "transition": "release", "cause": cause,
        "from": cfg.name, "to": dst.name, "restitution": None, "merge": False, "impact": False,
        "impulse": {"normal": 0.0, "vector": [0.0, 0.0]}, "normal": [0.0, 0.0],
        "contact_point": [float(point[0]), float(point[1])],
        "normal_velocity": {"before": 0.0, "after": 0.0},
        "omega_before": by_link(cfg, v), "omega_after": by_link(dst, v_new),
        "v_before": cfg.by_joint(v), "v_after": dst.by_joint(v_new), "joint_impulses": {},
        "kinetic_energy_before": float(ke), "kinetic_energy_after": float(ke + continuity[1]),
        "freed": {n: float(q_new[dst.joint_slice[n]][0]) for n in freed},
        "velocity_jump_max": continuity[0],
    }


def release(ctx: Context, cfg: Configuration, tr: TransitionSpec, target: str, t, q, v, known=None,
            cause: str = "guard") -> Outcome:
    """Free the joints ``target`` has and ``cfg`` lacks: no impulse (paper section 2.2); the freed
    joints' values and rates come from their links (or ``known`` values), every shared link's
    pose and velocity is checked continuous and the kinetic energy unchanged."""
    dst = ctx.mechanism.enter(target, cfg, q)  # a derived target locks the values it has now
    freed = [n for n in dst.joint_names if n not in cfg.joint_slice]
    q_new, v_new, _, offsets = switch(cfg, dst, t, q, v, known=known, what=f"{cause} release '{tr.name}'")
    continuity = _check_continuity(cfg, dst, t, q, v, q_new, v_new, "release")
    record = _release_event(cfg, dst, tr, t, q, v, q_new, v_new, freed, continuity, cause)
    return Outcome(target, q_new, v_new, record, offsets)


def handle_release(ctx: Context, cfg: Configuration, tr: TransitionSpec, t, q, v) -> Outcome:
    """A ``release`` transition of the scene, fired by its guard (a reaction guard on a point held
    by compression only: that point's lift-off, :func:`lift_off`)."""
    if tr.guard.type == "reaction" and pinned_contact(cfg, tr.guard.of):
        return lift_off(ctx, cfg, tr, t, q, v, cause=tr.guard.type)
    return release(ctx, cfg, tr, tr.target, t, q, v, cause=tr.guard.type)


def pinned_contact(cfg: Configuration, name: str) -> bool:
    """Is ``name`` a cut joint of ``cfg`` held by compression only (a contact normal)?"""
    return any(s.name == name and s.normal is not None for s in cfg.spec.cut_joints)


def unmerge(ctx: Context, cfg: Configuration, hold, target: str, t, q, v) -> Outcome:
    """Undo a stop-merge whose holding force would turn tensile: the stop's joints are freed at
    rest relative to each other, at the values they locked at."""
    return release(ctx, cfg, hold.transition, target, t, q, v, known=hold.joints, cause="tensile holding force")


def lift_off_transition(source: str, name: str, target: str) -> ReleaseSpec:
    """The release a point pinned by the cut joint ``name`` of ``source`` lifts off by (pcmm's own,
    not in the scene): its guard, the cut joint's normal force decreasing through 0."""
    return ReleaseSpec(name=f"lift-off {name}", source=source, cut=(), contact=None, target=target,
                       guard=GuardSpec("reaction", None, 0.0, -1, of=name))


def lift_off(ctx: Context, cfg: Configuration, tr: ReleaseSpec, t, q, v, cause: str = "tensile contact force") -> Outcome:
    """A point held by compression only (the cut joint ``name`` of ``cfg``, a contact normal) whose
    normal force turns tensile lifts off by itself into ``target`` (the scene's configuration
    without it, :meth:`pcmm.scene.spec.Scene.lift_off_target`): a release, with no impulse, the
    state continuous (:func:`release`).  The other points pinned at entry keep their anchors.
    Freed, the point must leave the surface: its normal acceleration in ``target`` is >= 0 (the
    tangential force the pin held is gone with it; a point pushed back into the surface would
    slide, which pcmm does not model, and the run stops saying so)."""
    name, target = tr.guard.of, tr.target
    closure = cfg.coords.closure
    k = next(i for i, s in enumerate(closure.specs) if s.name == name)
    Fn, Ft = cfg.coords.contact_forces(t, q, v)[name]
    cfg.kinematics(q)
    anchor = cfg.data.oMf[closure.frames_b[k]].translation[:2].copy()  # where the point lifts off
    keep = {s.name: closure.anchors[i] for i, s in enumerate(closure.specs) if i in closure.anchors and s.name != name}
    dst = ctx.mechanism.enter(target, cfg, q)
    if getattr(dst.coords, "constrained", False) and dst.coords.closure.anchored:
        dst.kinematics(q)
        dst.coords.closure.set_anchors(dst.data, keep)
    out = release(ctx, cfg, tr, target, t, q, v, cause=cause)
    # a scene's release may go to another tree: the check needs the same URDF (the same coordinates)
    same_tree = list(dst.joint_names) == list(cfg.joint_names)
    a_n = separating_acceleration(cfg, dst, k, t, out.q, out.v) if same_tree else math.nan
    scale = max(1.0, abs(float(np.linalg.norm(cfg.scene.gravity))))
    if a_n < -1e-9 * scale:
        # a located crossing of the normal force leaves it at round-off; a force well below zero was
        # tensile from the instant the configuration was entered (the strike that pinned the point)
        weight = scale * sum(float(I.mass) for I in cfg.model.inertias)
        when = (f"its normal force is already tensile where '{cfg.name}' is entered (the strike that pinned it): "
                f"N = {Fn:.6g} N" if Fn < -1e-6 * max(weight, abs(Ft), 1e-300) else
                f"its normal force turns tensile at this instant: N crosses 0, {Fn:.3g} N where located")
        raise SimulationError(
            f"t = {t:.9g} s, configuration '{cfg.name}': the point held by cut joint '{name}' lifts off ({when}, "
            f"tangential force {Ft:.6g} N), but freed in '{target}' it would be pushed back into the surface (normal "
            f"acceleration {a_n:.6g} m/s^2): it would slide, which pcmm does not model")
    out.event["lifted"] = {name: {"anchor": [float(x) for x in anchor], "normal_force": float(Fn),
                                  "tangential_force": float(Ft),
                                  "normal_acceleration_after": a_n if same_tree else None}}
    return out


def separating_acceleration(src: Configuration, dst: Configuration, k: int, t, q, v) -> float:
    """The normal acceleration (m/s^2, > 0 leaving) of the point of ``src``'s cut joint ``k``
    relative to a's, moving with ``dst``'s dynamics at (q, v): the same URDF, so ``dst``'s
    accelerations act on ``src``'s tree, whose model has the point's frames.  At the lift-off the
    two points coincide and move together, so the gap's second derivative is n . (a_b - a_a)."""
    a, _ = dst.coords.accelerations(t, q, v)
    closure = src.coords.closure
    spec = closure.specs[k]
    pin.forwardKinematics(src.model, src.data, src.to_pin(q), v, a)
    pin.updateFramePlacements(src.model, src.data)
    acc = (pin.getFrameClassicalAcceleration(src.model, src.data, closure.frames_b[k], LWA).linear[:2]
           - pin.getFrameClassicalAcceleration(src.model, src.data, closure.frames_a[k], LWA).linear[:2])
    n = src.data.oMf[closure.links_a[k]].rotation[:2, :2] @ np.asarray(spec.normal, float)
    return float(n @ acc) / float(np.linalg.norm(n))


def handle_pin(ctx: Context, cfg: Configuration, tr: TransitionSpec, t, q, v) -> Outcome:
    """A struck point pinned where it lands (:mod:`pcmm.events.pins`)."""
    return Outcome(*pin_strike(ctx, cfg, tr, t, q, v), angle_offsets={})


TRANSITIONS = {"latch": handle_latch, "stop": handle_stop, "release": handle_release, "pin": handle_pin}
