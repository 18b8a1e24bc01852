"""Whole runs of one scene in several source trees of pcmm, alternating finely between persistent processes.

``versus.py`` starts a fresh process per measurement: on this shared machine the CPU time of one
process against the next moves by 20-40 % with the other users' load, more than a change of a
tenth is worth.  Here one process per tree stays up (its scene loaded, one warm-up run) and the
trees take turns, ``--runs`` runs each (their median) per round, for ``--rounds`` rounds; the ratio
first tree / each tree is formed per round from neighbours in time, and the medians over the
rounds are printed with their interquartile range.  Prints only.

    python benchmarks/alternate.py examples/three_bar.toml /tmp/before . [--rounds 40] [--runs 5]

Each tree needs its compiled extension built (or copied) in place; each process runs its own
tree's copy of the scene (the path is taken relative to each tree).
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

CHILD = r'''
import sys, time, pcmm
scene = pcmm.load_scene(sys.argv[1])
pcmm.simulate(scene)
for line in sys.stdin:
    ts = []
    for _ in range(int(line)):
        t0 = time.process_time()
        pcmm.simulate(scene)
        ts.append(time.process_time() - t0)
    print(sorted(ts)[len(ts) // 2] * 1e3, flush=True)
'''


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="the scene, relative to each tree (e.g. examples/three_bar.toml)")
    ap.add_argument("trees", nargs="+", type=Path, help="source trees of pcmm; the first is the reference")
    ap.add_argument("--rounds", type=int, default=40)
    ap.add_argument("--runs", type=int, default=5, help="runs per tree and round (their median is the round's figure)")
    args = ap.parse_args(argv)
    trees = [t.resolve() for t in args.trees]
    procs = [subprocess.Popen([sys.executable, "-c", CHILD, args.scene], cwd=t, stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(t), "OPENBLAS_NUM_THREADS": "1"}) for t in trees]
    got = [[] for _ in trees]
    try:
        for _ in range(args.rounds):
            for p, g in zip(procs, got):
                p.stdin.write(f"{args.runs}\n")
                p.stdin.flush()
                g.append(float(p.stdout.readline()))
    finally:
        for p in procs:
            p.stdin.close()
            p.wait()
    print(f"{args.scene}: {args.rounds} rounds of {args.runs} runs per tree, CPU time; load average {os.getloadavg()[0]:.1f}")
    for t, g in zip(trees, got):
        ratios = [a / b for a, b in zip(got[0], g)]
        q = statistics.quantiles(ratios, n=4)
        print(f"  {t}: median {statistics.median(g):.2f} ms; first tree / this, per round: median "
              f"{statistics.median(ratios):.2f} (interquartile {q[0]:.2f}-{q[2]:.2f})")


if __name__ == "__main__":
    main()
