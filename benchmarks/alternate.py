"""Whole runs of one scene in several source trees of pcmm, alternating finely between persistent processes.

``versus.py`` starts a fresh process per measurement: on this shared machine the CPU time of one
process against the next moves by 20-40 % with the other users' load, more than a change of a
tenth is worth.  Here one process per tree stays up (its scene loaded, one warm-up run) and the
trees take turns, ``--runs`` runs each (their median) per round, for ``--rounds`` rounds; the ratio
first tree / each tree is formed per round from neighbours in time, and the medians over the
rounds are printed with their interquartile range.  The trees take their turns in the reverse
order every other round.  Prints only.

    python benchmarks/alternate.py examples/three_bar.toml /tmp/before . [--rounds 40] [--runs 5]
        [--part pcmm.run.loop:_guards]

``--part module:function`` also times the CPU time spent inside that function (a module attribute,
wrapped in each process: its callers must look it up in the module at each call), per event of
the run, and prints its medians and ratios the same way (the wrapper's own cost, two clock reads
per call, is in both trees' figures alike).

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
import importlib, sys, time, pcmm
scene = pcmm.load_scene(sys.argv[1])
inside = [0.0]
if len(sys.argv) > 2:  # --part module:function: the CPU time inside it, summed over the run
    module, name = sys.argv[2].split(":")
    module = importlib.import_module(module)
    timed = getattr(module, name)
    def part(*args, **kwargs):
        t0 = time.process_time()
        try:
            return timed(*args, **kwargs)
        finally:
            inside[0] += time.process_time() - t0
    setattr(module, name, part)
pcmm.simulate(scene)
for line in sys.stdin:
    ts, ps = [], []
    for _ in range(int(line)):
        inside[0] = 0.0
        t0 = time.process_time()
        traj = pcmm.simulate(scene)
        ts.append(time.process_time() - t0)
        ps.append(inside[0] / max(len(traj.events), 1))
    print(sorted(ts)[len(ts) // 2] * 1e3, sorted(ps)[len(ps) // 2] * 1e6, flush=True)
'''


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="the scene, relative to each tree (e.g. examples/three_bar.toml)")
    ap.add_argument("trees", nargs="+", type=Path, help="source trees of pcmm; the first is the reference")
    ap.add_argument("--rounds", type=int, default=40)
    ap.add_argument("--runs", type=int, default=5, help="runs per tree and round (their median is the round's figure)")
    ap.add_argument("--part", metavar="MODULE:FUNCTION",
                    help="also time the CPU time inside this function per event (e.g. pcmm.run.loop:_guards)")
    args = ap.parse_args(argv)
    trees = [t.resolve() for t in args.trees]
    part = [args.part] if args.part else []
    procs = [subprocess.Popen([sys.executable, "-c", CHILD, args.scene, *part], cwd=t, stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(t), "OPENBLAS_NUM_THREADS": "1"}) for t in trees]
    got = [[] for _ in trees]
    inside = [[] for _ in trees]
    try:
        for r in range(args.rounds):
            turns = list(zip(procs, got, inside))
            # every other round in the reverse order: with a fixed order the tree that ran first measured
            # faster whichever tree it was (the cycle, main against h-guardcache, 30-40 rounds: main first
            # 8 % faster, the branch first 5 % faster; both orders alternated: 1.00)
            for p, g, h in (turns if r % 2 == 0 else turns[::-1]):
                p.stdin.write(f"{args.runs}\n")
                p.stdin.flush()
                whole, per_event = p.stdout.readline().split()
                g.append(float(whole))
                h.append(float(per_event))
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
    if args.part:
        print(f"  inside {args.part}, per event:")
        for t, g in zip(trees, inside):
            ratios = [a / b for a, b in zip(inside[0], g)]
            q, qg = statistics.quantiles(ratios, n=4), statistics.quantiles(g, n=4)
            print(f"  {t}: median {statistics.median(g):.2f} us (interquartile {qg[0]:.2f}-{qg[2]:.2f}); first tree / "
                  f"this, per round: median {statistics.median(ratios):.3f} (interquartile {q[0]:.3f}-{q[2]:.3f})")


if __name__ == "__main__":
    main()
