"""States between a segment's recorded steps, on the dense output of those steps.

A recorded segment keeps the integrator's accepted steps (times and states).  Any time inside
it is reached again from the step that holds it, started from its recorded state with its
recorded size: DOP853's 7th-order dense output, or a fixed-step method's cubic Hermite from the
derivatives at both ends (its own dense output).  Used to resample a segment's series and by
the flight-energy audit's quadrature.  The audit has the dense output of each step as the
integrator took it (``kept``, :attr:`pcmm.ode.integrators.Segment.dense`): then no step is taken
again, and where every step asked for is DOP853's polynomial of one form (the compiled loop's
``contd8`` coefficients, or scipy's ``y_old, F``) the states at every time are evaluated at once,
each time on its own step's coefficients with that form's operations in their order (the same
bits as calling each step's interpolant: :func:`_polynomial_states`).
"""
from __future__ import annotations

import numpy as np

from ..ode.dop853 import DenseStep
from ..ode.integrators import _Contd8, _ScipyDense


def dense_states(t, y, times, stepping, kept=None) -> np.ndarray:
    """The states at ``times`` (within [t[0], t[-1]]) on the dense output of the recorded steps
    ``(t, y)`` (``y`` one column per step end); ``stepping = (fun, method, opts)`` as the segment
    was integrated.  ``kept``: per step, ``fun -> interpolant`` of that step as the integrator
    took it, or None (:attr:`~pcmm.ode.integrators.Segment.dense`); a step without one is taken
    again from its recorded start with its recorded size.  A state without components (a locked
    or fully driven stay) is a known function of time: nothing to interpolate."""
    times = np.asarray(times, float)
    t = np.asarray(t, float)
    n = t.shape[0]
    out = np.empty((y.shape[0], times.shape[0]))
    if y.shape[0] == 0 or times.shape[0] == 0:
        return out
    k_of = t.searchsorted(times, "right")
    k_of -= 1
    np.minimum(k_of, max(n - 2, 0), out=k_of)
    np.maximum(k_of, 0, out=k_of)
    # a time on a recorded step's end is that step's state; the others on the step's dense output
    at_start = times == t[k_of]
    at_end = times == t[np.minimum(k_of + 1, n - 1)]
    if np.count_nonzero(at_start) or np.count_nonzero(at_end):
        at_end &= ~at_start
        out[:, at_start] = y[:, k_of[at_start]]
        out[:, at_end] = y[:, k_of[at_end] + 1]
        inside = (~(at_start | at_end)).nonzero()[0]
        if not inside.size:
            return out
        k_in, times_in = k_of[inside], times[inside]
    else:
        inside, k_in, times_in = None, k_of, times
    fun = stepping[0]
    steps = sorted(set(k_in.tolist()))  # each step's interpolant formed once, in the order of the steps
    formed = {k: kept[k](fun) for k in steps if kept[k] is not None} if kept is not None else {}
    states = _polynomial_states(formed, steps, k_in, times_in) if len(formed) == len(steps) else None
    if states is None:
        states = _stepwise(t, y, k_in, times_in, stepping, formed)
    if inside is None:
        return states
    out[:, inside] = states
    return out


