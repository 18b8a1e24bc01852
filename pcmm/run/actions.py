"""What a fired guard does: the boxes of the paper's Fig. 3 after "guard fires", one entry per kind.

``GUARD_ACTIONS`` maps a guard's action to its handler; every handler takes the run's state
(:class:`~pcmm.run.state.RunState`, already at the guard's instant) and the guard, does what the
kind does, and says whether the run switched (a transformation: the run may end there at
``t_end``).  A transition kind (latch, stop, release, ...) is one entry of
:data:`pcmm.events.transitions.TRANSITIONS`; every one of them goes through :func:`transform`,
which keeps the event, the locks and the audit, and enters the next configuration (the
constraint checks of :func:`pcmm.events.transitions.enter` have run inside the handler).
"""
from __future__ import annotations

import time

from ..errors import SimulationError
from ..events.contact import contact_point, contact_state
from ..events.contact_laws import ContactPhase
from ..events.guards import guard_residual
from ..events.records import EventRecord, event_dict
from ..events.transitions import TRANSITIONS, Outcome, lift_off, lift_off_transition, unmerge
from .state import RunState

#: this many configuration switches at one instant are a cycle that time does not pass in
ZERO_TIME_CYCLE = 64


def repartition(run: RunState, guard) -> bool:
    """The coordinates' own guard: the loop's partition degenerates here; go on with a better
    one, or stop at a singular posture of the loop itself."""
    run.cfg.coords.at_guard(guard, run.t, run.q)
    return False


def start_contact(run: RunState, guard) -> bool:
    """A stop resolved by a continuous contact law: the collision is integrated (its phase)."""
    tr = guard.transition
    _, _, vn, _ = contact_state(run.cfg, run.q, run.v, tr.contact)
    run.phase = ContactPhase(run.cfg, tr, max(-vn, 1e-12), run.t, run.q.copy(), run.v.copy())
    return False


def separate(run: RunState, guard) -> bool:
    """The contact phase ends: the bodies separate; its event spans the whole collision."""
    event = contact_event(run.phase, run.t, run.q, run.v, run.impulse_integral)
    run.traj.events.append(event)
    run.fired.add(event["name"])
    run.stats["impacts"] += 1
    run.phase = None
    return False


def transition(run: RunState, guard) -> bool:
    """A transition of the scene: its kind's handler (:data:`TRANSITIONS`) solves the
    transformation (impulse, velocity jump, configuration switch)."""
    tr = guard.transition
    run.phase = None
    t0 = time.perf_counter()
    residual = _residual(run, guard) if tr.guard.type in ("coordinate", "gap") else None
    out = TRANSITIONS[tr.type](run.ctx, run.cfg, tr, run.t, run.q, run.v)
    run.stats["wall_s"] += time.perf_counter() - t0
    return transform(run, tr, out, residual)


def _residual(run: RunState, guard) -> float:
    """How far the located state lies from the fired guard's value (:func:`guard_residual`): a
    joint coordinate's guard that is an entry of the state reads it there (``Guard.linear``, a unit
    row: y[p] + d, which is y[p] - value to the bit) without building the guard again."""
    linear = getattr(guard, "linear", None)
    if linear is not None:
        held = _UNIT_ROWS.get(id(linear))
        if held is None or held[0] is not linear:  # (a bounce re-arms with the same guard: decided once)
            hot = linear[0].nonzero()[0]
            entry = int(hot[0]) if len(hot) == 1 and linear[0][hot[0]] == 1.0 and linear[1] == 0.0 else None
            if len(_UNIT_ROWS) >= 256:
                _UNIT_ROWS.clear()
            held = _UNIT_ROWS[id(linear)] = (linear, entry)
        if held[1] is not None:
            return float(run.y[held[1]] + linear[2])
    return guard_residual(run.cfg, guard.transition, run.t, run.y)


#: {id of a guard's ``linear``: (that ``linear``, the state entry it reads where it is a unit row, else None)}
_UNIT_ROWS: dict = {}


def release_merge(run: RunState, guard) -> bool:
    """A stop-merge held by compression only whose holding force turns tensile is undone."""
    run.phase = None
    t0 = time.perf_counter()
    hold = guard.payload
    out = unmerge(run.ctx, run.cfg, hold, run.holds.release_target(hold, run.cfg), run.t, run.q, run.v)
    run.stats["wall_s"] += time.perf_counter() - t0
    return transform(run, guard.transition, out, None)


def release_pin(run: RunState, guard) -> bool:
    """A point held by compression only whose normal force turns tensile lifts off by itself
    into the scene's configuration without its cut joint (``guard.payload``), with no impulse."""
    run.phase = None
    t0 = time.perf_counter()
    tr = lift_off_transition(run.cfg.name, *guard.payload)
    out = lift_off(run.ctx, run.cfg, tr, run.t, run.q, run.v)
    run.stats["wall_s"] += time.perf_counter() - t0
    return transform(run, tr, out, None)


