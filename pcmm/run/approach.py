"""Why a run ended without the expected event: each guard's closest approach to its value.

When a run reaches ``t_end`` in a configuration that still has transitions, none of their guards
fired.  For each, the instant of the run (in that configuration) where the guard came closest to its
value says whether it was a near miss (a guard value a hair off, an event_tol question) or never
close (a wrong value, direction or assembly branch).  The nearest recorded step is refined on the
integrator's dense output between its neighbours (a bounded Brent search,
:func:`pcmm.ode.roots.minimize_bounded`), so a near miss between two long steps is measured, not
the step's distance.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UsageError
from ..events.contact import contact_state
from ..model.configuration import Configuration
from ..ode.roots import minimize_bounded
from ..results.event_log import EventLog
from ..results.trajectory import SegmentRecord, Trajectory
from ..scene.spec import Scene


def guard_series(cfg: Configuration, tr, q: np.ndarray) -> np.ndarray:
    """The guard's measure (or the contact gap) at each row of ``q`` (samples x nv)."""
    if tr.guard.type == "coordinate":
        row, offset = cfg.measure_row(tr.guard.measure)
        return q @ row + offset
    zero = np.zeros(cfg.nv)
    return np.array([contact_state(cfg, qi, zero, tr.contact)[1] for qi in q])


def in_region(cfg: Configuration, tr, q: np.ndarray) -> np.ndarray | None:
    """For a guard armed by a region (``when``), which rows of ``q`` lie in the region (where the
    guard can fire, :func:`pcmm.events.guards.armed`); None for a guard without one.  Outside it the
    guard stays on its unfired side whatever its measure does: a compass gait's swing foot passing
    through the slope at mid-stance is neither a crossing nor an approach."""
    if tr.guard.when is None:
        return None
    measure, side, bound = tr.guard.when
    row, offset = cfg.measure_row(measure)
    return side * (q @ row + offset - bound) >= 0


def _refine(cfg: Configuration, tr, seg: SegmentRecord, lo: float, hi: float, t0: float, g0: float):
    """(t, g): the guard's closest approach to its value within [lo, hi] of ``seg`` on the dense
    output, or the recorded (t0, g0) when the segment has none (a loaded trajectory) or the
    search finds nothing nearer."""
    def g(t):
        return float(guard_series(cfg, tr, seg.resampled(np.array([t])).q)[0])
    if not hi > lo:
        return t0, g0
    try:
        t1 = minimize_bounded(lambda t: abs(g(t) - tr.guard.value), lo, hi, xatol=1e-12 * max(1.0, abs(hi)))
    except UsageError:  # no dense output
        return t0, g0
    g1 = g(t1)
    return (t1, g1) if abs(g1 - tr.guard.value) < abs(g0 - tr.guard.value) else (t0, g0)


