"""Start-up: ``pcmm run examples/three_bar.toml`` as a whole process against ``python -c "import pinocchio"``.

A short run is mostly start-up (Example 1's integration is a few milliseconds), so the whole
process is timed: the interpreter, the imports, loading the scene, the run and writing its
results.  The floor it is measured against is the one import the run cannot do without,
Pinocchio (which brings numpy).  Issue 26 asks for at most 2x.

The two commands alternate N times (a burst of load from another user of the machine hits both
alike); each child's CPU time (user + sys, from ``os.wait4``) and wall time are recorded, and
the medians and their ratios printed.  CPU time is the figure to quote on a shared machine: the
wall time mostly measures the neighbours.

Byte-code caches are written and used (``PYTHONDONTWRITEBYTECODE`` is removed from the children's
environment, and one warm-up run of each command comes first), as for an installed package;
without them every pcmm module is compiled at every start.

    python benchmarks/startup.py [--reps 15] [--scene examples/three_bar.toml] [--before DIR]

This checkout's sources are timed, with this interpreter.  ``--before DIR`` times another
checkout of pcmm (e.g. ``git archive`` of an earlier commit, its compiled extension copied in)
in the same alternation, for the saving of a change.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def timed(cmd: list[str], env: dict, cwd: str) -> tuple[float, float]:
    """(CPU s, wall s) of one child process; its output is discarded, a failure is fatal."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace")
    proc.stderr.close()
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed (exit {proc.returncode}):\n{err}")
    return usage.ru_utime + usage.ru_stime, wall


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=15, help="pairs of runs (default 15)")
    ap.add_argument("--scene", type=Path, default=ROOT / "examples" / "three_bar.toml")
    ap.add_argument("--before", type=Path, metavar="DIR", help="another pcmm checkout, timed alike")
    args = ap.parse_args(argv)
    base = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "PYTHONPATH")}
    envs = {"pinocchio": base, "pcmm run": dict(base, PYTHONPATH=str(ROOT))}
    with tempfile.TemporaryDirectory() as tmp:
        run = [sys.executable, "-m", "pcmm.cli", "run", str(args.scene.resolve()), "--out", str(Path(tmp) / "run"),
               "--force", "--quiet"]
        commands = {"pinocchio": [sys.executable, "-c", "import pinocchio"], "pcmm run": run}
        if args.before:
            commands["before"] = run
            envs["before"] = dict(base, PYTHONPATH=str(args.before.resolve()))
        for name, cmd in commands.items():  # warm-up: byte-code caches written, files in the page cache
            timed(cmd, envs[name], tmp)
        cpu = {name: [] for name in commands}
        wall = {name: [] for name in commands}
        for _ in range(args.reps):
            for name, cmd in commands.items():
                c, w = timed(cmd, envs[name], tmp)
                cpu[name].append(c)
                wall[name].append(w)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"{args.reps} alternating pairs, medians (load {load:.2f}, {os.cpu_count()} cores); "
          f"scene {args.scene.name}")
    print(f"{'command':<12} {'CPU s':>8} {'wall s':>8}")
    for name in commands:
        print(f"{name:<12} {statistics.median(cpu[name]):8.3f} {statistics.median(wall[name]):8.3f}")
    ratio_cpu = statistics.median(cpu["pcmm run"]) / statistics.median(cpu["pinocchio"])
    ratio_wall = statistics.median(wall["pcmm run"]) / statistics.median(wall["pinocchio"])
    print(f"ratio pcmm run / import pinocchio: CPU {ratio_cpu:.2f}x, wall {ratio_wall:.2f}x (target: <= 2x)")
    if args.before:
        saved = statistics.median(cpu["before"]) - statistics.median(cpu["pcmm run"])
        print(f"before ({args.before}) / import pinocchio: CPU "
              f"{statistics.median(cpu['before']) / statistics.median(cpu['pinocchio']):.2f}x; saved {saved:.3f} s CPU")
    return 0


if __name__ == "__main__":
    sys.exit(main())