def _polynomial_states(formed: dict, steps: list, k_in, times_in) -> np.ndarray | None:
    """The states at ``times_in`` (each on step ``k_in``) where every step's interpolant in
    ``formed`` is DOP853's polynomial of one form, or None: each time's own step's coefficients
    gathered, then the form's evaluation (:meth:`DenseStep.__call__`, :meth:`_Contd8.__call__`)
    over every time at once, its operations in their order, element by element: the same bits."""
    sols = [formed[k] for k in steps]
    kind = _form(sols[0])
    if kind is None:
        return None
    for s in sols:
        if _form(s) is not kind:
            return None
    if kind is DenseStep:
        coefficients = [(s.y_old, s.F) for s in sols]
        for y_old, F in coefficients:
            if not (type(F) is np.ndarray and F.dtype == float and F.shape == (7, y_old.shape[0])
                    and type(y_old) is np.ndarray and y_old.dtype == float):
                return None
    else:
        coefficients = [(s.cont,) for s in sols]
        for (cont,) in coefficients:
            if not (type(cont) is np.ndarray and cont.dtype == float and cont.ndim == 2 and cont.shape[0] == 8):
                return None
    if len(sols) == 1:  # one step: its own coefficients, each time's state a row
        t_old, h = sols[0].t_old, sols[0].h
        gathered = coefficients[0]
    else:  # each time's step's coefficients, gathered in one index
        pos = k_in - steps[0] if steps[-1] - steps[0] + 1 == len(steps) else np.searchsorted(steps, k_in)
        t_old = np.array([s.t_old for s in sols], float)[pos]
        h = np.array([s.h for s in sols], float)[pos]
        gathered = []
        for j, first in enumerate(coefficients[0]):
            stacked = np.empty((len(sols), *first.shape))
            for i, c in enumerate(coefficients):
                if c[j].shape != first.shape:
                    return None
                stacked[i] = c[j]
            gathered.append(stacked[pos])
    x = ((times_in - t_old) / h)[:, None]
    if kind is DenseStep:
        y_old, F = gathered  # (ny,), (7, ny) or, gathered, (m, ny), (m, 7, ny)
        F = F if F.ndim == 2 else F.transpose(1, 0, 2)  # F[j]: the j-th coefficient, (ny,) or (m, ny)
        y = np.zeros((times_in.shape[0], y_old.shape[-1]))
        for i in range(7):  # Horner's scheme in x and (1 - x), alternately, as DenseStep
            y += F[6 - i]
            if i % 2 == 0:
                y *= x
            else:
                y *= 1 - x
        y += y_old
        return y.T
    (c,) = gathered
    c = c if c.ndim == 3 else c[None]  # (m or 1, 8, ny)
    s1 = 1.0 - x
    par = c[:, 4] + x * (c[:, 5] + s1 * (c[:, 6] + x * c[:, 7]))
    return (c[:, 0] + x * (c[:, 1] + s1 * (c[:, 2] + x * (c[:, 3] + s1 * par)))).T


def _form(sol):
    """The form of DOP853's polynomial ``sol`` evaluates an array of times with: :class:`DenseStep`
    (scipy's ``y_old, F``; its subclass ``_ScipyDense`` evaluates arrays with ``DenseStep``'s own
    call), :class:`_Contd8`, or None (another interpolant)."""
    cls = type(sol)
    if cls is _Contd8 or cls is DenseStep:
        return cls
    if cls is _ScipyDense:
        return DenseStep
    return None


def _stepwise(t, y, k_in, times_in, stepping, formed: dict) -> np.ndarray:
    """The states at ``times_in`` (each on step ``k_in``) step by step, in the order they are
    asked for within each step: on the interpolant ``formed`` for the step, else the step's
    Hermite (a fixed-step method) or DOP853 taken again from the step's recorded start."""
    from ..ode.integrators import _dop853_dense, _hermite
    fun, method, opts = stepping
    out = np.empty((y.shape[0], times_in.shape[0]))
    order = np.argsort(k_in, kind="stable")
    for cols in np.split(order, np.flatnonzero(np.diff(k_in[order])) + 1):
        k = int(k_in[cols[0]])
        sol = formed.get(k)  # the step as taken
        if sol is None and method.fixed_step:
            sol = _hermite(t[k], y[:, k], fun(t[k], y[:, k]), t[k + 1], y[:, k + 1], fun(t[k + 1], y[:, k + 1]))
        elif sol is None:
            sol = _dop853_dense(fun, t[k], y[:, k], t[k + 1], opts)
        out[:, cols] = np.asarray(sol(times_in[cols]), float).reshape(y.shape[0], len(cols))
    return out
