"""Work-precision diagrams of pcmm's integrators on the paper's two examples.

For Example 1 (examples/three_bar.toml, t_end = 1 s: the latch at t ~ 0.167 s and
0.83 s in configuration 2) and Example 2 (examples/double_folded.toml, t_end =
3.5 s: the first stop impact at t ~ 3.004 s, the macro-impact of a few dozen impacts,
the merge at t ~ 3.163 s and ~0.34 s in the merged configuration), each integrator of
pcmm's registry runs over a sweep of tolerances (RK45, DOP853, DOP853F, Radau, LSODA:
rtol 1e-3 .. 1e-12, atol = rtol * 1e-2) or step sizes (the fixed-step RK4 of the
paper's MATLAB route).  Each run is compared with a reference run (DOP853,
rtol 1e-13, atol 1e-15):

* the first impact time,
* the state just after the first impact: max |difference| over the post-impact
  absolute angular velocities of the links (rad/s) and, in Example 2, the
  slider velocity (m/s),
* the final state: max |difference| of the link angles at t_end (rad),
* Example 2: the merge time (end of the macro-impact).

Cost: ``traj.stats["wall_s"]`` (solve time, recording excluded), median of the
repetitions; repetitions are the outer loop so every run sees the same load.
The script also splits Example 2's solve time into the integration of the free
motion and the sampling of the merged configuration, which has no free
coordinate (it is fully driven, so pcmm samples it with 1000 RK4 steps whatever
the method and tolerance); and it sweeps the accumulation tolerance
(accumulation_speed 1e-3 .. 1e-7 m/s) on Example 2.

    python benchmarks/work_precision.py            # full: < 10 min
    python benchmarks/work_precision.py --quick    # < 1 min (Example 2 to 3.02 s)

Writes docs/benchmarks/work_precision.{csv,md,png}.
"""
from __future__ import annotations

import argparse
import csv
import importlib
import math
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (DOCS, EXAMPLES, command_line, fmt, machine, machine_md, md_table, median,  # noqa: E402
                     scene_copy, timed_segments)

import pcmm  # noqa: E402
from pcmm import RunOptions  # noqa: E402

SIM = importlib.import_module("pcmm.run.loop")

REF = dict(method="DOP853", rtol=1e-13, atol=1e-15)
CHECKS = [dict(method="DOP853", rtol=1e-12, atol=1e-14), dict(method="RK45", rtol=1e-12, atol=1e-14)]
MAX_EVENTS = {"ex1": None, "ex2": 500}  # the reference has 45 impacts; a run past 500 events is chattering
ACC_MAX_EVENTS = 300  # accumulation sweep: a macro-impact that does not end is reported as such
MISSED = 1e-9  # m: a slider found this far past its stop in the free configuration has missed the stop
ADAPTIVE = ("RK45", "DOP853", "DOP853F", "Radau", "LSODA")
ATOL_FACTOR = 1e-2
_DEFAULTS = pcmm.scene.settings.SolverSettings()  # the scenes' defaults, so this page follows them
DEFAULT = dict(method=_DEFAULTS.method, rtol=_DEFAULTS.rtol, atol=_DEFAULTS.atol)
DEFAULT_TAG = f"{DEFAULT['method']} {DEFAULT['rtol']:.0e}"

FULL = {
    "ex1": dict(rtols=[10.0 ** -k for k in range(3, 13)], steps=[1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 3e-5, 1e-5], t_end=1.0),
    "ex2": dict(rtols=[10.0 ** -k for k in range(3, 13)], steps=[1e-2, 3e-3, 1e-3], t_end=3.5),
}
QUICK = {
    "ex1": dict(rtols=[1e-4, 1e-7, 1e-10], steps=[1e-2, 1e-3], t_end=1.0),
    "ex2": dict(rtols=[1e-4, 1e-7, 1e-10], steps=[1e-2], t_end=3.02),
}
SCENES = {
    "ex1": dict(path=EXAMPLES / "three_bar.toml", title="Example 1 (three-bar, latch)", sliders=()),
    "ex2": dict(path=EXAMPLES / "double_folded.toml", title="Example 2 (double-folded, stop + macro-impact)",
                sliders=("E",), stop=("E", 0.3195)),
}
ACCUM_FULL = [1e-3, 1e-4, 1e-5, 1e-6, 1e-7]
ACCUM_QUICK = [1e-3, 1e-5, 1e-7]
ERRORS = [("err_t_impact", "first impact time (s)"), ("err_post", "post-impact velocities"),
          ("err_final", "link angles at t_end (rad)"), ("err_merge", "merge time (s)")]