def closest_approach(scene: Scene, cfg: Configuration, traj: Trajectory) -> list[dict]:
    """One record per transition out of ``cfg``: where, over the run in ``cfg``, its guard came
    closest to its value (the nearest step, refined on the dense output)."""
    watched = [tr for tr in scene.transitions_from(cfg.name) if tr.guard.type in ("coordinate", "gap")]
    reactions = [tr for tr in scene.transitions_from(cfg.name) if tr.guard.type == "reaction"]
    timers = [tr for tr in scene.transitions_from(cfg.name) if tr.guard.type == "time" and tr.guard.at is not None]
    if not (watched or reactions or timers):
        return []
    fired_by = firings(traj.events, {tr.name for tr in watched + reactions + timers})
    segs = _segments_in(traj, cfg.name, watched if not (reactions or timers) else None, fired_by)
    if not segs:
        return []
    out = [r for r in (_timer_missed(tr, segs, fired_by) for tr in timers) if r is not None]
    out += [r for r in (_reaction_approach(tr, segs, fired_by) for tr in reactions) if r is not None]
    if not watched:
        return out
    t = np.concatenate([s.t for s in segs])
    q = np.concatenate([s.q for s in segs])
    owner = np.concatenate([np.full(s.t.size, k) for k, s in enumerate(segs)])
    for tr in watched:
        # a collision resolved by a contact law lasts from its first contact to the separation
        # (t_end), where the gap crosses back through its value: that crossing is not a miss
        fired = fired_by.get(tr.name)
        fired = [fired.latest] if fired else []  # (its latest firing: the max of its events' instants)
        after = t > max(fired) if fired else np.ones(t.size, bool)  # since it last fired
        if not after.any():
            continue
        region = in_region(cfg, tr, q)
        if region is not None:
            if not (after & region).any():  # it could not fire since: say so, not a distance
                out.append(_outside_region(tr, t, after, max(fired) if fired else None))
                continue
            after = after & region
        g = np.where(after, guard_series(cfg, tr, q), np.inf)
        d = np.abs(g - tr.guard.value)
        # after it fired, the guard starts at its value: its closest return towards the value
        # is a local minimum inside the run (else the nearer end); otherwise the nearest sample
        inner = np.flatnonzero((d[1:-1] <= d[:-2]) & (d[1:-1] <= d[2:]) & np.isfinite(d[:-2])) + 1
        i = int(inner[np.argmin(d[inner])]) if fired and inner.size else int(np.argmin(d))
        since = np.flatnonzero(after)
        if fired and not inner.size and i == since[0] and since.size > 1:
            # no minimum inside the run: nearest at its start (the first sample after the event)
            if d[since[-1]] >= np.max(d[since]):  # and farthest at its end: it only moved away
                out.append(_moved_away(tr, t, g, after, owner, max(fired)))
                continue
            i = int(since[-1])  # it turned back and was still approaching as the run ended
        k = owner[i]
        same = np.flatnonzero((owner == k) & after)  # the neighbours within the same segment
        lo, hi = t[max(i - 1, same[0])], t[min(i + 1, same[-1])]
        ti, gi = _refine(cfg, tr, segs[k], float(lo), float(hi), float(t[i]), float(g[i]))
        # at_entry: nearest where the run entered the configuration (a release at a stop, say): it
        # started there and never came closer, which is no near miss
        out.append(_record(tr, gi, ti, float(abs(gi - tr.guard.value)), max(fired) if fired else None,
                           ti == float(segs[k].t[0]) and _entered(traj, segs[k]), _past(tr, gi),
                           _crossed_against(tr, t, g, owner)))
    return out


def _moved_away(tr, t: np.ndarray, g: np.ndarray, after: np.ndarray, owner: np.ndarray, last_fired: float) -> dict:
    """The record of a guard that, since it last fired, only moved away from its value: the distance
    grows from the first sample after the firing and has no minimum inside the run (the rate never
    turned back towards the value), so there is no closest approach to report (the first sample
    after a release read "5.5e-06 short" while the freed joint moved monotonically away from its
    stop).  ``closest``, ``t`` and ``distance`` are None; ``final`` and ``t_final``: where the
    measure is at the run's last sample."""
    k = int(np.flatnonzero(after)[-1])
    return _record(tr, None, None, None, last_fired, False, False, _crossed_against(tr, t, g, owner),
                   moved_away=True, final=float(g[k]), t_final=float(t[k]))


def _outside_region(tr, t: np.ndarray, after: np.ndarray, last_fired: float | None) -> dict:
    """The record of a guard armed by a region (``when``) whose region the run did not enter since
    it last fired (or at all): no closest approach to report, the guard could not fire."""
    measure, side, bound = tr.guard.when
    since = t[after]
    return _record(tr, None, None, None, last_fired, False, False, None,
                   outside_when=f"{measure} {'above' if side > 0 else 'below'} {bound:.9g}",
                   t_from=float(since[0]), t_final=float(since[-1]))


def _record(tr, closest, t, distance, last_fired, at_entry: bool, past: bool, crossed_against, **more) -> dict:
    """The closest-approach record of a coordinate or gap guard (its keys in the summary's order;
    ``more``: a record's own keys after them)."""
    return {"transition": tr.name, "guard": str(tr.guard.measure) if tr.guard.measure else "contact gap",
            "value": tr.guard.value, "direction": "increasing" if tr.guard.direction > 0 else "decreasing",
            "closest": closest, "t": t, "distance": distance, "last_fired": last_fired, "at_entry": at_entry,
            "past": past, "crossed_against": crossed_against, **more}


