"""States between a segment's recorded steps, on the dense output of those steps.

A recorded segment keeps the integrator's accepted steps (times and states).  Any time inside
it is reached again from the step that holds it, started from its recorded state with its
recorded size: DOP853's 7th-order dense output, or a fixed-step method's cubic Hermite from the
derivatives at both ends (its own dense output).  Used to resample a segment's series and by
the flight-energy audit's quadrature.  The audit has the dense output of each step as the
integrator took it (``kept``, :attr:`pcmm.ode.integrators.Segment.dense`): then no step is taken
again.
"""
from __future__ import annotations

import numpy as np


def dense_states(t, y, times, stepping, kept=None) -> np.ndarray:
    """The states at ``times`` (within [t[0], t[-1]]) on the dense output of the recorded steps
    ``(t, y)`` (``y`` one column per step end); ``stepping = (fun, method, opts)`` as the segment
    was integrated.  ``kept``: per step, ``fun -> interpolant`` of that step as the integrator
    took it, or None (:attr:`~pcmm.ode.integrators.Segment.dense`); a step without one is taken
    again from its recorded start with its recorded size.  A state without components (a locked
    or fully driven stay) is a known function of time: nothing to interpolate."""
    from ..ode.integrators import _dop853_dense, _hermite
    fun, method, opts = stepping
    times = np.asarray(times, float)
    out = np.empty((y.shape[0], len(times)))
    if y.shape[0] == 0:
        return out
    k_of = np.clip(np.searchsorted(t, times, side="right") - 1, 0, max(len(t) - 2, 0))
    for k in np.unique(k_of):
        cols = np.flatnonzero(k_of == k)
        exact = {j for j in cols if times[j] == t[k] or times[j] == t[min(k + 1, len(t) - 1)]}
        for j in exact:
            out[:, j] = y[:, k] if times[j] == t[k] else y[:, k + 1]
        rest = [j for j in cols if j not in exact]
        if not rest:
            continue
        sol = kept[k](fun) if kept is not None and kept[k] is not None else None  # the step as taken
        if sol is None and method.fixed_step:
            sol = _hermite(t[k], y[:, k], fun(t[k], y[:, k]), t[k + 1], y[:, k + 1], fun(t[k + 1], y[:, k + 1]))
        elif sol is None:
            sol = _dop853_dense(fun, t[k], y[:, k], t[k + 1], opts)
        out[:, rest] = np.asarray(sol(times[rest]), float).reshape(y.shape[0], len(rest))
    return out
