"""Does writing a stored run's chunk hold the GIL?  (Whether the run could go on while the chunk is written.)

A bouncing ball's run of ``--impacts`` bounces is kept in memory (its series not derived), then its
segments and events are written as one chunk (``pcmm.results.store.write_chunk``: the series
derived, the events' JSON, the ``.npz``) on a thread, as ``StoreWriter.aside`` does: once alone,
once while the main thread counts in pure Python.  Prints the chunk's wall time both ways and the
main thread's counting rate against its rate alone: if the chunk's work let go of the GIL, both
threads would run at full rate on two cores (the chunk's wall time unchanged, the count's rate
~100 %); if it holds it, the two share one core (their shares summing to ~100 %).  Prints only.

    python benchmarks/store_writer_gil.py SCENE.toml --t-end 903.04728 --rounds 2
"""
from __future__ import annotations

import argparse
import tempfile
import threading
import time
from pathlib import Path

import pcmm
from pcmm.results.store import write_chunk


def _spin(stop: threading.Event) -> int:
    n = 0
    while not stop.is_set():
        n += 1
    return n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("--t-end", type=float, required=True)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    scene = pcmm.load_scene(args.scene)
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.rounds):
            traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=args.t_end))
            t = time.perf_counter()
            th = threading.Thread(target=write_chunk, args=(Path(tmp) / "a.npz", list(traj.segments), list(traj.events)))
            th.start()
            th.join()
            alone = time.perf_counter() - t
            stop = threading.Event()
            threading.Timer(alone, stop.set).start()
            solo = _spin(stop)
            traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=args.t_end))
            stop = threading.Event()

            def work(segs: list, events: list, stop: threading.Event) -> None:
                write_chunk(Path(tmp) / "b.npz", segs, events)
                stop.set()
            t = time.perf_counter()
            th = threading.Thread(target=work, args=(list(traj.segments), list(traj.events), stop))
            th.start()
            both = _spin(stop)
            th.join()
            together = time.perf_counter() - t
            print(f"{len(traj.segments)} segments, {len(traj.events)} events: the chunk {alone:.3f} s alone, "
                  f"{together:.3f} s beside the counting thread ({alone / together:.0%} of its rate); the counting "
                  f"thread at {both / solo * alone / together:.0%} of its rate alone")


if __name__ == "__main__":
    main()
