"""The extremes of a recorded series between its samples, on the run's dense output.

A run records the integrator's accepted steps; DOP853 steps up to tenths of a second apart over a
smooth stretch (a walker's stance), so the largest recorded sample of a force is below the force's
peak between two steps.  A designer sizes a latch or a foot's friction by that peak: it is found
here on the segment's dense output (:meth:`SegmentRecord.resampled`, the very path ``pcmm run --dt``
and :meth:`Trajectory.resampled` take, so the force is evaluated by the one implementation), by a
bracketing grid search around the sample, one batched evaluation per refinement for every candidate
of a segment.

Which samples are refined (:func:`local_extremes`, :data:`MARGIN`, :data:`MOST`): every local
extreme sample (at least its neighbours; a segment's end against its one neighbour) within
:data:`MARGIN` of the samples' range of the extreme sample, the :data:`MOST` nearest it.  A peak
between samples that falls short of its own local-extreme sample by more than a few per cent of
the range would need steps far longer than the force's own time scale, which the integrator's
error control does not take; the margin covers a second peak that the samples under-read more than
the first (``tests/test_holding_peaks.py`` builds one).  Measured on the shipped examples, the
samples under-read a peak by at most 0.17 % of the force's range over their whole runs (Example 1's
O3 hold; the compass gait's normal force 0.085 %), 0.43 % on the rimless wheel's first stance alone
(its tangential force, run to 0.7 s): a tenth of the margin or less.
The search brackets a candidate sample by its two neighbouring steps (a segment's end by its one),
so a peak in either interval is found; a peak is missed only where the force turns twice between
two samples (a dip and a peak within one step), faster than the integrator's steps resolve.
"""
from __future__ import annotations

import numpy as np

#: a local extreme sample is refined when within this fraction of the samples' range of the extreme sample
MARGIN = 0.05
#: at most this many candidates per quantity and direction (the nearest the extreme sample)
MOST = 8
#: grid points per half bracket at each refinement (a bracket shrinks by (GRID - 1) / 2 per refinement)
GRID = 9
#: the search stops when the best point's neighbours are this close (s), or at round-off of the times
T_TOL = 1e-12
#: ... or when the best point's value is within this relative amount of its neighbours'
F_TOL = 1e-10
#: each round places its points this many times closer than the best point's nearest neighbour
ZOOM = 32
#: at most this many rounds of evaluation
ROUNDS = 12
#: the dense output read at the candidate sample itself must give the recorded value to this relative
#: tolerance (else the candidate keeps its sample: e.g. a loop's Newton solve landing on another assembly)
AGREE = 1e-7


def local_extremes(col: np.ndarray, sign: float) -> np.ndarray:
    """Indices of the samples of ``col`` at least their neighbours (``sign`` +1: maxima, -1: minima);
    NaN samples are neither candidates nor neighbours that block one."""
    x = sign * np.asarray(col, float)
    x = np.where(np.isnan(x), -np.inf, x)
    if x.size == 0:
        return np.zeros(0, int)
    pad = np.concatenate(([-np.inf], x, [-np.inf]))
    ok = (x >= pad[:-2]) & (x >= pad[2:]) & np.isfinite(x)
    return ok.nonzero()[0]


