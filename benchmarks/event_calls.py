"""Function calls per event on the event path (Python and C, counted by ``sys.setprofile``), part by
part: a count the machine's load does not move, for changes too small for ``benchmarks/events.py``'s
timings to see on a shared machine.

    python benchmarks/event_calls.py [SCENE]   (default examples/three_bar_cycle.toml)

The scene is run once to warm up (models built, modules imported, the event log's readers made), then
once counted. Each call is counted in the innermost of the parts below that it runs in: the
location (``integrators._locate``), the re-arm (``loop._guards``, ``loop._pending``), the transition's
handler and what it calls (the guard residual, the stop's normal speed, the contacts closed with it,
the impulse, the held points' check, the event record, the switch with its entry), ``transform``'s
event-log append, progress check and flight audit (``FlightAudit.event``); and, between two events,
the flight's energy audit (``FlightAudit.flight``) and the segment's recording (``loop._record``).
Prints the mean per event of each part.
"""
from __future__ import annotations

import collections
import sys
from pathlib import Path

import pcmm
from pcmm.events import transitions
from pcmm.ode import integrators
from pcmm.results import event_log
from pcmm.run import actions, audit, loop

SCENE = Path(__file__).resolve().parents[1] / "examples" / "three_bar_cycle.toml"
PARTS = {  # part: the (owner, attribute) whose calls it counts
    "location": [(integrators, "_locate")],
    "re-arm": [(loop, "_guards"), (loop, "_pending")],
    "handler": [(actions.GUARD_ACTIONS, "transition")],
    "switch": [(transitions, "switch"), (actions, "transform")],
    "guard residual": [(actions, "guard_residual")],
    "normal speed": [(transitions, "normal_speed")],
    "closed with": [(transitions, "closed_with")],
    "impulse": [(transitions, "solve_impulse")],
    # a bounce in one compiled call (h-cbounce): the plan looked up, the call, its checks and its outcome
    "compiled bounce": [(transitions, "compiled_bounce"), (transitions, "solve_bounce"), (transitions, "_compiled_bounce")],
    "held points": [(transitions, "check_held_points_push")],
    "event record": [(transitions, "event_record"), (transitions, "bounce_record")],
    "entry": [(transitions, "enter"), (transitions, "enter_bounce")],
    "event log": [(event_log.EventLog, "append")],
    "progress check": [(actions, "check_progress")],
    "audit": [(audit.FlightAudit, "event")],
    "flight audit": [(audit.FlightAudit, "flight")],
    "recording": [(loop, "_record")],
}


def counted_run(scene) -> tuple[int, dict]:
    count: collections.Counter = collections.Counter()
    part = [None]

    def profile(frame, event, arg):
        if event in ("call", "c_call"):
            count[part[0]] += 1

    def wrap(fn, name):
        def counting(*args, **kwargs):
            outer = part[0]
            part[0] = name
            sys.setprofile(profile)
            try:
                return fn(*args, **kwargs)
            finally:
                part[0] = outer
                if outer is None:
                    sys.setprofile(None)
        return counting
    saved = []
    try:
        for name, places in PARTS.items():
            for owner, attr in places:
                if isinstance(owner, dict):
                    saved.append((owner, attr, owner[attr]))
                    owner[attr] = wrap(owner[attr], name)
                elif hasattr(owner, attr):
                    saved.append((owner, attr, getattr(owner, attr)))
                    setattr(owner, attr, wrap(getattr(owner, attr), name))
        traj = pcmm.simulate(scene)
    finally:
        for owner, attr, original in reversed(saved):
            if isinstance(owner, dict):
                owner[attr] = original
            else:
                setattr(owner, attr, original)
    return len(traj.events), {k: v for k, v in count.items() if k is not None}


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    scene = pcmm.load_scene(argv[0] if argv else SCENE)
    pcmm.simulate(scene)
    n, counts = counted_run(scene)
    print(f"{scene.name}: {n} events; function calls per event (Python and C), each in its innermost part:")
    for name in PARTS:
        if name in counts:
            print(f"  {name:15s} {counts[name] / n:8.1f}")
    print(f"  {'all':15s} {sum(counts.values()) / n:8.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
