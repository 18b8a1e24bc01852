"""Memory of a long bouncing run, kept in memory or streamed to a store (issue 26, item 5).

    python benchmarks/memory_long_run.py                  # 1e4 events, in memory and stored
    python benchmarks/memory_long_run.py --events 100000  # 1e5 (hours: ~10 ms of CPU per event)
    python benchmarks/memory_long_run.py --events 100000 --memory-only
    python benchmarks/memory_long_run.py --events 1000000 --store-only
    python benchmarks/memory_long_run.py --events 2000 --chunk 200   # several chunks in a short run
    python benchmarks/memory_long_run.py --events 100000 --memory-only --untraced --single --rss-every 5000

The scene is benchmarks/memory_events.py's ball (e = 1: one event and one segment per bounce).
Each mode runs two lengths, N/2 and N events, each in a subprocess of its own under
``tracemalloc`` (after a warm-up run, so models and modules are not counted): the difference of
what the run retains, divided by the difference in events (and in samples), is what it retains
per event (and per sample, all of it charged to the samples).  ``--store`` runs stream to a
temporary folder (``pcmm.simulate(..., store=DIR)``), whose size is printed too.  Each child
reports its peak RSS (the whole process: Python, numpy, scipy, Pinocchio and the run).  With
``--rss-every K`` the longer run also reads its RSS every K events and fits its growth per event
over the run's second half: what the run holds as the operating system counts it (the allocator's
slack and anything allocated outside Python included), without tracemalloc's slowing (2-3x).
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import traced_run_in_child  # noqa: E402
from memory_events import PERIOD, write_scene  # noqa: E402  (the same ball)

from pcmm.results.store import CHUNK_RECORDS  # noqa: E402

def measure(path: Path, events: int, store: Path | None, traced: bool, chunk: int, rss_every: int | None) -> dict:
    t_end = events * PERIOD  # the first impact at PERIOD/2, then one per PERIOD
    r = traced_run_in_child(path, t_end, store=store, chunk=chunk, traced=traced,
                            rss_every=None if rss_every is None else rss_every * PERIOD)
    if store is not None:
        r["store_mb"] = sum(p.stat().st_size for p in store.iterdir()) / 1e6
        shutil.rmtree(store)
    return r


def report(mode: str, a: dict | None, b: dict) -> None:
    for r in (a, b) if a is not None else (b,):
        retained = "" if r["retained"] is None else f"retained {r['retained'] / 1e6:8.2f} MB, "
        stored = f", store {r['store_mb']:.1f} MB on disk" if "store_mb" in r else ""
        print(f"{mode:>9}: {r['events']:>8} events, {r['samples']:>9} samples: {retained}"
              f"peak RSS {r['rss_peak_kb'] / 1e3:7.1f} MB, run {r['cpu_s']:.1f} s CPU{stored}")
    if b["rss_trace"]:
        events, kb = np.array([(t / PERIOD, k) for t, k in b["rss_trace"]]).T
        print(f"{mode:>9}: RSS (MB) at " + ", ".join(f"{e:.0f}: {k / 1e3:.1f}" for e, k in zip(events, kb)) + " events")
        half = events >= events[-1] / 2  # past the start-up's allocations
        if half.sum() >= 2:
            print(f"{mode:>9}: RSS growth over the second half of the run, least squares: "
                  f"{np.polyfit(events[half], kb[half] * 1e3, 1)[0]:.0f} B per event")
    if a is not None and a["retained"] is not None:
        dr = b["retained"] - a["retained"]
        print(f"{mode:>9}: retained per event {dr / (b['events'] - a['events']):.0f} B "
              f"(with its segment and {b['samples'] / b['events']:.1f} samples); "
              f"per sample, all of it charged to samples: {dr / (b['samples'] - a['samples']):.0f} B")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--events", type=int, default=10_000, help="events of the longer run (the shorter: half)")
    only = p.add_mutually_exclusive_group()
    only.add_argument("--store-only", action="store_true", help="only the stored runs (1e6 events in memory is large)")
    only.add_argument("--memory-only", action="store_true", help="only the runs kept in memory")
    p.add_argument("--chunk", type=int, default=CHUNK_RECORDS, help="segments or events per chunk of the store")
    p.add_argument("--untraced", action="store_true", help="no tracemalloc (faster; peak RSS only)")
    p.add_argument("--single", action="store_true", help="only the run of N events (no difference of two lengths)")
    p.add_argument("--rss-every", type=int, default=None, metavar="K",
                   help="read the RSS every K events (printed to stderr as the run goes) and fit its growth")
    args = p.parse_args()
    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        path = write_scene(Path(tmp), 1.0)
        modes = ["stored"] if args.store_only else ["in memory"] if args.memory_only else ["in memory", "stored"]
        for mode in modes:
            store = Path(tmp) / "store" if mode == "stored" else None
            a = None if args.single else measure(path, args.events // 2, store, not args.untraced, args.chunk, None)
            b = measure(path, args.events, store, not args.untraced, args.chunk, args.rss_every)
            report(mode, a, b)
    print(f"({time.time() - t0:.0f} s wall in all)")


if __name__ == "__main__":
    main()
