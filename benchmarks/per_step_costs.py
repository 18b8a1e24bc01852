"""The per-step costs of a run with locks and flights: the holding-force guards and the flights'
energy audit, prepared (this tree) against their unprepared routes, on whole runs.

``pcmm.simulate`` of ``examples/three_bar_cycle.toml`` (531 events, 516 audited flights), warm, in
one process, CPU time (``time.process_time``), alternating the two routes run by run:

* *prepared*: the guards' holding forces from :meth:`pcmm.events.holding.Holds.evaluator` (the map
  onto the reference configuration, the lock rows and the force elements built once per segment),
  the audit's powers at the quadrature nodes from :func:`pcmm.run.audit.drive_powers` (nodes
  unpacked at once, drive rows built once): the default;
* *unprepared*: :meth:`Holds.forces` at every guard value and :func:`pcmm.run.audit.power` node
  by node, as before.

Both must give the same bits: the script prints whether the two runs' event times and
``stats["macro_impacts"]`` (the audit's figures) are identical, and the time each route spends in
the guards' holding forces and in the audit.

    python benchmarks/per_step_costs.py [--scene examples/three_bar_cycle.toml] [--reps 8]
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import pcmm  # noqa: E402
from pcmm.events import holding  # noqa: E402
from pcmm.run import audit  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", type=Path, default=ROOT / "examples" / "three_bar_cycle.toml")
    ap.add_argument("--reps", type=int, default=8, help="alternating runs per route (after one warm-up round)")
    args = ap.parse_args(argv)
    scene = pcmm.load_scene(args.scene)
    prepared, powers, flight = holding.Holds.evaluator, audit.drive_powers, audit.FlightAudit.flight
    spent = {"guards": 0.0, "audit": 0.0}

    def timed(fn, key):
        def call(*a, **kw):
            t0 = time.process_time()
            try:
                return fn(*a, **kw)
            finally:
                spent[key] += time.process_time() - t0
        return call

    def unprepared(self, cfg):
        return lambda t, q, v: self.forces(cfg, t, q, v)

    routes = {"prepared": (prepared, powers), "unprepared": (unprepared, lambda cfg, coords, times, states: None)}
    times = {name: [] for name in routes}
    parts = {name: {"guards": [], "audit": []} for name in routes}
    runs = {}
    audit.FlightAudit.flight = timed(flight, "audit")  # each flight is measured as it ends
    try:
        for rep in range(args.reps + 1):
            for name in (routes if rep % 2 else reversed(list(routes))):
                evaluator, drive_powers = routes[name]
                holding.Holds.evaluator = lambda self, cfg, e=evaluator: timed(e(self, cfg), "guards")
                audit.drive_powers = drive_powers
                spent.update(guards=0.0, audit=0.0)
                t0 = time.process_time()
                runs[name] = pcmm.simulate(scene)
                if rep:
                    times[name].append(time.process_time() - t0)
                    for key in spent:
                        parts[name][key].append(spent[key])
    finally:
        holding.Holds.evaluator, audit.drive_powers, audit.FlightAudit.flight = prepared, powers, flight
    a, b = runs["prepared"], runs["unprepared"]
    same = ([e["t"] for e in a.events] == [e["t"] for e in b.events]
            and repr(a.stats["macro_impacts"]) == repr(b.stats["macro_impacts"]))
    print(f"{args.scene.name}: {len(a.events)} events, CPU s per run (median of {args.reps}), load {os.getloadavg()[0]:.1f}")
    for name in routes:
        med = {k: statistics.median(v) for k, v in parts[name].items()}
        print(f"  {name:10s} run {statistics.median(times[name]):.3f}  guards' holding forces {med['guards']:.3f}"
              f"  audit {med['audit']:.3f}   runs: " + " ".join(f"{x:.2f}" for x in times[name]))
    print(f"  unprepared / prepared: {statistics.median(times['unprepared']) / statistics.median(times['prepared']):.2f}x;"
          f" identical event times and audit figures: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
