"""DOP853 as scipy.integrate.DOP853 steps it, without importing scipy.integrate.

The method ``DOP853`` (the default with loops or drives) steps with :class:`DOP853`, and the
Fortran DOP853's events are located on :func:`dense_step`.

Hairer's Fortran DOP853 hands back only the ends of its steps.  Where a step holds an event, or a
resampled time, the step is taken again from its start with its own size by DOP853 as
``scipy.integrate.DOP853`` implements it (the same tableau, error norm and step-size control,
Hairer, Norsett and Wanner, *Solving ODEs I*, section II.10), which normally takes it in one, and
its dense output is read.  Importing ``scipy.integrate`` for that costs about 0.5 s of CPU at
start-up (its ``__init__`` imports quadrature, BVP, scipy.optimize, scipy.special, scipy.sparse):
more than a short run.  So the step is taken here, with scipy's own tableau
(``scipy.integrate._ivp.dop853_coefficients``, loaded alone by :mod:`pcmm._scipy`) and the same
floating-point operations in the same order, so the dense output has the same bits
(tests/test_integrators.py compares the two).
"""
from __future__ import annotations

import warnings

import numpy as np

from .._scipy import dop853_coefficients

EPS = np.finfo(float).eps
SAFETY, MIN_FACTOR, MAX_FACTOR = 0.9, 0.2, 10  # the step-size control's factors (scipy's RK)
TOO_SMALL_STEP = "Required step size is less than spacing between numbers."


class _Tableau:
    """DOP853's coefficients, read once on first use."""

    def __init__(self):
        c = dop853_coefficients()
        n = c.N_STAGES
        self.n_stages, self.n_extended, self.power = n, c.N_STAGES_EXTENDED, c.INTERPOLATOR_POWER
        self.A, self.B, self.C = c.A[:n, :n], c.B, c.C[:n]
        self.E3, self.E5, self.D = c.E3, c.E5, c.D
        self.A_extra, self.C_extra = c.A[n + 1:], c.C[n + 1:]
        self.error_exponent = -1 / (7 + 1)  # the error estimator's order is 7


_TABLEAU: list[_Tableau] = []
_PACKED: list[np.ndarray] = []


def _tableau() -> _Tableau:
    if not _TABLEAU:
        _TABLEAU.append(_Tableau())
    return _TABLEAU[0]


def packed_tableau() -> np.ndarray:
    """scipy's DOP853 coefficients in one array, as a compiled segment loop stepping like
    :class:`DOP853` reads them (pcmm/model/_segment_loop.hpp): A (16 x 16: the 12 stages, the
    final one's row unused, the dense output's 3 extra), B (12), C (16), E3 (13), E5 (13), D (4 x 16)."""
    if not _PACKED:
        c = dop853_coefficients()
        _PACKED.append(np.concatenate([np.asarray(x, float).ravel() for x in (c.A, c.B, c.C, c.E3, c.E5, c.D)]))
    return _PACKED[0]


class DenseStep:
    """DOP853's interpolant over one step [t_old, t]: called with a time it returns the state
    (ny,), with an array of times the states (ny, n)."""

    def __init__(self, t_old, t, y_old, F):
        self.t_old, self.t, self.h, self.y_old, self.F = t_old, t, t - t_old, y_old, F

    def __call__(self, t):
        t = np.asarray(t)
        if t.ndim > 1:
            raise ValueError("`t` must be a float or a 1-D array.")
        x = (t - self.t_old) / self.h
        if t.ndim == 0:
            y = np.zeros_like(self.y_old)
        else:
            x = x[:, None]
            y = np.zeros((len(x), len(self.y_old)), dtype=self.y_old.dtype)
        for i, f in enumerate(reversed(self.F)):  # Horner's scheme in x and (1 - x), alternately
            y += f
            if i % 2 == 0:
                y *= x
            else:
                y *= 1 - x
        y += self.y_old
        return y.T


class ConstantStep:
    """The dense output of a state without components (nothing to interpolate)."""

    def __init__(self, t_old, t, value):
        self.t_old, self.t, self.value = t_old, t, value

    def __call__(self, t):
        t = np.asarray(t)
        if t.ndim == 0:
            return self.value
        out = np.empty((self.value.shape[0], t.shape[0]))
        out[:] = self.value[:, None]
        return out


def _error_norm(K, h, scale, tab) -> float:
    """DOP853's error norm of a step: the 5th-order estimate, corrected by the 3rd-order one."""
    err5 = np.dot(K.T, tab.E5) / scale
    err3 = np.dot(K.T, tab.E3) / scale
    err5_norm_2 = np.linalg.norm(err5) ** 2
    err3_norm_2 = np.linalg.norm(err3) ** 2
    if err5_norm_2 == 0 and err3_norm_2 == 0:
        return 0.0
    denom = err5_norm_2 + 0.01 * err3_norm_2
    return np.abs(h) * err5_norm_2 / np.sqrt(denom * len(scale))


