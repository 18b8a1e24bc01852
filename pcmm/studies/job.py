"""One run of a design study: the varied scene rebuilt in the worker, simulated, and reduced
to one row of quantities.  A run that fails is a row with its status and error message."""
from __future__ import annotations

import hashlib
import json
import math
import time
import traceback
from dataclasses import dataclass
from typing import Any, Iterable

from ..errors import PcmmError, SceneError, SimulationError, UsageError

#: the quantities of every row, after the swept values, ``status`` and ``error``
QUANTITIES = {
    "events": "number of events (impacts, merges, switches, releases)",
    "impacts": "number of events with an impulse",
    "first_impact_t": "time of the first impact, s",
    "first_impulse": "normal impulse P_n of the first impact, N s; its normal part only (a pin's or a frictional "
                     "contact's tangential part is in first_impulse_magnitude; of contacts closed at once, the "
                     "first one's, as the event's P)",
    "peak_impulse": "largest |normal impulse P_n| at one contact over the run, N s; the normal part only, every "
                    "contact of an impact closing several at once counted",
    "total_impulse": "sum of |normal impulse P_n| over the run's impacts and their contacts, N s; the normal "
                     "part only",
    "first_impulse_magnitude": "|P| = sqrt(P_n^2 + P_t^2) of the first impact's contact impulse, normal and "
                               "tangential parts (= |first_impulse| without friction), N s",
    "peak_impulse_magnitude": "largest |P| = sqrt(P_n^2 + P_t^2) at one contact over the run, N s",
    "total_impulse_magnitude": "sum of |P| = sqrt(P_n^2 + P_t^2) over the run's impacts and their contacts, N s",
    "kinetic_energy_lost": "sum over impacts of KE before - KE after, J",
    "energy_dissipated": "sum over impacts of KE before + drive work - KE after, J (a collision resolved by a "
                         "continuous contact law: the kinetic + potential energy lost over its duration); "
                         "empty when a run's record cannot give it",
    "max_holding_force": "largest |holding force or moment| of any lock (stats.holding), N or N m; "
                         "empty when nothing was locked (a pinned point's stance force is not a lock's: "
                         "collect stats.holding.NAME.normal.max for it)",
    "last_merge_t": "time of the run's last merge (a latch, or a stop's bounces accumulated into a lock), s; "
                    "empty when none",
    "configuration_final": "the configuration the run ends in",
    "t_final": "the time the run ends at, s",
    "solve_s": "the solve's own wall time (integration and impacts), s",
    "wall_s": "the run's whole wall time in its worker (scene rebuild, model build, solve, summary), s",
}
SUMMARY_KEYS = ("scene", "scene_name", "impact", "status", "message", "configuration_initial",
                "configuration_final", "events", "final", "stats")



_BASES: dict[tuple[str, str], Any] = {}  # per worker process: the base scene, validated once


def _token(raw: dict) -> str:
    return hashlib.sha1(json.dumps(raw, sort_keys=True, default=str).encode()).hexdigest()


def base_scene(scene_path: str, raw: dict, token: str | None = None):
    """The scene parsed from ``raw``, kept per process (each worker validates it once)."""
    from ..scene.load import load_scene_data
    from ..scene.variations import read_urdf_cached
    key = (scene_path, token or _token(raw))
    if key not in _BASES:
        _BASES[key] = load_scene_data(raw, scene_path, read=read_urdf_cached)
    return _BASES[key]


@dataclass(frozen=True)
class Job:
    """What a worker needs for one run (picklable, small)."""

    index: int
    scene_path: str
    raw: dict
    token: str
    values: dict
    options: Any  # RunOptions
    collect: tuple[str, ...] = ()


def run_one(job: Job) -> dict:
    """Simulate one variation and return its row (never raises for a failing run)."""
    from ..run.loop import simulate
    from ..results.summary import summary
    t0 = time.perf_counter()
    row: dict[str, Any] = {"run": job.index, **job.values}
    summ, phases = None, {}
    try:
        scene = base_scene(job.scene_path, job.raw, job.token).with_values(job.values)
        try:
            traj = simulate(scene, job.options)
            row.update(status="complete", error="")
        except SimulationError as exc:
            if isinstance(exc.__context__, KeyboardInterrupt):
                raise exc.__context__ from None  # the sweep is stopping (Ctrl-C, SIGTERM): not a result of this run
            traj = exc.partial
            row.update(status="partial", error=exc.text())
        if traj is not None:
            summ = summary(traj, scene.initial_configuration)
            phases = contact_phase_losses(traj)
    except PcmmError as exc:
        row.update(status="failed", error=exc.text())
    except KeyboardInterrupt:
        raise
    except Exception as exc:  # a defect in pcmm must not lose the sweep: the run is a row with its error
        row.update(status="failed", error=f"{type(exc).__name__}: {exc} "
                   f"({traceback.extract_tb(exc.__traceback__)[-1].name})")
    row.update(quantities(summ, phases) if summ is not None else {})
    for path in job.collect:
        row[path] = collect_value(summ, path) if summ is not None else None
    row["wall_s"] = time.perf_counter() - t0
    return row


def failed_row(job: Job, status: str, message: str, seconds: float) -> dict:
    """The row of a run that gave no row itself: its worker crashed (``crashed``) or it was
    stopped at the time limit (``timeout``)."""
    return {"run": job.index, **job.values, "status": status, "error": message, "wall_s": seconds}


