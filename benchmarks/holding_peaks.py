"""The cost of ``stats["holding"]``'s peaks between the steps (pcmm.results.peaks): for each scene
given, the run, the first read of ``stats["holding"]`` (the series derived, then the extremes), and
``holding_extremes`` again with the series derived (the search alone, with the samples' pass, which
costs ~1 ms or less); run it against another tree (``PYTHONPATH=OTHER``) to compare.

    python benchmarks/holding_peaks.py examples/three_bar_cycle.toml examples/double_folded.toml
"""
from __future__ import annotations

import statistics
import sys
import time

import pcmm
from pcmm.results.trajectory import holding_extremes


def main(paths) -> None:
    for path in paths:
        traj = pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions())
        t0 = time.perf_counter()
        traj.stats["holding"]
        first = time.perf_counter() - t0
        again = []
        for _ in range(3):
            t0 = time.perf_counter()
            holding_extremes(traj)
            again.append(time.perf_counter() - t0)
        print(f"{path}: run wall_s {traj.stats['wall_s']:.3f} s, {len(traj.segments)} segments, first read "
              f"{first:.3f} s, holding_extremes again (series derived) median {statistics.median(again):.4f} s")


if __name__ == "__main__":
    main(sys.argv[1:])