def _segments_in(traj: Trajectory, name: str, watched, fired_by: dict | None = None) -> list[SegmentRecord]:
    """The run's segments in configuration ``name``.  Where only ``watched`` guards are asked about
    and each has fired, only the segments since the earliest of their last firings matter (a
    guard's approach is read since it last fired): they are taken from the end, so that a stored
    run of a million bounces reads its last segments, not all of them into memory at once."""
    segments = traj.segments
    if watched:
        names = {tr.name for tr in watched}
        fired_by = firings(traj.events, names) if fired_by is None else fired_by
        last = {n: fired_by[n].last for n in names if n in fired_by}
        if len(last) == len(names):
            since, tail = min(last.values()), []
            for k in range(len(segments) - 1, -1, -1):
                seg = segments[k]
                if seg.configuration == name:
                    tail.append(seg)
                if float(seg.t[0]) <= since:
                    break
            return tail[::-1]
    return [s for s in segments if s.configuration == name]


def _crossed_against(tr, t: np.ndarray, g: np.ndarray, owner: np.ndarray) -> float | None:
    """The first instant the measure crossed the guard's value against the guard's direction
    (between two samples of one segment, interpolated), or None: a guard written "decreasing"
    whose angle went up through its value did not fire, and that is what the user must hear."""
    side = np.sign(g - tr.guard.value)
    side[np.abs(g - tr.guard.value) <= _round_off(tr)] = 0  # a sample on the value is on neither side
    cross = np.flatnonzero(np.isfinite(g[:-1]) & np.isfinite(g[1:]) & (owner[:-1] == owner[1:])
                           & (side[:-1] != 0) & (side[1:] == -side[:-1]) & (side[1:] == -tr.guard.direction))
    if not cross.size:
        return None
    i = int(cross[0])
    a, b = abs(g[i] - tr.guard.value), abs(g[i + 1] - tr.guard.value)
    return float(t[i] + (t[i + 1] - t[i]) * a / (a + b))


def _timer_missed(tr, segs: list[SegmentRecord], fired_by: dict) -> dict | None:
    """A time guard ``at = T`` that never fired because the run was not in its configuration at T:
    it entered later, or ended first."""
    if tr.name in fired_by:
        return None
    at, entered, end = tr.guard.at, float(segs[0].t[0]), float(segs[-1].t[-1])
    if at < entered:
        why = (f"the run entered '{segs[0].configuration}' at t = {entered:.9g} s, after it; a time guard fires "
               "once, at that instant, and only if the run is in its configuration then")
    elif at > end:
        why = f"the run ended at t = {end:.9g} s, before it"
    else:
        return None
    return {"transition": tr.name, "guard": "time", "value": at, "direction": "increasing", "closest": entered,
            "t": entered, "distance": float(abs(at - entered)), "last_fired": None, "timer": why}


def _entered(traj: Trajectory, seg: SegmentRecord) -> bool:
    """Does ``seg`` start where the run entered its configuration (not after an impact in it)?"""
    j = next(i for i, s in enumerate(traj.segments) if s is seg)
    return j == 0 or traj.segments[j - 1].configuration != seg.configuration


def _reaction_approach(tr, segs: list[SegmentRecord], fired_by: dict) -> dict | None:
    """The closest approach of a reaction guard's holding force (or moment) to its value, over
    the recorded samples of the run in the configuration since the guard last fired (the hold
    is an algebraic function of the state: its samples are as fine as the output's)."""
    label = f"{tr.guard.of}.hold"
    fired = [fired_by[tr.name].t_max] if tr.name in fired_by else []
    ts, gs = [], []
    for s in segs:
        if label in s.constraint_labels:
            ts.append(s.t)
            gs.append(s.constraint_forces[:, s.constraint_labels.index(label)])
    if not ts:
        return None
    t, g = np.concatenate(ts), np.concatenate(gs)
    if fired:
        g = np.where(t > max(fired), g, np.inf)
    d = np.abs(g - tr.guard.value)
    if not np.isfinite(d).any():
        return None
    i = int(np.argmin(d))
    return {"transition": tr.name, "guard": f"holding force of '{tr.guard.of}'", "value": tr.guard.value,
            "direction": "increasing" if tr.guard.direction > 0 else "decreasing",
            "closest": float(g[i]), "t": float(t[i]), "distance": float(d[i]),
            "last_fired": max(fired) if fired else None, "past": _past(tr, float(g[i]))}


