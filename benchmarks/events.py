"""The event path, per event: ``examples/three_bar_cycle.toml`` (7.5 s, ~524 impacts).

Runs the scene with ``pcmm.simulate`` at its own settings and prints the mean CPU time per
event split into its four parts, plus the whole run's CPU time:

* **location** - finding the guard's crossing on an accepted step's dense output
  (``pcmm.ode.integrators._locate``: the grid, Brent's/Newton's root, the graze search);
* **impulse** - the impulse solve (``pcmm.events.impulse.solve_impulse``, the paper's Eqs. 21-43);
* **switch** - entering the next configuration: ``pcmm.events.transitions.switch`` (the state
  mapped and projected, ``pcmm.events.entry.enter``) and ``pcmm.run.actions.transform`` (the
  event kept, the locks, the next configuration adopted); the rest of the kind's handler (the
  event record, the contact state) is printed as **handler, other**;
* **re-arm** - the guards of the next segment built and checked (``pcmm.run.loop._guards`` and
  ``_pending``).

Each part is timed with ``time.process_time`` around its calls (CPU time: on a machine shared
by many processes the wall time mostly measures the neighbours), summed over the run and
divided by the number of events, each part's least over ``--reps`` runs (the machine's load
only ever adds); the whole run is timed once more without the wrappers.  The
numbers of events and impacts are printed so that a change can be checked to keep them::

    python benchmarks/events.py [--reps 3]
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
from pcmm.ode import integrators  # noqa: E402
from pcmm.run import actions, loop  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "examples" / "three_bar_cycle.toml"
PARTS = {  # part: (module, attribute) whose calls are timed
    "location": [(integrators, "_locate")],
    "impulse": [(transitions, "solve_impulse")],
    "switch": [(transitions, "switch"), (actions, "transform")],
    "re-arm": [(loop, "_guards"), (loop, "_pending")],
}
HANDLERS = [(actions.GUARD_ACTIONS, "transition"), (actions.GUARD_ACTIONS, "unmerge")]


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
        for part, places in PARTS.items():
            for mod, name in places:
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=3, help="runs of each kind; the minimum is printed")
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
    print(f"  whole run: {min(plain):.3f} s CPU (instrumented: {best['run']:.3f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
