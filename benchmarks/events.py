"""The event path, per event: ``examples/three_bar_cycle.toml`` (7.5 s, ~524 impacts).

Runs the scene with ``pcmm.simulate`` at its own settings and prints the mean CPU time per
event split into its four parts, plus the whole run's CPU time:

* **location** - finding the guard's crossing on an accepted step's dense output
  (``pcmm.ode.integrators._locate``: the grid, Brent's/Newton's root, the graze search);
* **impulse** - the impulse solve (``pcmm.events.impulse.solve_impulse``, the paper's Eqs. 21-43); a bounce
  taken by the one compiled call (``transitions.solve_bounce``) counts that call here, which also forms
  the event record's numbers and the projection onto the drives;
* **switch** - entering the next configuration: ``pcmm.events.transitions.switch`` (the state
  mapped and projected, ``pcmm.events.entry.enter``; a bounce's ``enter_bounce``, which stays in its
  configuration) and ``pcmm.run.actions.transform`` (the event kept, the locks, the next configuration
  adopted); the rest of the kind's handler (the
  event record, the contact state) is printed as **handler, other**;
* **re-arm** - the guards of the next segment built and checked (``pcmm.run.loop._guards`` and
  ``_pending``).

Between two events it times the same way the **flight audit** (``pcmm.run.audit.FlightAudit.flight``,
the flight's energy balance measured as it ends) and the **recording** of the segment
(``pcmm.run.loop._record``).

Each part is timed with ``time.process_time`` around its calls (CPU time: on a machine shared
by many processes the wall time mostly measures the neighbours), summed over the run and
divided by the number of events, each part's least over ``--reps`` runs (the machine's load
only ever adds); the whole run is timed once more without the wrappers.  The
numbers of events and impacts are printed so that a change can be checked to keep them::

    python benchmarks/events.py [--reps 3] [--replay 8]

On a shared machine those figures move by +-30 % from one run to the next.  ``--replay N`` adds
a measure the load hardly moves: the calls of the parts that are functions of their arguments
(the impulse solve, the entry of ``transitions.switch`` or ``enter_bounce``, the event record, a
bounce's ``bounce_record`` included, the guard residual; the entry's projection onto the
configuration's constraints, ``PartitionedCoordinates.project``, also counted in the entry; the
re-arm's check of the guards already at their crossing, ``loop._pending``)
are captured in one run and each call is repeated ``N`` times, its least time kept
(``time.perf_counter``: a repeat preempted or slowed by a neighbour is not the least), summed and
divided by the number of events.  The caches are warm in these repeats, so they are a lower
bound of the same parts in a run, where the integration between two events has evicted them.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # no BLAS threads spinning on a shared machine

import argparse  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from pathlib import Path  # noqa: E402

import pcmm  # noqa: E402
from pcmm.events import transitions  # noqa: E402
from pcmm.model.partitioned import PartitionedCoordinates  # noqa: E402
from pcmm.ode import integrators  # noqa: E402
from pcmm.run import actions, audit, loop  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "examples" / "three_bar_cycle.toml"
PARTS = {  # part: (module, attribute) whose calls are timed
    "location": [(integrators, "_locate")],
    # (a bounce in one compiled call, since h-cbounce: its impulse, record numbers and entry's projection)
    "impulse": [(transitions, "solve_impulse"), (transitions, "solve_bounce")],
    "switch": [(transitions, "switch"), (transitions, "enter_bounce"), (actions, "transform")],
    "re-arm": [(loop, "_guards"), (loop, "_pending")],
}
BETWEEN = {  # the glue of each segment between two events, timed the same way
    "flight audit": [(audit.FlightAudit, "flight")],  # the flight's energy audit, as it ends
    "recording": [(loop, "_record")],  # the segment kept
}
HANDLERS = [(actions.GUARD_ACTIONS, "transition"), (actions.GUARD_ACTIONS, "unmerge")]
REPLAYED = {  # the parts whose calls depend on their arguments alone (and scratch space): [(module, attribute)]
    "impulse": [(transitions, "solve_impulse"), (transitions, "solve_bounce")],  # (the compiled bounce's one call)
    "entry": [(transitions, "switch"), (transitions, "enter_bounce")],  # (a bounce's entry, since h-bounce)
    "record": [(transitions, "event_record"), (transitions, "bounce_record")],  # (a bounce's record, since h-bounce)
    "guard residual": [(actions, "guard_residual")],
    # inside the entry above, counted there too: a bounce's projection onto its configuration's drives
    "(entry's projection)": [(PartitionedCoordinates, "project")],
    "re-arm's pending check": [(loop, "_pending")],  # the guards at or past their crossing at the start
}


def timed(spent: dict, part: str, fn):
    def wrapper(*args, **kwargs):
        t0 = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            spent[part] += time.process_time() - t0
    return wrapper


def instrumented_run(scene):
    """One run with every part's calls timed; returns (trajectory, CPU seconds per part)."""
    spent = defaultdict(float)
    saved = []
    try:
        for part, places in {**PARTS, **BETWEEN}.items():
            for mod, name in places:
                if not hasattr(mod, name):  # (a tree before the name existed)
                    continue
                saved.append((mod, name, getattr(mod, name)))
                setattr(mod, name, timed(spent, part, getattr(mod, name)))
        for table, key in HANDLERS:
            saved.append((table, key, table[key]))
            table[key] = timed(spent, "handler", table[key])
        t0 = time.process_time()
        traj = pcmm.simulate(scene)
        spent["run"] = time.process_time() - t0
    finally:
        for owner, name, original in reversed(saved):
            if isinstance(owner, dict):
                owner[name] = original
            else:
                setattr(owner, name, original)
    return traj, spent


