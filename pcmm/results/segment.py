"""One segment of a run's record: the samples of one stay in one configuration."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UsageError

_ARRAYS = ("t", "q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces")
_DERIVED = _ARRAYS[1:]  # everything but t: computed from the integrator's states when first asked for


@dataclass
class SegmentRecord:
    """Samples of one stay in one configuration (the integrator's steps).

    A run records a segment as the integrator's states only (:meth:`deferred`); the
    coordinates and the derived series (angles, positions, energies, force elements,
    constraint forces) are computed on first access of any of them, once, so a run
    that nobody reads pays nothing for them."""

    configuration: str
    coordinates: list[str]  # one name per velocity: "O1", or "P.x", "P.y", "P.theta"
    links: list[str]
    force_names: list[str]
    constraint_labels: list[str]
    t: np.ndarray
    q: np.ndarray  # (n, nv)
    v: np.ndarray  # (n, nv) rates of q: a planar joint's x', y' in world axes
    theta: np.ndarray  # (n, nlinks) absolute angles, continuous across switches
    omega: np.ndarray  # (n, nlinks)
    xy: np.ndarray  # (n, nlinks, 2) link frame origins
    kinetic: np.ndarray  # (n,)
    # (n,) gravity (welded bodies included) + every spring's k x^2 / 2: the configuration's own and,
    # while a joint is held (a latch, a merged stop, a lock held from the start), its own springs at
    # the locked value (constant there, so the series does not jump at a lock or a release)
    potential: np.ndarray
    forces: np.ndarray  # (n, nforces) each force element's output (N or N m)
    constraint_forces: np.ndarray  # (n, m) cut-joint reactions and driving moments

    @classmethod
    def deferred(cls, derive, t: np.ndarray, resample=None, **meta) -> "SegmentRecord":
        """A segment whose arrays other than ``t`` come from ``derive()`` (a dict of them)
        when first needed; ``resample(times)`` gives the same dict at other times (on the
        integrator's dense output)."""
        rec = object.__new__(cls)
        rec.__dict__.update(meta, t=t, _derive=derive, _resample=resample)
        return rec

    def resampled(self, times: np.ndarray) -> "SegmentRecord":
        """The segment at ``times`` (within its own span), from the dense output of the run's
        steps: only a segment of the run that made it can do this, not one loaded from a file."""
        resample = self.__dict__.get("_resample")
        if resample is None:
            raise UsageError("resampling at a chosen rate needs the run's dense output: ask for it when "
                             "running (pcmm run --dt); a saved trajectory holds its steps only")
        times = np.asarray(times, float)
        rec = object.__new__(type(self))
        rec.__dict__.update({k: self.__dict__[k] for k in ("configuration", "coordinates", "links", "force_names",
                                                           "constraint_labels")}, t=times)
        rec.__dict__.update(resample(times))
        return rec

    def replaced(self, **arrays) -> "SegmentRecord":
        """A copy of this segment with ``arrays`` (``t`` and series at other times, as a plot's
        interpolation gives them) in place of its own; every other series is read now.  A plain
        record: neither derived later nor resampled."""
        rec = object.__new__(type(self))
        rec.__dict__.update(self.__getstate__(), **arrays)
        return rec

    def __getattr__(self, name):  # only called for attributes not yet set: the deferred arrays
        derive = self.__dict__.get("_derive")
        if name not in _DERIVED or derive is None:
            raise AttributeError(name)
        self.__dict__.update(derive())
        del self.__dict__["_derive"]
        return self.__dict__[name]

    def __getstate__(self):  # pickled (e.g. sent to another process) with its arrays, not its source
        for name in _DERIVED:
            getattr(self, name)
        return {k: v for k, v in self.__dict__.items() if k not in ("_derive", "_resample")}
