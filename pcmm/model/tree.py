"""A tree without loops or drives: its state is ``y = [q, v]`` and its accelerations one ``aba``
call (or the compiled right-hand side, :mod:`pcmm.model.compiled`); satisfies
:class:`~pcmm.model.coordinates.Coordinates`."""
from __future__ import annotations

import contextlib
import copy
import threading

import numpy as np
import pinocchio as pin

from . import compiled
from .configuration import Configuration


class TreeCoordinates:
    """A tree with no loops and no drives: ``y = [q, v]``, accelerations by ABA
    (satisfies :class:`~pcmm.coordinates.Coordinates`)."""

    constrained = False
    position_noise = 0.0  # coordinates are the integrator's own

    def __init__(self, cfg: Configuration):
        self.cfg = cfg
        self.nv = cfg.nv
        self.ny = 2 * cfg.nv
        self.labels: list[str] = []
        self._segment_forces = None  # a reader's own force elements (restored); None: the configuration's
        self._flight_tree = None  # (thread, force elements, compiled tree or None) last used by rhs_with_power
        self.rhs = self._make_rhs()

    @property
    def forces(self):
        """The force elements every evaluation applies: a segment reader's own (:meth:`restored`,
        a value: the run may compile the configuration's again meanwhile), else ``cfg.forces``."""
        return self.cfg.forces if self._segment_forces is None else self._segment_forces

    def _make_rhs(self):
        """The right-hand side as a closure over prebound names: per call one
        matrix-vector product for the force elements (into a buffer the closure
        owns: ``aba`` reads it and returns a new array), one ``aba`` and one new
        array out (integrators keep the arrays they are given); no Python
        attribute look-ups or planar conversions unless needed."""
        cfg, nv, forces = self.cfg, self.nv, self.forces
        self.evaluations = "python: not compiled: " + (
            "nothing to integrate" if nv == 0 else "point springs" if forces.points is not None else "a planar joint")
        if nv == 0:
            return lambda t, y: y
        model, data, aba = cfg.model, cfg.data, pin.aba
        Q0, KD = forces.Q0, forces.KD
        tau = np.empty(nv)
        dot, subtract, concatenate = np.dot, np.subtract, np.concatenate
        if forces.points is not None:  # point springs: their Jacobians at every evaluation
            to_pin, qdot, points = cfg.to_pin, cfg.qdot, forces.points

            def rhs_points(t, y):
                q, v = y[:nv], y[nv:]
                return concatenate((qdot(q, v), aba(model, data, to_pin(q), v,
                                                    subtract(Q0, dot(KD, y), tau) + points.generalized(q, v))))
            return rhs_points
        if cfg.has_planar:
            to_pin, qdot = cfg.to_pin, cfg.qdot

            def rhs_planar(t, y):
                q, v = y[:nv], y[nv:]
                return concatenate((qdot(q, v), aba(model, data, to_pin(q), v, subtract(Q0, dot(KD, y, tau), tau))))
            return rhs_planar

        def rhs(t, y):
            v = y[nv:]
            return concatenate((v, aba(model, data, y[:nv], v, subtract(Q0, dot(KD, y, tau), tau))))
        fast = compiled.tree_rhs(model, Q0, KD, rhs)
        self.evaluations = "compiled" if fast else f"python: {compiled.why_not()}"
        if fast:  # its flights (rhs_with_power) too, in the compiled loop: registered before the first one
            compiled._register_segment_loop(TreeCoordinates, _flight_segment_loop)
        return fast or rhs

    def forces_changed(self):
        """The right-hand side holds the force elements' Q0 and KD: built again."""
        self.rhs = self._make_rhs()

    # -- re-reading an accepted segment (a trajectory's lazy series)
    def frozen_state(self) -> dict:
        """A tree's segment needs nothing kept: its state is its coordinates."""
        return {}

    @contextlib.contextmanager
    def restored(self, frozen: dict, q_start, steps=None, forces=None):
        """A tree reads every state alone: itself, unchanged; with ``forces`` (the segment's own
        force elements, as a value) a copy that applies those."""
        if forces is None:
            yield self
            return
        reader = copy.copy(self)
        reader._segment_forces = forces
        yield reader

    def fresh_rhs(self):
        """A right-hand side on the calling thread's data (the closure holds the data of the
        thread it was built in: :meth:`Configuration.workspace`)."""
        return self._make_rhs()

    def pack(self, t, q, v):
        return np.concatenate([q, v])

    def unpack(self, t, y):
        return y[:self.nv], y[self.nv:]

    def state_entry(self, j: int) -> tuple[int, int]:
        """Where coordinate ``j`` and its rate sit in the state: ``y = [q, v]``."""
        return j, self.nv + j

    def unpack_many(self, ts, ys):
        """``(q, v)`` at many states at once (one column each)."""
        return ys[:self.nv], ys[self.nv:2 * self.nv]

    def derivative(self, t, q, v, extra):
        """State derivative at a full (q, v) with an extra generalized force (contact laws)."""
        cfg = self.cfg
        tau = self.forces.generalized(q, v) + extra
        return np.concatenate([cfg.qdot(q, v), pin.aba(cfg.model, cfg.data, cfg.to_pin(q), v, tau)])

    def accelerations(self, t, q, v):
        if self.nv == 0:
            return np.zeros(0), np.zeros(0)
        tau = self.forces.generalized(q, v)
        return pin.aba(self.cfg.model, self.cfg.data, self.cfg.to_pin(q), v, tau), np.zeros(0)

    def rhs_with_power(self, t, y):
        """``y`` is the state with the work so far appended; the state derivative with one more component: the power of the force elements
        (every applied force but gravity, which the potential energy accounts for).  Compiled where
        the right-hand side is (:meth:`_compiled_flight`): a flight between bounces, with a compiled
        segment loop."""
        fast = self._compiled_flight()
        if fast is not None:
            return fast.rhs_with_power(t, y)
        return self._python_rhs_with_power(t, y)

    def _compiled_flight(self):
        """The calling thread's compiled tree of :attr:`forces` (a reader's own included) whose
        ``rhs_with_power`` is :meth:`_python_rhs_with_power`, or None: the Python evaluation runs
        (a planar joint, point springs, nothing to integrate, or :func:`compiled.why_not`)."""
        forces, me = self.forces, threading.get_ident()
        held = self._flight_tree
        if held is not None and held[0] == me and held[1] is forces:
            return held[2]
        tree = None
        if self.nv and not self.cfg.has_planar and forces.points is None:
            tree = compiled.tree_power(self.cfg.model, forces.Q0, forces.KD, self._python_rhs,
                                       self._python_rhs_with_power)
        self._flight_tree = (me, forces, tree)
        return tree

    def _python_rhs(self, t, y):
        """``[q', aba(q, v, tau)]``: the Python right-hand side, the reference :meth:`_compiled_flight` checks."""
        q, v = self.unpack(t, y)
        tau = self.forces.generalized(q, v)
        return np.concatenate([self.cfg.qdot(q, v), pin.aba(self.cfg.model, self.cfg.data, self.cfg.to_pin(q), v, tau)])

    def _python_rhs_with_power(self, t, y):
        q, v = self.unpack(t, y[:-1])
        if self.nv == 0:
            return np.zeros(1)
        tau = self.forces.generalized(q, v)
        a = pin.aba(self.cfg.model, self.cfg.data, self.cfg.to_pin(q), v, tau)
        return np.concatenate([self.cfg.qdot(q, v), a, [tau @ v]])

    def equality(self, t, model, data):
        return np.zeros((0, model.nv))

    def rows(self, t, q, v):
        return np.zeros((0, self.nv)), np.zeros(0)

    redundant = False  # no rows, none redundant (PartitionedCoordinates.solving_rows)
    solving_rows = rows

    def take_notes(self) -> list[str]:
        """Nothing to report: a tree has no rows (see PartitionedCoordinates.take_notes)."""
        return []

    def time_rows(self):
        """``(Phi_q, bias_of)``: a tree has no rows (see PartitionedCoordinates.time_rows)."""
        return np.zeros((0, self.nv)), lambda t: np.zeros(0)

    def residual(self, t, q) -> float:
        return 0.0

    def project(self, t, q, v, prefer_independent=()):
        return q, v

    def seed(self, q):
        """Set the guess for the dependent coordinates (nothing to do in a tree)."""

    def guards(self) -> list:
        """A tree needs no guard of its own."""
        return []

    def at_guard(self, guard, t, q):
        raise ValueError("a tree contributes no guard")  # never reached: guards() is empty

    def recording(self):
        """Recording a tree's segment checks nothing that could stop the run."""
        return contextlib.nullcontext()

    def cut_joint_frames(self) -> tuple:
        return ()

    def loop_rows(self, q) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros(0), np.zeros((0, self.cfg.nv))


def _flight_segment_loop(coords: TreeCoordinates, *args, **options):
    """The compiled segment loop of a tree's flight (``rhs_with_power``, registered for
    :data:`pcmm.ode.integrators.SEGMENT_LOOPS`): over the calling thread's compiled tree of its
    force elements; a ValueError where there is none (the integrator then steps in Python)."""
    tree = coords._compiled_flight()
    if tree is None:
        raise ValueError(f"no compiled right-hand side: {compiled.why_not()}")
    return compiled.segment_loop(tree, *args, **options)
