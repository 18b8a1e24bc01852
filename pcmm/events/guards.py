"""Guards: the conditions that fire a configuration transformation.

Each guard is a :class:`pcmm.witness.Guard`, a witness function of the integrator's state
(value, rate read from the state, direction, and what its firing does); the event is located
on the integrator's dense output.  Guard kinds form a registry (``GUARD_BUILDERS``), each
builder taking (configuration, transition) and returning the value and rate functions:

* ``coordinate``: a joint coordinate, a link angle or a relative angle reaches a value;
* ``gap``: the contact gap reaches a value;
* ``time``: t reaches an instant, or each instant of a period (repeated cycles);
* ``reaction``: the holding force or moment of a locked joint or merged stop crosses a
  value (:mod:`pcmm.holding`);
* ``entry``: the configuration is entered (a release fired at that instant: the run's loop
  fires it before the segment is integrated, :func:`pcmm.run.loop._pending`).
"""
from __future__ import annotations

import math

import numpy as np

from ..model import compiled
from ..model.configuration import Configuration
from .contact import compiled_contact, contact_state, gap_rate
from ..scene.spec import TransitionSpec
from ..ode.witness import Guard
from .holding import decidable, guard_value as holding_guard_value


def _coordinate(cfg: Configuration, tr: TransitionSpec, ctx=None):
    row, offset = cfg.measure_row(tr.guard.measure)
    target = tr.guard.value - offset
    unpack = cfg.coords.unpack
    entry = _state_entry(cfg, row)
    if entry is not None:  # the measured coordinate and its rate are entries of the state itself
        p, r = entry

        def value(t, y):
            return y[p] - target

        def rate(t, y, f):
            return y[r]
        value.many = lambda ts, ys: (ys[p] - target, ys[r])
        value.linear = (_unit(p, max(p, r) + 1), 0.0, -target, _unit(r, max(p, r) + 1), 0.0)
        return value, rate

    def value(t, y):
        q, _ = unpack(t, y)
        return row @ q - target
    value.many = _coordinate_many(cfg, row, target)
    value.evaluator = _loop_evaluator(cfg, row, target)
    if not cfg.coords.constrained and not cfg.has_planar:
        nv = cfg.nv

        def rate(t, y, f):  # q' = v, the second half of the state
            return row @ y[nv:]
    else:  # the full (q, v) of a loop, or a planar joint's q' from v
        def rate(t, y, f):
            return row @ cfg.qdot(*unpack(t, y))
    return value, rate


#: whether a closed loop's joint-coordinate guard is located by the compiled locator on the compiled Loop's
#: solutions (pcmm/model/_guard_eval.hpp, kind "loop"); off, in Python (the reference the tests compare it with)
COMPILED_LOOP_GUARDS = True


def _loop_evaluator(cfg: Configuration, row: np.ndarray, target: float):
    """Where ``row`` is one joint coordinate j of a configuration with closed loops (a unit row, no planar
    joint): a function giving the guard's compiled description at locate time, ``("loop", loop, j,
    target)`` with the Loop that solves the configuration then (its value ``q_j - target`` and rate ``q'_j``
    on that Loop's unpack, the call ``value`` makes), or None where no compiled Loop solves it now
    (PartitionedCoordinates.solving_loop); else None (the guard is located in Python)."""
    coords = cfg.coords
    hot = np.flatnonzero(row)
    if (not COMPILED_LOOP_GUARDS or len(hot) != 1 or row[hot[0]] != 1.0 or cfg.has_planar
            or not getattr(coords, "constrained", False) or not coords.closure.size or not compiled.enabled()):
        return None
    j, target = int(hot[0]), float(target)

    def describe():
        loop = coords.solving_loop() if COMPILED_LOOP_GUARDS else None
        return None if loop is None else ("loop", loop, j, target)
    return describe


def _unit(i: int, n: int) -> np.ndarray:
    row = np.zeros(n)
    row[i] = 1.0
    return row