GUARD_ACTIONS = {
    "repartition": repartition,
    "contact": start_contact,
    "separation": separate,
    "transition": transition,
    "unmerge": release_merge,
    "lift-off": release_pin,
}


def action_of(run: RunState, guard) -> str:
    """The entry of :data:`GUARD_ACTIONS` a fired guard takes: its own action, except that a
    transition whose contact has a continuous law (in a run with impact) starts a contact phase."""
    tr = guard.transition
    if guard.action == "transition" and run.ctx.impact and tr.type == "stop" and tr.law != "impulse":
        return "contact"
    return guard.action


def transform(run: RunState, tr, out: Outcome, guard_residual: float | None) -> bool:
    """Keep the transformation's event and go on in its configuration with its state."""
    run.stats["impacts"] += int(out.event.get("impact", False))
    run.traj.events.append(out.event)
    run.fired.add(out.event["name"])
    check_progress(run, tr, out.event)
    if out.configuration != run.cfg.name:
        run.offsets = {k: run.offsets.get(k, 0.0) + d for k, d in out.angle_offsets.items()}
    else:
        run.bounced = tr
    run.audit.event(run.cfg, run.q, out.event, run.bounced is not None, guard_residual)
    nxt = run.mech[out.configuration]
    if nxt is run.cfg and out.locks is None:
        # a bounce (or a strike) that stays in its configuration: its angle offsets and holds are
        # those it had (continue_angles and follow were done on entering it); only the state changes
        run.q, run.v = out.q, out.v
        return True
    nxt.continue_angles(run.offsets)  # measures (springs, guards) continue the series' angles
    if out.locks is not None:
        run.holds.lock(run.cfg, nxt, tr, run.q, merge=out.locks == "merge")
    run.holds.follow(nxt)
    run.cfg, run.q, run.v = nxt, out.q, out.v
    return True


def check_progress(run: RunState, tr, last: dict | None = None) -> None:
    """Stop a run whose events no longer let time pass (a cycle of switches at one instant) or
    exceed the event budget.  ``last``: the event just kept, as a dict (the log's last)."""
    t = run.t
    cycle = zero_time_cycle(run.traj.events, last)
    if cycle:
        raise SimulationError(
            f"at t = {t:.9g} s the run switched configuration {ZERO_TIME_CYCLE} times without time "
            f"passing: {cycle} keep firing, each one's guard already past its value when the run "
            "enters its configuration (a release into a configuration whose forces push it straight "
            "back into the stop that merged it, say); change a guard, or the forces acting right "
            "after a switch")
    if len(run.traj.events) > run.opts.max_events:
        raise SimulationError(f"more than {run.opts.max_events} events by t = {t:.9g} s (last: "
                              f"'{tr.name}'); raise solver.max_events or the accumulation "
                              "tolerances if the impacts are meant to go on")


def zero_time_cycle(events: list[dict], last: dict | None = None) -> str:
    """The transitions of a cycle of switches at one instant ('' if the last ``ZERO_TIME_CYCLE``
    events are not one): with no time passing no impulse can end it, as a macro-impact's
    accumulation ends a bounce sequence, and only the event budget would stop the run.  ``last``:
    the log's last event where the caller holds it (one record fewer to build)."""
    n = len(events)
    # the two ends first: a run's event log builds each record it is asked for (pcmm.results.event_log),
    # and all the last ZERO_TIME_CYCLE of them at every event cost milliseconds
    if n < ZERO_TIME_CYCLE or (last is not None and last["from"] == last["to"]):
        return ""  # (a bounce, the last of the tail, ends any cycle: below)
    time_of = getattr(events, "time", None)  # a compact log reads a time without building the record
    first = time_of(n - ZERO_TIME_CYCLE) if time_of is not None else events[n - ZERO_TIME_CYCLE]["t"]
    if first != (events[n - 1] if last is None else last)["t"]:
        return ""
    tail = events[-ZERO_TIME_CYCLE:]
    if any(e["from"] == e["to"] for e in tail):
        return ""
    return ", ".join(dict.fromkeys(f"'{e['name']}' ({e['from']} -> {e['to']})" for e in tail))


def contact_event(phase: ContactPhase, t, q, v, impulse_integral) -> EventRecord:
    """The event of a collision resolved by a continuous law (from first contact to separation)."""
    cfg, tr = phase.cfg, phase.tr
    n, _, vn, _ = contact_state(cfg, q, v, tr.contact)
    M0, M1 = cfg.mass_matrix(phase.q_start), cfg.mass_matrix(q)
    return event_dict(
        cfg, tr, phase.t_start, transition="stop", to=cfg.name, restitution=tr.restitution, merge=False,
        impact=True, P=impulse_integral, normal=n,
        point=contact_point(cfg, tr.contact),
        vn=(-phase.v_impact, vn), v=(phase.v_start, v),
        ke=(0.5 * phase.v_start @ M0 @ phase.v_start, 0.5 * v @ M1 @ v),
        t_end=float(t), duration=float(t - phase.t_start), law=tr.law)
