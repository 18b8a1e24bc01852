"""A stored chunk's series derived three ways: the per-sample reference, the whole-segment pass, and the
whole-segment pass over every segment of one context at once.

Runs SCENE in memory (``--t-end``), then, alternating for ``--rounds`` rounds, writes its segments as
one chunk (``pcmm.results.store.write_chunk``, the series derived as a store's writer derives them)
with each route in turn:

* ``per-sample``: ``pcmm.run.series.derived_series`` set to ``per_sample_series`` (main's route at 661ae69),
  a segment at a time;
* ``whole-segment``: the default ``derived_series`` (``whole_segment_series`` where it applies), a
  segment at a time;
* ``grouped``: the same, after ``store.derive_together`` derived the segments sharing a context in one
  call each (what ``StoreWriter.flush`` does).

Prints the CPU time of each write (process time: the writer is this thread), the medians, their
ratios, and the largest difference between any two routes' series relative to each series' scale
(max(1, |x|)).  Then it times the first read of the run's series kept in memory (``traj.series("kinetic")``
on records not yet derived, which derives every series of every segment), alternating: ``in memory,
one by one`` (``trajectory.derive_series`` off: each segment derives its own, main's route before
h-read) and ``in memory, grouped`` (the default: the segments of one tree context in one call).
With ``--stored-runs`` it then times whole runs in this process, alternating: stored
(``pcmm.simulate(scene, store=DIR)``: the run, its chunks written on the store's thread, the end)
with each route, and kept in memory with its series not read (the run alone).

    python benchmarks/series_pass.py /tmp/bb1k.toml --rounds 5 [--stored-runs]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

import pcmm
from pcmm.results import store, trajectory
from pcmm.run import series

KEYS = ("q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces")
DEFAULT, TOGETHER = series.derived_series, store.derive_together
#: route: (derived_series to use, whether the segments sharing a context are derived together)
ROUTES = {"per-sample": (series.per_sample_series, False), "whole-segment": (DEFAULT, False),
          "grouped": (DEFAULT, True)}


def fresh_records(log) -> list:
    """The log's segments as records not yet derived (each write derives them again)."""
    log._records.clear()
    return [log[i] for i in range(len(log))]


def use(route: str) -> None:
    """Set the route (``None``: the defaults back)."""
    derive, together = ROUTES[route] if route else (DEFAULT, True)
    series.derived_series = derive
    store.derive_together = TOGETHER if together else (lambda log: 0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("--t-end", type=float, default=None)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--stored-runs", action="store_true", help="time whole runs too (stored, and in memory)")
    args = ap.parse_args(argv)
    scene = pcmm.load_scene(args.scene)
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=args.t_end) if args.t_end else pcmm.RunOptions())
    log = traj.segments
    samples = sum(len(s.t) for s in fresh_records(log))
    print(f"{args.scene.name}: {len(log)} segments, {samples} samples, {len(traj.events)} events")
    times = {name: [] for name in ROUTES}
    kept = {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for name in ROUTES:
                use(name)
                try:
                    records = fresh_records(log)
                    t0 = time.process_time()
                    store.derive_together(log)
                    store.write_chunk(Path(tmp) / f"{r}.npz", records, [])
                    times[name].append(time.process_time() - t0)
                finally:
                    use(None)
                kept[name] = records
                print(f"round {r + 1} {name}: {times[name][-1] * 1e3:.1f} ms", flush=True)
    worst = 0.0
    for other in ("whole-segment", "grouped"):
        for a, b in zip(kept[other], kept["per-sample"]):
            for key in KEYS:
                x, y = np.asarray(getattr(a, key)), np.asarray(getattr(b, key))
                worst = max(worst, float(np.max(np.abs(x - y), initial=0.0))
                            / max(1.0, float(np.max(np.abs(y), initial=0.0))))
    med = {name: statistics.median(v) for name, v in times.items()}
    for name, m in med.items():
        print(f"chunk, {name}: median {m * 1e3:.1f} ms ({min(times[name]) * 1e3:.1f}-{max(times[name]) * 1e3:.1f}), "
              f"{m / len(log) * 1e6:.1f} us per segment; per-sample / this {med['per-sample'] / m:.2f}x")
    print(f"largest relative difference of any series from the per-sample route's: {worst:.3g}")
    in_memory(traj, args.rounds)
    if args.stored_runs:
        runs(scene, args)


def in_memory(traj, rounds: int) -> None:
    """The first read of an in-memory run's series: segment by segment, then grouped, alternating."""
    log, grouped = traj.segments, trajectory.derive_series
    times = {"in memory, one by one": [], "in memory, grouped": []}
    kept = {}
    for r in range(rounds):
        for name, spent in times.items():
            trajectory.derive_series = grouped if name.endswith("grouped") else (lambda segments: 0)
            try:
                fresh_records(log)
                traj.segments.__dict__.pop("_walked", None)  # (the log's mark of being walked already)
                t0 = time.process_time()
                kept[name] = traj.series("kinetic")
                spent.append(time.process_time() - t0)
            finally:
                trajectory.derive_series = grouped
            print(f"round {r + 1} {name}: {spent[-1] * 1e3:.1f} ms", flush=True)
    a, b = kept.values()
    same = np.array_equal(a, b)
    med = {name: statistics.median(v) for name, v in times.items()}
    one = med["in memory, one by one"]
    for name, m in med.items():
        print(f"{name}: median {m * 1e3:.1f} ms ({min(times[name]) * 1e3:.1f}-{max(times[name]) * 1e3:.1f}), "
              f"{m / len(log) * 1e6:.1f} us per segment; one by one / this {one / m:.2f}x")
    print(f"the kinetic energy the same bits both ways: {same}")


def runs(scene, args) -> None:
    """Whole runs in this process, alternating: stored with each route, and in memory (series not read)."""
    options = pcmm.RunOptions(t_end=args.t_end) if args.t_end else pcmm.RunOptions()
    names = [*ROUTES, "in memory"]
    times = {name: [] for name in names}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for name in names:
                use(name if name in ROUTES else None)
                try:
                    t0 = time.process_time()
                    traj = pcmm.simulate(scene, options, store=None if name == "in memory" else Path(tmp) / f"{name}-{r}")
                    times[name].append(time.process_time() - t0)
                finally:
                    use(None)
                print(f"run {r + 1} {name}: {times[name][-1]:.3f} s CPU, {len(traj.events)} events", flush=True)
    med = {name: statistics.median(v) for name, v in times.items()}
    alone = med["in memory"]
    for name, m in med.items():
        extra = "" if name == "in memory" else f"; the store adds {(m - alone) * 1e3:.0f} ms to the run in memory"
        print(f"run, {name}: median {m:.3f} s ({min(times[name]):.3f}-{max(times[name]):.3f}){extra}")


if __name__ == "__main__":
    main()