def _state_entry(cfg: Configuration, row: np.ndarray) -> tuple[int, int] | None:
    """``(p, r)`` where a joint measure (``row`` a unit vector: ``row @ q`` is that coordinate
    itself, exactly, the other products being zeros) and its rate are the state's entries
    ``y[p]``, ``y[r]``: a tree's coordinate, or a free coordinate beside drives without a loop
    (their partition never changes); None otherwise (a loop's coordinates are solved, a planar
    joint's q' is not v)."""
    hot = np.flatnonzero(row)
    if len(hot) != 1 or row[hot[0]] != 1.0 or cfg.has_planar:
        return None
    entry = getattr(cfg.coords, "state_entry", None)
    return entry(int(hot[0])) if callable(entry) else None


def _coordinate_many(cfg: Configuration, row: np.ndarray, target: float):
    """A joint coordinate's guard at many states at once: ``(values, rates)`` at the times
    ``ts`` and states ``ys`` (one column each), for the event grid of an accepted step
    (:func:`pcmm.ode.integrators._locate`); None where that is not the per-state value to the
    bit.  For a joint measure ``row`` is a unit vector and ``row @ q`` is that coordinate
    itself, exactly (the other products are zeros); the coordinates must give all the grid's
    states in one call (``unpack_many``: a tree, or drives without a loop), without a planar
    joint (its q' is not v)."""
    hot = np.flatnonzero(row)
    if len(hot) != 1 or row[hot[0]] != 1.0 or cfg.has_planar:
        return None
    if not callable(getattr(cfg.coords, "unpack_many", None)):
        return None
    j = int(hot[0])
    coords = cfg.coords

    def many(ts, ys):
        states = coords.unpack_many(ts, ys)
        if states is None:
            return None
        Q, V = states
        return Q[j] - target, V[j]
    return many


def _gap(cfg: Configuration, tr: TransitionSpec, ctx=None):
    unpack = cfg.coords.unpack

    def value(t, y):
        q, v = unpack(t, y)
        return contact_state(cfg, q, v, tr.contact)[1] - tr.guard.value

    def rate(t, y, f):
        return gap_rate(cfg, *unpack(t, y), tr.contact)
    desc = compiled_contact(cfg, tr.contact, tr.guard.value)  # a tree's point contact: in C++
    if desc is None:
        return value, rate
    # compiled: the same value and rate (checked at probe states) from one C++ call each, here too (the
    # steps the segment loop hands back, the event's residual), not only in the compiled loop and locator
    evaluate = compiled.guard_value

    def value(t, y):
        return evaluate(desc, y)[0]

    def rate(t, y, f):
        return evaluate(desc, y)[1]
    value.evaluator = desc
    return value, rate


def _time(cfg: Configuration, tr: TransitionSpec, ctx=None):
    """t - the next instant: ``at``, or the first ``start + k every`` after the segment's start
    (``ctx``: the segment's start time)."""
    g = tr.guard
    if g.at is not None:
        instant = g.at
    else:
        t0 = 0.0 if ctx is None else ctx
        k = max(0, math.floor((t0 - g.start) / g.every) + 1) if t0 >= g.start else 0
        instant = g.start + k * g.every

    def value(t, y):
        return t - instant
    value.linear = (_NO_ROW, 1.0, -instant, _NO_ROW, 1.0)  # t + (-instant): t - instant, the same bits
    return value, (lambda t, y, f: 1.0)


_NO_ROW = np.zeros(0)


def _entry(cfg: Configuration, tr: TransitionSpec, ctx=None):
    """t - the instant the configuration was entered (``ctx``: the segment's start time): zero where
    the segment starts, where the run's loop fires it (:func:`pcmm.run.loop._pending`); it is never
    handed to an integrator, so no crossing of it is ever searched."""
    instant = 0.0 if ctx is None else float(ctx)

    def value(t, y):
        return t - instant
    return value, (lambda t, y, f: 1.0)


