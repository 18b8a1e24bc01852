"""The modelling trade: the impulse law against continuous contact-force laws.

On two scenes, the first stop impact is resolved by Newton's impulse law (the
scene as written) and by each continuous law of pcmm (``law`` =
"hunt_crossley" | "lankarani_nikravesh" | "flores", ``exponent`` = 1.5) over a
sweep of stiffness, by modified TOML copies written to a temporary folder:

* ``examples/three_bar_stop.toml``: a mobile impact (link 3 folds onto link 2,
  e = 0.8), first impact at t ~ 0.167 s; stiffness 1e4 .. 1e13 N/m^1.5.
* Example 2 (``examples/double_folded.toml``): the slider strikes its stop
  (stable impact, e = 0.8) at t ~ 3.004 s; stiffness 1e6 .. 1e13 N/m^1.5 (below
  1e6 the contact outlasts the 58 ms to the next impact).  To keep the sweep
  cheap the copy starts at a recorded state ~10 ms before the impact (the crank
  drive's polynomial shifted in time accordingly); the impulse solution of the
  shifted copy matches the full run's to round-off (printed).

For every run: the post-contact state (absolute angular velocities of the
links and, in Example 2, the slider velocity, at separation) against the
impulse solution (max |difference|), the contact duration, the effective
restitution of the law (-v_n after / v_n before at the contact point), and the
solve time ``wall_s`` of the window (t_end just past the longest contact; same
window for the impulse run), plus the contact phase's own solve time.  Each
law has its own effective restitution, so as the stiffness grows its
post-contact state tends to Newton's impulse *with that restitution*; the
script also runs the impulse law at each law's limiting restitution to
separate that bias from the finite-stiffness error.

    python benchmarks/contact_laws.py [--reps 5]

Writes docs/benchmarks/contact_laws.{csv,md,png}.
"""
from __future__ import annotations

import argparse
import csv
import math
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (DOCS, EXAMPLES, command_line, fmt, loglog_slope, machine, machine_md, md_table,  # noqa: E402
                     median, scene_copy, timed_segments)

import pcmm  # noqa: E402
from pcmm import RunOptions  # noqa: E402

LAWS = ("hunt_crossley", "lankarani_nikravesh", "flores")
LAW_NAMES = {"hunt_crossley": "Hunt-Crossley", "lankarani_nikravesh": "Lankarani-Nikravesh", "flores": "Flores"}
E = 0.8


def law_edit(law, k, restitution=E):
    def edit(text):
        text = text.replace(f"restitution = {E}", f"restitution = {restitution!r}", 1)
        if law != "impulse":
            text = text.replace(f"restitution = {restitution!r}",
                                f'restitution = {restitution!r}\nlaw = "{law}"\nstiffness = {k!r}\nexponent = 1.5', 1)
        return text
    return edit


def shifted_start(names, q, v, ts):
    """Edit Example 2 to start at the recorded state (q, v) of time ts (drive shifted by ts)."""
    def edit(text):
        qs = ", ".join(f"{n} = {float(x)!r}" for n, x in zip(names, q))
        vs = ", ".join(f"{n} = {float(x)!r}" for n, x in zip(names, v))
        text = re.sub(r"^q = \{.*\}$", "q = { " + qs + " }", text, count=1, flags=re.M)
        text = re.sub(r"^v = \{.*\}$", "v = { " + vs + " }", text, count=1, flags=re.M)
        c0 = math.pi + math.pi / 5 * ts  # Eq. 48: theta1 = pi + (pi/5) t
        return re.sub(r"^coefficients = \[.*\]$", f"coefficients = [{c0!r}, {math.pi / 5!r}]", text, count=1,
                      flags=re.M)
    return edit


def post_state(ev, links, sliders):
    return np.array([ev["omega_after"][k] for k in links] + [ev["v_after"][j] for j in sliders])