def contact_phase_losses(traj) -> dict[float, float]:
    """{start time: kinetic + potential energy lost} of each collision the run resolved by a
    continuous contact law (an event with ``t_end``): its contact force acts over the stay from
    ``t`` to ``t_end``, so what it dissipates is not an impulse's KE- + drive work - KE+ (gravity,
    springs and drives work during it) but the mechanical energy lost across the stay (the
    potential holds gravity and the springs; the contact's own elastic energy is zero at both ends,
    where the bodies meet and part)."""
    out = {}
    for e in traj.events:
        if e.get("t_end") is None or not e.get("impact"):
            continue
        stay = [s for s in traj.segments if s.t[0] >= e["t"] and s.t[-1] <= e["t_end"] and s.t[-1] > s.t[0]]
        if stay and stay[0].t[0] == e["t"] and stay[-1].t[-1] == e["t_end"]:
            first, last = stay[0], stay[-1]
            out[e["t"]] = float(first.kinetic[0] + first.potential[0] - last.kinetic[-1] - last.potential[-1])
    return out


def impulse_magnitude(impulse: dict) -> float:
    """|P| of an event's contact impulse: its normal part ``P_n`` and, where the contact takes one
    (a pin, a frictional point contact), its tangential part ``P_t``, sqrt(P_n^2 + P_t^2).  A
    pinned rocking block's strike has P_t / P_n = 0.24: its |P| is 3 % above P_n."""
    return math.hypot(float(impulse["normal"]), float(impulse.get("tangential") or 0.0))


def contact_impulses(event: dict) -> list[dict]:
    """The impulse at each contact of an impact: the event's own, or, for contacts closed at once
    (one complementarity solve), each contact's in its ``simultaneous`` block; the event's own
    ``impulse`` is then the first contact's alone (a rod landing flat on both ends: the table's
    total summed one end's and its peak could miss the larger end)."""
    block = event.get("simultaneous")
    return [c["impulse"] for c in block.values()] if block else [event["impulse"]]


def quantities(summ: dict, phases: dict | None = None) -> dict:
    """The per-run quantities of :data:`QUANTITIES` from a run summary; ``phases``: the energy
    lost over each collision resolved by a continuous contact law (:func:`contact_phase_losses`),
    by its start time.  Without it such a collision's dissipation is unknown, and so is the run's
    ``energy_dissipated`` (empty, never a partial sum)."""
    phases = phases or {}
    events = summ["events"]
    impacts = [e for e in events if e.get("impact")]
    at_contacts = [p for e in impacts for p in contact_impulses(e)]
    impulses = [abs(p["normal"]) for p in at_contacts]
    magnitudes = [impulse_magnitude(p) for p in at_contacts]
    merges = [e for e in events if e.get("merge")]
    dissipated = [e["energy_dissipated"] if e.get("energy_dissipated") is not None else phases.get(e["t"])
                  for e in impacts]
    holding = [abs(v) for h in ((summ.get("stats") or {}).get("holding") or {}).values()
               for v in (h.get("min"), h.get("max")) if isinstance(v, (int, float)) and math.isfinite(v)]
    return {
        "events": len(events), "impacts": len(impacts),
        "first_impact_t": impacts[0]["t"] if impacts else None,
        "first_impulse": impacts[0]["impulse"]["normal"] if impacts else None,
        "peak_impulse": max(impulses) if impulses else 0.0,
        "total_impulse": math.fsum(impulses),
        "first_impulse_magnitude": impulse_magnitude(impacts[0]["impulse"]) if impacts else None,
        "peak_impulse_magnitude": max(magnitudes) if magnitudes else 0.0,
        "total_impulse_magnitude": math.fsum(magnitudes),
        "kinetic_energy_lost": math.fsum(e["kinetic_energy_before"] - e["kinetic_energy_after"] for e in impacts),
        "energy_dissipated": None if None in dissipated else math.fsum(dissipated),
        "max_holding_force": max(holding) if holding else None,
        "last_merge_t": merges[-1]["t"] if merges else None,
        "configuration_final": summ.get("configuration_final"),
        "t_final": (summ.get("final") or {}).get("t"),
        "solve_s": (summ.get("stats") or {}).get("wall_s"),
    }


def collect_value(summ: dict, path: str):
    """The summary value at ``path`` (``final.theta.link3``, ``events[0].impulse.normal``,
    ``stats.steps``); ``None`` when this run's summary has none there."""
    from ..scene.variations import resolve
    try:
        steps = resolve(summ, path, "summary")
        node = summ
        for s in steps:
            node = node[s]
    except (SceneError, KeyError, IndexError, TypeError):
        return None
    return node if isinstance(node, (int, float, str, bool)) or node is None else json.dumps(node)


def check_collect(paths: Iterable[str]) -> None:
    import difflib
    for p in paths:
        head = p.split(".", 1)[0].split("[", 1)[0]
        if head not in SUMMARY_KEYS:
            close = difflib.get_close_matches(head, SUMMARY_KEYS, n=2, cutoff=0.4)
            hint = f" (did you mean {' or '.join(map(repr, close))}?)" if close else ""
            raise UsageError(f"--collect {p!r}: the summary has no {head!r}{hint}; its top-level keys: "
                             f"{', '.join(SUMMARY_KEYS)}")