@dataclass
class Firing:
    """What the closest approach reads of one transition's events: ``latest``, the greatest of
    their instants (an event's ``t_end`` where it has one that is not 0 or None -- a collision
    resolved by a contact law lasts until then -- else its ``t``); ``last``, that instant of the
    last of them in the log's order; ``t_max``, the greatest of their ``t``."""
    latest: float
    last: float
    t_max: float

    def then(self, later: Firing) -> Firing:
        """These events followed by ``later``'s (of the same transition)."""
        return Firing(max(self.latest, later.latest), later.last, max(self.t_max, later.t_max))


def firings(events, names: set) -> dict[str, Firing]:
    """The :class:`Firing` of each transition in ``names`` that has an event in ``events``, in one
    pass and, where the events are kept as columns (an :class:`EventLog`, a store's chunks), without
    building their records: from each layout's columns (its ``name`` a constant of the layout, its
    ``t`` and ``t_end`` columns of numbers).  A record of any other layout is built and read (the
    reference: :func:`_firings_of_records`)."""
    parts = events.logs() if hasattr(events, "logs") else (events,)
    out: dict[str, Firing] = {}
    for part in parts:
        found = _firings_of_log(part, names) if isinstance(part, EventLog) else _firings_of_records(part, names)
        for name, f in found.items():
            out[name] = out[name].then(f) if name in out else f
    return out


def _firings_of_records(events, names: set) -> dict[str, Firing]:
    """:func:`firings` by reading every record (a list of dicts, a store's chunk written as JSON)."""
    out: dict[str, Firing] = {}
    for e in events:
        name = e.get("name")
        if name in names:
            f = Firing(e.get("t_end") or e["t"], e.get("t_end") or e["t"], e["t"])
            out[name] = out[name].then(f) if name in out else f
    return out


def _width(node) -> int:
    """How many numbers of a row a layout node (:mod:`pcmm.results.event_log`'s tuples) holds: one
    per number and per value kept aside (its index), none per constant."""
    if isinstance(node, str):
        return 1
    if node[0] == "c":
        return 0
    return sum(_width(sub) for sub in (node[2] if node[0] == "d" else node[1]))


def _fields(layout) -> dict | None:
    """A record layout's top-level ``key -> (node, its column of the row or None)``; None where the
    layout is not a dict's."""
    if not (type(layout) is tuple and layout[0] == "d"):
        return None
    out, at = {}, 0
    for key, sub in zip(layout[1], layout[2]):
        out[key] = (sub, at if isinstance(sub, str) else None)
        at += _width(sub)
    return out


def _instants(fields: dict, rows: np.ndarray):
    """(each event's instant -- its ``t_end`` where that is not 0 or None, else its ``t`` -- and its
    ``t``) as float arrays over a layout's ``rows``, or None where the layout's ``t`` is not a float
    of the row or its ``t_end`` neither a float of the row, nor None, nor absent (read the records)."""
    t, t_end = fields.get("t"), fields.get("t_end")
    if t is None or t[0] != "f":
        return None
    times = rows[:, t[1]]
    if t_end is None or t_end[0] == ("c", None):
        return times, times
    if t_end[0] != "f":
        return None
    ends = rows[:, t_end[1]]
    return np.where(ends != 0.0, ends, times), times  # (``t_end or t``: 0.0 and -0.0 are false, NaN true)


