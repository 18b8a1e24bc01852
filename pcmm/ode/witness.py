"""The guard type: a witness function of the integrator's state.

A :class:`Guard` is what Drake calls a witness function: a scalar of the state whose
crossing of zero, in its ``direction``, fires something in the paper's Fig. 3 loop.  It
carries what it watches (``description``), its value and (where it has one) its rate read
from the state, and the ``action`` the loop takes when it fires:

* ``"transition"``: the scene transition ``transition`` (a latch, a stop, a release) fires;
* ``"unmerge"``: a stop-merge held by compression only would have to pull (``payload`` is
  the merge); the bodies separate with no impulse;
* ``"lift-off"``: a point held by compression only (a cut joint with a contact normal) would
  have to pull (``payload`` is (the cut joint, the configuration without it)); it is freed with
  no impulse;
* ``"separation"``: a collision resolved by a continuous contact law ends (the gap reopens);
* ``"repartition"``: a loop's partition of its coordinates degenerates (a new one is chosen,
  or the loop is at a singular posture).

The integrators read the value by calling the guard, ``terminal`` and ``direction`` (scipy's
event convention), and ``rate(t, y, f)`` for their graze test where it is given; ``affine``
declares a guard linear in the state (a tree's joint-angle and stop guards, time guards), which a
compiled segment loop then scans without calling back into Python.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

ACTIONS = ("transition", "unmerge", "lift-off", "separation", "repartition")


@dataclass(eq=False)
class Guard:
    description: str
    value: Callable[[float, np.ndarray], float]
    direction: int  # +1: fires when rising through zero, -1: falling, 0: either
    action: str = "transition"
    transition: Any = None  # the scene's TransitionSpec it fires ("transition", "unmerge")
    rate: Callable[[float, np.ndarray, np.ndarray | None], float] | None = None
    rate_from_state: bool = False  # the rate needs no state derivative (the graze test is cheap)
    payload: Any = None  # what the action needs ("unmerge": the merge it watches; "lift-off": (cut joint, target))
    terminal: bool = True
    #: optional: the values at many states at once, ``many(ts, ys) -> list`` (ys one column per
    #: time), equal to ``value`` state by state to the bit, or None where it cannot say; an
    #: event grid reads it (:func:`pcmm.ode.integrators._locate`)
    many: Callable[[np.ndarray, np.ndarray], list | None] | None = None
    # (c, ct, d) where the value is affine in the state, g = c . y + ct t + d exactly (c None: no
    # state term; c shorter than the state: its first len(c) entries), so its rate along the flow is
    # c . y' + ct: a compiled segment loop scans it itself
    affine: tuple | None = None
    #: optional: the value and the rate as linear forms of the state, ``(c, ct, d, r, rt, rearm, unfired)``:
    #: g = c . y + ct t + d and g' = r . y + rt over the first ``len(c)`` components of y (float64
    #: arrays), exactly as ``value`` and ``rate`` compute them; ``rearm``: read as a re-armed guard
    #: (held at ``-direction unfired`` until its rate approaches the fired side).  The compiled
    #: locator reads it (:func:`pcmm.ode.integrators._locate`, pcmm/model/_locate.hpp)
    linear: tuple | None = None
    # (compiled holding forces, index, offset) where the value is that compiled evaluator's holding force
    # ``index`` at the state minus ``offset`` (pcmm.events.holding.guard_value), with no rate of its own:
    # a compiled segment loop scans it itself (its rate by pcmm.ode.integrators._rate's forward difference)
    holding: tuple | None = None
    # a closed loop's guard read from the loop's solution (q, q') at the state, which a compiled segment
    # loop over the loop scans itself: ("coordinate", c, d, unfired): c . q + d, rate c . q' (unfired > 0:
    # re-armed after a bounce, held at that distance on its unfired side until it approaches); ("singularity",):
    # the scaled determinant of the partition's dependent block (PartitionedCoordinates.singularity_guard)
    loop_scan: tuple | None = None
    #: optional: ``(description, rearm, unfired)`` where a compiled evaluator reads the value and the rate at
    #: a state (pcmm/model/_guard_eval.hpp: a tree's contact gap, ``("gap", ...)``), as ``value`` and ``rate``
    #: compute them (checked at probe states), re-armed or plain as ``linear``'s: a compiled segment loop scans
    #: it and the compiled locator locates it (:func:`pcmm.ode.integrators._locate`)
    evaluator: tuple | None = None

    def __post_init__(self):
        if self.action not in ACTIONS:
            raise ValueError(f"guard action {self.action!r}: must be one of {', '.join(ACTIONS)}")

    def __call__(self, t: float, y: np.ndarray) -> float:
        return self.value(t, y)

    def on_state(self, n: int) -> "Guard":
        """This guard read on the first ``n`` components of a longer state (an integrated
        quantity appended to it: a flight's work, a contact law's impulse), its rate too."""
        value, rate, many = self.value, self.rate, self.many
        # still affine (c . y over the state's first len(c) entries: a compiled loop reads it with zeros
        # beside), and a holding guard reads the state's first entries itself (its compiled state map).
        # Every other field as it is: a copy of the fields, not dataclasses.replace (which rebuilds the
        # guard through __init__ and its check, at every flight's every guard)
        out = object.__new__(Guard)
        out.__dict__.update(self.__dict__)
        out.value = lambda t, y: value(t, y[:n])
        out.rate = None if rate is None else (lambda t, y, f: rate(t, y[:n], None if f is None else f[:n]))
        out.many = None if many is None else (lambda ts, ys: many(ts, ys[:n]))
        return out
