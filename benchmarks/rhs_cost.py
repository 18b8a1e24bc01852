"""Cost of one right-hand-side evaluation against one raw ``pinocchio.aba`` call.

Example 1, configuration 1 (a tree: ``TreeCoordinates``, y = [q, v]):
``Mechanism(scene)["config1"].coords.rhs(t, y)`` against ``pin.aba(model, data,
q, v, tau)`` on the same model, in the same run (goal: rhs within 4x of aba).

Example 2, configuration 1 (a closed loop with a driven crank:
``PartitionedCoordinates``, y = [q_I, v_I]): the same comparison (reported, no
goal), with a breakdown of where its time goes, and the right-hand side of a
continuous-contact phase (three_bar_stop with Hunt-Crossley) for comparison.

Every figure is the median over interleaved repetitions (the repetitions are
the outer loop).  The partitioned right-hand side is stateful (its Newton solve
of the dependent coordinates is warm-started from the previous call), so it is
timed twice: at one fixed state (best case: the warm start is the solution) and
replaying the exact sequence of (t, y) at which DOP853 called it during 1 s of
a real run.

    python benchmarks/rhs_cost.py [--reps 15]

Writes docs/benchmarks/rhs_cost.md.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy.integrate import solve_ivp

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import DOCS, EXAMPLES, command_line, machine, machine_md, md_table, median, per_call  # noqa: E402

import pcmm  # noqa: E402
from pcmm.model.mechanism import Mechanism  # noqa: E402
from pcmm.events.contact_laws import ContactPhase  # noqa: E402
from pcmm.run.loop import RunOptions, initial_state  # noqa: E402


def recorded_calls(fun, t0, y0, t_end, n_max=4000):
    """The (t, y) sequence at which DOP853 (rtol 1e-10) calls ``fun``."""
    calls = []

    def logged(t, y):
        calls.append((t, y.copy()))
        return fun(t, y)
    solve_ivp(logged, (t0, t_end), y0, method="DOP853", rtol=1e-10, atol=1e-12)
    return calls[:n_max]


def replay(fun, calls):
    t0 = time.perf_counter()
    for t, y in calls:
        fun(t, y)
    return (time.perf_counter() - t0) / len(calls)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=25)
    ap.add_argument("--out", type=Path, default=DOCS)
    args = ap.parse_args(argv)
    T0 = time.perf_counter()
    info = machine()
    print(machine_md(info))

    # ---- Example 1, configuration 1 --------------------------------------------------
    s1 = pcmm.load_scene(EXAMPLES / "three_bar.toml")
    traj = pcmm.simulate(s1, RunOptions(t_end=0.15))
    seg = traj.segments[0]
    i = len(seg.t) // 2  # a state in mid-motion
    cfg1 = Mechanism(s1)["config1"]
    q1, v1 = seg.q[i].copy(), seg.v[i].copy()
    y1 = np.concatenate([q1, v1])
    tau1 = cfg1.forces.generalized(q1, v1)
    rhs1, model1, data1 = cfg1.coords.rhs, cfg1.model, cfg1.data
    assert np.allclose(rhs1(0.0, y1)[3:], pin.aba(model1, data1, q1, v1, tau1))

    def noop(t, y):
        return y
    KD = cfg1.forces.KD

    # ---- Example 2, configuration 1 ----------------------------------------------------
    s2 = pcmm.load_scene(EXAMPLES / "double_folded.toml")
    cfg2 = Mechanism(s2)["config1"]
    co2 = cfg2.coords
    q2, v2, _ = initial_state(s2, cfg2)
    y2 = co2.pack(0.0, q2, v2)
    calls2 = recorded_calls(co2.rhs, 0.0, y2, 1.0)
    tq, ty = calls2[len(calls2) // 2]
    q2m, v2m = co2.unpack(tq, ty)  # a mid-run state
    tau2 = cfg2.forces.generalized(q2m, v2m)
    model2, data2 = cfg2.model, cfg2.data
    qp2 = cfg2.to_pin(q2m)

    def rhs2_fixed():
        return co2.rhs(tq, ty)

    def unpack2():
        return co2.unpack(tq, ty)

    def acc2():
        return co2.accelerations(tq, q2m, v2m)

    def drives2():
        return co2.drives.value(tq, 2)

    coef = co2.drives.coefficients[0]
    dcoef2 = np.polynomial.polynomial.polyder(coef, 2)

    def polyval2():  # what a precompiled drive would cost: Horner on stored coefficients
        return np.polynomial.polynomial.polyval(tq, dcoef2)

    def phi2():
        return co2._phi(tq, q2m)

    def crba_chol():
        M = pin.crba(model2, data2, qp2)
        return np.linalg.cholesky(np.triu(M) + np.triu(M, 1).T)

    # ---- three_bar_stop contact phase (Hunt-Crossley) ------------------------------------
    s3 = pcmm.load_scene(EXAMPLES / "three_bar_stop.toml")
    cfg3 = Mechanism(s3)["config1"]
    tr3 = dataclasses.replace(s3.transitions[0], law="hunt_crossley", stiffness=1e9, exponent=1.5)
    phase = ContactPhase(cfg3, tr3, 1.0, 0.0, q1.copy(), v1.copy())
    f3 = phase.rhs()
    y3 = np.append(y1, 0.0)

    variants = {
        "ex1 rhs": (rhs1, (0.0, y1), 4000),
        "ex1 pin.aba": (pin.aba, (model1, data1, q1, v1, tau1), 4000),
        "python call floor (def f(t, y): return y)": (noop, (0.0, y1), 4000),
        "ex1 KD @ y (force elements)": (KD.__matmul__, (y1,), 4000),
        "ex2 rhs, fixed state": (rhs2_fixed, (), 500),
        "ex2 pin.aba (same model, nv = 4)": (pin.aba, (model2, data2, qp2, v2m, tau2), 4000),
        "ex2 unpack (Newton solve of dependent coords)": (unpack2, (), 500),
        "ex2 accelerations (constraint rows + crba + solves)": (acc2, (), 500),
        "ex2 _phi (kinematics + constraint rows)": (phi2, (), 500),
        "ex2 Drives.value(t, 2)": (drives2, (), 2000),
        "ex2 polyval on stored derivative coefficients": (polyval2, (), 4000),
        "ex2 crba + Cholesky": (crba_chol, (), 2000),
        "three_bar_stop contact-phase rhs (Hunt-Crossley)": (f3, (0.0, y3), 1000),
    }
    samples = {k: [] for k in variants}
    samples["ex2 rhs, replayed DOP853 calls"] = []
    ratio1 = []
    for _ in range(args.reps):
        for k, (fn, a, n) in variants.items():
            samples[k].append(per_call(fn, a, n))
        samples["ex2 rhs, replayed DOP853 calls"].append(replay(co2.rhs, calls2))
        ratio1.append(samples["ex1 rhs"][-1] / samples["ex1 pin.aba"][-1])
    med = {k: median(v) for k, v in samples.items()}
    r1_of_medians = med["ex1 rhs"] / med["ex1 pin.aba"]
    r1 = median(ratio1)  # headline: each ratio from two adjacent measurements, then the median
    r2f = med["ex2 rhs, fixed state"] / med["ex2 pin.aba (same model, nv = 4)"]
    r2r = med["ex2 rhs, replayed DOP853 calls"] / med["ex2 pin.aba (same model, nv = 4)"]
    rc = med["three_bar_stop contact-phase rhs (Hunt-Crossley)"] / med["ex1 rhs"]
    runtime = time.perf_counter() - T0

    rows = [[k, f"{v * 1e6:.2f}", f"{v / med['ex1 pin.aba']:.1f}" if k.startswith(("ex1", "python", "three"))
             else f"{v / med['ex2 pin.aba (same model, nv = 4)']:.1f}"] for k, v in med.items()]
    print(md_table(["call", "µs per call (median)", "× aba of its model"], rows))
    print(f"Example 1: rhs / aba = {r1:.2f} (median of per-repetition ratios; ratio of medians {r1_of_medians:.2f}; goal <= 4): "
          f"{'met' if r1 <= 4 else 'NOT met'}")
    print(f"Example 2: rhs / aba = {r2f:.1f} at a fixed state, {r2r:.1f} replaying a real run's calls "
          f"({len(calls2)} calls)")
    print(f"contact-phase rhs / lean rhs (three_bar) = {rc:.1f}")
    print(f"run time {runtime:.0f} s")

    L = ["# Cost of one right-hand-side evaluation", "",
         f"Regenerate: `{command_line()}` (run time {runtime:.0f} s).", "", machine_md(info), "",
         f"Median over {args.reps} interleaved repetitions; each sample is the mean over a few hundred to a few "
         "thousand calls. The ratio is formed within this run.", "",
         md_table(["call", "µs per call (median)", "× aba of its model"], rows), "",
         "## Results", "",
         f"* **Example 1, configuration 1** (`TreeCoordinates`, 3 revolute joints): one `coords.rhs(t, y)` costs "
         f"{med['ex1 rhs'] * 1e6:.2f} µs, one raw `pin.aba` {med['ex1 pin.aba'] * 1e6:.2f} µs: ratio **{r1:.2f}** "
         f"(median of the per-repetition ratios; ratio of the medians {r1_of_medians:.2f}); goal ≤ 4: **{'met' if r1 <= 4 else 'not met'}**. "
         f"The rest is Python: a bare Python function call costs "
         f"{med['python call floor (def f(t, y): return y)'] * 1e6:.2f} µs, the force elements' `KD @ y` "
         f"{med['ex1 KD @ y (force elements)'] * 1e6:.2f} µs.",
         f"* **Example 2, configuration 1** (`PartitionedCoordinates`: loop A-B-C-D-E cut at C, crank driven, "
         f"1 free coordinate): {med['ex2 rhs, fixed state'] * 1e6:.0f} µs at a fixed state "
         f"(**{r2f:.0f}×** aba), {med['ex2 rhs, replayed DOP853 calls'] * 1e6:.0f} µs replaying the "
         f"{len(calls2)} calls DOP853 made over 1 s of the run (**{r2r:.0f}×** aba). No goal; the breakdown: "
         f"`unpack` (Newton solve of the dependent coordinates, ≥ 1 `_phi` evaluation) "
         f"{med['ex2 unpack (Newton solve of dependent coords)'] * 1e6:.0f} µs, `accelerations` (constraint rows "
         f"with bias, CRBA, Cholesky, multipliers) {med['ex2 accelerations (constraint rows + crba + solves)'] * 1e6:.0f} µs; "
         f"one `_phi` (forward kinematics, joint Jacobians, frame placements, the cut joint's rows in Python) "
         f"{med['ex2 _phi (kinematics + constraint rows)'] * 1e6:.0f} µs; CRBA + Cholesky "
         f"{med['ex2 crba + Cholesky'] * 1e6:.0f} µs; the drive polynomial `Drives.value(t, 2)` "
         f"{med['ex2 Drives.value(t, 2)'] * 1e6:.2f} µs (numpy `polyval` on stored coefficients: "
         f"{med['ex2 polyval on stored derivative coefficients'] * 1e6:.2f} µs). One evaluation runs the "
         "kinematics at least twice (the Newton residual check in `unpack`, then `rows` with the bias "
         "accelerations) and CRBA once, so it costs tens of `aba` calls; replaying a real run costs more than the "
         "fixed state because the warm-started Newton needs extra iterations between the stages of a step.",
         f"* A continuous-contact phase (three_bar_stop, Hunt-Crossley) evaluates "
         f"{med['three_bar_stop contact-phase rhs (Hunt-Crossley)'] * 1e6:.0f} µs per call, {rc:.0f}× the lean "
         "right-hand side: each call also evaluates the contact state (forward kinematics, joint Jacobians, frame "
         "placements and the contact points' Jacobians) for the force.", ""]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "rhs_cost.md").write_text("\n".join(L))


if __name__ == "__main__":
    main()