def _firings_of_log(log: EventLog, names: set) -> dict[str, Firing]:
    """:func:`firings` of one :class:`EventLog`, from its columns: per layout whose ``name`` is a
    constant in ``names``, its ``t`` and ``t_end`` columns; a layout of any other shape has its
    records built (slices of the log: built afresh, none kept)."""
    layouts, rows, index, _ = log.columns()
    parts: dict[str, list] = {}  # name -> [(position of its last event in the log, Firing)] of each layout
    for k, layout in enumerate(layouts):
        fields = _fields(layout)
        if not len(rows[k]) or fields is not None and "name" not in fields:
            continue  # no event, or no transition's event in this layout
        name = fields["name"][0] if fields is not None else None
        constant = isinstance(name, tuple) and name[0] == "c"
        if constant and name[1] not in names:
            continue
        positions = np.flatnonzero(index[:, 0] == k)  # this layout's events, in the log's order
        found = _instants(fields, rows[k]) if constant else None
        if found is None:  # read this layout's records (a record kept aside whole: not a plain dict)
            for j in positions.tolist():
                e = log[j:j + 1][0]
                if e.get("name") in names:
                    instant = e.get("t_end") or e["t"]
                    parts.setdefault(e["name"], []).append((j, Firing(instant, instant, e["t"])))
            continue
        instants, times = found
        last = int(index[positions[-1], 1])  # the row of this layout's last event in the log's order
        parts.setdefault(name[1], []).append((int(positions[-1]), Firing(
            float(np.max(instants)), float(instants[last]), float(np.max(times)))))
    out = {}
    for name, found in parts.items():
        found.sort(key=lambda p: p[0])
        f = found[0][1]
        for _, later in found[1:]:
            f = f.then(later)
        out[name] = f
    return out


def _round_off(tr) -> float:
    """How far from the guard's value a measure is still on it: a few ulps of the value.  A state
    mapped onto a new configuration (a release at a stop) lands on the value to round-off, on
    either side by the route that mapped it; from there a departure against the guard's direction
    is no crossing against it, and a hair past the value is not past it."""
    return 16.0 * np.finfo(float).eps * max(1.0, abs(float(tr.guard.value)))


def _past(tr, closest: float) -> bool:
    """Was the guard, where nearest its value, already on the side it fires to?  (It stayed past
    its value: a guard fires on a crossing in its direction, which never came.)"""
    return bool(tr.guard.direction * (closest - tr.guard.value) > _round_off(tr))


def describe(records: list[dict]) -> str:
    return "\n".join(_describe_one(r) for r in records)


def _describe_one(r: dict) -> str:
    if r.get("timer"):
        return f"time guard of '{r['transition']}' (at = {r['value']:.9g} s) did not fire: {r['timer']}"
    if r.get("crossed_against") is not None:
        against = "decreasing" if r["direction"] == "increasing" else "increasing"
        return (f"guard of '{r['transition']}' ({r['guard']} {r['direction']} to {r['value']:.9g}) did not fire: "
                f"the measure crossed {r['value']:.9g} {against} at t = {r['crossed_against']:.6g} s, against the "
                f"guard's direction ({r['direction']}); check `direction`")
    if r.get("outside_when"):
        return (f"guard of '{r['transition']}' ({r['guard']} {r['direction']} to {r['value']:.9g}) did not fire"
                + (" again" if r.get("last_fired") is not None else "")
                + f": from t = {r['t_from']:.6g} s to {r['t_final']:.6g} s the run never entered its `when` region "
                f"({r['outside_when']}), where alone it fires")
    if r.get("moved_away"):
        return (f"guard of '{r['transition']}' ({r['guard']} {r['direction']} to {r['value']:.9g}) did not fire "
                f"again: since its last event at t = {r['last_fired']:.9g} s the measure moved away from its value "
                f"and never turned back towards it (at t = {r['t_final']:.6g} s it is {r['final']:.9g}, "
                f"{abs(r['final'] - r['value']):.3g} from it)")
    return (
        f"guard of '{r['transition']}' ({r['guard']} {r['direction']} to {r['value']:.9g}) did not fire: "
        f"closest {r['closest']:.9g} at t = {r['t']:.6g} s"
        + (" (where the run entered the configuration)" if r.get("at_entry") else "")
        + (f", {r['distance']:.3g} past it, on the side it fires to (a guard fires on a crossing in "
           "its direction)" if r.get("past") else f", {r['distance']:.3g} short")
        + (f" (since it last fired at t = {r['last_fired']:.9g} s)" if r.get("last_fired") is not None else ""))
