"""Closed loops stepped by the compiled segment loop against pcmm's DOP853 stepping them in Python.

Whole ``pcmm.simulate`` runs of one scene under ``method = "auto"`` (a scene that names DOP853, as
``examples/andrews.toml`` does, keeps the Python stepping otherwise), alternating in one process:
``pcmm.model.partitioned.STEP_LOOPS_COMPILED`` on (the loops stepped in C++ over the compiled loop)
and off (pcmm's DOP853 in Python over the same compiled right-hand side), CPU time; the medians, the
per-pair ratio (median and range), the events of each and their largest time difference.  Prints only.

    python benchmarks/loop_stepping.py examples/andrews.toml [--reps 15]
"""
from __future__ import annotations

import argparse
import statistics
import time

import pcmm
from pcmm.model import partitioned


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--reps", type=int, default=15)
    args = ap.parse_args(argv)
    scene = pcmm.load_scene(args.scene)
    opts = pcmm.RunOptions(method="auto")
    times: dict[bool, list[float]] = {True: [], False: []}
    runs = {}
    for mode in (True, False):  # warm: models built and checked
        partitioned.STEP_LOOPS_COMPILED = mode
        runs[mode] = pcmm.simulate(scene, opts)
    for _ in range(args.reps):
        for mode in (True, False):
            partitioned.STEP_LOOPS_COMPILED = mode
            t = time.process_time()
            pcmm.simulate(scene, opts)
            times[mode].append(time.process_time() - t)
    partitioned.STEP_LOOPS_COMPILED = True
    ratios = sorted(b / a for a, b in zip(times[True], times[False]))
    fast, slow = runs[True], runs[False]
    gap = max((abs(a["t"] - b["t"]) for a, b in zip(fast.events, slow.events)), default=0.0)
    print(f"{args.scene}: {args.reps} alternating pairs, CPU time, method auto")
    print(f"  loops stepped in C++:    {1e3 * statistics.median(times[True]):8.1f} ms  ({len(fast.events)} events)")
    print(f"  loops stepped in Python: {1e3 * statistics.median(times[False]):8.1f} ms  ({len(slow.events)} events)")
    print(f"  speed-up per pair: median {statistics.median(ratios):.2f} (range {ratios[0]:.2f}-{ratios[-1]:.2f}); "
          f"largest event-time difference {gap:.2g} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