def refine(segment, jobs: list) -> list:
    """The extremes between samples of ``segment`` (a record with dense output) for ``jobs``, each
    ``(i, sign, column)``: the sample index, +1 for a maximum or -1 for a minimum, and
    ``column(record) -> array`` the quantity at a record's samples.  Returns per job ``(value, t)``
    of the extreme found in ``[t[i-1], t[i+1]]``, or None where the sample is the extreme (or beyond
    it by less than :data:`F_TOL`: round-off of a flat force, or the dense output cannot be read there).

    First a grid of :data:`GRID` points on each side of the sample; then, around the best point so
    far, the vertex of the parabola through it and its two neighbours with two points beside it
    (:data:`ZOOM` times closer than its nearest neighbour), until the best point's value is within
    :data:`F_TOL` of its neighbours' (the extreme of a parabola through three points exceeds the
    middle one by at most a quarter of that difference) or its neighbours are :data:`T_TOL` apart.
    One dense-output evaluation per round for all the jobs of the segment."""
    t = np.asarray(segment.t, float)
    n = t.size
    out: list = [None] * len(jobs)
    if n < 2 or not jobs or segment.__dict__.get("_resample") is None:
        return out
    recorded = [float(col(segment)[i]) for i, _, col in jobs]
    pts = [{} for _ in jobs]  # per job: {time: sign * value}
    asked = {j: np.unique(np.concatenate((np.linspace(t[max(i - 1, 0)], t[i], GRID),
                                          np.linspace(t[i], t[min(i + 1, n - 1)], GRID))))
             for j, (i, _, _) in enumerate(jobs)}
    first = True
    for _ in range(ROUNDS):
        if not asked:
            break
        times = np.unique(np.concatenate(list(asked.values())))
        rec = segment.resampled(times)
        nxt = {}
        for j, g in asked.items():
            i, sign, col = jobs[j]
            vals = sign * np.asarray(col(rec), float)[np.searchsorted(times, g)]
            if first:  # the dense output at the sample itself must give the recorded value
                v0 = vals[np.searchsorted(g, t[i])]
                if not (np.isfinite(v0) and abs(v0 - sign * recorded[j]) <= AGREE * (1.0 + abs(recorded[j]))):
                    continue  # it does not (e.g. another assembly of a loop): the sample stays
            pts[j].update((float(a), float(b)) for a, b in zip(g, vals) if np.isfinite(b))
            tt = np.array(sorted(pts[j]))
            vv = np.array([pts[j][x] for x in tt])
            k = int(np.argmax(vv))
            if 0 < k < tt.size - 1:
                lo, hi = tt[k] - tt[k - 1], tt[k + 1] - tt[k]
                drop = vv[k] - min(vv[k - 1], vv[k + 1])
                if drop <= 4 * F_TOL * (1.0 + abs(vv[k])) or tt[k + 1] - tt[k - 1] <= max(
                        T_TOL, 8 * np.finfo(float).eps * abs(tt[k])):
                    continue
                # the parabola's vertex through the three points (clamped inside their span)
                d1, d2 = (vv[k] - vv[k - 1]) / lo, (vv[k + 1] - vv[k]) / hi
                curv = (d2 - d1) / (lo + hi)
                tv = tt[k] if curv >= 0 else 0.5 * (tt[k - 1] + tt[k]) - d1 / (2 * curv)
                tv = min(max(tv, tt[k - 1] + lo / ZOOM), tt[k + 1] - hi / ZOOM)
                # beside it: as far as the drop F_TOL asks for on this parabola, within (1/ZOOM^2, 1/ZOOM)
                # of the nearer neighbour (an inexact vertex stays bracketed by them)
                near = min(abs(tv - tt[k - 1]), abs(tt[k + 1] - tv))
                need = np.sqrt(F_TOL * (1.0 + abs(vv[k])) / -curv) if curv < 0 else near
                h = min(max(need, near / ZOOM ** 2), near / ZOOM)
            else:  # at the bracket's end, a segment's end sample (a sample bracketed by lower ones is
                continue  # interior): the grid found no higher point inside, the end is the extreme
            g = np.array([tv - h, tv, tv + h])
            g = g[(g >= tt[0]) & (g <= tt[-1])]
            g = np.array([x for x in g if float(x) not in pts[j]])
            if g.size:
                nxt[j] = g
        asked, first = nxt, False
    for j, (i, sign, _) in enumerate(jobs):
        if pts[j]:
            tb = max(pts[j], key=pts[j].get)
            if pts[j][tb] > sign * recorded[j] + F_TOL * (1.0 + abs(recorded[j])):  # (not round-off of a flat force)
                out[j] = (sign * pts[j][tb], tb)
    return out
