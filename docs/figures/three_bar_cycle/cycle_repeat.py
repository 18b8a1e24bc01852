"""Draw docs/figures/three_bar_cycle/cycle_repeat.png: the working cycle of
examples/three_bar_cycle.toml repeats.

(a) the two metamorphic joints' angles against the crank angle, one curve per cycle (a cycle starts
    when O2's pin lets go of the folded arm), drawn over each other;
(b) how far each event of cycle k + 1 falls from the same event of cycle k one crank period (2 s)
    later, event by event (releases, every bounce of the two macro-impacts, the merges); a difference of exactly 0 is drawn
    at 1e-16.

Run: python docs/figures/three_bar_cycle/cycle_repeat.py  (writes the PNG next to this file)
"""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import pcmm  # noqa: E402

HERE = Path(__file__).resolve().parent
SCENE = HERE.parents[2] / "examples" / "three_bar_cycle.toml"
OMEGA, PERIOD = math.pi, 2.0


def main() -> None:
    traj = pcmm.simulate(pcmm.load_scene(SCENE))
    starts = [e["t"] for e in traj.events
              if e["transition"] == "release" and e["from"] == "folded" and e["name"].startswith("O2 pin")]
    dense = traj.resampled(1e-3)
    t = dense.t
    q2 = dense.series("theta", "link2") - dense.series("theta", "link1")
    q3 = dense.series("theta", "link3") - dense.series("theta", "link2")
    fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(12, 4.2))
    ax_a2 = ax_a.twinx()
    styles = ["-", "--", ":"]
    for k, (a, b) in enumerate(zip(starts, starts[1:])):
        m = (t >= a) & (t <= b)
        phase = np.degrees(OMEGA * t[m]) % 360
        phase = np.where(phase < np.degrees(OMEGA * a) % 360 - 1e-6, phase + 360, phase)
        ax_a.plot(phase, np.degrees(q2[m]), styles[k], color="#0072bd", lw=1.6, label=f"O2, cycle {k + 1}")
        ax_a2.plot(phase, np.degrees(q3[m]), styles[k], color="#d95319", lw=1.6, label=f"O3, cycle {k + 1}")
    ax_a.set_xlabel("crank angle θ1 (deg)")
    ax_a.set_ylabel("θ2 − θ1 (deg), O2's pin at 90°", color="#0072bd")
    ax_a2.set_ylabel("θ3 − θ2 (deg), O3's pin at 180°", color="#d95319")
    ax_a.set_title("(a) the joints over three cycles (drawn over each other)")
    lines = ax_a.get_legend_handles_labels()
    lines2 = ax_a2.get_legend_handles_labels()
    ax_a.legend(lines[0] + lines2[0], lines[1] + lines2[1], fontsize=8, loc="lower left", ncol=2)

    cycles = [[e for e in traj.events if a <= e["t"] < b] for a, b in zip(starts, starts[1:])]
    for k, (c0, c1) in enumerate(zip(cycles, cycles[1:])):
        d = [abs(e1["t"] - e0["t"] - PERIOD) for e0, e1 in zip(c0, c1)]
        ax_b.semilogy(range(len(d)), np.maximum(d, 1e-16), "o", ms=3, label=f"cycle {k + 2} vs {k + 1}")
    ax_b.axhline(1e-8, color="k", lw=0.8, ls="--", label="bound asserted (1e-8 s)")
    o3 = next(i for i, e in enumerate(cycles[0]) if e["transition"] == "release" and e["name"].startswith("O3"))
    ax_b.set_xlabel(f"event of the cycle\n(0: O2 release, 1-{o3 - 1}: O2's impacts and merge, {o3}: O3 release, "
                    f"{o3 + 1}-{len(cycles[0]) - 1}: O3's)", fontsize=9)
    ax_b.set_ylim(5e-17, 1e-7)
    ax_b.set_ylabel("|t(k+1) − t(k) − 2 s| (s)")
    ax_b.set_title("(b) every event one crank period after its twin")
    ax_b.legend(fontsize=8)
    fig.suptitle("examples/three_bar_cycle.toml: the working cycle repeats (folded → O2 open → folded → O3 open → folded)")
    fig.tight_layout()
    fig.savefig(HERE / "cycle_repeat.png", dpi=110)


if __name__ == "__main__":
    main()
