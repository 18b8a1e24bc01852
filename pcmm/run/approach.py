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

import numpy as np

from ..model.configuration import Configuration
from ..ode.roots import minimize_bounded
from ..events.contact import contact_state
from ..scene.spec import Scene
from ..errors import UsageError
from ..results.trajectory import SegmentRecord, Trajectory


def guard_series(cfg: Configuration, tr, q: np.ndarray) -> np.ndarray:
    """The guard's measure (or the contact gap) at each row of ``q`` (samples x nv)."""
    if tr.guard.type == "coordinate":
        row, offset = cfg.measure_row(tr.guard.measure)
        return q @ row + offset
    zero = np.zeros(cfg.nv)
    return np.array([contact_state(cfg, qi, zero, tr.contact)[1] for qi in q])


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
    segs = _segments_in(traj, cfg.name, watched if not (reactions or timers) else None)
    if not segs:
        return []
    out = [r for r in (_timer_missed(tr, segs, traj) for tr in timers) if r is not None]
    out += [r for r in (_reaction_approach(tr, segs, traj) for tr in reactions) if r is not None]
    if not watched:
        return out
    t = np.concatenate([s.t for s in segs])
    q = np.concatenate([s.q for s in segs])
    owner = np.concatenate([np.full(s.t.size, k) for k, s in enumerate(segs)])
    for tr in watched:
        # a collision resolved by a contact law lasts from its first contact to the separation
        # (t_end), where the gap crosses back through its value: that crossing is not a miss
        fired = [e.get("t_end") or e["t"] for e in traj.events if e.get("name") == tr.name]
        after = t > max(fired) if fired else np.ones(t.size, bool)  # since it last fired
        if not after.any():
            continue
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
        out.append({"transition": tr.name, "guard": str(tr.guard.measure) if tr.guard.measure else "contact gap",
                    "value": tr.guard.value, "direction": "increasing" if tr.guard.direction > 0 else "decreasing",
                    "closest": gi, "t": ti, "distance": float(abs(gi - tr.guard.value)),
                    "last_fired": max(fired) if fired else None,
                    # nearest where the run entered the configuration (a release at a stop, say): it
                    # started there and never came closer, which is no near miss
                    "at_entry": ti == float(segs[k].t[0]) and _entered(traj, segs[k]),
                    "past": _past(tr, gi),
                    "crossed_against": _crossed_against(tr, t, g, owner)})
    return out


def _moved_away(tr, t: np.ndarray, g: np.ndarray, after: np.ndarray, owner: np.ndarray, last_fired: float) -> dict:
    """The record of a guard that, since it last fired, only moved away from its value: the distance
    grows from the first sample after the firing and has no minimum inside the run (the rate never
    turned back towards the value), so there is no closest approach to report (the first sample
    after a release read "5.5e-06 short" while the freed joint moved monotonically away from its
    stop).  ``closest``, ``t`` and ``distance`` are None; ``final`` and ``t_final``: where the
    measure is at the run's last sample."""
    k = int(np.flatnonzero(after)[-1])
    return {"transition": tr.name, "guard": str(tr.guard.measure) if tr.guard.measure else "contact gap",
            "value": tr.guard.value, "direction": "increasing" if tr.guard.direction > 0 else "decreasing",
            "closest": None, "t": None, "distance": None, "last_fired": last_fired, "at_entry": False,
            "past": False, "crossed_against": _crossed_against(tr, t, g, owner), "moved_away": True,
            "final": float(g[k]), "t_final": float(t[k])}


def _segments_in(traj: Trajectory, name: str, watched) -> list[SegmentRecord]:
    """The run's segments in configuration ``name``.  Where only ``watched`` guards are asked about
    and each has fired, only the segments since the earliest of their last firings matter (a
    guard's approach is read since it last fired): they are taken from the end, so that a stored
    run of a million bounces reads its last segments, not all of them into memory at once."""
    segments = traj.segments
    if watched:
        names, last = {tr.name for tr in watched}, {}
        for e in traj.events:
            if e.get("name") in names:
                last[e["name"]] = e.get("t_end") or e["t"]
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


def _timer_missed(tr, segs: list[SegmentRecord], traj: Trajectory) -> dict | None:
    """A time guard ``at = T`` that never fired because the run was not in its configuration at T:
    it entered later, or ended first."""
    if any(e.get("name") == tr.name for e in traj.events):
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


def _reaction_approach(tr, segs: list[SegmentRecord], traj: Trajectory) -> dict | None:
    """The closest approach of a reaction guard's holding force (or moment) to its value, over
    the recorded samples of the run in the configuration since the guard last fired (the hold
    is an algebraic function of the state: its samples are as fine as the output's)."""
    label = f"{tr.guard.of}.hold"
    fired = [e["t"] for e in traj.events if e.get("name") == tr.name]
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
