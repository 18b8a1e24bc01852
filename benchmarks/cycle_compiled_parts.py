"""What each compiled part of a run with locks and drives is worth, on whole runs of one scene.

``pcmm.simulate`` of ``examples/three_bar_cycle.toml`` (531 events), warm, in one process, CPU time
(``time.process_time``), the variants taking turns run by run (medians over ``--reps`` rounds):

* *all*: the default (the compiled holding forces of the lock guards, scanned by the compiled
  segment loop; "auto" stepping the drives in that loop with scipy's DOP853 tableau; the flights'
  audit powers in one compiled call);
* *no holding*: the guards' holding forces by the prepared Python evaluator (``Holds.evaluator``);
* *no loop*: "auto" stepping the drives by pcmm's DOP853 in Python (the method "DOP853"), as before;
* *no powers*: the audit's powers by the Python route (``audit.python_drive_powers``);
* *none*: the three off together (main before this change, but for its compiled impulse and
  right-hand side, which all variants share);
* *DOP853F*: all on, the method DOP853F (Hairer's step-size control, beta 0.04) instead of "auto";
* *DenseStep*: all on, the loop's steps read at one time by scipy's ``DenseStep`` itself instead of
  its Horner sums on floats (``integrators._ScipyDense``: the same bits).

For each variant: the median time, the ratio none / variant, and its events against *none* and
*all* (number, order and kind the same; the largest event-time differences).

    python benchmarks/cycle_compiled_parts.py [--scene examples/three_bar_cycle.toml] [--reps 5]
        [--variants all,DenseStep]   (only these, "all" and "none" always among them)
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import pcmm  # noqa: E402
from pcmm.events import holding  # noqa: E402
from pcmm.ode import integrators  # noqa: E402
from pcmm.ode.dop853 import DenseStep  # noqa: E402
from pcmm.run import audit  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = {"all": (), "no holding": ("holding",), "no loop": ("loop",), "no powers": ("powers",),
            "none": ("holding", "loop", "powers"), "DOP853F": ("DOP853F",), "DenseStep": ("dense",)}


def run(scene, off):
    compiled_evaluator, compiled_powers = holding._compiled_evaluator, audit._compiled_drive_powers
    scipy_dense = integrators._ScipyDense
    try:
        if "dense" in off:
            integrators._ScipyDense = DenseStep
        if "holding" in off:
            holding._compiled_evaluator = lambda *args: (None, "off")
        if "powers" in off:
            audit._compiled_drive_powers = lambda cfg, coords: None
        integrators.AUTO_DOP853.compiled_steps = "loop" not in off
        options = pcmm.RunOptions(method="DOP853F") if "DOP853F" in off else pcmm.RunOptions()
        t0 = time.process_time()
        out = pcmm.simulate(scene, options)
        return time.process_time() - t0, out
    finally:
        holding._compiled_evaluator, audit._compiled_drive_powers = compiled_evaluator, compiled_powers
        integrators.AUTO_DOP853.compiled_steps = True
        integrators._ScipyDense = scipy_dense


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default=str(ROOT / "examples" / "three_bar_cycle.toml"))
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--variants", default=",".join(VARIANTS), help="comma-separated, of: " + ", ".join(VARIANTS))
    args = ap.parse_args(argv)
    chosen = {"all", "none", *args.variants.split(",")}
    variants = {name: off for name, off in VARIANTS.items() if name in chosen}
    scene = pcmm.load_scene(args.scene)
    for off in variants.values():  # warm: models, trees and checks built once
        run(scene, off)
    times = {name: [] for name in variants}
    runs = {}
    for _ in range(args.reps):
        for name, off in variants.items():
            t, runs[name] = run(scene, off)
            times[name].append(t)
    load = os.getloadavg()[0]
    base = statistics.median(times["none"])
    kinds = lambda run: [(e["name"], e.get("kind")) for e in run.events]  # noqa: E731
    gap = lambda a, b: max((abs(x["t"] - y["t"]) for x, y in zip(a.events, b.events)), default=0.0)  # noqa: E731
    print(f"{Path(args.scene).name}: {args.reps} rounds, CPU time, load average {load:.1f}")
    for name in variants:
        med = statistics.median(times[name])
        same = kinds(runs[name]) == kinds(runs["none"]) == kinds(runs["all"])
        print(f"  {name:11s} {med * 1e3:8.1f} ms  {base / med:5.2f}x  events {len(runs[name].events)}"
              f" {'same kinds' if same else 'DIFFERENT'}, largest time gap to 'none' {gap(runs[name], runs['none']):.2g} s,"
              f" to 'all' {gap(runs[name], runs['all']):.2g} s")


if __name__ == "__main__":
    main()
