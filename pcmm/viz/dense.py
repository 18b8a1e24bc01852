"""Curves true to the run between its steps, for the figures.

A fresh run draws its figures from the integrator's dense output (``Trajectory.resampled``).  A
saved run holds its steps only, but at each step both a coordinate and its rate: ``q`` with
``v`` and each link's angle ``theta`` with ``omega``.  :func:`hermite` draws those through each
step interval as the cubic Hermite polynomial matching the values and rates at both ends (C1: no
kink at a step; error O(h^4) in the step h, far below a figure's pixel for steps the tolerances
accept).  The other series (rates, positions, energies, forces) are linear between steps at the
same times: their own rates are not recorded."""
from __future__ import annotations

import dataclasses

import numpy as np

from .marks import RecordedRun

#: Samples over the whole run that a figure is drawn at (its plot resolution).
PLOT_SAMPLES = 2000
_LINEAR = ("omega", "v", "xy", "kinetic", "potential", "forces", "constraint_forces")


def cubic_hermite(t: np.ndarray, y: np.ndarray, dy: np.ndarray, times: np.ndarray) -> np.ndarray:
    """The C1 piecewise cubic through ``(t, y)`` with slopes ``dy`` (along axis 0), at ``times``."""
    y = np.asarray(y, float)
    if len(t) < 2:
        return np.repeat(y[:1], len(times), axis=0)
    k = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(t) - 2)
    h = (t[k + 1] - t[k])
    s = ((times - t[k]) / np.where(h > 0, h, 1.0))
    shape = (-1,) + (1,) * (y.ndim - 1)
    s, hh = s.reshape(shape), h.reshape(shape)
    h00, h10 = 2 * s ** 3 - 3 * s ** 2 + 1, s ** 3 - 2 * s ** 2 + s
    h01, h11 = -2 * s ** 3 + 3 * s ** 2, s ** 3 - s ** 2
    return h00 * y[k] + h10 * hh * dy[k] + h01 * y[k + 1] + h11 * hh * dy[k + 1]


def _linear(t, y, times):
    y = np.asarray(y, float)
    if y.ndim == 1:
        return np.interp(times, t, y)
    flat = y.reshape(len(t), -1)
    out = np.column_stack([np.interp(times, t, flat[:, j]) for j in range(flat.shape[1])]) if flat.shape[1] else \
        np.zeros((len(times), 0))
    return out.reshape((len(times),) + y.shape[1:])


def segment_times(a: float, b: float, dt: float) -> np.ndarray:
    """``a``, the multiples of ``dt`` inside, ``b`` (an event's instant stays a sample)."""
    inner = np.arange(np.ceil(a / dt), np.floor(b / dt) + 1) * dt
    inner = inner[(inner > a) & (inner < b)]
    return np.concatenate(([a], inner, [b])) if b > a else np.array([a])


def plot_times(traj: RecordedRun, seg, samples: int = PLOT_SAMPLES) -> np.ndarray:
    """The times a segment is drawn at: its steps and the plot resolution's grid (``samples``
    over the whole run) between them, so no step longer than a pixel is drawn straight."""
    t0, t1 = float(traj.segments[0].t[0]), float(traj.segments[-1].t[-1])
    dt = max(t1 - t0, 1e-12) / samples
    return np.union1d(np.asarray(seg.t, float), segment_times(float(seg.t[0]), float(seg.t[-1]), dt))


def hermite(traj: RecordedRun, samples: int = PLOT_SAMPLES) -> RecordedRun:
    """``traj`` at plot resolution (``samples`` over the run, plus every segment's ends), angles
    and coordinates by cubic Hermite on their recorded rates; a copy, ``traj`` is unchanged."""
    if not traj.segments:
        return traj
    segs = []
    for s in traj.segments:
        t = np.asarray(s.t, float)
        times = plot_times(traj, s, samples)
        if len(times) == len(t):  # every step already shorter than the plot's resolution
            segs.append(s)
            continue
        segs.append(s.replaced(t=times, theta=cubic_hermite(t, s.theta, s.omega, times),
                               q=cubic_hermite(t, s.q, s.v, times),
                               **{name: _linear(t, getattr(s, name), times) for name in _LINEAR}))
    return dataclasses.replace(traj, segments=segs)
