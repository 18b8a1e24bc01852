"""A coasting parallelogram four-bar run into its change point from many starting angles: does each
run's recorded angle series stay continuous and on its parallelogram branch?

    python benchmarks/change_point_survey.py [--route auto|python|all-python] [--starts 30]

``auto``: the loops stepped by the compiled segment loop (the default stepping); ``python``: pcmm's
DOP853 stepping them in Python over the compiled loop (``partitioned.STEP_LOOPS_COMPILED = False``);
``all-python``: that with ``PCMM_COMPILED=0`` (set it in the environment).  For each start from
0.31 to 1.19 rad (omega = 2 rad/s, tests/builders.parallelogram) it prints ``ok``, or the first jump
between consecutive recorded samples (more than 1.5 max|v| dt + 1e-9), classed as ``turns`` (the
same posture 2 pi k away) or ``assembly`` (another assembly), or the error reading the series
raised; or, continuous and on its branch, where its rates leave +-omega by more than 1e-6 (coasting,
its kinetic energy is conserved).  tests/test_loop_turns.py holds cases of it.
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import builders  # noqa: E402

import pcmm  # noqa: E402
from pcmm.errors import SimulationError  # noqa: E402
from pcmm.model import compiled, partitioned  # noqa: E402


OMEGA = 2.0


def verdict(run) -> str:
    t = np.concatenate([np.asarray(s.t) for s in run.segments])
    q = np.concatenate([np.asarray(s.q) for s in run.segments])
    v = np.concatenate([np.asarray(s.v) for s in run.segments])
    dq, dt = np.abs(np.diff(q, axis=0)), np.diff(t)
    bad = dq > 1.5 * np.maximum(np.abs(v[1:]), np.abs(v[:-1])) * dt[:, None] + 1e-9
    if not bad.any():
        off = max(np.max(np.abs(q[:, 2] - q[:, 0])), np.max(np.abs(q[:, 1] + q[:, 0])))
        if off > 1e-9:
            return f"off its branch by {off:.3g}"
        # coasting on this branch every joint turns at +-omega (kinetic energy conserved)
        drift = np.abs(np.abs(v) - OMEGA).max(axis=1)
        if drift.max() > 1e-6:
            k = int(np.argmax(drift > 1e-6))
            return f"speed: its rates |v| - omega reach {drift.max():.3g} rad/s, from t = {t[k]:.6f} s"
        return "ok"
    k = int(np.nonzero(bad.any(axis=1))[0][0])
    d = q[k + 1] - q[k]
    turns = all(abs(math.remainder(x, 2 * math.pi)) < 1e-6 for x in d)
    return f"{'turns' if turns else 'assembly'} at t = {t[k]:.6f} s: {np.array2string(d, precision=4)}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--route", choices=("auto", "python", "all-python"), default="auto")
    ap.add_argument("--starts", type=int, default=30)
    args = ap.parse_args()
    if (args.route == "all-python") == compiled.enabled():
        sys.exit(f"--route {args.route}: set {compiled.ENV}=0 for all-python, leave it unset otherwise")
    partitioned.STEP_LOOPS_COMPILED = args.route == "auto"
    bad = 0
    with tempfile.TemporaryDirectory() as tmp:
        for k, theta0 in enumerate(np.linspace(0.31, 1.19, args.starts)):
            compiled.forget_trees()
            path = builders.parallelogram(Path(tmp) / str(k), float(theta0), OMEGA, t_end=2.0)
            try:
                run = pcmm.simulate(pcmm.load_scene(path))
            except SimulationError as exc:
                run = exc.partial
            try:
                out = verdict(run)
            except SimulationError as exc:
                out = f"reading its series: {str(exc)[:160]}"
            bad += out != "ok"
            print(f"{theta0:.4f} {out}")
    print(f"{bad} of {args.starts} starts not ok ({args.route})")


if __name__ == "__main__":
    main()
