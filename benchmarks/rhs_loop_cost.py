"""What one right-hand-side evaluation costs inside the compiled segment loop (C++, no Python).

Example 1's first configuration (a tree; ``examples/three_bar.toml`` by default) integrated by the
compiled segment loop (``pcmm._tree_dynamics.SegmentLoop``, DOP853 in C++, no guards) from the
scene's initial state over the scene's duration, its CPU time divided by its number of
evaluations: the per-evaluation cost the whole run pays (DOP853's own arithmetic, for 6 numbers,
is a few per cent of it).  Then, where the build has ``Tree.evaluation_cost``, the evaluation's
parts timed in C++ at a mid-run state: the whole ``evaluate_rhs``, the force elements'
``Q0 - KD y`` alone, Pinocchio's ``aba`` as compiled into the extension, and the ``pin`` wheel's
own instantiation of ``aba`` (what ``pin.aba`` runs, here without Python around it).  And
``pin.aba`` called from Python, for scale.

``--against OTHER.so`` times another build of the extension (an earlier commit's, say) in the same
process, alternating with this one run by run, so the ratio is not the machine's load.

    python benchmarks/rhs_loop_cost.py [--scene examples/three_bar.toml] [--reps 21] [--against /path/_tree_dynamics.so]
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402

import pcmm  # noqa: E402
from pcmm.model import compiled  # noqa: E402
from pcmm.model.mechanism import Mechanism  # noqa: E402
from pcmm.run.loop import initial_state  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def load_build(path: Path):
    """Another build of the extension, as its own module (its init function is PyInit__tree_dynamics)."""
    spec = importlib.util.spec_from_file_location("other_build._tree_dynamics", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def compiled_tree(module, scene, name: str):
    """The configuration's compiled tree as ``module`` builds it (pcmm's own checks pass first)."""
    held = compiled._tree_dynamics
    compiled._tree_dynamics = module
    compiled.forget_trees()
    try:
        cfg = Mechanism(scene)[name]
        rhs = cfg.coords.rhs
    finally:
        compiled._tree_dynamics = held
        compiled.forget_trees()
    tree = getattr(rhs, "__self__", None)
    if not isinstance(tree, module.Tree):
        raise SystemExit(f"{name}: no compiled right-hand side ({compiled.why_not()})")
    return cfg, tree


def loop_run(module, tree, y0, t_end, rtol, atol):
    """CPU seconds and evaluations of one compiled segment loop over [0, t_end] (no guards)."""
    n = y0.size
    t0 = time.process_time()
    loop = module.SegmentLoop(tree, 0.0, y0, t_end, rtol, atol, 0.0, 10**7, 0.04, np.zeros((0, n)), np.zeros(0),
                              np.zeros(0), np.zeros(0), False)
    while (code := loop.run()) == 2:
        loop.take()
    seconds = time.process_time() - t0
    if code != 0:
        raise SystemExit(f"the segment loop stopped with code {code}")
    return seconds, loop.counts()[0], loop.take()[-1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", type=Path, default=ROOT / "examples" / "three_bar.toml")
    ap.add_argument("--reps", type=int, default=21)
    ap.add_argument("--against", type=Path, help="another build of pcmm/model/_tree_dynamics*.so to compare")
    args = ap.parse_args(argv)
    if compiled._tree_dynamics is None:
        print(f"no compiled extension: {compiled.why_not()}", file=sys.stderr)
        return 1
    scene = pcmm.load_scene(args.scene)
    name = scene.initial_configuration
    builds = {"this build": compiled._tree_dynamics}
    if args.against:
        builds[f"{args.against}"] = load_build(args.against)
    trees = {label: compiled_tree(module, scene, name) for label, module in builds.items()}
    cfg = trees["this build"][0]
    q, v, _ = initial_state(scene, cfg)
    y0 = np.concatenate([q, v])
    t_end, rtol, atol = float(scene.t_end), float(scene.solver.rtol), float(scene.solver.atol)
    per_eval = {label: [] for label in builds}
    evals, ends = {}, {}
    for rep in range(args.reps + 1):  # the first round warms up
        order = list(builds) if rep % 2 else list(reversed(builds))
        for label in order:
            seconds, nfcn, last = loop_run(builds[label], trees[label][1], y0, t_end, rtol, atol)
            evals[label], ends[label] = nfcn, last
            if rep:
                per_eval[label].append(seconds / nfcn)
    print(f"{args.scene.name}, {name}: compiled segment loop over [0, {t_end:g}] s (rtol {rtol:g}, atol {atol:g}), "
          f"CPU time per evaluation, median of {args.reps}")
    med = {label: statistics.median(ts) for label, ts in per_eval.items()}
    for label in builds:
        print(f"  {label:30s} {1e6 * med[label]:6.3f} us  ({evals[label]} evaluations)")
    if args.against:
        other = list(builds)[1]
        pairs = sorted(o / t for o, t in zip(per_eval[other], per_eval["this build"]))
        diff = float(np.max(np.abs(ends[other] - ends["this build"])))
        print(f"  ratio other/this {med[other] / med['this build']:.2f}x (per alternating pair: median "
              f"{statistics.median(pairs):.2f}x, range {pairs[0]:.2f}-{pairs[-1]:.2f}); final states differ by {diff:.2g}")
    # the parts, at the state the loop reaches half-way
    y_mid = ends["this build"][1:]
    tree = trees["this build"][1]
    if hasattr(tree, "evaluation_cost"):
        parts = {}
        for rep in range(args.reps):
            for part, seconds in tree.evaluation_cost(y_mid, 20000).items():
                parts.setdefault(part, []).append(seconds)
        print("  its parts in C++ (Tree.evaluation_cost, 20 000 calls each, median of "
              f"{args.reps}): " + ", ".join(f"{part} {1e6 * statistics.median(s):.3f} us" for part, s in parts.items()))
    model, data = cfg.model, cfg.data
    nv = model.nv
    qm, vm = y_mid[:nv].copy(), y_mid[nv:].copy()
    tau = cfg.forces.generalized(qm, vm)
    calls = []
    for _ in range(args.reps):
        t0 = time.process_time()
        for _ in range(5000):
            pin.aba(model, data, qm, vm, tau)
        calls.append((time.process_time() - t0) / 5000)
    print(f"  pin.aba from Python (for scale): {1e6 * statistics.median(calls):.3f} us per call")
    return 0


if __name__ == "__main__":
    sys.exit(main())