def _stages(fun, t, y, f, h, K, tab):
    """One Runge-Kutta step's stages into ``K``: (y_new, f_new)."""
    K[0] = f
    for s, (a, c) in enumerate(zip(tab.A[1:], tab.C[1:]), start=1):
        dy = np.dot(K[:s].T, a[:s]) * h
        K[s] = fun(t + c * h, y + dy)
    y_new = y + h * np.dot(K[:-1].T, tab.B)
    f_new = fun(t + h, y_new)
    K[-1] = f_new
    return y_new, f_new


def _rms(x) -> float:
    return np.linalg.norm(x) / x.size ** 0.5


def _initial_step(fun, t0, y0, t_bound, max_step, f0, direction, rtol, atol):
    """scipy's choice of the first step (Hairer, Norsett and Wanner, II.4), for order 7."""
    if y0.size == 0:
        return np.inf
    interval_length = abs(t_bound - t0)
    if interval_length == 0.0:
        return 0.0
    scale = atol + np.abs(y0) * rtol
    d0 = _rms(y0 / scale)
    d1 = _rms(f0 / scale)
    h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
    h0 = min(h0, interval_length)  # not beyond t_bound
    y1 = y0 + h0 * direction * f0
    f1 = fun(t0 + h0 * direction, y1)
    d2 = _rms((f1 - f0) / scale) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** (1 / (7 + 1))
    return min(100 * h0, h1, interval_length, max_step)


class DOP853:
    """DOP853 from ``(t0, y0)`` towards ``t_bound``, as ``scipy.integrate.DOP853`` (the same
    constructor, ``step()``, ``dense_output()``, ``t``, ``y``, ``f``, ``status``): one accepted
    step per :meth:`step` (``None`` or the failure's message), :meth:`dense_output` its
    interpolant."""

    def __init__(self, fun, t0, y0, t_bound, max_step=np.inf, rtol=1e-3, atol=1e-6, first_step=None):
        self.tab = tab = _tableau()
        y0 = np.asarray(y0).astype(float, copy=False)
        if y0.ndim != 1:
            raise ValueError("`y0` must be 1-dimensional.")
        if not np.isfinite(y0).all():
            raise ValueError("All components of the initial state `y0` must be finite.")
        self.fun = lambda t, y: np.asarray(fun(t, y), dtype=float)
        self.t, self.y, self.t_bound, self.n = t0, y0, t_bound, y0.size
        self.direction = np.sign(t_bound - t0) if t_bound != t0 else 1
        if max_step <= 0:
            raise ValueError("`max_step` must be positive.")
        self.max_step = max_step
        if np.any(rtol < 100 * EPS):
            warnings.warn(f"At least one element of `rtol` is too small. Setting `rtol = np.maximum(rtol, "
                          f"{100 * EPS})`.", stacklevel=2)
            rtol = np.maximum(rtol, 100 * EPS)
        self.rtol, self.atol = rtol, np.asarray(atol)
        self.f = self.fun(t0, y0)
        if first_step is None:
            self.h_abs = _initial_step(self.fun, t0, y0, t_bound, max_step, self.f, self.direction, self.rtol,
                                       self.atol)
        elif first_step <= 0 or first_step > np.abs(t_bound - t0):
            raise ValueError(f"the first step {first_step!r} is not in (0, |t_bound - t0|]")
        else:
            self.h_abs = first_step
        self.t_old, self.y_old, self.h_previous = None, None, None
        self.K_extended = np.empty((tab.n_extended, self.n), dtype=self.y.dtype)
        self.K = self.K_extended[:tab.n_stages + 1]
        self.status = "running"

    def step(self) -> str | None:
        if self.n == 0 or self.t == self.t_bound:
            self.t_old, self.t, self.status = self.t, self.t_bound, "finished"
            return None
        t = self.t
        message = self._step()
        if message is not None:
            self.status = "failed"
        else:
            self.t_old = t
            if self.direction * (self.t - self.t_bound) >= 0:
                self.status = "finished"
        return message

    def _step(self) -> str | None:
        t, y, tab = self.t, self.y, self.tab
        min_step = 10 * np.abs(np.nextafter(t, self.direction * np.inf) - t)
        if self.h_abs > self.max_step:
            h_abs = self.max_step
        elif self.h_abs < min_step:
            h_abs = min_step
        else:
            h_abs = self.h_abs
        rejected = False
        while True:
            if h_abs < min_step:
                return TOO_SMALL_STEP
            h = h_abs * self.direction
            t_new = t + h
            if self.direction * (t_new - self.t_bound) > 0:
                t_new = self.t_bound
            h = t_new - t
            h_abs = np.abs(h)
            y_new, f_new = _stages(self.fun, t, y, self.f, h, self.K, tab)
            scale = self.atol + np.maximum(np.abs(y), np.abs(y_new)) * self.rtol
            error_norm = _error_norm(self.K, h, scale, tab)
            if error_norm < 1:
                factor = MAX_FACTOR if error_norm == 0 else min(MAX_FACTOR, SAFETY * error_norm ** tab.error_exponent)
                if rejected:
                    factor = min(1, factor)
                h_abs *= factor
                break
            h_abs *= max(MIN_FACTOR, SAFETY * error_norm ** tab.error_exponent)
            rejected = True
        self.h_previous, self.y_old = h, y
        self.t, self.y, self.h_abs, self.f = t_new, y_new, h_abs, f_new
        return None

    def dense_output(self):
        """The interpolant of the last accepted step (DOP853's extra stages, evaluated here)."""
        if self.t_old is None:
            raise RuntimeError("Dense output is available after a successful step was made.")
        if self.n == 0 or self.t == self.t_old:
            return ConstantStep(self.t_old, self.t, self.y)
        return _interpolant(self.fun, self.t_old, self.t, self.y_old, self.y, self.f, self.K_extended,
                            self.h_previous, self.tab)

    def accepted_stages(self) -> AcceptedStages:
        """The last accepted step's stages, kept (a copy) so that its interpolant can be formed
        later by :meth:`AcceptedStages.dense_output`, with another right-hand side for its 3
        extra stages, without taking the step again."""
        if self.t_old is None:
            raise RuntimeError("Stages are available after a successful step was made.")
        return AcceptedStages(self.t_old, self.t, self.y_old, self.y, self.f, self.K.copy(), self.h_previous)


