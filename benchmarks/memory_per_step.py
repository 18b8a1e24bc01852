"""Memory a run holds per accepted step (docs/limits.md, "Memory per step").

    python benchmarks/memory_per_step.py examples/three_bar_stop.toml 3.0
    python benchmarks/memory_per_step.py examples/double_folded.toml 7.0

``tracemalloc`` traces a whole run after a short warm-up run (models built, modules imported);
it reports what the finished trajectory retains per sample, the part of it that is the
trajectory's own arrays, and the peak while the segments integrate.
"""
from __future__ import annotations

import gc
import sys
import tracemalloc

import pcmm


def main(scene_path: str, t_end: float) -> None:
    scene = pcmm.load_scene(scene_path)
    pcmm.simulate(scene, pcmm.RunOptions(t_end=0.01))
    gc.collect()
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=t_end))
    gc.collect()
    current, peak = tracemalloc.get_traced_memory()
    samples = traj.t.size
    arrays = sum(getattr(s, a).nbytes for s in traj.segments
                 for a in ("t", "q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces"))
    print(f"{scene_path} to t = {t_end:g} s: {traj.stats['steps']} steps, {samples} samples; retained "
          f"{(current - base) / samples:.0f} B per sample (arrays {arrays / samples:.0f} B), "
          f"peak {(peak - base) / samples:.0f} B per sample")


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]))