def short_status(status: str) -> str:
    """A table-sized status: the failure kinds seen in these sweeps get a short name."""
    if status == "ok" or status.startswith("stop missed"):
        return status
    if "different signs" in status:
        return "raised ValueError (brentq: f(a) and f(b) must have different signs)"
    m = re.search(r"more than (\d+) events by t = ([0-9.]+) s", status)
    if m:
        return f"raised: more than {m.group(1)} events by t = {m.group(2)} s (chatter)"
    if "separating" in status:
        m = re.search(r"t = ([0-9.]+) s", status)
        return f"raised: guard fired while separating{f' at t = {m.group(1)} s' if m else ''}"
    return status[:120]


def accumulation_edit(speed):
    """Set the stop's own accumulation_speed (it overrides the run option) in a copy of Example 2."""
    def edit(text):
        head, tail = text.split("[[transitions]]", 1)
        line = f"accumulation_speed = {speed!r}"
        if re.search(r"^accumulation_speed\s*=", tail, re.M):
            tail = re.sub(r"^accumulation_speed\s*=.*$", line, tail, count=1, flags=re.M)
        else:
            tail = re.sub(r"^(restitution\s*=.*)$", lambda m: m.group(1) + "\n" + line, tail, count=1, flags=re.M)
        return head + "[[transitions]]" + tail
    return edit


# ---- one run ----------------------------------------------------------------------------
def run(scene, sliders, t_end, stop=None, max_events=None, **kw):
    """Simulate; return the metrics (or the failure)."""
    log = []
    if max_events:
        kw["max_events"] = max_events
    try:
        with timed_segments(log):
            traj = pcmm.simulate(scene, RunOptions(t_end=t_end, **kw))
    except Exception as exc:  # a failing method is a result too
        msg = f"{type(exc).__name__}: {exc}".splitlines()[0]
        part = getattr(exc, "partial", None)  # pcmm's SimulationError carries the run up to the failure
        extra = {"wall_s_partial": part.stats.get("wall_s"), "impacts_partial": part.stats.get("impacts")} \
            if part is not None and part.stats else {}
        return {"ok": False, "status": "failed: " + msg[:150], **extra}
    ev = traj.events
    first = ev[0] if ev else None
    post = None
    if first is not None:
        post = {k: v for k, v in first["omega_after"].items() if k != "frame"}
        post.update({f"v:{j}": first["v_after"][j] for j in sliders})
    last = traj.segments[-1]
    final = {k: float(last.theta[-1, i]) for i, k in enumerate(last.links) if k != "frame"}
    merges = [e for e in ev if e.get("merge") and e.get("transition") == "stop"]
    driven = [x for x in log if x.ny == 0]
    penetration = math.nan
    if stop:  # sanity: the slider must never be found beyond its stop while free (configuration 1)
        joint, x_stop = stop
        penetration = max(float(np.max(s.q[:, s.coordinates.index(joint)])) - x_stop
                          for s in traj.segments if joint in s.coordinates and s.configuration == "config1")
    missed = np.isfinite(penetration) and penetration > MISSED
    return {
        "ok": True, "status": f"stop missed ({penetration:.1e} m past)" if missed else "ok", "wall_s": traj.stats["wall_s"], "steps": traj.stats["steps"], "rhs_evals": traj.stats["rhs_evals"],
        "impacts": traj.stats["impacts"], "t_impact": first["t"] if first else math.nan, "post": post, "final": final,
        "t_merge": merges[0]["t"] if merges else math.nan,
        "driven_s": sum(x.seconds for x in driven), "driven_rhs": sum(x.nfev for x in driven),
        "events_s": traj.stats["wall_s"] - sum(x.seconds for x in log),  # impulse solves and switches
        "penetration": penetration,
    }