def _interpolant(fun, t_old, t, y_old, y, f, K, h, tab) -> DenseStep:
    """DOP853's interpolant of the step from ``(t_old, y_old)`` to ``(t, y)`` (size ``h``, ``f`` the
    derivative at its end) whose first ``n_stages + 1`` stages fill ``K`` (``n_extended`` rows): the
    extra stages evaluated by ``fun`` into ``K``, then scipy's ``F`` (its ``dense_output``)."""
    n = len(y_old)
    for s, (a, c) in enumerate(zip(tab.A_extra, tab.C_extra), start=tab.n_stages + 1):
        dy = np.dot(K[:s].T, a[:s]) * h
        K[s] = fun(t_old + c * h, y_old + dy)
    F = np.empty((tab.power, n), dtype=y_old.dtype)
    f_old = K[0]
    delta_y = y - y_old
    F[0] = delta_y
    F[1] = h * f_old - delta_y
    F[2] = 2 * delta_y - h * (f + f_old)
    F[3:] = h * np.dot(tab.D, K)
    return DenseStep(t_old, t, y_old, F)


class AcceptedStages:
    """An accepted step of :class:`DOP853` as the integrator took it: its ends, the derivative at
    its end and its stages.  Its interpolant is DOP853's dense output of that step, the 3 extra
    stages evaluated by the right-hand side :meth:`dense_output` is given (the flight-energy audit
    gives its own reader's, so the run's warm starts are left alone): 3 evaluations instead of the
    16 that taking the step again costs."""

    __slots__ = ("K", "f", "h", "t", "t_old", "y", "y_old")

    def __init__(self, t_old, t, y_old, y, f, K, h):
        self.t_old, self.t, self.y_old, self.y, self.f, self.K, self.h = t_old, t, y_old, y, f, K, h

    def dense_output(self, fun):
        if len(self.y_old) == 0 or self.t == self.t_old:
            return ConstantStep(self.t_old, self.t, self.y)
        tab = _tableau()
        K = np.empty((tab.n_extended, len(self.y_old)), dtype=self.y_old.dtype)
        K[:len(self.K)] = self.K
        def fun_float(t, y):  # as DOP853 wraps its right-hand side
            return np.asarray(fun(t, y), dtype=float)
        return _interpolant(fun_float, self.t_old, self.t, self.y_old, self.y, self.f, K, self.h, tab)


class Pieces:
    """The dense output of a step that DOP853 split: each piece's interpolant on its own interval
    (a time on a boundary belongs to the piece before it, as in ``scipy.integrate.OdeSolution``)."""

    def __init__(self, ts, pieces, ny):
        self.ts, self.pieces, self.ny = np.asarray(ts, float), pieces, ny

    def _piece(self, t):
        k = int(np.searchsorted(self.ts, t, side="left")) - 1
        return self.pieces[min(max(k, 0), len(self.pieces) - 1)]

    def __call__(self, t):
        t = np.asarray(t, float)
        if t.ndim == 0:
            return self._piece(t)(t)
        out = np.empty((self.ny, t.shape[0]))
        for j, tj in enumerate(t):
            out[:, j] = self._piece(tj)(tj)
        return out


def dense_step(fun, t_a, y_a, t_b, rtol, atol):
    """DOP853's dense output over the step [t_a, t_b] of the Fortran code (see the module's
    docstring); ``(None, message)`` where DOP853 fails on it, else ``(interpolant, None)``."""
    steps = DOP853(fun, t_a, y_a, t_b, rtol=rtol, atol=atol, first_step=t_b - t_a)
    ts, pieces = [t_a], []
    while steps.status == "running":
        message = steps.step()
        if steps.status == "failed":
            return None, message
        ts.append(steps.t)
        pieces.append(steps.dense_output())
    return (pieces[0] if len(pieces) == 1 else Pieces(ts, pieces, steps.n)), None
