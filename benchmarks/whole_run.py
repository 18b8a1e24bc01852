"""Whole runs, as a user meets them: ``pcmm.simulate`` on each shipped example at its defaults.

Measured in one process, interleaved (the repetitions are the outer loop), medians:

* ``pcmm.simulate(scene)`` for Example 1 (``examples/three_bar.toml``, 1 s) and Example 2
  (``examples/double_folded.toml``, 7 s) at the scene's own settings, with the solve-only part
  (``stats["wall_s"]``: integration, impulses, switches) and the recording part
  (``stats["record_s"]``) beside it;
* the import time of the command line, ``python -c "import pcmm.cli"`` in a subprocess, less
  the same interpreter's bare start-up (``python -c pass``);
* the per-run time in a sweep: N runs of Example 1 in one process (a parameter study), the
  scene loaded once;
* the event times of each example, to compare accuracy before and after a change.

Every figure is a ratio to a fixed reference workload measured in the same run, right before
and after each repetition: ``REF_CALLS`` calls of ``pinocchio.aba`` on Example 1's first
configuration at a fixed state (built directly from the URDF, so it does not depend on pcmm).
The ratios are formed from CPU time (``time.process_time``; the child's CPU time for the import):
on a machine shared by many processes the wall time mostly measures the neighbours (it ran up
to 7x the CPU time while these figures were taken), the CPU time what pcmm does.  Wall times are
printed too.

    python benchmarks/whole_run.py [--reps 7] [--sweep 20] [--json FILE] [--before FILE]

``--json`` saves the figures; ``--before`` reads such a file (e.g. measured on an earlier commit
with this same script) and adds the speed-up against it.  Writes docs/benchmarks/whole_run.md.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # no BLAS threads spinning on a shared machine

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import DOCS, EXAMPLES, ROOT, command_line, machine, machine_md, md_table, median  # noqa: E402

import pcmm  # noqa: E402
from pcmm.scene.urdf import dynamics_xml  # noqa: E402

REF_CALLS = 20000


def timed(fn):
    """(cpu seconds, wall seconds, result) of ``fn()``."""
    c0, w0 = time.process_time(), time.perf_counter()
    out = fn()
    return time.process_time() - c0, time.perf_counter() - w0, out


def reference_workload():
    """A fixed, pcmm-independent workload: REF_CALLS ``pin.aba`` calls on Example 1's first
    configuration (three revolute bars) at a fixed state."""
    model = pin.buildModelFromXML(dynamics_xml(ROOT / "urdf" / "three_bar_config1.urdf"))
    data = model.createData()
    q, v, tau = np.array([0.3, -0.2, 1.1]), np.array([1.0, -2.0, 3.0]), np.array([0.1, 0.2, 0.3])
    aba = pin.aba

    def run():
        for _ in range(REF_CALLS):
            aba(model, data, q, v, tau)
    return run


def import_time(python: str) -> tuple[float, float, float]:
    """(CPU s, wall s) of ``import pcmm.cli`` in a fresh interpreter, less a bare start-up's,
    and the bare start-up's wall time."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}

    def once(code):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        w0 = time.perf_counter()
        subprocess.run([python, "-c", code], check=True, env=env, cwd=ROOT)
        w = time.perf_counter() - w0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        return (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime), w
    bare = once("pass")
    full = once("import pcmm.cli")
    return full[0] - bare[0], full[1] - bare[1], bare[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--sweep", type=int, default=20, help="runs of Example 1 per sweep sample")
    ap.add_argument("--json", type=Path, help="save the figures (for a later --before)")
    ap.add_argument("--before", type=Path, help="figures of an earlier measurement (--json) to compare with")
    ap.add_argument("--out", type=Path, default=DOCS)
    args = ap.parse_args(argv)
    T0 = time.perf_counter()
    info = machine()
    print(machine_md(info))
    ref = reference_workload()
    scenes = {"Example 1": pcmm.load_scene(EXAMPLES / "three_bar.toml"),
              "Example 2": pcmm.load_scene(EXAMPLES / "double_folded.toml")}
    keys = [*scenes, "sweep", "import"]
    ratio = {k: [] for k in keys}
    wall = {k: [] for k in keys}
    parts = {k: {"solve": [], "record": []} for k in scenes}
    refs_cpu, events, settings = [], {}, {}
    for rep in range(args.reps):
        cpu0, _, _ = timed(ref)
        got = {}
        for name, sc in scenes.items():
            c, w, traj = timed(lambda sc=sc: pcmm.simulate(sc))
            got[name] = (c, w)
            parts[name]["solve"].append(traj.stats["wall_s"])
            parts[name]["record"].append(traj.stats["record_s"])
            events[name] = [e["t"] for e in traj.events]
            settings[name] = f"{traj.stats['method']}, rtol {traj.stats['rtol']:g}, atol {traj.stats['atol']:g}"
        c, w, _ = timed(lambda: [pcmm.simulate(scenes["Example 1"]) for _ in range(args.sweep)])
        got["sweep"] = (c / args.sweep, w / args.sweep)
        ic, iw, bare = import_time(sys.executable)
        got["import"] = (ic, iw)
        cpu1, _, _ = timed(ref)
        r = 0.5 * (cpu0 + cpu1)
        refs_cpu.append(r)
        for k, (c, w) in got.items():
            ratio[k].append(c / r)
            wall[k].append(w)
        print(f"[{time.perf_counter() - T0:5.1f} s] rep {rep}: reference {r * 1e3:.1f} ms CPU; "
              + ", ".join(f"{k} {ratio[k][-1]:.3f} ref ({wall[k][-1] * 1e3:.0f} ms wall)" for k in keys), flush=True)
    med = {k: median(v) for k, v in ratio.items()}
    before = json.loads(args.before.read_text()) if args.before else None
    labels = {k: f"`pcmm.simulate` {k} ({sc.path.name}, t_end {sc.t_end:g} s; {settings[k]})" for k, sc in scenes.items()}
    labels["sweep"] = f"one run in a sweep ({args.sweep} runs of Example 1 in one process, scene loaded once)"
    labels["import"] = "`import pcmm.cli` in a fresh interpreter (less a bare start-up)"
    header = ["whole run", "× reference (CPU, median)", "wall ms (median)", "solve / record (ms wall)"]
    if before:
        header += ["before (× reference)", "speed-up"]
    rows = []
    for k in keys:
        row = [labels[k], f"{med[k]:.3f}", f"{median(wall[k]) * 1e3:.1f}",
               f"{median(parts[k]['solve']) * 1e3:.1f} / {median(parts[k]['record']) * 1e3:.1f}" if k in parts else "—"]
        if before:
            b = before["ratio"].get(k)
            row += [f"{b:.3f}" if b else "—", f"{b / med[k]:.2f}×" if b else "—"]
        rows.append(row)
    table = md_table(header, rows)
    ev_rows = []
    for k, ts in events.items():
        row = [k, len(ts), f"{ts[0]:.15g}" if ts else "—", f"{ts[-1]:.15g}" if ts else "—"]
        if before and before["events"].get(k):
            bt = before["events"][k]
            n = min(len(bt), len(ts))
            row += [len(bt), f"{max(abs(a - b) for a, b in zip(ts[:n], bt[:n])):.2g}"]
        ev_rows.append(row)
    ev = md_table(["scene", "events", "first event t (s)", "last event t (s)"]
                  + (["events before", "largest |Δt| against before (s)"] if before else []), ev_rows)
    runtime = time.perf_counter() - T0
    r_med = median(refs_cpu)
    print(table)
    print(ev)
    print(f"reference: {REF_CALLS} pin.aba calls = {r_med * 1e3:.2f} ms CPU (median); run time {runtime:.0f} s")
    if args.json:
        args.json.write_text(json.dumps({"ratio": med, "events": events, "reference_cpu_s": r_med,
                                         "sources": info["pcmm_sources"]}, indent=1))
    page = ["# Whole runs", "", f"Regenerate: `{command_line()}` (run time {runtime:.0f} s).", "",
            machine_md(info), "",
            f"Median of {args.reps} interleaved repetitions. The reference workload is {REF_CALLS} calls of "
            "`pinocchio.aba` on Example 1's first configuration (built from `urdf/three_bar_config1.urdf` "
            f"without pcmm) at a fixed state, measured before and after every repetition: {r_med * 1e3:.2f} ms of "
            "CPU in this run. \"× reference\" is each whole run's CPU time divided by it (the import: the child "
            "interpreter's CPU time), so the figure follows pcmm's cost, not the machine's load; on this shared "
            "machine the wall time (also given) ran up to several times the CPU time. `solve` is "
            "`stats[\"wall_s\"]` (integration, impulses and switches); `record` is `stats[\"record_s\"]` (keeping "
            "the integrator's states: the series are computed when first read). The sweep reuses the models of "
            "the first run (models are built once per process), and so does every repetition after the first.",
            ""]
    if before:
        page += [f"\"before\" is the same script on pcmm sources {before.get('sources', '?')} "
                 f"(`--before {args.before.name}`), measured on the same machine just before.", ""]
    page += [table, "", "Event times (accuracy is compared against the measurement before):", "", ev, ""]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "whole_run.md").write_text("\n".join(page))


if __name__ == "__main__":
    main()
