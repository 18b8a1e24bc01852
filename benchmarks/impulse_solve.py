"""One impulse solve, compiled against Python: every impulse of a run (``three_bar_cycle.toml``
by default, 532) captured, then each solved again ``--reps`` times by the compiled call alone
(``ImpulsePlan.solve``, pcmm/model/_impulse.hpp), by ``solve_impulse`` with it (the ``Impulse``
assembled in Python) and by the Python solve (``solve_impulse_python``, the cut system); each
call's least ``time.perf_counter`` kept (warm caches), summed and divided by the impulses; with
the largest difference of the post-impact velocities between the two solves.  Prints only::

    python benchmarks/impulse_solve.py [--scene examples/three_bar_cycle.toml] [--reps 7]
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # no BLAS threads spinning on a shared machine

import argparse
import time
from pathlib import Path

import numpy as np

import pcmm
from pcmm.events import impulse, transitions
from pcmm.events.impulse_compiled import compiled_impulse, reasons

ROOT = Path(__file__).resolve().parents[1]


def captured(scene) -> list[tuple]:
    """Every (cfg, t, q, v, contact, e, cut) the run's handlers solved an impulse at."""
    calls, solve = [], transitions.solve_impulse

    def capture(cfg, t, q, v, contact, e, cut, name=None):
        calls.append((cfg, t, q.copy(), v.copy(), contact, e, tuple(cut)))
        return solve(cfg, t, q, v, contact, e, cut, name=name)
    transitions.solve_impulse = capture
    try:
        pcmm.simulate(scene)
    finally:
        transitions.solve_impulse = solve
    return calls


def least(calls, fn, reps: int) -> float:
    """us per call: each call's least of ``reps``, summed over the calls, divided by their number."""
    best = [float("inf")] * len(calls)
    clock = time.perf_counter
    for _ in range(reps):
        for i, c in enumerate(calls):
            t0 = clock()
            fn(*c)
            best[i] = min(best[i], clock() - t0)
    return 1e6 * sum(best) / len(calls)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default=str(ROOT / "examples" / "three_bar_cycle.toml"))
    ap.add_argument("--reps", type=int, default=7)
    args = ap.parse_args(argv)
    calls = captured(pcmm.load_scene(args.scene))
    if not calls:
        print(f"{args.scene}: no impulse solved")
        return 1
    where = {what for c in calls for what in reasons(c[0]).values()}
    if where != {"compiled"}:
        print(f"not every impulse plan runs compiled: {sorted(where)}")

    def core(cfg, t, q, v, contact, e, cut):
        fast = compiled_impulse(cfg, impulse._plan(cfg, contact, cut))
        return fast.plan.solve(q, v, e) if fast is not None else None

    def compiled(cfg, t, q, v, contact, e, cut):
        return impulse.solve_impulse(cfg, t, q, v, contact, e, cut)

    def python(cfg, t, q, v, contact, e, cut):
        return impulse.solve_impulse_python(cfg, t, q, v, contact, e, cut)

    worst = max(float(np.max(np.abs(compiled(*c).v_after - python(*c).v_after)))
                / float(np.max(np.abs(np.concatenate([c[3], python(*c).v_after])))) for c in calls)
    print(f"{Path(args.scene).name}: {len(calls)} impulses; us per impulse, each call's least of {args.reps} "
          f"(warm), load {os.getloadavg()[0]:.1f}:")
    print(f"  compiled call alone        {least(calls, core, args.reps):8.1f}")
    print(f"  solve_impulse (compiled)   {least(calls, compiled, args.reps):8.1f}")
    print(f"  solve_impulse_python       {least(calls, python, args.reps):8.1f}")
    print(f"  largest |v+ compiled - v+ Python| / max|v|: {worst:.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
