"""Whole ``pcmm run`` processes of one scene in several source trees, alternating: CPU time and peak memory.

``alternate.py`` times ``pcmm.simulate`` in persistent processes; this one times what a user waits
for, a whole ``python -m pcmm.cli run SCENE --quiet [--store DIR]`` process (start-up, the run, the
store written), one process per tree in turn for ``--rounds`` rounds, each with the sources of its
tree first on ``PYTHONPATH`` (its compiled extension built in place).  Per run: the child's user +
system CPU time and its peak resident set (``wait4``'s ``ru_maxrss``, what ``/usr/bin/time -v``
reports as "Maximum resident set size").  Prints each run, then per tree the median CPU time, the
median peak RSS and the ratio of the first tree's median to each tree's.  Prints only.

    python benchmarks/alternate_cli.py /tmp/bb1k.toml /work/main . --rounds 5 --store
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path


def run_once(tree: Path, scene: Path, store: bool, work: Path) -> tuple[float, float]:
    """(CPU seconds, peak RSS in MB) of one whole ``pcmm run`` with ``tree``'s sources."""
    cmd = [sys.executable, "-m", "pcmm.cli", "run", str(scene), "--quiet"]
    out = work / "store"
    if store:
        shutil.rmtree(out, ignore_errors=True)
        cmd += ["--store", str(out)]
    env = dict(os.environ, PYTHONPATH=str(tree))
    proc = subprocess.Popen(cmd, cwd=work, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode()
    proc.stderr.close()
    if proc.returncode != 0:
        raise SystemExit(f"{tree}: pcmm run {scene} exited {proc.returncode}:\n{err}")
    return usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", type=Path, help="the scene (one path for every tree)")
    ap.add_argument("trees", nargs="+", type=Path, help="source trees of pcmm; the first is the reference")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--store", action="store_true", help="write the run to a store (--store DIR)")
    args = ap.parse_args(argv)
    scene = args.scene.resolve()
    trees = [t.resolve() for t in args.trees]
    cpu = {t: [] for t in trees}
    rss = {t: [] for t in trees}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for t in trees:
                c, m = run_once(t, scene, args.store, Path(tmp))
                cpu[t].append(c)
                rss[t].append(m)
                print(f"round {r + 1} {t}: {c:.3f} s CPU, {m:.0f} MB peak RSS", flush=True)
    ref = statistics.median(cpu[trees[0]])
    for t in trees:
        med = statistics.median(cpu[t])
        ratios = sorted(a / b for a, b in zip(cpu[trees[0]], cpu[t]))
        print(f"{t}: median {med:.3f} s CPU (range {min(cpu[t]):.3f}-{max(cpu[t]):.3f}), peak RSS median "
              f"{statistics.median(rss[t]):.0f} MB; {ref / med:.2f}x against the first (per round "
              f"{ratios[0]:.2f}-{ratios[-1]:.2f})")


if __name__ == "__main__":
    main()
