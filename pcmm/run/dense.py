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
bits as calling each step's interpolant: :func:`_polynomial_states`).  The compiled loop hands its
steps' dense outputs back as rows of coefficients, kept as rows (no interpolant formed): a flight's
nodes are read off them at once (:func:`states_on_rows`; a short flight on Python floats, the same
operations), with the same bits.
"""
from __future__ import annotations

import numpy as np

from ..model import compiled
from ..ode.dop853 import DenseStep
from ..ode.integrators import _Contd8, _Row, _ScipyDense, contd8_row_dense, scipy_row_dense


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
    if kept is not None:  # the compiled loop's rows: every time read off them at once, no interpolant formed
        states = _row_states(kept, k_in, times_in)
        if states is not None:
            if inside is None:
                return states
            out[:, inside] = states
            return out
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


def states_on_rows(t, y, times, k_of, kept, components=None) -> np.ndarray | None:
    """:func:`dense_states` where the caller knows each time's step ``k_of`` (the step that holds it:
    ``t[k] <= time <= t[k + 1]``, as the flight audit's Gauss nodes lie) and every step of ``kept`` is
    a row of the compiled loop (:class:`~pcmm.ode.integrators._Row`); None otherwise, and where a time
    falls on a recorded step's end (a step shorter than its time's round-off: :func:`dense_states`
    reads that end's state).  The same bits as :func:`dense_states`; ``components``: at least the first
    so many components of the state (the rest may be left out)."""
    if kept is None or y.shape[0] == 0 or not len(kept):
        return None
    form = _rows_form(kept)
    if form is None:
        return None
    n = (kept[0].row.shape[0] - 2) // 8
    if times.shape[0] * n > _FLOAT_SIZE:
        states = _row_states(kept, k_of, times)
        return None if ((times == t[k_of]) | (times == t[k_of + 1])).any() else states
    # a short flight (the most, in a bouncing run): on Python floats, the very operations the arrays do,
    # each step's coefficients read out once per component (the first `components`)
    m = n if components is None else min(components, n)
    tl, out, last, coefficients = t.tolist(), [], None, None
    for ti, k in zip(times.tolist(), k_of.tolist()):
        if ti == tl[k] or ti == tl[k + 1]:
            return None
        if k != last:
            row, last = kept[k].row.tolist(), k
            if form is scipy_row_dense:  # per component: y_old, then F[6], F[5], ..., F[0]
                coefficients = [(row[2 + j], *row[2 + 7 * n + j:2 + j:-n]) for j in range(m)]  # (7 of them)
                t_old, h = row[0], row[1] - row[0]  # DenseStep's h = t - t_old
            else:  # _Contd8: per component its 8 coefficients
                coefficients = [row[2 + j::n] for j in range(m)]
                t_old, h = row[0], row[1]
        x = (ti - t_old) / h
        if form is scipy_row_dense:  # DenseStep: y = 0; y += F[6 - i], y *= x or (1 - x) alternately; y += y_old
            x1 = 1 - x  # (the loop over F written out: the same operations in the same order)
            state = [((((((((0.0 + f6) * x + f5) * x1 + f4) * x + f3) * x1 + f2) * x + f1) * x1 + f0) * x) + y0
                     for y0, f6, f5, f4, f3, f2, f1, f0 in coefficients]
        else:
            s1 = 1.0 - x
            state = [c[0] + x * (c[1] + s1 * (c[2] + x * (c[3] + s1 * (c[4] + x * (c[5] + s1 * (c[6] + x * c[7]))))))
                     for c in coefficients]
        out.append(state)
    return np.array(out).T


def compiled_node_states(t, y, kept, x, w, components):
    """``(times, weights, states)``: the Gauss-Legendre nodes of every step of ``t`` (``x``: the nodes'
    abscissae plus one, ``w`` their weights, as floats) and the states there, the first ``components``,
    in one compiled call (``SegmentLoop.gauss_states``, pcmm/model/_segment_loop.hpp) where every step of
    ``kept`` is a row of the compiled loop (:class:`~pcmm.ode.integrators._Row`) of one form: the
    operations of pcmm.run.audit._nodes and :func:`states_on_rows` on the same doubles in their order,
    so the same bits.  None otherwise (the compiled evaluations off, another dense output kept), and
    where a node falls on its step's end (:func:`states_on_rows` leaves those to :func:`dense_states`)."""
    if kept is None or y.shape[0] == 0 or not len(kept) or not compiled.enabled():
        return None
    nodes = _GAUSS_STATES[0] if _GAUSS_STATES else _gauss_states()
    if nodes is None:
        return None
    form = _rows_form(kept)
    if form is None:
        return None
    return nodes(t, [e.row for e in kept], form is scipy_row_dense, x, w, components)


