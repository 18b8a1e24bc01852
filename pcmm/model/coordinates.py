"""The contract between a configuration's coordinates and everything that integrates them.

A configuration integrates its dynamics (paper Eq. 1) in a state ``y`` that its
coordinate strategy chooses; the run loop (:func:`pcmm.simulate.simulate`),
the guards, the impulse solver and the contact laws see that strategy only
through :class:`Coordinates`.  Two strategies satisfy it
(:mod:`pcmm.model.constraints`): :class:`~pcmm.model.tree.TreeCoordinates` (a tree,
``y = [q, v]``, one ``aba``) and :class:`~pcmm.model.partitioned.PartitionedCoordinates`
(loops and drives, ``y = [q_I, q'_I]``, the dependent coordinates solved by
Newton at every evaluation).
"""
from __future__ import annotations

from contextlib import AbstractContextManager
from typing import Callable, Protocol, Sequence, runtime_checkable

import numpy as np


@runtime_checkable
class Coordinates(Protocol):
    """How a configuration's state is integrated, assembled and recorded.

    State
        ``pack(t, q, v) -> y`` turns an assembled full state (``q``, ``v``: one entry per
        velocity, see :class:`~pcmm.configuration.Configuration`) into the integrator's
        ``y`` (``ny`` entries) and may choose a new partition there, at the start of a
        segment; ``unpack(t, y) -> (q, v)`` is its inverse along the segment (for a loop it
        solves the dependent coordinates, so ``q`` holds the constraints to the Newton
        tolerance).  ``seed(q)`` gives ``unpack`` its first guess for a segment that
        starts at ``q``.  ``state_entry(j) -> (p, r)`` says where coordinate ``j`` and its rate
        sit in ``y`` (``q_j = y[p]``, ``q'_j = y[r]``), None where they are not entries of it.
    Dynamics
        ``rhs(t, y) -> y'`` is the right-hand side the integrator calls; ``derivative(t,
        q, v, extra)`` is the same with an extra generalized force (a continuous contact
        law); ``rhs_with_power(t, [y, W]) -> [y', P]`` is the right-hand side with the work W of
        the force elements and drives appended to the state (its rate P: the power of every
        applied force but gravity, a drive's motor included), which the run integrates over a
        flight between bounces to audit its energy; ``accelerations(t, q, v) -> (a, lam)`` gives the accelerations and the
        multipliers (one per entry of ``labels``: loop cut joints' reactions and drives'
        moments); ``rows(t, q, v) -> (Phi_q, bias)`` the constraint rows with
        ``Phi_q a + bias = 0``; ``equality(t, model, data)`` the same rows' velocity part
        on another model of the tree (the cut system of an impact).
    Assembly
        ``project(t, q, v, prefer_independent=()) -> (q, v)`` puts a state onto the
        constraints (after a switch or an impulse), keeping the independent coordinates
        and preferring those listed; ``residual(t, q)`` is the constraint violation
        (0 for a tree); ``position_noise`` is how far ``unpack``'s coordinates may sit from
        the exact ones (0 for a tree: its coordinates are the integrator's own), which a
        guard restarted after a bounce must tolerate.
    Guards it contributes
        ``guards()`` lists the terminal guards (:class:`~pcmm.witness.Guard`, action
        ``"repartition"``) the strategy itself needs (a loop's singularity guard: the partition degenerates when the determinant of its
        dependent block changes sign); when one fires at ``(t, q)`` the loop calls
        ``at_guard(guard, t, q)``, which either returns (a new partition is chosen when
        the next segment is packed) or raises :class:`~pcmm.errors.SimulationError`
        (the loop itself is at a singular posture).  Along a segment ``unpack`` may raise
        :class:`~pcmm.errors.Repartition` to restart it with a better partition.
    Recording
        ``frozen_state()`` gives, as values, what an accepted segment was integrated in (a loop's
        partition and anchors) and ``restored(frozen, q_start, steps, forces)`` is a context manager
        that yields a reader of that segment: coordinates in that state, warm-started at ``q_start``,
        along the segment's accepted ``steps = (t, y)`` and applying its force elements ``forces``
        (a value; ``forces`` is what every evaluation applies), leaving these coordinates alone (a
        trajectory's series are computed lazily, possibly in another thread while a run goes on);
        ``fresh_rhs()`` is a right-hand side bound to
        the current data; ``forces_changed()`` rebuilds what holds the configuration's force
        elements after they were compiled again (``cfg.forces``, at an angle offset).  ``recording()`` is a context manager under which an accepted segment is re-read
        for the trajectory (``unpack``, ``accelerations`` and ``residual`` at its steps)
        without the conditioning checks that would stop a run: the segment was already
        accepted.  ``labels`` names the recorded multipliers (``constraint_forces``).
    Impulses
        ``cut_joint_frames()`` gives each loop cut joint's spec and its two point frames
        (empty for a tree), so an impulse can report the loop joints' impulsive reactions;
        ``loop_rows(q) -> (Phi, Phi_q)`` the loop-closure rows alone at a posture (what a check
        of a pose reads; empty for a tree).
    """

    nv: int
    ny: int
    labels: list[str]
    forces: object  # the ForceField every evaluation applies (a segment reader's own, else cfg.forces)
    position_noise: float
    constrained: bool  # constraint rows exist (loops or drives): q' is not simply the state's second half
    evaluations: str  # "compiled" (pcmm.compiled in use) or "python: <why not>"

    def pack(self, t: float, q: np.ndarray, v: np.ndarray) -> np.ndarray: ...

    def unpack(self, t: float, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def unpack_many(self, ts: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None: ...

    def seed(self, q: np.ndarray) -> None: ...

    def state_entry(self, j: int) -> tuple[int, int] | None: ...

    def frozen_state(self) -> dict: ...

    def restored(self, frozen: dict, q_start: np.ndarray, steps: tuple | None = None, forces=None): ...

    def fresh_rhs(self): ...

    def forces_changed(self) -> None: ...

    rhs: Callable[[float, np.ndarray], np.ndarray]

    def derivative(self, t: float, q: np.ndarray, v: np.ndarray, extra: np.ndarray) -> np.ndarray: ...

    def rhs_with_power(self, t: float, y: np.ndarray) -> np.ndarray: ...

    def accelerations(self, t: float, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def rows(self, t: float, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    #: the motion is solved with a maximal independent subset of dependent rows (redundant but consistent)
    redundant: bool

    def solving_rows(self, t: float, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def take_notes(self) -> list[str]: ...

    def time_rows(self) -> tuple[np.ndarray, Callable[[float], np.ndarray]] | None: ...

    def equality(self, t: float, model, data) -> np.ndarray: ...

    def project(self, t: float, q: np.ndarray, v: np.ndarray,
                prefer_independent: Sequence[int] = ()) -> tuple[np.ndarray, np.ndarray]: ...

    def residual(self, t: float, q: np.ndarray) -> float: ...

    def guards(self) -> list[Callable]: ...

    def at_guard(self, guard: Callable, t: float, q: np.ndarray) -> None: ...

    def recording(self) -> AbstractContextManager: ...

    def cut_joint_frames(self) -> tuple: ...

    def loop_rows(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...
