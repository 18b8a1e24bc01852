"""The compiled segment loop against the Python-stepped Fortran DOP853, on whole runs.

``pcmm.simulate`` of a scene (Example 1, ``examples/three_bar.toml``, by default), warm, in one
process, alternating the two paths run by run (the repetitions are the outer loop), CPU time
(``time.process_time``: on a shared machine the wall time mostly measures the neighbours):

* *compiled loop*: DOP853 and the guard scan in C++ (pcmm.model._segment_loop.hpp), the default
  where a tree's compiled right-hand side runs;
* *Python-stepped*: the path before it (scipy's Fortran dop853 calling the compiled right-hand side
  back through Python for every evaluation; events located on scipy's DOP853 re-taking the step),
  selected by emptying ``pcmm.ode.integrators.SEGMENT_LOOPS``.

Both use the same compiled right-hand side, so the ratio is the stepping loop's alone.  Also
prints the largest event-time difference between the two.

With ``--drives`` (default scene ``examples/three_bar_cycle.toml``: drives without loops, stepped by
scipy's DOP853 under "auto") the paths are three, alternating likewise:

* *Python evaluations*: ``PCMM_COMPILED=0`` (the right-hand side of drives in Python, as before
  issue 26's compiled drives; the trees' too);
* *compiled rhs*: the drives' right-hand side compiled whole (pcmm.model.compiled.drive_tree),
  stepped by pcmm's DOP853 in Python: the default;
* *compiled rhs + loop*: the same, stepped by the compiled loop as scipy's DOP853
  (``pcmm.ode.integrators.COMPILED_SCIPY_STEPS = True``: not the default, its steps are not numpy's
  to the bit).

    python benchmarks/segment_loop.py [--scene examples/three_bar.toml] [--reps 21]
    python benchmarks/segment_loop.py --drives [--scene examples/three_bar_cycle.toml] [--reps 5]
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import pcmm  # noqa: E402
from pcmm.model import compiled  # noqa: E402
from pcmm.ode import integrators  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", type=Path, default=ROOT / "examples" / "three_bar.toml")
    ap.add_argument("--reps", type=int, default=None, help="alternating runs per path (default 21; 5 with --drives)")
    ap.add_argument("--drives", action="store_true", help="the three paths of a scene with drives (see above)")
    args = ap.parse_args(argv)
    td = compiled._tree_dynamics
    if td is None or not hasattr(td, "SegmentLoop"):
        print(f"no compiled segment loop in this build: {compiled.why_not()}", file=sys.stderr)
        return 1
    if args.drives:
        return drives(args.scene if args.scene != ap.get_default("scene") else ROOT / "examples" / "three_bar_cycle.toml",
                      args.reps or 5)
    args.reps = args.reps or 21
    scene = pcmm.load_scene(args.scene)
    register = compiled._register_segment_loop
    compiled._register_segment_loop = lambda *args: None  # the paths are chosen here, run by run
    paths = {"compiled loop": {td.Tree: td.SegmentLoop}, "Python-stepped": {}}
    try:
        times, runs = _alternating(scene, paths, args.reps, lambda loops: setattr(integrators, "SEGMENT_LOOPS", loops))
    finally:
        compiled._register_segment_loop = register
        integrators.SEGMENT_LOOPS = {}
    fast, slow = runs["compiled loop"], runs["Python-stepped"]
    dt = max((abs(a["t"] - b["t"]) for a, b in zip(fast.events, slow.events, strict=True)), default=0.0)
    med = {name: statistics.median(ts) for name, ts in times.items()}
    print(f"{args.scene.name}: pcmm.simulate, CPU time, median of {args.reps} alternating runs")
    for name in paths:
        run = runs[name]
        print(f"  {name:15s} {1e3 * med[name]:8.2f} ms  ({run.stats['steps']} steps, "
              f"{run.stats['rhs_evals']} evaluations, {len(run.events)} events)")
    pairs = sorted(s / f for s, f in zip(times["Python-stepped"], times["compiled loop"]))
    print(f"  speed-up {med['Python-stepped'] / med['compiled loop']:.2f}x (per alternating pair: median "
          f"{statistics.median(pairs):.2f}x, range {pairs[0]:.2f}-{pairs[-1]:.2f}); "
          f"largest event-time difference {dt:.2g} s")
    return 0


def _alternating(scene, paths: dict, reps: int, choose) -> tuple[dict, dict]:
    """({path: [CPU s of each timed run]}, {path: its last run}): ``reps`` + 1 rounds of
    ``pcmm.simulate(scene)`` on every path (``choose(paths[name])`` sets one up), in alternating
    order; the first round warms up (models built, caches filled) and is not timed."""
    times, runs = {name: [] for name in paths}, {}
    for rep in range(reps + 1):
        for name, how in (paths.items() if rep % 2 else reversed(paths.items())):
            choose(how)
            t0 = time.process_time()
            runs[name] = pcmm.simulate(scene)
            if rep:
                times[name].append(time.process_time() - t0)
    return times, runs


def drives(path: Path, reps: int) -> int:
    """The three paths of a scene with drives (the module's docstring), alternating run by run."""
    scene = pcmm.load_scene(path)
    paths = {"Python evaluations": ("0", False), "compiled rhs": ("1", False), "compiled rhs + loop": ("1", True)}
    before = os.environ.get(compiled.ENV)

    def choose(how):
        os.environ[compiled.ENV], integrators.COMPILED_SCIPY_STEPS = how
    try:
        times, runs = _alternating(scene, paths, reps, choose)
    finally:
        integrators.COMPILED_SCIPY_STEPS = False
        if before is None:
            os.environ.pop(compiled.ENV, None)
        else:
            os.environ[compiled.ENV] = before
    base = runs["Python evaluations"]
    med = {name: statistics.median(ts) for name, ts in times.items()}
    print(f"{path.name}: pcmm.simulate, CPU time, median of {reps} alternating runs; load average "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    for name in paths:
        run = runs[name]
        dt = max((abs(a["t"] - b["t"]) for a, b in zip(run.events, base.events, strict=True)), default=0.0)
        print(f"  {name:20s} {1e3 * med[name]:8.1f} ms  x{med['Python evaluations'] / med[name]:.2f}  "
              f"({run.stats['steps']} steps, {run.stats['rhs_evals']} evaluations, {len(run.events)} events; "
              f"largest event-time difference from the Python evaluations' {dt:.2g} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
