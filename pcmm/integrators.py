"""Integrators: a registry of methods sharing one contract.

Contract: ``method.integrate(fun, t0, y0, t_bound, events, opts)`` integrates
``y' = fun(t, y)`` from ``t0`` until ``t_bound`` or the first terminal event
and returns a :class:`Segment`.  ``events`` are functions with ``terminal``
and ``direction`` attributes (scipy's convention).  An event is located on the
method's dense output, so event accuracy is the interpolant's (DOP853: 7th
order; RK45: 4th; fixed-step RK4: cubic Hermite).  ``opts`` has ``rtol``,
``atol``, ``max_step`` and, for fixed-step methods, ``step``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq


@dataclass
class Segment:
    t: np.ndarray  # (n,)
    y: np.ndarray  # (ny, n)
    event: int | None  # index into events of the event that ended it
    nfev: int
    nsteps: int
    status: int  # 0 reached t_bound, 1 event, -1 failure
    message: str


class ScipyMethod:
    """One of scipy's ``solve_ivp`` methods."""

    fixed_step = False

    def __init__(self, name: str):
        self.name = name

    def integrate(self, fun, t0, y0, t_bound, events, opts) -> Segment:
        sol = solve_ivp(fun, (t0, t_bound), y0, method=self.name, rtol=opts.rtol, atol=opts.atol,
                        max_step=opts.max_step, events=events or None)
        event = None
        if sol.status == 1:
            fired = [i for i, te in enumerate(sol.t_events) if len(te)]
            event = min(fired, key=lambda i: sol.t_events[i][-1])
        return Segment(sol.t, sol.y, event, sol.nfev, max(len(sol.t) - 1, 0), sol.status, sol.message)


class FixedStepRK4:
    """Classical Runge-Kutta with a fixed step (the paper's MATLAB route).

    Events are located by Brent's method on the cubic Hermite interpolant of
    the step in which the guard changes sign in its direction.
    """

    fixed_step = True
    name = "RK4"

    def integrate(self, fun, t0, y0, t_bound, events, opts) -> Segment:
        h = opts.step
        ts, ys = [t0], [np.asarray(y0, float)]
        t, y = t0, np.asarray(y0, float)
        f = fun(t, y)
        nfev = 1
        g_prev = [e(t, y) for e in events]
        while t < t_bound - 1e-15 * max(1.0, abs(t_bound)):
            hh = min(h, t_bound - t)
            k1 = f
            k2 = fun(t + hh / 2, y + hh / 2 * k1)
            k3 = fun(t + hh / 2, y + hh / 2 * k2)
            k4 = fun(t + hh, y + hh * k3)
            y_new = y + hh / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            t_new = t + hh
            f_new = fun(t_new, y_new)
            nfev += 4
            hit = None
            for i, e in enumerate(events):
                g_new = e(t_new, y_new)
                up = g_prev[i] < 0 <= g_new
                down = g_prev[i] > 0 >= g_new
                if (e.direction >= 0 and up) or (e.direction <= 0 and down):
                    dense = _hermite(t, y, f, t_new, y_new, f_new)
                    te = brentq(lambda s: e(s, dense(s)), t, t_new, xtol=1e-14, rtol=4 * np.finfo(float).eps)
                    if hit is None or te < hit[0]:
                        hit = (te, i, dense(te))
                g_prev[i] = g_new
            if hit is not None:
                ts.append(hit[0])
                ys.append(hit[2])
                return Segment(np.array(ts), np.array(ys).T, hit[1], nfev, len(ts) - 1, 1, "event")
            t, y, f = t_new, y_new, f_new
            ts.append(t)
            ys.append(y)
        return Segment(np.array(ts), np.array(ys).T, None, nfev, len(ts) - 1, 0, "reached t_end")


def _hermite(t0, y0, f0, t1, y1, f1):
    h = t1 - t0

    def y(s):
        x = (s - t0) / h
        h00, h10 = 2 * x**3 - 3 * x**2 + 1, x**3 - 2 * x**2 + x
        h01, h11 = -2 * x**3 + 3 * x**2, x**3 - x**2
        return h00 * y0 + h10 * h * f0 + h01 * y1 + h11 * h * f1
    return y


INTEGRATORS = {name: ScipyMethod(name) for name in ("RK45", "DOP853", "Radau", "LSODA", "BDF", "RK23")}
INTEGRATORS["RK4"] = FixedStepRK4()
