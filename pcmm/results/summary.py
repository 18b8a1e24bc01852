"""The run summary (JSON) and the short human table of events."""
from __future__ import annotations

import math

from .trajectory import Trajectory


def summary(traj: Trajectory, initial_configuration: str | None = None) -> dict:
    last = traj.segments[-1] if traj.segments else None
    final = {}
    if last is not None:
        final = {"t": float(last.t[-1]), "configuration": last.configuration,
                 "theta": {n: float(x) for n, x in zip(last.links, last.theta[-1])},
                 "omega": {n: float(x) for n, x in zip(last.links, last.omega[-1])},
                 "q": {n: float(x) for n, x in zip(last.coordinates, last.q[-1])},
                 "v": {n: float(x) for n, x in zip(last.coordinates, last.v[-1])},
                 "kinetic_energy": float(last.kinetic[-1]), "potential_energy": float(last.potential[-1])}
    return {
        "scene": traj.scene, "scene_name": traj.scene_name, "impact": traj.impact,
        "status": traj.status, "message": traj.message,
        "configuration_initial": initial_configuration or (traj.segments[0].configuration if traj.segments else None),
        "configuration_final": last.configuration if last is not None else None,
        "events": list(traj.events), "final": final, "stats": traj.stats,
        # the final configuration's guards that did not fire: where each came closest to its value
        "closest_approach": traj.stats.get("closest_approach", []),
        "warnings": list(traj.stats.get("warnings", [])) + [w for e in traj.events for w in e.get("warnings", ())],
    }


def _others_at_once(e: dict, num) -> str:
    """The other contacts of an impact that closed several at once: the row's vn and P are its
    first contact's alone (its ``simultaneous`` block holds each), so the others are named with
    their own impulse, or their speed away where they separate."""
    block = e.get("simultaneous") or {}
    others = [(name, c) for name, c in block.items() if name != e["name"]]
    if not others:
        return ""
    def one(name, c):
        if c.get("mode") == "separate":
            return f"{name} separates (vn+ {num(c['normal_velocity']['after']).strip()} m/s)"
        return (f"{name} P_n {num(c['impulse']['normal']).strip()}"
                + (f" P_t {num(c['impulse']['tangential']).strip()}" if c["impulse"].get("tangential") else "") + " N s")
    return f"  at once: {', '.join(one(name, c) for name, c in others)} (vn, P: {e['name']}'s alone)"


def event_table(traj: Trajectory) -> str:
    if not traj.events:
        return "no configuration transformation before t_end"
    wn = min(40, max(len("event"), *(len(e["name"]) for e in traj.events)))
    wc = min(48, max(len("from -> to"), *(len(e["from"] + " -> " + e["to"]) for e in traj.events)))
    wt = max(6, *(len(e["transition"]) for e in traj.events))
    head = (f"{'t [s]':>13}  {'event':<{wn}} {'kind':<7} {'type':<{wt}} {'from -> to':<{wc}} "
            f"{'vn- [m/s]':>11} {'vn+ [m/s]':>11} {'P [N s]':>11} {'KE- [J]':>11} {'KE+ [J]':>11}")
    rows = []

    def num(x):
        return f"{x + 0.0:11.4e}"  # + 0.0: no "-0.0000e+00"
    for e in traj.events:
        imp = e.get("impulse") or {}
        note = ""
        if imp.get("joint") and "moment" in imp:  # a revolute joint stop: its rate, its moment (at the arm)
            note = (f"  joint stop {imp['joint']}: vn in rad/s, P at its {imp['arm']:g} m arm" if imp.get("arm")
                    else f"  joint stop {imp['joint']}: vn in rad/s, P in N m s (no arm)")
        elif imp.get("joint"):  # a prismatic joint stop: its rate and axial impulse, the header's units
            note = (f"  joint stop {imp['joint']} (prismatic): vn and P along its axis,"
                    " signed along the stop's normal (vn- < 0 closing, P > 0 pushing apart)")
        elif imp.get("tangential"):  # a pin's or a frictional contact's impulse is two-dimensional
            note = (f"  2-D impulse: P_t {num(imp['tangential']).strip()}, |P| "
                    f"{num(math.hypot(imp['normal'], imp['tangential'])).strip()} N s (the P column is P_n)")
        rows.append(
            f"{e['t']:13.9f}  {e['name'][:wn]:<{wn}} {e['kind']:<7} {e['transition']:<{wt}} "
            f"{(e['from'] + ' -> ' + e['to'])[:wc]:<{wc}} {num(e['normal_velocity']['before'])} "
            f"{num(e['normal_velocity']['after'])} {num(imp['normal'])} "
            f"{num(e['kinetic_energy_before'])} {num(e['kinetic_energy_after'])}"
            + ("  merge" if e["merge"] else "") + note + _others_at_once(e, num))
    # a long run: its first and last 20 events, and every transformation between them (a merge, a
    # latch, a release) with the bounces in between counted, not shown
    shown = [i for i, e in enumerate(traj.events)
             if i < 20 or i >= len(traj.events) - 20 or e["merge"] or e["transition"] != "stop"]
    out, last = [head, "-" * len(head)], -1
    for i in shown:
        if i > last + 1:
            n = i - last - 1
            out.append(f"  ... {n} more event{'s' if n > 1 else ''} (all in the summary JSON) ...")
        out.append(rows[i])
        last = i
    return "\n".join(out)