def _cut_joint_force(cfg: Configuration, tr: TransitionSpec):
    """The normal force of a cut joint held by compression only (``of`` names it): n . F, with F its
    multipliers (the force on b, world axes) and n its contact normal, > 0 while it pushes."""
    spec = next(s for s in cfg.spec.cut_joints if s.name == tr.guard.of)
    labels = cfg.coords.labels
    ix, iy = labels.index(f"{spec.name}.fx"), labels.index(f"{spec.name}.fy")
    unpack = cfg.coords.unpack
    frame_a = cfg.link_frame[spec.a]

    def value(t, y):
        q, v = unpack(t, y)
        _, lam = cfg.coords.accelerations(t, q, v)
        n = cfg.data.oMf[frame_a].rotation[:2, :2] @ np.asarray(spec.normal, float)
        force = float(n @ lam[[ix, iy]]) / float(np.linalg.norm(n))
        return decidable(cfg, t, spec.name, force) - tr.guard.value  # NaN: indeterminate (redundant rows)
    return value, None


def _reaction(cfg: Configuration, tr: TransitionSpec, ctx=None):
    """The holding force/moment of ``tr.guard.of`` (``ctx``: the run's :class:`pcmm.holding.Holds`),
    or the normal force of the configuration's own cut joint of that name (a pinned foot's lift-off)."""
    if any(s.name == tr.guard.of for s in cfg.spec.cut_joints):
        return _cut_joint_force(cfg, tr)
    if ctx is None or not ctx.holds(tr.guard.of, cfg):
        raise _NotHeld(tr.guard.of)
    forces = ctx.evaluator(cfg)  # the holding forces as this segment has them, prepared once
    # (compiled where it can be: then a compiled segment loop scans it too, value.holding)
    return holding_guard_value(cfg, forces, ctx.label(tr.guard.of), tr.guard.value), None


class _NotHeld(Exception):
    """A reaction guard whose joint or stop is not held in this configuration."""


GUARD_BUILDERS = {"coordinate": _coordinate, "gap": _gap, "time": _time, "reaction": _reaction, "entry": _entry}
UNFIRED = np.finfo(float).tiny  # the least distance from zero of a re-armed guard before its apex


def describe_guard(tr: TransitionSpec) -> str:
    """``transition 'name': what its guard reads = value`` (a guard's name, and messages)."""
    g = tr.guard
    what = {"coordinate": lambda: f"{g.measure} = {g.value:.9g}", "gap": lambda: f"contact gap = {g.value:.9g}",
            "time": lambda: f"t = {g.at:.9g} s" if g.at is not None else f"t = {g.start:.9g} + k {g.every:.9g} s",
            "reaction": lambda: f"holding force of {g.of} = {g.value:.9g}",
            "entry": lambda: f"on entering '{tr.source}'"}[g.type]()
    return f"transition '{tr.name}': {what}"


def armed(cfg: Configuration, tr: TransitionSpec, raw, raw_rate):
    """A guard armed by a region (``when``): with u = -direction * value (> 0 on the unfired side)
    and d the signed distance into the region (``measure - above``, or ``below - measure``), the
    guard reads -direction * max(u, -d).  Outside the region it stays on its unfired side, inside
    and near its crossing it is the plain guard, so the crossing is located exactly.  (Also a
    crossing where the measure enters the region while the plain value is already past its fired
    side: Drake's compass-gait witness max(2 gamma - theta_s - theta_w, theta_w - theta_s) does
    the same.)"""
    measure, side, bound = tr.guard.when
    row, offset = cfg.measure_row(measure)
    direction = tr.guard.direction
    unpack = cfg.coords.unpack

    def inside(t, y):
        q, _ = unpack(t, y)
        return side * (row @ q + offset - bound)

    def value(t, y):
        u, d = -direction * raw(t, y), inside(t, y)
        return -direction * (u if u >= -d else -d)

    def rate(t, y, f):
        if -direction * raw(t, y) >= -inside(t, y):
            return raw_rate(t, y, f) if raw_rate is not None else None
        q, v = unpack(t, y)
        return direction * side * float(row @ cfg.qdot(q, v))
    return value, (rate if raw_rate is not None else None)


