"""A stored chunk's series derived both ways: the per-sample reference against the whole-segment pass.

Runs SCENE in memory (``--t-end``), then, alternating for ``--rounds`` rounds, writes its segments as one
chunk (``pcmm.results.store.write_chunk``, the series derived as a store's writer derives them) with
``pcmm.run.series.derived_series`` set to each route in turn: the per-sample loop
(``per_sample_series``) and the default (``whole_segment_series`` where it applies).  Prints the CPU
time of each write (process time: the writer's thread is this one), the medians, their ratio, and the
largest difference between the two routes' series relative to each series' scale (max(1, |x|)).
With ``--stored-runs`` it then times whole stored runs, ``pcmm.simulate(scene, store=DIR)`` in this
process (the run, its chunks written on the store's thread, the end), the two routes and a run kept
in memory (its series not read) alternating.

    python benchmarks/series_pass.py /tmp/bb1k.toml --t-end 903.04728 --rounds 5 [--stored-runs]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

import pcmm
from pcmm.results import store
from pcmm.run import series

KEYS = ("q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces")


def fresh_records(log) -> list:
    """The log's segments as records not yet derived (each write derives them again)."""
    log._records.clear()
    return [log[i] for i in range(len(log))]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("--t-end", type=float, default=None)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--stored-runs", action="store_true", help="time whole stored runs too")
    args = ap.parse_args(argv)
    scene = pcmm.load_scene(args.scene)
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=args.t_end) if args.t_end else pcmm.RunOptions())
    log = traj.segments
    samples = sum(len(s.t) for s in fresh_records(log))
    print(f"{args.scene.name}: {len(log)} segments, {samples} samples, {len(traj.events)} events")
    routes = {"per-sample": series.per_sample_series, "whole-segment": series.derived_series}
    times = {name: [] for name in routes}
    kept = {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for name, route in routes.items():
                series.derived_series = route
                try:
                    records = fresh_records(log)
                    t0 = time.process_time()
                    store.write_chunk(Path(tmp) / f"{r}.npz", records, [])
                    times[name].append(time.process_time() - t0)
                finally:
                    series.derived_series = routes["whole-segment"]
                kept[name] = records
                print(f"round {r + 1} {name}: {times[name][-1] * 1e3:.1f} ms", flush=True)
    worst = 0.0
    for a, b in zip(kept["whole-segment"], kept["per-sample"]):
        for key in KEYS:
            x, y = np.asarray(getattr(a, key)), np.asarray(getattr(b, key))
            worst = max(worst, float(np.max(np.abs(x - y), initial=0.0)) / max(1.0, float(np.max(np.abs(y), initial=0.0))))
    med = {name: statistics.median(v) for name, v in times.items()}
    for name, m in med.items():
        print(f"{name}: median {m * 1e3:.1f} ms ({min(times[name]) * 1e3:.1f}-{max(times[name]) * 1e3:.1f}), "
              f"{m / len(log) * 1e6:.1f} us per segment")
    print(f"per-sample / whole-segment: {med['per-sample'] / med['whole-segment']:.2f}x; "
          f"largest relative difference of any series: {worst:.3g}")
    if args.stored_runs:
        stored_runs(scene, args, routes)


def stored_runs(scene, args, routes) -> None:
    """Whole stored runs in this process, the routes alternating: CPU seconds each, medians, ratio."""
    options = pcmm.RunOptions(t_end=args.t_end) if args.t_end else pcmm.RunOptions()
    routes = {**routes, "in memory, no store": series.derived_series}  # the run alone, its series not read
    times = {name: [] for name in routes}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for name, route in routes.items():
                series.derived_series = route
                try:
                    t0 = time.process_time()
                    traj = pcmm.simulate(scene, options, store=None if name.startswith("in memory") else
                                         Path(tmp) / f"{name}-{r}")
                    times[name].append(time.process_time() - t0)
                finally:
                    series.derived_series = routes["whole-segment"]
                print(f"run {r + 1} {name}: {times[name][-1]:.3f} s CPU, {len(traj.events)} events",
                      flush=True)
    med = {name: statistics.median(v) for name, v in times.items()}
    for name, m in med.items():
        print(f"run, {name}: median {m:.3f} s ({min(times[name]):.3f}-{max(times[name]):.3f})")
    alone = med["in memory, no store"]
    print(f"stored run, per-sample / whole-segment: {med['per-sample'] / med['whole-segment']:.2f}x; what the store "
          f"adds to the run in memory: {(med['per-sample'] - alone) * 1e3:.0f} ms per-sample, "
          f"{(med['whole-segment'] - alone) * 1e3:.0f} ms whole-segment")


if __name__ == "__main__":
    main()
