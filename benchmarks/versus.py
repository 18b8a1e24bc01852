"""Whole runs of these sources against another source tree of pcmm, in one run, process by process.

``whole_run.py`` compares against a ``--before`` file measured in another run, through a
reference workload (``pinocchio.aba`` calls) that is meant to follow the machine's speed; on this
shared machine that reference itself moved by 20 % between two runs minutes apart (25.0 and
30.4 ms), which moved every ratio with it.  Here the trees are measured in the same run instead,
in alternating child processes (``before, now, now with PCMM_COMPILED=0, before, ...``), each
process timing ``pcmm.simulate`` on its own tree's example scene (CPU time, after one warm-up run,
median of its repetitions); the ratios of each triple are formed from neighbours in time, and the
figures are the medians over the triples.  The third child runs these sources on their Python
evaluations alone, as on a machine where the optional compiled extension was not built.

    git archive a520a99 | tar -x -C /tmp/before
    python benchmarks/versus.py /tmp/before --label a520a99 [--pairs 5] [--out docs/benchmarks]

Each tree runs its own ``examples/three_bar.toml`` and ``examples/double_folded.toml`` (a
scene of the time, as a user of that version had it).  Writes ``versus.md``.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import DOCS, ROOT, command_line, machine, machine_md, md_table  # noqa: E402

#: the child: load the scene, one warm-up run, then REPS timed runs; prints "median_ms events"
CHILD = """
import statistics, sys, time, pcmm
scene = pcmm.load_scene(sys.argv[1])
pcmm.simulate(scene)
times = []
for _ in range(int(sys.argv[2])):
    t0 = time.process_time()
    traj = pcmm.simulate(scene)
    times.append(time.process_time() - t0)
try:  # which right-hand side the tree's runs used (trees before pcmm.model.compiled have only Python's)
    from pcmm import compiled
    rhs = "compiled" if compiled.trees_built() else "python"
except ImportError:
    rhs = "python"
print(statistics.median(times) * 1e3, len(traj.events), rhs)
"""

SCENES = {"Example 1": ("examples/three_bar.toml", 15), "Example 2": ("examples/double_folded.toml", 3)}


def child(tree: Path, scene: str, reps: int, compiled: bool = True) -> tuple[float, int, str]:
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1", "PCMM_COMPILED": "1" if compiled else "0"}
    out = subprocess.run([sys.executable, "-c", CHILD, scene, str(reps)], cwd=tree, env=env,
                         check=True, capture_output=True, text=True).stdout.split()
    return float(out[0]), int(out[1]), out[2]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("before", type=Path, help="a source tree of pcmm (pcmm/, examples/, urdf/)")
    ap.add_argument("--label", help="what the before tree is (e.g. its commit); default its folder")
    ap.add_argument("--pairs", type=int, default=5, help="how many triples (before, now, now without the extension)")
    ap.add_argument("--out", type=Path, default=DOCS)
    args = ap.parse_args(argv)
    before = args.before.resolve()
    if not (before / "pcmm" / "__init__.py").is_file():
        ap.error(f"{before}: not a pcmm source tree (no pcmm/__init__.py)")
    T0 = time.perf_counter()
    info = machine()
    print(machine_md(info))
    got = {name: {"before": [], "now": [], "python": [], "ratio": [], "ratio_python": [], "events": {}, "rhs": ""}
           for name in SCENES}
    for k in range(args.pairs):
        for name, (scene, reps) in SCENES.items():
            # before, now, now without the compiled right-hand side (PCMM_COMPILED=0): one triple
            b, nb, _ = child(before, scene, reps)
            n, nn, rhs = child(ROOT, scene, reps)
            p, _, _ = child(ROOT, scene, reps, compiled=False)
            g = got[name]
            g["before"].append(b)
            g["now"].append(n)
            g["python"].append(p)
            g["ratio"].append(b / n)
            g["ratio_python"].append(b / p)
            g["events"] = {"before": nb, "now": nn}
            g["rhs"] = rhs
            print(f"[{time.perf_counter() - T0:5.1f} s] pair {k}: {name}: before {b:.1f} ms, now {n:.1f} ms "
                  f"({rhs} evaluations), {b / n:.2f}x; PCMM_COMPILED=0 {p:.1f} ms, {b / p:.2f}x", flush=True)
    rows = []
    for name, g in got.items():
        r, rp = g["ratio"], g["ratio_python"]
        rows.append([f"{name} (`{SCENES[name][0]}`, each tree's own; {SCENES[name][1]} timed runs per process)",
                     f"{statistics.median(g['before']):.1f} ({g['events']['before']} events)",
                     f"{statistics.median(g['now']):.1f} ({g['events']['now']} events; {g['rhs']})",
                     f"**{statistics.median(r):.2f}×** ({min(r):.2f}–{max(r):.2f})",
                     f"{statistics.median(g['python']):.1f}",
                     f"{statistics.median(rp):.2f}× ({min(rp):.2f}–{max(rp):.2f})"])
    text = "\n".join([
        "# Whole runs against another source tree, measured in one run",
        "",
        f"Regenerate: `{command_line()}` (run time {time.perf_counter() - T0:.0f} s).",
        "",
        machine_md(info),
        "",
        f"Before: {args.label or before} (`{before}`). {args.pairs} triples of child processes, before, now and "
        "now with `PCMM_COMPILED=0` (the Python tree right-hand side, as on a machine where the optional "
        "extension was not built) alternating; each child times `pcmm.simulate` on its own tree's scene (CPU time, one warm-up run "
        "first, median of its runs). The speed-up is the median over the triples of before / now, with its range.",
        "",
        md_table(["whole run, defaults", "before (ms CPU)", "now (ms CPU)", "speed-up (range over triples)",
                  "now, PCMM_COMPILED=0 (ms CPU)", "its speed-up"], rows),
        "",
    ])
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "versus.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
