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

    mkdir -p /tmp/d6676d9 && git archive d6676d9 | tar -x -C /tmp/d6676d9
    (cd /tmp/d6676d9 && python setup.py build_ext --inplace)   # its compiled right-hand side
    python benchmarks/versus.py /tmp/d6676d9 --label d6676d9 --pairs 5 --out docs/benchmarks/versus_d6676d9.md

Each tree runs its own ``examples/three_bar.toml`` (Example 1), ``examples/three_bar_cycle.toml``
(Example 1 driven round its cycle, hundreds of impacts) and ``examples/double_folded.toml``
(Example 2): each a scene of the time, as a user of that version had it.  Besides the times, each
child reports its run's events, and the page says per scene whether the trees' events are the same:
the same number, and every event time within 1e-9 s of the other tree's event of the same index
(the times compared pairwise in order over the events both runs have), and which evaluations
(compiled or Python) each tree's configurations used, from its run's ``stats["evaluations"]``.
Writes ``docs/benchmarks/versus.md`` unless ``--out`` names another page.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import DOCS, ROOT, command_line, machine, machine_md, md_table  # noqa: E402

#: the child: load the scene, one warm-up run, then REPS timed runs; prints one JSON line:
#: the median CPU time (ms), the last run's event times, and which evaluations its configurations used
CHILD = """
import json, statistics, sys, time, pcmm
scene = pcmm.load_scene(sys.argv[1])
pcmm.simulate(scene)
times = []
for _ in range(int(sys.argv[2])):
    t0 = time.process_time()
    traj = pcmm.simulate(scene)
    times.append(time.process_time() - t0)
events = [e["t"] if isinstance(e, dict) else e.t for e in traj.events]
evaluations = traj.stats.get("evaluations", {})  # per configuration: "compiled" or "python: <why not>"
print(json.dumps({"ms": statistics.median(times) * 1e3, "events": events, "evaluations": evaluations}))
"""

#: name: (scene, timed runs per child process)
SCENES = {"Example 1": ("examples/three_bar.toml", 15),
          "Example 1's cycle": ("examples/three_bar_cycle.toml", 1),
          "Example 2": ("examples/double_folded.toml", 3)}

#: two event times within this are the same event time
SAME_TIME = 1e-9