def run(path, t_end, links, sliders):
    log = []
    try:
        with timed_segments(log):
            traj = pcmm.simulate(pcmm.load_scene(path), RunOptions(t_end=t_end))
    except Exception as exc:
        return {"ok": False, "status": f"failed: {type(exc).__name__}: {str(exc).splitlines()[0][:120]}"}
    evs = [e for e in traj.events if e.get("impact")]
    if not evs:
        return {"ok": False, "status": "no impact in the window"}
    ev = evs[0]
    if ev.get("law") and ev.get("t_end", math.inf) > t_end - 1e-12:
        return {"ok": False, "status": "contact did not end in the window"}
    contact = [x for x in log if abs(x.t0 - ev["t"]) < 1e-12] if ev.get("law") else []
    nv = ev["normal_velocity"]
    return {"ok": True, "status": "ok", "wall_s": traj.stats["wall_s"], "rhs_evals": traj.stats["rhs_evals"],
            "post": post_state(ev, links, sliders), "t_contact": ev["t"], "duration": ev.get("duration", 0.0),
            "e_eff": -nv["after"] / nv["before"], "v_impact": -nv["before"],
            "contact_s": contact[0].seconds if contact else 0.0, "contact_rhs": contact[0].nfev if contact else 0}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--out", type=Path, default=DOCS)
    args = ap.parse_args(argv)
    T0 = time.perf_counter()
    info = machine()
    print(machine_md(info))
    tmp = Path(tempfile.mkdtemp(prefix="pcmm_contact_laws_"))

    # ---- the two scenes (files in tmp) -------------------------------------------------
    ex2 = EXAMPLES / "double_folded.toml"
    full = pcmm.simulate(pcmm.load_scene(ex2), RunOptions(t_end=3.01))
    seg = full.segments[0]
    t_imp = full.events[0]["t"]
    i = int(np.searchsorted(seg.t, t_imp - 0.002)) - 1
    ts = float(seg.t[i])
    shift = shifted_start(seg.coordinates, seg.q[i], seg.v[i], ts)
    cases = {
        "three_bar_stop": dict(src=EXAMPLES / "three_bar_stop.toml", pre=None, links=("link1", "link2", "link3"),
                               sliders=(), ks=[10.0 ** p for p in range(4, 14)], probe=0.3,
                               title="three_bar_stop (mobile impact, link 3 on link 2)"),
        "example2": dict(src=ex2, pre=shift, links=("link2", "link3"), sliders=("E",),
                         ks=[10.0 ** p for p in range(6, 14)], probe=0.05,
                         title=f"Example 2 (stable impact, slider on its stop; started at t = {ts:.4f} s)"),
    }

    def write(case, name, law, k, restitution=E):
        c = cases[case]
        base = law_edit(law, k, restitution)
        edit = (lambda text: base(c["pre"](text))) if c["pre"] else base
        return scene_copy(c["src"], tmp, f"{case}_{name}.toml", edit)

    # shifted Example 2 against the full run (impulse law)
    chk = run(write("example2", "impulse_check", "impulse", None), 0.02, cases["example2"]["links"], ("E",))
    full_post = post_state(full.events[0], cases["example2"]["links"], ("E",))
    shift_err = (abs(chk["t_contact"] + ts - t_imp), float(np.max(np.abs(chk["post"] - full_post))))
    print(f"Example 2 started at t = {ts:.6f} s: impulse solution vs the full run: |dt| = {shift_err[0]:.1e} s, "
          f"max |d post| = {shift_err[1]:.1e}")

    # windows: just past the longest contact (the softest one), same window for every run of a case
    windows = {}
    for case, c in cases.items():
        imp = run(write(case, "impulse_probe", "impulse", None), c["probe"], c["links"], c["sliders"])
        longest = 0.0
        for law in LAWS:
            r = run(write(case, f"{law}_probe", law, c["ks"][0]), c["probe"], c["links"], c["sliders"])
            if not r["ok"]:
                raise SystemExit(f"{case}: {law} at k = {c['ks'][0]:g}: {r['status']}; raise the lowest stiffness")
            longest = max(longest, r["t_contact"] + r["duration"])
        windows[case] = longest + 0.1 * (longest - imp["t_contact"]) + 1e-3
        print(f"{case}: impulse contact at t = {imp['t_contact']:.6f} s; window t_end = {windows[case]:.4f} s")

    # ---- the sweep: repetitions outer ------------------------------------------------------
    plan = [(case, "impulse", None) for case in cases]
    plan += [(case, law, k) for case, c in cases.items() for law in LAWS for k in c["ks"]]
    files = {p: write(p[0], f"{p[1]}_{p[2]:g}" if p[2] else "impulse", p[1], p[2]) for p in plan}
    first, walls, cwalls = {}, {p: [] for p in plan}, {p: [] for p in plan}
    for rep in range(args.reps):
        for p in plan:
            c = cases[p[0]]
            r = run(files[p], windows[p[0]], c["links"], c["sliders"])
            first.setdefault(p, r)
            if r["ok"]:
                walls[p].append(r["wall_s"])
                cwalls[p].append(r["contact_s"])

    # Newton's impulse at each law's limiting restitution (the stiffest run's effective e)
    e_lim, newton_at = {}, {}
    for case, c in cases.items():
        for law in LAWS:
            stiff = [first[(case, law, k)] for k in c["ks"] if first[(case, law, k)]["ok"]][-1]  # stiffest that ran
            e_lim[(case, law)] = stiff["e_eff"]
            r = run(write(case, f"impulse_e_{law}", "impulse", None, round(stiff["e_eff"], 12)), windows[case],
                    c["links"], c["sliders"])
            newton_at[(case, law)] = r["post"]

    rows = []
    for p in plan:
        case, law, k = p
        r, ref = first[p], first[(case, "impulse", None)]
        row = {"case": case, "law": law, "stiffness": k, "status": r["status"], "reps": len(walls[p]),
               "wall_s": median(walls[p]), "contact_s": median(cwalls[p]), "rhs_evals": r.get("rhs_evals"),
               "contact_rhs": r.get("contact_rhs"), "duration_s": r.get("duration"), "e_eff": r.get("e_eff"),
               "err_vs_impulse": math.nan, "err_vs_impulse_at_law_e": math.nan, "restitution_bias": math.nan}
        if r["ok"]:
            row["err_vs_impulse"] = float(np.max(np.abs(r["post"] - ref["post"])))
            if law != "impulse":
                row["err_vs_impulse_at_law_e"] = float(np.max(np.abs(r["post"] - newton_at[(case, law)])))
                row["restitution_bias"] = float(np.max(np.abs(newton_at[(case, law)] - ref["post"])))
        rows.append(row)
        print(f"{case:15s} {law:20s} k {k if k else 0:8.0e}  {r['status']:4s} wall {row['wall_s']:.4f} s "
              f"(contact {row['contact_s']:.4f} s, {row['contact_rhs']} rhs) duration {fmt(row['duration_s'], '.2e')} s "
              f"e_eff {fmt(row['e_eff'], '.4f')} err {fmt(row['err_vs_impulse'], '.2e')} "
              f"err(e_eff) {fmt(row['err_vs_impulse_at_law_e'], '.2e')}", flush=True)

    runtime = time.perf_counter() - T0
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "contact_laws.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    plot(args.out / "contact_laws.png", rows, cases)
    write_md(args.out / "contact_laws.md", rows, cases, windows, e_lim, shift_err, ts, args, info, runtime)
    print(f"wrote {args.out / 'contact_laws.md'}, .csv, .png; run time {runtime:.0f} s")


