"""The end of a long run: its closest approach (``pcmm.run.approach.closest_approach``, read by every
run's stats), this tree's against another tree's, on the same run.

Runs a ball bouncing ``--events`` times (e = 1, never merged: one event and one segment per bounce,
tests/builders.py's ``ball``) in memory, and streamed to a store with ``--stored``; then, alternating
for ``--rounds`` rounds, times (process CPU) the closest approach of its final configuration by this
tree's ``pcmm/run/approach.py`` and by ``BEFORE/pcmm/run/approach.py`` (loaded as a module of this
tree's package: only that file differs), checks the two records are equal, and prints the medians,
the ratio and the CPU per event, and the peak memory each call allocates (one traced call each).

    python benchmarks/run_end.py --before /work/main --events 10000 --rounds 3 [--stored]
"""
from __future__ import annotations

import argparse
import importlib.util
import math
import statistics
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import builders

import pcmm
from pcmm.model.mechanism import Mechanism
from pcmm.run import approach


def module_of(tree: Path):
    """``tree``'s approach.py as a module of this tree's ``pcmm.run`` package."""
    spec = importlib.util.spec_from_file_location("pcmm.run._approach_before", tree / "pcmm/run/approach.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def cpu(fn) -> tuple[float, object]:
    t0 = time.process_time()
    out = fn()
    return time.process_time() - t0, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", type=Path, required=True, help="the other tree (e.g. /work/main)")
    ap.add_argument("--events", type=int, default=10_000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--stored", action="store_true", help="stream the run to a store (its events in chunks)")
    args = ap.parse_args()
    before = module_of(args.before)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        period = 2.0 * math.sqrt(2.0 / builders.G)
        scene = pcmm.load_scene(builders.ball(tmp, 1.0, t_end=(args.events - 0.25) * period, merge=False,
                                              solver={"max_events": 10 * args.events}))
        run_s, traj = cpu(lambda: pcmm.simulate(scene, store=tmp / "store") if args.stored else pcmm.simulate(scene))
        cfg = Mechanism(scene)["free"]
        n = len(traj.events)
        print(f"{n} events, {'stored' if args.stored else 'in memory'}; the run {run_s:.2f} s CPU")
        times = {"before": [], "now": []}
        for _ in range(args.rounds):
            for label, mod in (("before", before), ("now", approach)):
                s, rec = cpu(lambda mod=mod: mod.closest_approach(scene, cfg, traj))
                times[label].append(s)
                times.setdefault(label + "_rec", rec)
        assert times["before_rec"] == times["now_rec"], (times["before_rec"], times["now_rec"])
        b, a = statistics.median(times["before"]), statistics.median(times["now"])
        print(f"closest approach, CPU s per round: before {[round(x, 3) for x in times['before']]}, "
              f"now {[round(x, 3) for x in times['now']]}")
        peaks = {}
        for label, mod in (("before", before), ("now", approach)):
            tracemalloc.start()
            mod.closest_approach(scene, cfg, traj)
            peaks[label] = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        print(f"peak memory allocated during the call (tracemalloc): before {peaks['before'] / 1e6:.2f} MB, "
              f"now {peaks['now'] / 1e6:.2f} MB")
        print(f"medians: before {b:.3f} s ({1e6 * b / n:.1f} us per event), now {a:.3f} s "
              f"({1e6 * a / n:.1f} us per event): {b / a:.1f}x; the records equal")


if __name__ == "__main__":
    main()