def child(tree: Path, scene: str, reps: int, compiled: bool = True) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1", "PCMM_COMPILED": "1" if compiled else "0"}
    out = subprocess.run([sys.executable, "-c", CHILD, scene, str(reps)], cwd=tree, env=env,
                         check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def unbuilt_extension(tree: Path) -> str | None:
    """Why ``tree`` would be measured without its compiled extension (None: it has none, or it is built):
    a source tree from ``git archive`` has the C++ source but not the module built from it, and its
    runs would then measure its Python evaluations, not the version as installed."""
    for source in sorted(tree.glob("pcmm/**/_tree_dynamics.cpp")):
        if not any(source.parent.glob("_tree_dynamics*.so")):
            return (f"{tree}: {source.relative_to(tree)} is not built, so its runs would use its Python "
                    f"evaluations; build it in place first: (cd {tree} && CPLUS_INCLUDE_PATH=<Eigen headers> "
                    f"{Path(sys.executable).name} setup.py build_ext --inplace)")
    return None


def evaluations_md(evaluations: dict) -> str:
    """'compiled', 'python', or which configurations used which (a tree before stats['evaluations']: '?')."""
    if not evaluations:
        return "evaluations not reported"
    kinds = {name: ("compiled" if how == "compiled" else "python") for name, how in evaluations.items()}
    if len(set(kinds.values())) == 1:
        return next(iter(kinds.values()))
    compiled = sorted(name for name, k in kinds.items() if k == "compiled")
    return f"compiled in {len(compiled)} of {len(kinds)} configurations ({', '.join(compiled)})"


def _events(n: int) -> str:
    return f"{n} event{'' if n == 1 else 's'}"


def same_events(a: list[float], b: list[float]) -> tuple[bool, str]:
    """Whether two runs' events are the same (count, and the times of the events both have within SAME_TIME)."""
    n = min(len(a), len(b))
    gap = max((abs(x - y) for x, y in zip(a[:n], b[:n])), default=0.0)
    first = next((k for k in range(n) if abs(a[k] - b[k]) > SAME_TIME), None)
    same = len(a) == len(b) and first is None
    text = f"{_events(len(a))} and {_events(len(b))}; the {n} times both have differ by {gap:.1e} s at most"
    if first is not None:
        text += f", first beyond {SAME_TIME:g} s at event {first} (t = {a[first]:.9f} vs {b[first]:.9f} s)"
    return same, ("**same**: " if same else "**different**: ") + text


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("before", type=Path, help="a source tree of pcmm (pcmm/, examples/, urdf/)")
    ap.add_argument("--label", help="what the before tree is (e.g. its commit); default its folder")
    ap.add_argument("--pairs", type=int, default=5, help="how many triples (before, now, now without the extension)")
    ap.add_argument("--out", type=Path, default=DOCS / "versus.md",
                    help="the page to write (a folder: versus.md in it); default docs/benchmarks/versus.md")
    ap.add_argument("--scenes", nargs="+", choices=list(SCENES), default=list(SCENES), metavar="NAME",
                    help=f"which of {', '.join(repr(s) for s in SCENES)} to run (default all)")
    args = ap.parse_args(argv)
    before = args.before.resolve()
    if not (before / "pcmm" / "__init__.py").is_file():
        ap.error(f"{before}: not a pcmm source tree (no pcmm/__init__.py)")
    unbuilt = unbuilt_extension(before)
    if unbuilt:
        ap.error(unbuilt)
    out = args.out / "versus.md" if args.out.suffix != ".md" else args.out
    scenes = {name: SCENES[name] for name in args.scenes}
    T0 = time.perf_counter()
    info = machine()
    print(machine_md(info))
    got = {name: {"before": [], "now": [], "python": [], "ratio": [], "ratio_python": [], "runs": {}}
           for name in scenes}
    for k in range(args.pairs):
        for name, (scene, reps) in scenes.items():
            # before, now, now without the compiled evaluations (PCMM_COMPILED=0): one triple
            b = child(before, scene, reps)
            n = child(ROOT, scene, reps)
            p = child(ROOT, scene, reps, compiled=False)
            g = got[name]
            g["before"].append(b["ms"])
            g["now"].append(n["ms"])
            g["python"].append(p["ms"])
            g["ratio"].append(b["ms"] / n["ms"])
            g["ratio_python"].append(b["ms"] / p["ms"])
            g["runs"] = {"before": b, "now": n, "python": p}
            print(f"[{time.perf_counter() - T0:5.1f} s] triple {k}: {name}: before {b['ms']:.1f} ms "
                  f"({evaluations_md(b['evaluations'])}), now {n['ms']:.1f} ms ({evaluations_md(n['evaluations'])}), "
                  f"{b['ms'] / n['ms']:.2f}x; PCMM_COMPILED=0 {p['ms']:.1f} ms, {b['ms'] / p['ms']:.2f}x", flush=True)
    rows, event_rows = [], []
    for name, g in got.items():
        r, rp, runs = g["ratio"], g["ratio_python"], g["runs"]
        rows.append([f"{name} (`{scenes[name][0]}`, each tree's own; {scenes[name][1]} timed run{'s' if scenes[name][1] > 1 else ''} per process)",
                     f"{statistics.median(g['before']):.1f} ({_events(len(runs['before']['events']))}; {evaluations_md(runs['before']['evaluations'])})",
                     f"{statistics.median(g['now']):.1f} ({_events(len(runs['now']['events']))}; {evaluations_md(runs['now']['evaluations'])})",
                     f"**{statistics.median(r):.2f}×** ({min(r):.2f}–{max(r):.2f})",
                     f"{statistics.median(g['python']):.1f}",
                     f"{statistics.median(rp):.2f}× ({min(rp):.2f}–{max(rp):.2f})"])
        event_rows.append([name, same_events(runs["before"]["events"], runs["now"]["events"])[1],
                           same_events(runs["now"]["events"], runs["python"]["events"])[1]])
    text = "\n".join([
        "# Whole runs against another source tree, measured in one run",
        "",
        f"Regenerate: `{command_line()}` (run time {time.perf_counter() - T0:.0f} s).",
        "",
        machine_md(info),
        "",
        f"Before: {args.label or before} (`{before}`). {args.pairs} triples of child processes, before, now and "
        "now with `PCMM_COMPILED=0` (the Python evaluations, as on a machine where the optional "
        "extension was not built) alternating; each child times `pcmm.simulate` on its own tree's scene (CPU time, one warm-up run "
        "first, median of its runs). The speed-up is the median over the triples of before / now, with its range. "
        "In brackets: the last run's number of events, and which evaluations its configurations used "
        "(its `stats[\"evaluations\"]`).",
        "",
        md_table(["whole run, defaults", "before (ms CPU)", "now (ms CPU)", "speed-up (range over triples)",
                  "now, PCMM_COMPILED=0 (ms CPU)", "its speed-up"], rows),
        "",
        f"Events of the last triple's runs: the same when both runs have the same number of events and every "
        f"event time is within {SAME_TIME:g} s of the other run's event of the same index (compared in order "
        "over the events both runs have; the largest difference is given either way).",
        "",
        md_table(["scene", "before against now", "now against now with PCMM_COMPILED=0"], event_rows),
        "",
    ])
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