def plot(path, rows, cases):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(3, 2, figsize=(12, 11))
    col = {"hunt_crossley": "C0", "lankarani_nikravesh": "C1", "flores": "C2"}
    for j, case in enumerate(cases):
        imp = next(r for r in rows if r["case"] == case and r["law"] == "impulse")
        for law in LAWS:
            sel = [r for r in rows if r["case"] == case and r["law"] == law and r["status"] == "ok"]
            k = [r["stiffness"] for r in sel]
            axes[0, j].loglog(k, [r["err_vs_impulse"] for r in sel], "o-", color=col[law],
                              label=f"{LAW_NAMES[law]} vs Newton e = {E}")
            axes[0, j].loglog(k, [max(r["err_vs_impulse_at_law_e"], 1e-16) for r in sel], "s--", color=col[law],
                              ms=4, label=f"{LAW_NAMES[law]} vs Newton at its own e_eff")
            axes[0, j].axhline(sel[-1]["restitution_bias"], color=col[law], ls=":", lw=1)
            axes[1, j].loglog(k, [r["wall_s"] for r in sel], "o-", color=col[law], label=f"{LAW_NAMES[law]}: run")
            axes[1, j].loglog(k, [r["contact_s"] for r in sel], "^:", color=col[law], ms=4,
                              label=f"{LAW_NAMES[law]}: contact phase")
            axes[2, j].loglog(k, [r["duration_s"] for r in sel], "o-", color=col[law], label=LAW_NAMES[law])
        axes[1, j].axhline(imp["wall_s"], color="k", ls="--", label="impulse law: run")
        kk = np.array(cases[case]["ks"], float)
        d0 = [r for r in rows if r["case"] == case and r["law"] == "hunt_crossley" and r["status"] == "ok"][-1]
        axes[2, j].loglog(kk, d0["duration_s"] * (kk / d0["stiffness"]) ** -0.4, "k:", label="∝ k^-2/5 (Hertz)")
        axes[0, j].set_title(f"{cases[case]['title']}\npost-contact velocity error (dotted: restitution bias)",
                             fontsize=9)
        axes[1, j].set_title("solve time of the window (wall_s, median)", fontsize=9)
        axes[2, j].set_title("contact duration (s)", fontsize=9)
        for i in range(3):
            axes[i, j].set_xlabel("stiffness k (N/m^1.5)")
            axes[i, j].grid(True, which="both", alpha=0.3)
        axes[0, j].set_ylabel("max |Δ| (rad/s, m/s)")
        axes[1, j].set_ylabel("s")
    axes[0, 0].legend(fontsize=7)
    axes[1, 0].legend(fontsize=7)
    axes[2, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_md(path, rows, cases, windows, e_lim, shift_err, ts, args, info, runtime):
    L = ["# Continuous contact laws against the impulse law", "",
         f"Regenerate: `{command_line()}` (run time {runtime:.0f} s).", "", machine_md(info), "",
         "Each stop's impulse law (Newton, e = 0.8) is replaced by a continuous law "
         "`F = k δ^1.5 (1 + D(e) δ'/v⁻)` (modified TOML copies in a temporary folder: `law`, `stiffness`, "
         "`exponent = 1.5`); DOP853 at the scenes' rtol 1e-10, atol 1e-12. Errors: max |difference| of the "
         "post-contact absolute angular velocities of the links (rad/s) and, in Example 2, of the slider velocity "
         "(m/s), at separation, against the impulse solution. `wall_s`: solve time of the whole window (median of "
         f"{args.reps} interleaved repetitions); `contact`: the contact phase's own integration time.", "",
         f"* three_bar_stop: window t = 0 .. {windows['three_bar_stop']:.4f} s (first contact at t ≈ 0.1673 s).",
         f"* Example 2: the copy starts at the recorded state of t = {ts:.6f} s (≈ 10 ms before the first impact; the "
         f"crank's drive polynomial shifted by that time); window {windows['example2']:.4f} s after that start. Its "
         f"impulse solution matches the full run's to {shift_err[1]:.1e} (post-impact velocities) and "
         f"{shift_err[0]:.1e} s (impact time).", ""]
    for case, c in cases.items():
        L += [f"## {c['title']}", ""]
        tab = []
        for r in rows:
            if r["case"] != case:
                continue
            tab.append([LAW_NAMES.get(r["law"], "impulse (Newton)"), fmt(r["stiffness"], ".0e") if r["stiffness"] else "—",
                        r["status"], fmt(r["duration_s"], ".2e") if r["law"] != "impulse" else "0",
                        fmt(r["e_eff"], ".4f"), fmt(r["err_vs_impulse"], ".2e") if r["law"] != "impulse" else "0",
                        fmt(r["err_vs_impulse_at_law_e"], ".2e"), fmt(r["wall_s"], ".4f"), fmt(r["contact_s"], ".4f"),
                        r["rhs_evals"] if r["rhs_evals"] is not None else "",
                        r["contact_rhs"] if r["law"] != "impulse" and r["contact_rhs"] is not None else ""])
        L += [md_table(["law", "k (N/m^1.5)", "status", "contact duration (s)", "effective e",
                        "post-contact error vs Newton e = 0.8", "error vs Newton at the law's limiting e",
                        "wall_s (s)", "contact phase (s)", "rhs (run)", "rhs (contact)"], tab), ""]
    L += ["## Effective restitution", "",
          "Each law derives its hysteresis damping D(e) from the restitution coefficient with its own "
          "approximation, so the coefficient it actually produces differs from the e = 0.8 it was given. Measured at "
          "the stiffest run that completed, as −v_n after / v_n before at the contact point:", ""]
    tab = []
    for law in LAWS:
        cells = [LAW_NAMES[law]]
        for case in cases:
            sel = [r for r in rows if r["case"] == case and r["law"] == law and r["status"] == "ok"]
            cells += [f"{e_lim[(case, law)]:.4f} ({(e_lim[(case, law)] - E) / E * 100:+.1f} %)",
                      f"{sel[-1]['restitution_bias']:.2e}", f"{sel[-1]['err_vs_impulse_at_law_e']:.2e}"]
        tab.append(cells)
    hdr = ["law"]
    for case in cases:
        hdr += [f"{case}: effective e", f"{case}: Newton(e_eff) vs Newton(0.8), max abs diff",
                f"{case}: stiffest run vs Newton(e_eff)"]
    L += [md_table(hdr, tab), ""]
    L += ["## Convergence and cost (computed from the tables)", ""]
    for case in cases:
        imp = next(r for r in rows if r["case"] == case and r["law"] == "impulse")
        for law in LAWS:
            sel = [r for r in rows if r["case"] == case and r["law"] == law and r["status"] == "ok"]
            # the limiting e is the stiffest run's own, so that run is left out of the fit
            hi = [r for r in sel[:-1] if r["stiffness"] >= 1e8 and r["err_vs_impulse_at_law_e"] > 0]
            slope = loglog_slope([r["stiffness"] for r in hi], [r["err_vs_impulse_at_law_e"] for r in hi]) \
                if len(hi) >= 3 else math.nan
            dslope = loglog_slope([r["stiffness"] for r in sel], [r["duration_s"] for r in sel])
            failed = [f"{r['stiffness']:.0e} ({r['status']})" for r in rows
                      if r["case"] == case and r["law"] == law and r["status"] != "ok"]
            L.append(f"* {case}, {LAW_NAMES[law]}: error against Newton at the law's own restitution falls as "
                     f"k^{slope:.2f} for 1e8 ≤ k < {sel[-1]['stiffness']:.0e} (contact duration ∝ k^{dslope:.2f}); the solve time of the window is "
                     f"{median([r['wall_s'] for r in sel]):.4f} s (median over k; range "
                     f"{min(r['wall_s'] for r in sel):.4f}–{max(r['wall_s'] for r in sel):.4f} s) against "
                     f"{imp['wall_s']:.4f} s with the impulse law, i.e. "
                     f"{median([r['wall_s'] for r in sel]) / imp['wall_s']:.1f}×; the contact phase takes "
                     f"{min(r['contact_rhs'] for r in sel)}–{max(r['contact_rhs'] for r in sel)} right-hand-side "
                     "evaluations whatever k" + (f"; failed: {', '.join(failed)}" if failed else "") + ".")
    L += [""]
    L += ["Reading: as k grows the contact shortens as k^-2/5 (Hertz) and each law's post-contact state converges, "
          "not to the Newton impulse with e = 0.8, but to the Newton impulse with the law's own effective "
          "restitution (the dashed curves fall, the solid ones level off at the dotted restitution bias; the last dashed point "
          "is biased low because the limiting restitution is measured on that very run). "
          "Hunt-Crossley (D = 3(1−e)/2, derived for e → 1) and Lankarani-Nikravesh (D = 3(1−e²)/4, also for e near 1) "
          "overshoot e = 0.8; Flores (D = 8(1−e)/(5e), meant for any e) comes closest. To reproduce an impulse "
          "solution with a continuous law, give the law the restitution that maps to the wanted effective one. "
          "With DOP853 the number of right-hand-side evaluations of a contact phase hardly depends on k (a single "
          "pulse is resolved in a roughly constant number of steps), so the continuous laws cost about the same at "
          "every stiffness; their extra cost over the impulse law is the contact phase's steps and its "
          "right-hand side (see rhs_cost.md).", "",
          "![contact laws](contact_laws.png)", ""]
    path.write_text("\n".join(L))


if __name__ == "__main__":
    main()
