"""Brent's method for a guard's zero in a bracket, without scipy.optimize.

The event scanner locates a crossing of a guard that has no rate of its own on the dense output
(:func:`pcmm.ode.integrators._locate`).  It used ``scipy.optimize.brentq``; importing
scipy.optimize costs about 0.3 s of CPU at start-up (it imports scipy's array-API layer, linear
programming, scipy.sparse ...), more than a short run.  This is Brent's algorithm (R. P. Brent,
*Algorithms for Minimization without Derivatives*, 1973, ch. 4) in the variant scipy's
``brentq`` implements (inverse quadratic extrapolation, secant, bisection; a step shorter than
the tolerance is lengthened to it), with the same tests and the same floating-point operations,
so it returns the same bits for the same guard (tests/test_integrators.py compares the two).
"""
from __future__ import annotations

EPS = 2.220446049250313e-16


def brentq(f, a: float, b: float, xtol: float = 2e-12, rtol: float = 4 * EPS, maxiter: int = 100) -> float:
    """A zero of ``f`` in [a, b], where ``f(a)`` and ``f(b)`` differ in sign, to within
    ``xtol + rtol |x|``; ``ValueError`` without a sign change, ``RuntimeError`` after ``maxiter``
    iterations without convergence, ``ValueError`` at a NaN value (scipy's messages)."""
    if xtol <= 0:
        raise ValueError(f"xtol too small ({xtol:g} <= 0)")
    if rtol < 4 * EPS:
        raise ValueError(f"rtol too small ({rtol:g} < {4 * EPS:g})")

    def value(x):
        fx = float(f(x))
        if fx != fx:
            raise ValueError(f"The function value at x={x} is NaN; solver cannot continue.")
        return fx
    x_prev, x_cur = float(a), float(b)
    f_prev, f_cur = value(x_prev), value(x_cur)
    if f_prev * f_cur > 0:
        raise ValueError("f(a) and f(b) must have different signs")
    if f_prev == 0:
        return x_prev
    if f_cur == 0:
        return x_cur
    # x_cur: the best estimate; x_blk: the other end of the bracket; x_prev: the estimate before
    x_blk = f_blk = s_prev = s_cur = 0.0
    for _ in range(maxiter):
        if f_prev * f_cur < 0:  # the bracket is [x_prev, x_cur]: start the contrapoint there
            x_blk, f_blk = x_prev, f_prev
            s_prev = s_cur = x_cur - x_prev
        if abs(f_blk) < abs(f_cur):  # keep the smaller value at x_cur
            x_prev, x_cur, x_blk = x_cur, x_blk, x_cur
            f_prev, f_cur, f_blk = f_cur, f_blk, f_cur
        delta = (xtol + rtol * abs(x_cur)) / 2
        s_bis = (x_blk - x_cur) / 2
        if f_cur == 0 or abs(s_bis) < delta:
            return x_cur
        step = None
        if abs(s_prev) > delta and abs(f_cur) < abs(f_prev):
            if x_prev == x_blk:  # two points: the secant
                trial = -f_cur * (x_cur - x_prev) / (f_cur - f_prev)
            else:  # three points: inverse quadratic extrapolation
                d_prev = (f_prev - f_cur) / (x_prev - x_cur)
                d_blk = (f_blk - f_cur) / (x_blk - x_cur)
                trial = -f_cur * (f_blk * d_blk - f_prev * d_prev) / (d_blk * d_prev * (f_blk - f_prev))
            if 2 * abs(trial) < min(abs(s_prev), 3 * abs(s_bis) - delta):
                step = trial  # a good short step
        if step is None:
            s_prev = s_cur = s_bis
        else:
            s_prev, s_cur = s_cur, step
        x_prev, f_prev = x_cur, f_cur
        if abs(s_cur) > delta:
            x_cur += s_cur
        else:  # a step shorter than the tolerance: the tolerance, towards the contrapoint
            x_cur += delta if s_bis > 0 else -delta
        f_cur = value(x_cur)
    raise RuntimeError(f"Failed to converge after {maxiter} iterations, value is {x_cur}")