def compare(r, ref):
    if not r["ok"]:
        return {k: math.nan for k, _ in ERRORS}
    out = {"err_t_impact": abs(r["t_impact"] - ref["t_impact"]), "err_merge": abs(r["t_merge"] - ref["t_merge"])}
    if r["status"] != "ok":  # the stop was missed: the late-time errors are not integration errors
        out["err_merge"] = math.nan
    keys = set(ref["post"]) & set(r["post"] or {})
    out["err_post"] = max(abs(r["post"][k] - ref["post"][k]) for k in keys) if keys else math.nan
    keys = set(ref["final"]) & set(r["final"])
    out["err_final"] = max(abs(r["final"][k] - ref["final"][k]) for k in keys) if keys else math.nan
    return out


# ---- main -------------------------------------------------------------------------------
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer tolerances, one repetition, Example 2 to 3.02 s")
    ap.add_argument("--reps", type=int, default=None, help="repetitions (default 3; --quick: 1)")
    ap.add_argument("--slow", type=float, default=4.0,
                    help="a run whose first repetition's wall_s exceeds this many seconds is not repeated")
    ap.add_argument("--methods", nargs="+", default=list(ADAPTIVE),
                    help=f"adaptive methods of pcmm's registry to sweep (default: {' '.join(ADAPTIVE)}); RK4 always runs")
    ap.add_argument("--out", type=Path, default=DOCS)
    args = ap.parse_args(argv)
    T0 = time.perf_counter()
    methods = [m for m in args.methods if m != "RK4"]
    unknown = [m for m in methods if m not in SIM.INTEGRATORS]
    if unknown:
        ap.error(f"unknown method(s) {unknown}; pcmm has {list(SIM.INTEGRATORS)}")
    plan = QUICK if args.quick else FULL
    reps = args.reps or (1 if args.quick else 3)
    info = machine()
    print(machine_md(info))
    scenes = {k: pcmm.load_scene(v["path"]) for k, v in SCENES.items()}

    # references (and the reference's own error: |CHECK - REF|)
    refs, ref_check, ref_cost = {}, {}, {}
    for ex, sc in scenes.items():
        refs[ex] = run(sc, SCENES[ex]["sliders"], plan[ex]["t_end"], SCENES[ex].get("stop"), MAX_EVENTS[ex], **REF)
        if refs[ex]["status"] != "ok":
            raise SystemExit(f"{ex}: the reference run did not complete cleanly: {refs[ex]['status']}")
        ref_check[ex] = []
        for chk_kw in CHECKS:
            chk = run(sc, SCENES[ex]["sliders"], plan[ex]["t_end"], SCENES[ex].get("stop"), MAX_EVENTS[ex], **chk_kw)
            ref_check[ex].append((f"{chk_kw['method']} rtol {chk_kw['rtol']:.0e}", chk["status"], compare(chk, refs[ex])))
        print(f"{ex}: reference t_impact = {refs[ex]['t_impact']:.15g} s, t_merge = {refs[ex]['t_merge']:.15g} s, "
              f"impacts = {refs[ex]['impacts']}, wall {refs[ex]['wall_s']:.2f} s; " + "; ".join(
                  f"|{n} - ref| ({st}): " + ", ".join(f"{k} {v:.1e}" for k, v in e.items()) for n, st, e in ref_check[ex]),
              flush=True)

    # the plan: (example, method, rtol, atol, step)
    cases = []
    for ex in scenes:
        for m in methods:
            for rt in plan[ex]["rtols"]:
                cases.append((ex, m, rt, rt * ATOL_FACTOR, None))
        for h in plan[ex]["steps"]:
            cases.append((ex, "RK4", None, None, h))
    samples = {c: [] for c in cases}
    first = {}
    for rep in range(reps):
        for c in cases:
            ex, m, rt, at, h = c
            if rep and (not first[c]["ok"] or first[c]["wall_s"] > args.slow):
                continue
            kw = dict(method=m, step=h) if h else dict(method=m, rtol=rt, atol=at)
            r = run(scenes[ex], SCENES[ex]["sliders"], plan[ex]["t_end"], SCENES[ex].get("stop"), MAX_EVENTS[ex], **kw)
            if rep == 0:
                first[c] = r
            if r["ok"]:
                samples[c].append((r["wall_s"], r["driven_s"], r["events_s"]))
            if rep == 0:
                e = compare(r, refs[ex])
                tag = f"step {h:g}" if h else f"rtol {rt:.0e}"
                print(f"[{time.perf_counter() - T0:6.1f} s] {ex} {m:6s} {tag:11s} "
                      + (f"wall {r['wall_s']:.3f} s  rhs {r['rhs_evals']:6d}  impacts {r['impacts']:3d}  "
                         f"err t {e['err_t_impact']:.1e} post {e['err_post']:.1e} final {e['err_final']:.1e} "
                         f"merge {e['err_merge']:.1e} {r['status']}" if r["ok"] else r["status"]),
                      flush=True)

    rows = []
    for c in cases:
        ex, m, rt, at, h = c
        r = first[c]
        e = compare(r, refs[ex])
        rows.append({
            "example": ex, "t_end": plan[ex]["t_end"], "method": m, "rtol": rt, "atol": at, "step": h,
            "status": r["status"], "ok": r["ok"], "reps": len(samples[c]),
            "wall_s": median([s[0] for s in samples[c]]), "driven_s": median([s[1] for s in samples[c]]),
            "events_s": median([s[2] for s in samples[c]]),
            "rhs_evals": r.get("rhs_evals"), "driven_rhs": r.get("driven_rhs"), "steps": r.get("steps"),
            "impacts": r.get("impacts"), "penetration_m": r.get("penetration"), **e})

    # accumulation tolerance on Example 2 (default integrator; t_end must reach the merge).  The scene's stop may
    # carry its own accumulation_speed, which wins over the run option, so the sweep edits TOML copies.
    acc_t_end = FULL["ex2"]["t_end"]  # 3.5 s in both modes (see the md: a shorter t_end can miss the merge)
    speeds = ACCUM_QUICK if args.quick else ACCUM_FULL
    tmp = Path(tempfile.mkdtemp(prefix="pcmm_wp_"))
    scene_text = SCENES["ex2"]["path"].read_text()
    own = re.search(r"^accumulation_speed\s*=\s*(\S+)", scene_text.split("[[transitions]]", 1)[1], re.M)
    acc_scenes = {s: pcmm.load_scene(scene_copy(SCENES["ex2"]["path"], tmp, f"acc_{s:g}.toml", accumulation_edit(s)))
                  for s in speeds}
    acc_samples = {s: [] for s in speeds}
    acc_first = {}
    for rep in range(reps):
        for s in speeds:
            if rep and not acc_first[s]["ok"]:
                continue
            r = run(acc_scenes[s], ("E",), acc_t_end, SCENES["ex2"]["stop"], ACC_MAX_EVENTS, **DEFAULT)
            acc_first.setdefault(s, r)
            if r["ok"]:
                acc_samples[s].append((r["wall_s"], r["driven_s"], r["events_s"]))
    acc_rows = []
    for s in speeds:
        r = acc_first[s]
        acc_rows.append({"accumulation_speed": s, "status": r["status"],
                         "impacts": r.get("impacts", r.get("impacts_partial")), "t_first": r.get("t_impact", math.nan),
                         "t_merge": r.get("t_merge", math.nan),
                         "wall_s": median([x[0] for x in acc_samples[s]]) if acc_samples[s]
                         else r.get("wall_s_partial", math.nan),
                         "driven_s": median([x[1] for x in acc_samples[s]]),
                         "events_s": median([x[2] for x in acc_samples[s]]),
                         "rhs_evals": r.get("rhs_evals"), "steps": r.get("steps"),
                         "penetration_m": r.get("penetration")})
    ok_acc = [a for a in acc_rows if a["status"] == "ok"]
    tight = ok_acc[-1]["t_merge"] if ok_acc else math.nan
    for a in acc_rows:
        a["d_merge_vs_tightest"] = abs(a["t_merge"] - tight)
        a["d_merge_vs_ref"] = abs(a["t_merge"] - refs["ex2"]["t_merge"])
        print(f"accumulation_speed {a['accumulation_speed']:.0e}: {a['status']}, impacts {a['impacts']}, merge at "
              f"{a['t_merge']:.9f} s (|diff| to the tightest clean run: {a['d_merge_vs_tightest']:.1e} s), "
              f"wall {a['wall_s']:.2f} s (merged-configuration sampling {a['driven_s']:.2f} s)", flush=True)

    args.out.mkdir(parents=True, exist_ok=True)
    write_csv(args.out / "work_precision.csv", rows, acc_rows)
    plot(args.out / "work_precision.png", rows, plan, methods)
    runtime = time.perf_counter() - T0
    write_md(args.out / "work_precision.md", rows, acc_rows, refs, ref_check, plan, reps, args, info, runtime,
             own.group(1) if own else None)
    print(f"wrote {args.out / 'work_precision.md'}, .csv, .png; run time {runtime:.0f} s")