def make_guard(cfg: Configuration, tr: TransitionSpec, rearm: bool = False, context=None) -> Guard | None:
    """The guard of ``tr`` in ``cfg`` (None for a reaction guard whose joint or stop is not held
    in ``cfg``); ``rearm=True`` for the guard right after a bounce at this contact;
    ``context``: the segment's start time (time guards) or the run's holds (reaction guards).

    Re-arming invariant: the restart state is the post-impact state itself, never moved
    (no shift into or out of the stop), and a re-armed guard fires only where its value
    reaches the fired side *while approaching*, i.e. while its rate (read from the state)
    points towards the fired side.  Until the flight turns back towards the stop the guard
    reads ``-direction * max(|value|, UNFIRED)``, strictly on its unfired side whatever
    round-off puts the restart state at; from the flight's apex on it is the plain guard.
    So the bodies fly exactly from the impact state and the only work done in flight is that
    of the applied forces and drives (audited per flight by :func:`pcmm.simulate.simulate`).
    A bounce too small to open the gap beyond round-off has its apex on the fired side: the
    guard fires there, at the apex, with an approach speed of round-off size, and the stop's
    accumulation rule merges the bodies.

    (Until pcmm 0.1 the restarted guard was shifted by the loop's Newton tolerance, 1e-12 m:
    the bodies sank that deep into the stop at every bounce, the loads did work through that
    depth, and a torque-driven slider-crank chattered at 4.7e-6 m/s for ever instead of
    accumulating in 37 impacts.)
    """
    try:
        raw, raw_rate = GUARD_BUILDERS[tr.guard.type](cfg, tr, context)
    except _NotHeld:
        return None
    direction = tr.guard.direction
    raw_many = getattr(raw, "many", None)  # all the states of an event grid at once, where given
    if tr.guard.when is not None:
        raw, raw_rate = armed(cfg, tr, raw, raw_rate)
        raw_many = None
    value, rate = raw, raw_rate
    many = None
    if raw_many is not None:
        def many(ts, ys):
            got = raw_many(ts, ys)
            return None if got is None else got[0].tolist()
    affine = _affine(cfg, tr, context) if tr.guard.when is None and not rearm else None
    linear = getattr(raw, "linear", None) if tr.guard.when is None else None
    evaluator = getattr(raw, "evaluator", None) if tr.guard.when is None else None
    if evaluator is not None:  # read in C++ at a state (a contact gap), plain or re-armed as below
        evaluator = (evaluator, bool(rearm), UNFIRED)
    if linear is None and tr.guard.when is None and raw_rate is not None:
        plain = affine if not rearm else _affine(cfg, tr, context)
        if plain is not None and plain[0] is not None:  # a tree's joint-angle guard: rate row @ v
            c = np.asarray(plain[0], float)
            nq = c.size - cfg.nv
            linear = (c, float(plain[1]), float(plain[2]), np.concatenate([np.zeros(nq), c[:nq]]), 0.0)
    if linear is not None:
        linear = (*linear, bool(rearm), UNFIRED)
    holding = getattr(raw, "holding", None) if tr.guard.when is None and not rearm else None
    loop_scan = _loop_scan(cfg, tr, rearm) if tr.guard.when is None else None
    if rearm:
        def value(t, y):
            val = raw(t, y)
            if direction * raw_rate(t, y, None) > 0.0:  # approaching: the plain guard
                return val
            # strictly on the unfired side, also where the impact left the value at exactly 0
            # (a root finder would take a bracket end at 0 for the crossing) or a hair on the
            # fired side: held at UNFIRED there, never |val|, which dips back to 0 as the
            # separating bodies pass the contact and looked like a crossing to the step's
            # cubic model (a point contact after its 12th bounce, 0.47 mm/s, at rtol 1e-10)
            return -direction * max(-direction * val, UNFIRED)

        def rate(t, y, f):
            r = raw_rate(t, y, f)
            if direction * r > 0.0 or -direction * raw(t, y) > UNFIRED:
                return r
            return 0.0  # held at UNFIRED
        if raw_many is not None:
            def many(ts, ys):  # value above, state by state, from the grid's values and rates
                got = raw_many(ts, ys)
                if got is None:
                    return None
                return [val if direction * r > 0.0 else -direction * max(-direction * val, UNFIRED)
                        for val, r in zip(got[0].tolist(), got[1].tolist())]
    return Guard(describe_guard(tr), value, direction, "transition", tr, rate, rate is not None, many=many,
                 affine=affine, linear=linear, holding=holding, loop_scan=loop_scan, evaluator=evaluator)