def replayed(scene, repeats: int) -> tuple[int, dict]:
    """(events, {part: seconds per event}): each replayed part's calls of one run repeated
    ``repeats`` times, the least time of each call summed (see the module's text)."""
    calls = {(mod, name): [] for places in REPLAYED.values() for mod, name in places if hasattr(mod, name)}
    saved = []

    def capture(key, fn):
        def wrapper(*args, **kwargs):
            calls[key].append((args, kwargs))
            return fn(*args, **kwargs)
        return wrapper
    try:
        for mod, name in calls:
            saved.append((mod, name, getattr(mod, name)))
            setattr(mod, name, capture((mod, name), getattr(mod, name)))
        traj = pcmm.simulate(scene)
    finally:
        for mod, name, original in reversed(saved):
            setattr(mod, name, original)
    out = {}
    clock = time.perf_counter
    for part, places in REPLAYED.items():
        out[part] = 0.0
        for key in places:
            if key not in calls:
                continue
            fn, least = getattr(*key), [float("inf")] * len(calls[key])
            for _ in range(repeats):
                for i, (args, kwargs) in enumerate(calls[key]):
                    t0 = clock()
                    fn(*args, **kwargs)
                    least[i] = min(least[i], clock() - t0)
            out[part] += sum(least) / len(traj.events)
    return len(traj.events), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=3, help="runs of each kind; the minimum is printed")
    ap.add_argument("--replay", type=int, default=0, metavar="N",
                    help="also repeat each call of the replayed parts N times and print their least sums")
    args = ap.parse_args(argv)
    scene = pcmm.load_scene(SCENE)
    pcmm.simulate(scene)  # warm: models built, modules imported
    best, plain, counts = {}, [], set()
    for _ in range(args.reps):
        traj, spent = instrumented_run(scene)
        counts.add((len(traj.events), traj.stats["impacts"]))
        for part, s in spent.items():  # each part's minimum over the runs: the least disturbed by the load
            best[part] = min(best.get(part, s), s)
        t0 = time.process_time()
        traj = pcmm.simulate(scene)
        plain.append(time.process_time() - t0)
        counts.add((len(traj.events), traj.stats["impacts"]))
    if len(counts) != 1:
        print(f"the runs disagree on their numbers of events and impacts: {sorted(counts)}")
        return 1
    (n_events, n_impacts), = counts
    us = 1e6 / n_events
    switch_other = best["handler"] - best["impulse"] - best["switch"]
    print(f"{SCENE.name}: {n_events} events ({n_impacts} impacts); CPU time, each part the least of {args.reps} runs, "
          f"load {os.getloadavg()[0]:.1f}")
    print(f"  per event: location {best['location'] * us:8.1f} us")
    print(f"             impulse  {best['impulse'] * us:8.1f} us")
    print(f"             switch   {best['switch'] * us:8.1f} us")
    print(f"             re-arm   {best['re-arm'] * us:8.1f} us")
    total = sum(best[k] for k in ("location", "impulse", "switch", "re-arm"))
    print(f"             total    {total * us:8.1f} us  (handler, other: {max(switch_other, 0.0) * us:.1f} us)")
    print(f"  the event all told (the four and the handler's rest; issue 26's target: 100 us): "
          f"{(total + max(switch_other, 0.0)) * us:.1f} us")
    print("  between events, per event: " + ", ".join(f"{part} {best[part] * us:.1f} us" for part in BETWEEN))
    print(f"  whole run: {min(plain):.3f} s CPU (instrumented: {best['run']:.3f} s)")
    if args.replay:
        n, parts = replayed(scene, args.replay)
        print(f"  replayed, each call's least of {args.replay} repeats (warm caches), per event over {n} events: "
              + ", ".join(f"{part} {s * 1e6:.1f} us" for part, s in parts.items())
              + f"; load {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