_GAUSS_STATES: list = []


def _gauss_states():
    """The compiled ``gauss_states``, or None (an extension built before it)."""
    loop = getattr(getattr(compiled, "_tree_dynamics", None), "SegmentLoop", None)
    _GAUSS_STATES.append(getattr(loop, "gauss_states", None))
    return _GAUSS_STATES[0]


#: times x components up to which :func:`states_on_rows` evaluates on Python floats (numpy's call per
#: operation costs more below)
_FLOAT_SIZE = 64


def _rows_form(kept):
    """The form shared by every step of ``kept`` where each is a row of the compiled loop of one width
    (:class:`~pcmm.ode.integrators._Row`), else None."""
    first = kept[0]
    if type(first) is not _Row:
        return None
    form, width = first.form, first.row.shape[0]
    for e in kept:
        if type(e) is not _Row or e.form is not form or e.row.shape[0] != width:
            return None
    return form if form is scipy_row_dense or form is contd8_row_dense else None


def _row_states(kept, k_in, times_in) -> np.ndarray | None:
    """The states at ``times_in`` (each on step ``k_in``) where every step of ``kept`` is a row of the
    compiled loop's dense outputs of one form (:class:`~pcmm.ode.integrators._Row`), or None: the rows
    stacked, each time's own row gathered, then the form's evaluation as :func:`_polynomial_states`
    does it (the same coefficients, the same operations in their order: the same bits), with none of
    the steps' interpolants formed."""
    form = _rows_form(kept)
    if form is None:
        return None
    n = (kept[0].row.shape[0] - 2) // 8
    rows = np.array([e.row for e in kept])[k_in]  # (times, width): each time's step
    t_old = rows[:, 0]
    if form is scipy_row_dense:  # (t_old, t_new, y_old, F): DenseStep's h = t - t_old
        return _dense_step_states(times_in, t_old, rows[:, 1] - t_old, rows[:, 2:2 + n],
                                  rows[:, 2 + n:].reshape(-1, 7, n).transpose(1, 0, 2))
    return _contd8_states(times_in, t_old, rows[:, 1], rows[:, 2:].reshape(-1, 8, n))  # (t_old, h, cont)


def _dense_step_states(times_in, t_old, h, y_old, F) -> np.ndarray:
    """scipy's DOP853 polynomial (:meth:`DenseStep.__call__`) at ``times_in``: ``y_old`` (ny,) or (m, ny),
    ``F`` (7, ny) or (7, m, ny) (``F[j]`` the j-th coefficient), ``t_old``, ``h`` scalars or (m,).
    Horner's scheme in x and (1 - x), alternately, as DenseStep: its zeros plus the last coefficient
    is that coefficient plus 0.0 (a -0.0 turned +0.0 alike), then times x."""
    x = ((times_in - t_old) / h)[:, None]
    x1 = 1 - x
    y = (F[6] + 0.0) * x
    for i in range(1, 7):
        y += F[6 - i]
        y *= x if i % 2 == 0 else x1
    y += y_old
    return y.T


def _contd8_states(times_in, t_old, h, c) -> np.ndarray:
    """Hairer's contd8 polynomial (:meth:`_Contd8.__call__`) at ``times_in``: ``c`` (m or 1, 8, ny)."""
    x = ((times_in - t_old) / h)[:, None]
    s1 = 1.0 - x
    par = c[:, 4] + x * (c[:, 5] + s1 * (c[:, 6] + x * c[:, 7]))
    return (c[:, 0] + x * (c[:, 1] + s1 * (c[:, 2] + x * (c[:, 3] + s1 * par)))).T


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
    if kind is DenseStep:
        y_old, F = gathered  # (ny,), (7, ny) or, gathered, (m, ny), (m, 7, ny)
        F = F if F.ndim == 2 else F.transpose(1, 0, 2)  # F[j]: the j-th coefficient, (ny,) or (m, ny)
        return _dense_step_states(times_in, t_old, h, y_old, F)
    (c,) = gathered
    return _contd8_states(times_in, t_old, h, c if c.ndim == 3 else c[None])  # (m or 1, 8, ny)


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
