"""The worked design study of docs/studies.md: O2's spring preload and stop angle of the working
cycle (examples/three_bar_cycle.toml) chosen to minimise the peak impulse, subject to O2 re-locking
between 1.5 s and 2.18 s (the first working half-cycle completes, and by then), then checked by a
fine grid around the optimum.

    python examples/studies/cycle_design.py [--tables DIR] [--grid 5] [--half 0.004 0.004]

runs (in DIR, default docs/figures/design_study/):
    pcmm optimize examples/three_bar_cycle.toml --vary "forces.spring O2.value=0.65:0.8" \\
        --vary "transitions.O2 pin (O3 locked).guard.value=1.45:1.65" --minimize peak_impulse \\
        --subject-to "last_merge_t>=1.5" --subject-to "last_merge_t<=2.18" --t-end 2.22 \\
        --max-evals 30 --tol 1e-3 --out cycle_opt.csv
    pcmm sweep examples/three_bar_cycle.toml --set "forces.spring O2.value=A:B:N" \\
        --set "transitions.O2 pin (O3 locked).guard.value=C:D:N" --t-end 2.22 --out cycle_grid.csv
(each skipped when its table is there: ``--resume`` completes it) and draws cycle_opt.png.
"""
from __future__ import annotations

import argparse
import csv
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "examples" / "three_bar_cycle.toml"
P, A = "forces.spring O2.value", "transitions.O2 pin (O3 locked).guard.value"
LOW, HIGH = 1.5, 2.18
T_END = "2.22"


def pcmm(*args):
    subprocess.run([sys.executable, "-m", "pcmm.cli", *args], check=True)


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def feasible(r):
    try:
        t = float(r["last_merge_t"])
    except ValueError:
        return False
    return r["status"] == "complete" and LOW <= t <= HIGH


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tables", type=Path, default=ROOT / "docs" / "figures" / "design_study")
    ap.add_argument("--grid", type=int, default=5)
    ap.add_argument("--half", type=float, nargs=2, default=(0.004, 0.004),
                    help="the grid's half-widths in preload (N m) and angle (rad)")
    args = ap.parse_args()
    d = args.tables
    opt, grid = d / "cycle_opt.csv", d / "cycle_grid.csv"
    pcmm("optimize", str(SCENE), "--vary", f"{P}=0.65:0.8", "--vary", f"{A}=1.45:1.65", "--minimize",
         "peak_impulse", "--subject-to", f"last_merge_t>={LOW}", "--subject-to", f"last_merge_t<={HIGH}",
         "--t-end", T_END, "--max-evals", "30", "--tol", "1e-3", "--out", str(opt),
         *(["--resume"] if opt.exists() else []))
    best = min((r for r in rows(opt) if feasible(r)), key=lambda r: float(r["peak_impulse"]))
    p0, a0 = float(best[P]), float(best[A])
    hp, ha = args.half
    n = args.grid
    pcmm("sweep", str(SCENE), "--set", f"{P}={p0 - hp!r}:{p0 + hp!r}:{n}", "--set", f"{A}={a0 - ha!r}:{a0 + ha!r}:{n}",
         "--t-end", T_END, "--out", str(grid), "--quiet", *(["--resume"] if grid.exists() else []))
    g = rows(grid)
    ok = [r for r in g if feasible(r)]
    gbest = min(ok, key=lambda r: float(r["peak_impulse"])) if ok else None
    print(f"optimum (run {best['run']}): {P} = {p0!r}, {A} = {a0!r}: peak_impulse = {best['peak_impulse']}, "
          f"last_merge_t = {best['last_merge_t']}")
    if gbest is not None:
        print(f"grid's best feasible of {len(g)} ({len(ok)} feasible): {P} = {gbest[P]}, {A} = {gbest[A]}: "
              f"peak_impulse = {gbest['peak_impulse']}, last_merge_t = {gbest['last_merge_t']}")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    ax = axes[0]
    o = rows(opt)
    for r in o:
        ax.plot(float(r[P]), float(r[A]), "o" if feasible(r) else "x", color="C0" if feasible(r) else "C3", ms=4)
    ax.plot([float(r[P]) for r in o], [float(r[A]) for r in o], "-", color="0.7", lw=0.6, zorder=0)
    ax.plot(p0, a0, "*", color="k", ms=12)
    ax.add_patch(plt.Rectangle((p0 - hp, a0 - ha), 2 * hp, 2 * ha, fill=False, ls="--"))
    ax.set_xlabel("O2 spring preload (forces.spring O2.value), N m")
    ax.set_ylabel("O2 stop angle, rad")
    ax.set_title("COBYQA's runs (o meets the re-lock window, x does not)", fontsize=9)
    ax = axes[1]
    for r in g:
        x, y = float(r[P]), float(r[A])
        if feasible(r):
            sc = ax.scatter(x, y, c=float(r["peak_impulse"]), cmap="viridis", s=60,
                            vmin=min(float(q["peak_impulse"]) for q in ok), vmax=max(float(q["peak_impulse"]) for q in ok))
        else:
            ax.plot(x, y, "x", color="C3")
    if ok:
        fig.colorbar(sc, ax=ax, label="peak impulse, N s")
    ax.plot(p0, a0, "*", color="k", ms=12)
    ax.set_xlabel("O2 spring preload, N m")
    ax.set_title(f"the {n} x {n} grid around the optimum (x: outside the window)", fontsize=9)
    fig.tight_layout()
    fig.savefig(d / "cycle_opt.png", dpi=110)
    print(f"wrote {d / 'cycle_opt.png'}")


if __name__ == "__main__":
    main()