def left_at_value(cfg: Configuration, guards: list, leaving, t) -> list:
    """``guards`` with each one at an index in ``leaving`` re-armed (:func:`make_guard`'s ``rearm``):
    guards that sit at their value where a segment starts while their contact separates, or rests
    with the loads pulling it apart (the state a release leaves: a merge let go at its stop, the
    freed joint at its stop's value to an ulp or two), as :func:`pcmm.run.loop._pending` reads them
    at the segment's first instant.  Such a guard is not at a crossing: like a stop's guard after a
    bounce, it fires only where its contact comes back and reaches the value while approaching.  Read
    plain, the segment's scan took round-off at its first instant for a crossing: the four-bar's
    merge, let go with its joint -2.2e-16 rad from the stop, was merged again at once with no
    impulse (the stop guard's value read 0.0 there by the compiled loop's solve, -2.2e-16 by the
    state's) and let go again, three events for one release
    (tests/test_release_events.py).  ``t``: the segment's start (a time guard's context)."""
    out = list(guards)
    for i in leaving:
        out[i] = make_guard(cfg, guards[i].transition, rearm=True, context=t)
    return out


def _affine(cfg: Configuration, tr: TransitionSpec, context=None):
    """(c, ct, d) with the plain guard's value c . y + ct t + d, where it is affine in a tree's state
    [q, v] (a coordinate guard: the row of the measure on q; a time guard: t - the instant); else None."""
    g = tr.guard
    if g.type == "time":
        return None, 1.0, _time(cfg, tr, context)[0](0.0, None)
    if g.type == "coordinate" and not cfg.coords.constrained and not cfg.has_planar:
        row, offset = cfg.measure_row(g.measure)
        return np.concatenate([np.asarray(row, float), np.zeros(cfg.nv)]), 0.0, -(g.value - offset)
    return None


def _loop_scan(cfg: Configuration, tr: TransitionSpec, rearm: bool):
    """``("coordinate", row, d, unfired)`` where the guard is a joint coordinate's (or a link or
    relative angle's) in a closed loop: its value ``row . q + d`` on the loop's solution ``q`` at the
    state and its rate ``row . q'`` (:func:`_coordinate`), re-armed (``unfired = UNFIRED``) or plain
    (0), which a compiled segment loop over the loop scans itself (:attr:`Guard.loop_scan`); else None."""
    closure = getattr(cfg.coords, "closure", None)
    if tr.guard.type != "coordinate" or closure is None or not closure.size or cfg.has_planar:
        return None
    row, offset = cfg.measure_row(tr.guard.measure)
    return "coordinate", np.asarray(row, float), -(tr.guard.value - offset), UNFIRED if rearm else 0.0


def guard_residual(cfg: Configuration, tr: TransitionSpec, t, y) -> float:
    """The plain guard's value at an integrator state: at an event, how far the located
    state lies from the guard's ``value`` (m or rad; zero to round-off when the event sits
    on the contact)."""
    return float(GUARD_BUILDERS[tr.guard.type](cfg, tr)[0](t, y))


def guard_value(cfg: Configuration, tr: TransitionSpec, t, q, v) -> float:
    """The guard's value at a full state (for reports and restart checks)."""
    return make_guard(cfg, tr)(t, cfg.coords.pack(t, q, v))
