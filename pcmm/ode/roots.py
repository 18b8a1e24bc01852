"""Brent's methods for a guard's zero in a bracket and for its extremum in an interval, without
scipy.optimize.

The event scanner locates a crossing of a guard that has no rate of its own on the dense output
(:func:`pcmm.ode.integrators._locate`).  It used ``scipy.optimize.brentq``; importing
scipy.optimize costs about 0.3 s of CPU at start-up (it imports scipy's array-API layer, linear
programming, scipy.sparse ...), more than a short run.  This is Brent's algorithm (R. P. Brent,
*Algorithms for Minimization without Derivatives*, 1973, ch. 4) in the variant scipy's
``brentq`` implements (inverse quadratic extrapolation, secant, bisection; a step shorter than
the tolerance is lengthened to it), with the same tests and the same floating-point operations,
so it returns the same bits for the same guard (tests/test_startup.py compares the two).
:func:`minimize_bounded` is the same for ``minimize_scalar(method="bounded")``.
"""
from __future__ import annotations

import math

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


def _maximum(a: float, b: float) -> float:
    """``numpy.maximum`` of two floats (a NaN wins)."""
    return a if (a != a or a >= b) else b


def _sign_or_one(x: float) -> float:
    """The sign of ``x``, 1 at zero (``np.sign(x) + (x == 0)``)."""
    return 1.0 if x >= 0 else -1.0 if x < 0 else x


def minimize_bounded(f, lo: float, hi: float, xatol: float = 1e-5, maxiter: int = 500) -> float:
    """The minimiser of ``f`` on [lo, hi] to ``xatol``: Brent's golden-section search with
    parabolic steps (Brent 1973, ch. 5; Forsythe, Malcolm and Moler's ``fminbound``), in the
    variant of ``scipy.optimize.minimize_scalar(method="bounded")``, with the same floating-point
    operations (its ``x``, bit for bit: tests/test_startup.py).  Used where a guard's graze is
    searched between two samples and for a guard's closest approach: importing scipy.optimize
    would cost 0.3 s of start-up."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError("Optimization bounds must be finite scalars.")
    if lo > hi:
        raise ValueError("The lower bound exceeds the upper bound.")
    sqrt_eps = math.sqrt(2.2e-16)
    golden_mean = 0.5 * (3.0 - math.sqrt(5.0))
    a, b = lo, hi
    # xf: the best point so far; nfc: the second best; fulc: the previous value of nfc
    fulc = a + golden_mean * (b - a)
    nfc = xf = fulc
    rat = e = 0.0
    x = xf
    fx = f(x)
    calls = 1
    ffulc = fnfc = fx
    xm = 0.5 * (a + b)
    tol1 = sqrt_eps * abs(xf) + xatol / 3.0
    tol2 = 2.0 * tol1
    while abs(xf - xm) > (tol2 - 0.5 * (b - a)):
        golden = True
        if abs(e) > tol1:  # try a parabola through the three best points
            golden = False
            r = (xf - nfc) * (fx - ffulc)
            q = (xf - fulc) * (fx - fnfc)
            p = (xf - fulc) * q - (xf - nfc) * r
            q = 2.0 * (q - r)
            if q > 0.0:
                p = -p
            q = abs(q)
            r = e
            e = rat
            if abs(p) < abs(0.5 * q * r) and p > q * (a - xf) and p < q * (b - xf):
                rat = (p + 0.0) / q
                x = xf + rat
                if (x - a) < tol2 or (b - x) < tol2:  # not too near the bounds
                    rat = tol1 * _sign_or_one(xm - xf)
            else:
                golden = True
        if golden:  # a golden-section step into the larger part
            e = (a - xf) if xf >= xm else (b - xf)
            rat = golden_mean * e
        x = xf + _sign_or_one(rat) * _maximum(abs(rat), tol1)
        fu = f(x)
        calls += 1
        if fu <= fx:
            if x >= xf:
                a = xf
            else:
                b = xf
            fulc, ffulc = nfc, fnfc
            nfc, fnfc = xf, fx
            xf, fx = x, fu
        else:
            if x < xf:
                a = x
            else:
                b = x
            if fu <= fnfc or nfc == xf:
                fulc, ffulc = nfc, fnfc
                nfc, fnfc = x, fu
            elif fu <= ffulc or fulc == xf or fulc == nfc:
                fulc, ffulc = x, fu
        xm = 0.5 * (a + b)
        tol1 = sqrt_eps * abs(xf) + xatol / 3.0
        tol2 = 2.0 * tol1
        if calls >= maxiter:
            break
    return float(xf)
