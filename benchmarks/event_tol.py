"""Effect of the event-location tolerance (solver.event_tol, --event-tol) on Example 1.

Sweeps event_tol from 1e-14 (the default) to 1e-3 s with DOP853 at the default rtol and
measures the first impact time's error against a tight reference (rtol 1e-13, event_tol
1e-15), the post-impact angular velocities' error and the solve time (median of 5).

Regenerate: python benchmarks/event_tol.py   (writes docs/benchmarks/event_tol.md)
"""
from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import _common  # noqa: E402

import pcmm  # noqa: E402


def run(scene, **kw):
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=0.2, **kw))
    ev = traj.events[0]
    omega = np.array([ev["omega_after"][k] for k in ("link1", "link2", "link3")])
    return ev["t"], omega, traj.stats["wall_s"]


def main():
    t_start = time.perf_counter()
    scene = pcmm.load_scene(ROOT / "examples" / "three_bar.toml")
    t_ref, w_ref, _ = run(scene, rtol=1e-13, atol=1e-15, event_tol=1e-15)
    rows = []
    for tol in (1e-14, 1e-12, 1e-10, 1e-8, 1e-6, 1e-5, 1e-4, 1e-3):
        times, out = [], None
        try:
            for _ in range(5):
                out = run(scene, event_tol=tol)
                times.append(out[2])
        except pcmm.SimulationError as exc:
            rows.append((tol, None, None, None))
            print(f"event_tol {tol:8.0e}: stops: {exc.text()[:160]}")
            continue
        rows.append((tol, abs(out[0] - t_ref), float(np.max(np.abs(out[1] - w_ref))), statistics.median(times)))
        print(f"event_tol {tol:8.0e}: event time error {rows[-1][1]:.2e} s, post-impact omega error "
              f"{rows[-1][2]:.2e} rad/s, solve {rows[-1][3] * 1e3:.2f} ms")
    lines = ["# Event-location tolerance (Example 1)", "",
             "Regenerate: `python benchmarks/event_tol.py`", "", _common.machine_md(_common.machine()), "",
             "DOP853, rtol 1e-10, atol 1e-12, t_end 0.2 s (the latch at 0.1673 s and 33 ms after it). "
             "Reference: rtol 1e-13, atol 1e-15, event_tol 1e-15. The event is located by Brent's method on "
             "the 7th-order dense output to `event_tol`; the post-impact state inherits the located time's error.", "",
             "| event_tol (s) | first impact time error (s) | post-impact ω error (rad/s) | solve time (ms, median of 5) |",
             "|---|---|---|---|"]
    lines += [f"| {t:.0e} | {e:.2e} | {w:.2e} | {s * 1e3:.2f} |" if e is not None else
              f"| {t:.0e} | stops: the located latch is too far from its guard for the 1e-9 pose check | — | — |"
              for t, e, w, s in rows]
    lines += ["", "Reading: the event time follows `event_tol` down to the integrator's own accuracy "
              "(about 1e-12 s at rtol 1e-10); the cost of locating it precisely is a few guard evaluations, "
              "so the default (1e-14) costs nothing measurable. A loose `event_tol` shifts the impact and "
              "the post-impact velocities with it, and a latch located further from its guard than the "
              "switch's 1e-9 pose check allows stops the run with a message naming event_tol, rather "
              "than merging the links at a wrong pose.", "",
              f"run time {time.perf_counter() - t_start:.0f} s"]
    (ROOT / "docs" / "benchmarks" / "event_tol.md").write_text("\n".join(lines) + "\n")
    print("wrote docs/benchmarks/event_tol.md")


if __name__ == "__main__":
    main()