def write_csv(path, rows, acc_rows):
    keys = list(rows[0])
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    with open(path.with_name("work_precision_accumulation.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(acc_rows[0]))
        w.writeheader()
        for r in acc_rows:
            w.writerow({k: (f"{v:.12g}" if isinstance(v, float) else v) for k, v in r.items()})


def plot(path, rows, plan, methods):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 4, figsize=(17, 8.2))
    colors = {"RK45": "C0", "DOP853": "C1", "Radau": "C2", "LSODA": "C3", "RK4": "C4"}
    for i, m in enumerate(x for x in methods if x not in colors):
        colors[m] = f"C{5 + i}"
    for i, ex in enumerate(("ex1", "ex2")):
        for j, (key, label) in enumerate(ERRORS):
            ax = axes[i, j]
            if ex == "ex1" and key == "err_merge":
                ax.axis("off")
                continue
            if key == "err_merge" and plan[ex]["t_end"] < 3.3:
                ax.text(0.5, 0.5, "merge not reached\n(quick mode: t_end = 3.02 s)", ha="center", va="center",
                        transform=ax.transAxes)
                ax.set_xticks([])
                ax.set_yticks([])
                continue
            late = key in ("err_final", "err_merge")  # runs that missed the stop are not integration errors there
            for m in (*methods, "RK4"):
                sel = [r for r in rows if r["example"] == ex and r["method"] == m and r["ok"] and np.isfinite(r[key])]
                pts = [(r["wall_s"], max(r[key], 1e-16)) for r in sel if r["status"] == "ok" or not late]
                if pts:
                    x, y = zip(*pts)
                    ax.loglog(x, y, "o-", color=colors[m], ms=4, label=m + (" (fixed step)" if m == "RK4" else ""))
                bad = [(r["wall_s"], max(r[key], 1e-16)) for r in sel if r["status"] != "ok" and late]
                if bad:
                    x, y = zip(*bad)
                    ax.loglog(x, y, "x", color=colors[m], ms=7, mew=2)
            d = [r for r in rows if r["example"] == ex and r["method"] == DEFAULT["method"]
                 and r["rtol"] == DEFAULT["rtol"]]
            if d and d[0]["status"] == "ok":
                ax.loglog([d[0]["wall_s"]], [max(d[0][key], 1e-16)], "k*", ms=12, label=f"default ({DEFAULT_TAG})")
            ax.set_title(f"{SCENES[ex]['title'].split(' (')[0]}: {label}", fontsize=9)
            ax.set_xlabel("solve time wall_s (s, median)")
            ax.set_ylabel("error vs reference")
            ax.grid(True, which="both", alpha=0.3)
    h, lab = axes[0, 0].get_legend_handles_labels()
    if plan["ex2"]["t_end"] >= 3.3:
        h = h + [plt.Line2D([], [], color="k", marker="x", ls="", mew=2)]
        lab = lab + ["slider missed the stop\n(final state wrong, no merge)"]
    axes[0, 3].legend(h, lab, loc="center", fontsize=10, title="error vs solve time")
    fig.suptitle(f"pcmm work-precision (Example 1 to t = {plan['ex1']['t_end']} s, Example 2 to t = "
                 f"{plan['ex2']['t_end']} s; reference DOP853 rtol 1e-13, atol 1e-15)", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def cheapest(rows, ex, target, keys):
    ok = [r for r in rows if r["example"] == ex and r["status"] == "ok"
          and all(np.isfinite(r[k]) and r[k] <= target for k in keys)]
    return min(ok, key=lambda r: r["wall_s"]) if ok else None


def tag(r):
    return f"{r['method']} step {r['step']:g}" if r["step"] else f"{r['method']} rtol {r['rtol']:.0e}"


def write_md(path, rows, acc_rows, refs, ref_check, plan, reps, args, info, runtime, own_speed=None):
    full2 = plan["ex2"]["t_end"] >= 3.3
    checks = []
    for ex, lst in ref_check.items():
        for name, st, e in lst:
            vals = ", ".join(f"{k.removeprefix('err_')} {v:.1e}" for k, v in e.items() if np.isfinite(v))
            checks.append(f"{ex} {name}: " + (vals if st == "ok" else f"{st}" + (f" ({vals})" if vals else "")))
    L = [f"# Work-precision of pcmm's integrators{' (quick mode)' if args.quick else ''}", "",
         f"Regenerate: `{command_line()}` (run time of this run: {runtime:.0f} s).", "",
         machine_md(info), "",
         "## Setup", "",
         f"* Example 1: `examples/three_bar.toml` to t_end = {plan['ex1']['t_end']} s (the latch of O3, a mobile "
         "impact, at t ≈ 0.167 s, then configuration 2).",
         f"* Example 2: `examples/double_folded.toml` to t_end = {plan['ex2']['t_end']} s. "
         + (f"3.5 s covers the first impact (t ≈ {refs['ex2']['t_impact']:.4f} s), the macro-impact (the reference "
            f"resolves {refs['ex2']['impacts']} stable impacts, e = 0.8) and the merge at t ≈ "
            f"{refs['ex2']['t_merge']:.4f} s, followed by {plan['ex2']['t_end'] - refs['ex2']['t_merge']:.2f} s in the "
            "merged configuration; the scene's 7 s would add only more of the merged, fully driven motion (no free "
            "coordinate). `max_events` = 500 for these runs so that a chattering run fails in seconds instead of "
            "minutes."
            if full2 else
            "Quick mode: 3.02 s covers the first impact (t ≈ 3.004 s) only, not the macro-impact or the merge."),
         f"* Methods: {', '.join(m for m in args.methods if m != 'RK4')} (pcmm's integrator registry: scipy's "
         "steppers of those names driven by pcmm's step loop and event scanner; DOP853F: Hairer's Fortran DOP853, "
         "its accepted steps scanned by the same event scanner) with atol = rtol × 1e-2; the fixed-step classical RK4 "
         "(the paper's MATLAB route) with step h. Guards are located on each method's dense output.",
         "* Reference: DOP853, rtol 1e-13, atol 1e-15. Its own error is estimated by two other tight runs "
         "(|run − reference|): " + "; ".join(checks) + ". Errors below these levels are not resolved.",
         "* Errors: `t_impact` = |first impact time − ref|; `post` = max |difference| of the absolute angular "
         "velocities of the links just after the first impact (rad/s) and, in Example 2, of the slider velocity "
         "(m/s); `final` = max |difference| of the link angles at t_end (rad); `merge` = |merge time − ref| "
         "(Example 2).",
         f"* Cost: `wall_s` = `traj.stats['wall_s']` (integration + impulse solves, recording excluded), median "
         f"of {reps} interleaved repetition(s); a run slower than {args.slow:g} s in its first repetition is not "
         "repeated (`reps` column). `rhs` = right-hand-side evaluations. All figures of this page come from one run "
         "of the script; the machine is shared, so compare times within this page only.", ""]
    if full2:
        L += ["**Example 2 caveats.** (1) After the merge the mechanism has no free coordinate (slider at the stop, "
              "crank driven, loop closed): pcmm samples that segment with 1000 fixed RK4 steps of the constraint "
              "solver whatever the method and tolerance, so `driven_s` (part of `wall_s`; `events_s` is the part spent "
              "in impulse solves and switches) is a floor common to "
              "every run that merges, and `final` (link angles at 3.5 s) depends only on the drive and the stop "
              "position, not on the integration error. The merge time is the informative late-time error. "
              "(2) The number of impacts of the macro-impact can depend on the accuracy (`impacts` column); the last "
              "bounces are very short, so the merge time is the most sensitive quantity. (3) `max x_E − stop` "
              "checks that the slider never passes its stop while free; a run where it does is marked "
              "`stop missed` (its final state and merge are wrong, drawn as × in the figure), see "
              "*Robustness of the macro-impact end* below.", ""]
    header = ["method", "rtol / step", "status", "wall_s (s)", "reps", "rhs", "steps", "impacts",
              "err t_impact (s)", "err post", "err final (rad)"]
    for ex in ("ex1", "ex2"):
        L += [f"## {SCENES[ex]['title']}", ""]
        ref = refs[ex]
        L += [f"Reference: first impact at {ref['t_impact']:.13f} s, {ref['impacts']} impact(s)"
              + (f", merge at {ref['t_merge']:.13f} s" if np.isfinite(ref['t_merge']) else "")
              + f"; reference wall_s {ref['wall_s']:.2f} s.", ""]
        hdr = header + (["err merge (s)", "driven_s (s)", "events_s (s)", "max x_E − stop (m)"] if ex == "ex2" else [])
        tab = []
        for r in rows:
            if r["example"] != ex:
                continue
            base = [r["method"], f"{r['step']:g} s" if r["step"] else f"{r['rtol']:.0e}", short_status(r["status"])]
            if not r["ok"]:
                tab.append(base + [""] * (len(hdr) - 3))
                continue
            row = base + [fmt(r["wall_s"], ".3f"), r["reps"], r["rhs_evals"], r["steps"], r["impacts"],
                          fmt(r["err_t_impact"], ".1e"), fmt(r["err_post"], ".1e"), fmt(r["err_final"], ".1e")]
            if ex == "ex2":
                row += [fmt(r["err_merge"], ".1e"), fmt(r["driven_s"], ".2f"), fmt(r["events_s"], ".3f"),
                        fmt(r["penetration_m"], ".1e")]
            tab.append(row)
        L += [md_table(hdr, tab), ""]

    if full2:
        L += ["## Robustness of the macro-impact end (Example 2)", "",
              "Out of each method's sweep: runs that end cleanly (merge, slider never past the stop), runs where the "
              "slider passes through the stop after the last bounce (silently wrong), and runs that raise.", ""]
        tab = []
        for m in dict.fromkeys(r["method"] for r in rows):
            sel = [r for r in rows if r["example"] == "ex2" and r["method"] == m]
            fails = {}
            for r in sel:
                if not r["ok"]:
                    k = r["status"].removeprefix("failed: ")
                    k = ("ValueError (brentq: f(a) and f(b) must have different signs)" if "different signs" in k
                         else "max_events exceeded (chattering)" if "more than" in k
                         else "guard fired while separating" if "separating" in k else k[:60])
                    fails[k] = fails.get(k, 0) + 1
            tab.append([m, len(sel), sum(r["status"] == "ok" for r in sel),
                        sum(r["ok"] and r["status"] != "ok" for r in sel),
                        "; ".join(f"{v} × {k}" for k, v in fails.items()) or "0"])
        L += [md_table(["method", "runs", "clean", "stop missed", "raised"], tab), ""]

    # cheapest settings per accuracy target
    L += ["## Cheapest setting per accuracy target", "",
          "For each target, the fastest clean run (median wall_s) whose first-impact time error *and* post-impact "
          "velocity error are both at or below the target"
          + (" (Example 2: also the merge-time error; clean runs only)" if full2 else "") + ".", ""]
    tab = []
    for target in (1e-3, 1e-4, 1e-6, 1e-8, 1e-10):
        cells = [f"{target:.0e}"]
        for ex in ("ex1", "ex2"):
            keys = ["err_t_impact", "err_post"] + (["err_merge"] if ex == "ex2" and full2 else [])
            c = cheapest(rows, ex, target, keys)
            cells.append(f"{tag(c)} ({c['wall_s']:.3f} s)" if c else "none")
        tab.append(cells)
    L += [md_table(["target", "Example 1", "Example 2"], tab), ""]
    d = {ex: next((r for r in rows if r["example"] == ex and r["method"] == DEFAULT["method"]
                   and r["rtol"] == DEFAULT["rtol"]), None) for ex in ("ex1", "ex2")}
    L += [f"Default settings ({DEFAULT['method']}, rtol {DEFAULT['rtol']:.0e}, atol {DEFAULT['atol']:.0e}): " + "; ".join(
        f"{ex}: {r['status']}, first impact time error {r['err_t_impact']:.1e} s, post-impact velocity error "
        f"{r['err_post']:.1e}, wall_s {r['wall_s']:.3f} s" for ex, r in d.items() if r and r["ok"]) + ".", ""]

    L += ["## Accumulation tolerance (Example 2)", "",
          f"{DEFAULT['method']}, rtol {DEFAULT['rtol']:.0e}, atol {DEFAULT['atol']:.0e}, t_end = {FULL['ex2']['t_end']} s, "
          "accumulation_interval 1e-9 s "
          "(the default). A stop impact whose post-impact normal speed is at or below `accumulation_speed` is "
          "made plastic and the slider merges with the frame. "
          + (f"The scene's stop sets its own `accumulation_speed = {own_speed}`, which takes precedence over "
             "`RunOptions(accumulation_speed=...)` (and the CLI's `--accumulation-speed`), so the sweep edits the "
             "stop's value in TOML copies. " if own_speed else
             "The sweep sets the stop's own `accumulation_speed` in TOML copies. ")
          + f"At most {ACC_MAX_EVENTS} events per run: a macro-impact that does not end by then is reported as "
          "failed (with the impacts and solve time up to that point).", ""]
    tab = [[f"{a['accumulation_speed']:.0e}", short_status(a["status"]), a.get("impacts", ""),
            fmt(a["t_merge"], ".9f"), fmt(a["d_merge_vs_tightest"], ".1e"), fmt(a["d_merge_vs_ref"], ".1e"),
            fmt(a["wall_s"], ".2f"), fmt(a["driven_s"], ".2f"), fmt(a["events_s"], ".3f"), a.get("rhs_evals") or "",
            a.get("steps") or ""]
           for a in acc_rows]
    ok_rows = [a for a in acc_rows if a["status"] == "ok"]
    tight = ok_rows[-1]["accumulation_speed"] if ok_rows else None
    L += [md_table(["accumulation_speed (m/s)", "status", "impacts", "merge time (s)",
                    f"Δ merge vs {tight:.0e} (s)" if tight else "Δ merge", "Δ merge vs reference (s)",
                    "wall_s (s)", "of which merged-config sampling (s)", "of which impulse solves (s)", "rhs",
                    "steps"], tab), ""]
    bad = [a for a in acc_rows if a["status"] != "ok"]
    if ok_rows:
        L += [f"From {ok_rows[0]['accumulation_speed']:.0e} to {tight:.0e} m/s the macro-impact resolves "
              f"{ok_rows[0]['impacts']} to {ok_rows[-1]['impacts']} impacts and the merge moves by "
              f"{abs(ok_rows[0]['t_merge'] - ok_rows[-1]['t_merge']):.1e} s; the solve time goes from "
              f"{ok_rows[0]['wall_s']:.2f} to {ok_rows[-1]['wall_s']:.2f} s (each impact costs an impulse solve and "
              "an integrator restart; the merged-configuration sampling is a fixed part)."
              + (" " + "; ".join(f"At {a['accumulation_speed']:.0e} m/s: {short_status(a['status'])}" for a in bad)
                 + " — the rebounds settle into a chatter above that speed instead of decaying (the scene file "
                 "attributes it to the driven crank's impulsive work at each impact), so the macro-impact never ends "
                 "on its own." if bad else ""), ""]
    L += ["![work-precision](work_precision.png)", ""]
    path.write_text("\n".join(L))


if __name__ == "__main__":
    main()
