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
from scipy.integrate import ode, solve_ivp
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


class FortranDOP853:
    """Hairer's DOP853 in Fortran (scipy.integrate.ode) for the stepping.

    The Fortran code calls the right-hand side with almost no overhead per
    evaluation (scipy's pure-Python ``solve_ivp`` adds several microseconds
    per call, more than a lean right-hand side costs).  Guards are checked
    after every accepted step; the step in which one changes sign in its
    direction is integrated again by ``solve_ivp``'s DOP853 and the event is
    located on that 7th-order dense output, so the event accuracy is that of
    ``DOP853``.
    """

    fixed_step = False
    name = "DOP853F"

    def integrate(self, fun, t0, y0, t_bound, events, opts) -> Segment:
        nfev = [0]

        def f(t, y):
            nfev[0] += 1
            return fun(t, y)
        ts, ys = [t0], [np.array(y0, float)]
        g_prev = [e(t0, ys[0]) for e in events]
        hit = []

        def solout(t, y):
            if t == ts[-1]:
                return 0
            g_new = [e(t, y) for e in events]
            fired = [i for i, e in enumerate(events) if _crossed(g_prev[i], g_new[i], e.direction)]
            if fired:
                hit.append((t, y.copy()))
                return -1
            g_prev[:] = g_new
            ts.append(t)
            ys.append(y.copy())
            return 0
        solver = ode(f).set_integrator("dop853", rtol=opts.rtol, atol=opts.atol, nsteps=10**9,
                                       max_step=opts.max_step if np.isfinite(opts.max_step) else 0.0)
        solver.set_solout(solout)
        solver.set_initial_value(np.array(y0, float), t0)
        solver.integrate(t_bound)
        if not hit:
            if not solver.successful():
                return Segment(np.array(ts), np.array(ys).T, None, nfev[0], len(ts) - 1, -1,
                               f"DOP853 (Fortran) failed with code {solver.get_return_code()}")
            if ts[-1] < t_bound:
                ts.append(t_bound)
                ys.append(np.array(solver.y, float))
            return Segment(np.array(ts), np.array(ys).T, None, nfev[0], len(ts) - 1, 0, "reached t_end")
        # locate the event inside the last step on DOP853's dense output
        t_a, y_a = ts[-1], ys[-1]
        t_b = hit[0][0]
        sol = solve_ivp(f, (t_a, t_b), y_a, method="DOP853", rtol=opts.rtol, atol=opts.atol,
                        first_step=t_b - t_a, dense_output=True)
        best = None
        for i, e in enumerate(events):
            g_a, g_b = e(t_a, y_a), e(t_b, sol.sol(t_b))
            if not _crossed(g_a, g_b, e.direction):
                continue
            te = brentq(lambda s: e(s, sol.sol(s)), t_a, t_b, xtol=4 * np.finfo(float).eps * max(1.0, abs(t_b)),
                        rtol=4 * np.finfo(float).eps)
            if best is None or te < best[0]:
                best = (te, i)
        if best is None:  # the re-integration ends just short of the crossing: take the step's end
            best = (t_b, next(i for i, e in enumerate(events) if _crossed(g_prev[i], e(t_b, hit[0][1]), e.direction)))
            ye = hit[0][1]
        else:
            ye = sol.sol(best[0])
        ts.append(best[0])
        ys.append(np.asarray(ye, float))
        return Segment(np.array(ts), np.array(ys).T, best[1], nfev[0], len(ts) - 1, 1, "event")


def _crossed(g_old, g_new, direction) -> bool:
    """scipy's rule: a sign change (zero counts) in the event's direction."""
    up = g_old <= 0 <= g_new and g_old != g_new
    down = g_old >= 0 >= g_new and g_old != g_new
    return (direction >= 0 and up) or (direction <= 0 and down)


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
INTEGRATORS["DOP853F"] = FortranDOP853()
INTEGRATORS["RK4"] = FixedStepRK4()
