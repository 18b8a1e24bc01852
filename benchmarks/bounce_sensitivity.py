"""How a macro-impact's event times respond to a difference of round-off size in where an event
is located: Example 4 (examples/three_bar_cycle.toml, to t = 2 s) is run twice, its events
located once by pcmm's bracketed Newton and once by scipy's brentq (both to the same 1e-14 s),
and the difference of the two runs' event times is fitted, in each burst of impacts, by a
geometric growth per bounce.  The pins' restitution is set to each value given, to test that the
growth follows the bounces (the ill-conditioning of a bounce sequence), not the locator.

    python benchmarks/bounce_sensitivity.py [E ...]      (default: 0.8 0.6)

Prints only.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

import pcmm

ROOT = Path(__file__).resolve().parents[1]
PINS = ["O3 pin", "O3 pin (O2 locked)", "O2 pin", "O2 pin (O3 locked)"]


def event_times(scene) -> list[float]:
    return [ev["t"] for ev in pcmm.simulate(scene, pcmm.RunOptions(t_end=2.0)).events]


def growth(e: float) -> tuple[int, list[float]]:
    integrators = sys.modules["pcmm.ode.integrators"]
    scene = pcmm.load_scene(ROOT / "examples" / "three_bar_cycle.toml").with_values(
        {f"transitions.{n}.restitution": e for n in PINS})
    a = event_times(scene)
    newton = integrators._bracketed_newton
    integrators._bracketed_newton = lambda g, dg, lo, hi, g_lo, g_hi, xtol, max_iter=100: brentq(
        g, lo, hi, xtol=xtol, rtol=4 * integrators.EPS)
    try:
        b = event_times(scene)
    finally:
        integrators._bracketed_newton = newton
    n = min(len(a), len(b))
    d = np.abs(np.array(a[:n]) - np.array(b[:n]))
    rates, start = [], 0
    for i in range(1, n + 1):  # bursts: events less than 0.05 s apart
        if i == n or a[i] - a[i - 1] > 0.05:
            k = np.arange(start, i)
            k = k[d[k] > 1e-12]  # above round-off
            if k.size >= 8:
                rates.append(float(np.exp(np.polyfit(k, np.log(d[k]), 1)[0])))
            start = i
    return n, rates


if __name__ == "__main__":
    for e in [float(x) for x in sys.argv[1:]] or [0.8, 0.6]:
        n, rates = growth(e)
        print(f"restitution {e}: {n} events; growth of the difference per bounce, by burst: "
              f"{', '.join(f'{r:.3f}' for r in rates)} (1/e = {1 / e:.3f})")
