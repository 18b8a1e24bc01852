"""Andrews' squeezing mechanism (examples/andrews.toml) against the published reference solution.

The reference at t = 0.03 s is the IVP test set's (Mazzia, Magherini et al., Test Set for IVP
Solvers, https://archimede.uniba.it/~testset/, problem "andrews", andrews.f, subroutine solut:
PSIDE at rtol = atol = 1e-14) for the model of Hairer & Wanner, Solving ODEs II, section VII.7.
The second column of figures is the independent model of ``tests/reference_andrews.py``
(Lagrange's equations in the seven angles with multipliers, scipy DOP853 at rtol 1e-13).

For each rtol the scene is run once (the scene's own 1e-12 three times, the median wall time
reported): the relative error of every angle at t = 0.03 s, the steps, the right-hand-side
evaluations and the wall time of ``pcmm.simulate`` (model build included).

    python benchmarks/andrews.py

Writes docs/benchmarks/andrews.md, docs/figures/andrews/angles.png and
docs/figures/andrews/spring_energy.png.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import DOCS, EXAMPLES, ROOT, command_line, fmt, machine, machine_md, md_table, median  # noqa: E402

sys.path.insert(0, str(ROOT / "tests"))
import reference_andrews  # noqa: E402

import pcmm  # noqa: E402

ANGLES = ("beta", "Theta", "gamma", "Phi", "delta", "Omega", "epsilon")
SYMBOLS = (r"$\beta$", r"$\Theta$", r"$\gamma$", r"$\Phi$", r"$\delta$", r"$\Omega$", r"$\varepsilon$")
PUBLISHED = np.array([0.1581077119629904e+2, -0.1575637105984298e+2, 0.4082224013073101e-1,
                      -0.5347301163226948e+0, 0.5244099658805304e+0, 0.5347301163226948e+0,
                      0.1048080741042263e+1])
FIGURES = ROOT / "docs" / "figures" / "andrews"


def run(scene, rtol=None, atol=None):
    t0 = time.perf_counter()
    traj = pcmm.simulate(scene, pcmm.RunOptions(rtol=rtol, atol=atol))
    wall = time.perf_counter() - t0
    seg = traj.segments[-1]
    q = seg.q[-1, [seg.coordinates.index(a) for a in ANGLES]]
    return traj, q, wall


def figures(traj):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    seg = traj.segments[-1]
    t = seg.t
    col = {a: seg.coordinates.index(a) for a in ANGLES}
    FIGURES.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    for ax, group in zip(axes, (ANGLES[:2], ANGLES[2:])):
        for a in group:
            i = ANGLES.index(a)
            line, = ax.plot(t, seg.q[:, col[a]], lw=1.4, label=SYMBOLS[i])
            ax.plot([0.03], [PUBLISHED[i]], "o", mfc="none", mec="k", ms=7)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("angle (rad)")
        ax.set_xlim(0, 0.0305)
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=9)
    axes[0].set_title("(a) crank angle β and coupler angle Θ")
    axes[1].set_title("(b) γ, Φ, δ, Ω, ε")
    fig.suptitle("Andrews' squeezing mechanism, pcmm (lines) and the test set's reference at t = 0.03 s (circles)")
    fig.savefig(FIGURES / "angles.png", dpi=130)
    plt.close(fig)

    beta = seg.q[:, col["beta"]]
    work = 0.033 * (beta - beta[0])
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    axes[0].plot(t, seg.forces[:, seg.force_names.index("spring")], lw=1.4)
    axes[0].set_ylabel("f (N), > 0 pushing D and C apart")
    axes[0].set_title("(a) the point spring between C and D")
    axes[1].plot(t, seg.kinetic, lw=1.4, label="kinetic energy")
    axes[1].plot(t, seg.potential - seg.potential[0], lw=1.4, label="spring energy − its initial value")
    axes[1].plot(t, work, "--", lw=1.4, label="motor work 0.033 (β − β0)")
    axes[1].set_ylabel("energy (J)")
    axes[1].set_title("(b) energy balance")
    axes[1].legend(fontsize=9)
    for ax in axes:
        ax.set_xlabel("t (s)")
        ax.set_xlim(0, 0.0305)
        ax.grid(alpha=0.3)
    fig.savefig(FIGURES / "spring_energy.png", dpi=130)
    plt.close(fig)


def main():
    info = machine()
    start = time.perf_counter()
    scene = pcmm.load_scene(EXAMPLES / "andrews.toml")
    walls, rows_rtol = [], []
    best = None
    for _ in range(3):
        traj, q, wall = run(scene)
        walls.append(wall)
        best = (traj, q)
    traj, q = best
    t_ind = time.perf_counter()
    q_ind, _ = reference_andrews.solve()
    wall_ind = time.perf_counter() - t_ind
    rows = []
    for i, a in enumerate(ANGLES):
        rows.append([a, f"{PUBLISHED[i]:.16g}", f"{q[i]:.16g}", fmt(abs(q[i] - PUBLISHED[i]) / abs(PUBLISHED[i]), ".1e"),
                     fmt(abs(q_ind[i] - PUBLISHED[i]) / abs(PUBLISHED[i]), ".1e"),
                     fmt(abs(q[i] - q_ind[i]) / abs(q_ind[i]), ".1e")])
    for rtol in (1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-13):
        try:
            tr, qq, wall = run(scene, rtol=rtol, atol=rtol * 1e-2) if rtol != 1e-12 else (traj, q, median(walls))
        except pcmm.SimulationError as exc:
            rows_rtol.append([f"{rtol:g}", f"{rtol * 1e-2:g}", "stops: " + exc.text().split(": ", 1)[1][:150] + " …",
                              "—", "—", "—", "—"])
            print(rows_rtol[-1], flush=True)
            continue
        err = np.max(np.abs(qq - PUBLISHED) / np.abs(PUBLISHED))
        err_ind = np.max(np.abs(qq - q_ind) / np.abs(q_ind))
        rows_rtol.append([f"{rtol:g}", f"{rtol * 1e-2:g}", fmt(err, ".1e"), fmt(err_ind, ".1e"), tr.stats["steps"],
                          tr.stats["rhs_evals"], f"{wall:.2f}"])
        print(rows_rtol[-1], flush=True)
    figures(traj)
    page = [
        "# Andrews' squeezing mechanism against the published reference", "",
        f"Regenerate: `{command_line()}` (run time {time.perf_counter() - start:.0f} s).", "",
        machine_md(info), "",
        "Reference: IVP test set (Mazzia, Magherini et al., https://archimede.uniba.it/~testset/, problem "
        "`andrews`, `andrews.f`, subroutine `solut`; PSIDE at rtol = atol = 1e-14), for the model of Hairer & "
        "Wanner, *Solving ODEs II*, section VII.7. Independent model: `tests/reference_andrews.py` (Lagrange's "
        f"equations in the seven angles with multipliers, scipy DOP853 at rtol 1e-13; {wall_ind:.1f} s).", "",
        f"## The scene's settings (DOP853, rtol {scene.solver.rtol:g}, atol {scene.solver.atol:g})", "",
        f"Wall time of `pcmm.simulate` over 0.03 s (model build included), median of 3: **{median(walls):.2f} s** "
        f"(runs: {', '.join(f'{w:.2f}' for w in walls)} s); {traj.stats['steps']} steps, "
        f"{traj.stats['rhs_evals']} right-hand-side evaluations; loop closure error at most "
        f"{traj.stats['constraint_drift_max']:.1e} m.", "",
        md_table(["angle", "published, t = 0.03 s", "pcmm", "pcmm vs published", "independent vs published",
                  "pcmm vs independent"], rows), "",
        "## Accuracy against rtol (atol = rtol/100), largest relative error over the seven angles", "",
        md_table(["rtol", "atol", "vs published", "vs independent", "steps", "rhs evaluations", "wall (s)"],
                 rows_rtol), "",
    ]
    (DOCS / "andrews.md").write_text("\n".join(page))
    print("\n".join(page))


if __name__ == "__main__":
    main()
