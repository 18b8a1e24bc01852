"""Memory a run holds per accepted step (docs/limits.md, "Memory per step").

    python benchmarks/memory_per_step.py examples/three_bar_stop.toml 3.0
    python benchmarks/memory_per_step.py examples/double_folded.toml 7.0

``tracemalloc`` traces a whole run after a short warm-up run (models built, modules imported);
it reports what the finished trajectory retains per sample, the part of it that is the
trajectory's own arrays, and the peak while the segments integrate.
"""
from __future__ import annotations

import sys
from pathlib import Path

import pcmm

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import traced_run  # noqa: E402


def main(scene_path: str, t_end: float) -> None:
    traj, figures = traced_run(pcmm.load_scene(scene_path), t_end, warm_up=0.01)
    samples = traj.t.size
    arrays = sum(getattr(s, a).nbytes for s in traj.segments
                 for a in ("t", "q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces"))
    print(f"{scene_path} to t = {t_end:g} s: {traj.stats['steps']} steps, {samples} samples; retained "
          f"{figures['retained'] / samples:.0f} B per sample (arrays {arrays / samples:.0f} B), "
          f"peak {figures['peak'] / samples:.0f} B per sample")


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]))
