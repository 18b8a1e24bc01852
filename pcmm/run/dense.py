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
    # a time on a recorded step's end is that step's state; the others, step by step (in the
    # order they are asked for within each step) on the step's dense output
    at_start = times == t[k_of]
    at_end = ~at_start & (times == t[np.minimum(k_of + 1, len(t) - 1)])
    out[:, at_start] = y[:, k_of[at_start]]
    out[:, at_end] = y[:, k_of[at_end] + 1]
    inside = np.flatnonzero(~(at_start | at_end))
    order = inside[np.argsort(k_of[inside], kind="stable")]
    for cols in np.split(order, np.flatnonzero(np.diff(k_of[order])) + 1) if len(order) else ():
        k = int(k_of[cols[0]])
        sol = kept[k](fun) if kept is not None and kept[k] is not None else None  # the step as taken
        if sol is None and method.fixed_step:
            sol = _hermite(t[k], y[:, k], fun(t[k], y[:, k]), t[k + 1], y[:, k + 1], fun(t[k + 1], y[:, k + 1]))
        elif sol is None:
            sol = _dop853_dense(fun, t[k], y[:, k], t[k + 1], opts)
        out[:, cols] = np.asarray(sol(times[cols]), float).reshape(y.shape[0], len(cols))
    return out
