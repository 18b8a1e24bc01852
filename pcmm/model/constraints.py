"""Closed loops and driven coordinates: constraints on a configuration's tree.

A scene names the joints that close loops (``cut_joints``); the URDF holds
the spanning tree.  Each cut joint gives planar rows from frame Jacobians:

* revolute: 2 rows, ``p_b - p_a = 0`` (world x, y);
* prismatic: 2 rows, ``n . (p_b - p_a) = 0`` (n normal to the axis, fixed in a)
  and ``theta_b - theta_a = angle``;
* weld: 3 rows, the point rows and the angle row.

A driven joint adds the rheonomic row ``q_j - f(t) = 0``.  The multipliers
are the cut joints' reaction forces (on b, world axes) and the motor's moment.

Integration uses generalized coordinate partitioning: the state is the
independent coordinates ``y = [q_I, v_I]``, the dependent ones are solved from
the constraints at every evaluation (Newton, warm-started), so loops stay closed
to the Newton tolerance instead of drifting.  A tree without loops or drives
uses :class:`TreeCoordinates`, a plain ``y = [q, v]`` and one ``aba`` call.
"""
from __future__ import annotations

import contextlib
import functools
import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin
import scipy.linalg as sla
from scipy.linalg.lapack import dgesv

from . import compiled
from .configuration import Configuration
from ..errors import Repartition, SimulationError
from .pinocchio_helpers import LWA, frame_jacobian
from ..scene.spec import CutJointSpec
from ..ode.witness import Guard

NEWTON_TOL = 1e-13
SINGULAR_COND = 1e9


def _perp(n):
    return np.array([-n[1], n[0]])


@dataclass(frozen=True)
class ClosureRows:
    """Point frames and link frames of one configuration's cut joints."""

    specs: tuple[CutJointSpec, ...]
    frames_a: tuple[int, ...]
    frames_b: tuple[int, ...]
    links_a: tuple[int, ...]
    links_b: tuple[int, ...]
    #: {index of a cut joint anchored at entry: its anchor A (world)}: the rows are p_b - p_a - A, set
    #: when the run enters the configuration (:meth:`set_anchors`); a property of the instance, not of
    #: the model (no frame is registered for A)
    anchors: dict = field(default_factory=dict, compare=False)

    @property
    def anchored(self) -> tuple[int, ...]:
        return tuple(k for k, s in enumerate(self.specs) if s.anchor_at_entry)

    def set_anchors(self, data, keep: dict | None = None) -> dict[str, np.ndarray]:
        """Anchor every cut joint anchored at entry where b's point is now (frame placements must be
        computed on ``data``), except those in ``keep`` ({name: A}, e.g. still held from the source).
        Returns {name: A}."""
        keep = keep or {}
        out = {}
        for k in self.anchored:
            s = self.specs[k]
            A = np.asarray(keep[s.name], float).copy() if s.name in keep else \
                data.oMf[self.frames_b[k]].translation[:2] - data.oMf[self.frames_a[k]].translation[:2]
            self.anchors[k] = A
            out[s.name] = A
        return out

    def anchor_of(self, name: str) -> np.ndarray | None:
        for k, s in enumerate(self.specs):
            if s.name == name and k in self.anchors:
                return self.anchors[k]
        return None

    @property
    def size(self) -> int:
        return sum({"revolute": 2, "prismatic": 2, "weld": 3}[s.type] for s in self.specs)

    @functools.cached_property
    def revolute_only(self) -> bool:
        """Only point rows (``p_b - p_a = 0``): the lean evaluations below apply."""
        return all(s.type == "revolute" for s in self.specs)

    def point_rows(self, model, data):
        """(Phi, Phi_q) of revolute cut joints only; placements, frame placements and joint
        Jacobians must be computed on ``data``."""
        nv, get, LWA_, oMf = model.nv, pin.getFrameJacobian, LWA, data.oMf
        phi = np.empty(2 * len(self.specs))
        rows = np.empty((2 * len(self.specs), nv))
        for k, (fa, fb) in enumerate(zip(self.frames_a, self.frames_b)):
            phi[2 * k:2 * k + 2] = oMf[fb].translation[:2] - oMf[fa].translation[:2]
            if k in self.anchors:
                phi[2 * k:2 * k + 2] -= self.anchors[k]
            Jb, Ja = get(model, data, fb, LWA_), get(model, data, fa, LWA_)
            if nv == 1:  # eigenpy returns a 1-D array for one column
                Jb, Ja = Jb.reshape(6, 1), Ja.reshape(6, 1)
            np.subtract(Jb[:2], Ja[:2], out=rows[2 * k:2 * k + 2])
        return phi, rows

    def point_bias(self, model, data) -> np.ndarray:
        """``d2Phi/dt2`` at zero acceleration for revolute cut joints only; placements,
        velocities and accelerations (at a = 0) must be computed on ``data`` (no frame
        placements or Jacobians needed: a frame's classical acceleration comes from its joint's)."""
        acc = pin.getFrameClassicalAcceleration
        out = np.empty(2 * len(self.specs))
        for k, (fa, fb) in enumerate(zip(self.frames_a, self.frames_b)):
            out[2 * k:2 * k + 2] = acc(model, data, fb, LWA).linear[:2] - acc(model, data, fa, LWA).linear[:2]
        return out

    def labels(self) -> list[str]:
        out = []
        for s in self.specs:
            out += {"revolute": [f"{s.name}.fx", f"{s.name}.fy"],
                    "prismatic": [f"{s.name}.fn", f"{s.name}.mz"],
                    "weld": [f"{s.name}.fx", f"{s.name}.fy", f"{s.name}.mz"]}[s.type]
        return out

    def evaluate(self, model, data, need_bias: bool):
        """(Phi, Phi_q, bias) with ``Phi_q a + bias = d2Phi/dt2``; kinematics (and,
        for the bias, accelerations at a = 0) must be computed on ``data``."""
        phi, rows, bias = [], [], []
        for k, (s, fa, fb, la, lb) in enumerate(zip(self.specs, self.frames_a, self.frames_b, self.links_a, self.links_b)):
            pa, pb = data.oMf[fa].translation[:2], data.oMf[fb].translation[:2]
            if k in self.anchors:
                pa = pa + self.anchors[k]
            Ja = frame_jacobian(model, data, fa)
            Jb = frame_jacobian(model, data, fb)
            Jrel = Jb[:2] - Ja[:2]
            Ra = data.oMf[la].rotation
            th_a = math.atan2(Ra[1, 0], Ra[0, 0])
            Rb = data.oMf[lb].rotation
            th_rel = math.atan2(Rb[1, 0], Rb[0, 0]) - th_a
            Jang = Jb[5] - Ja[5]
            if need_bias:
                acc_a = pin.getFrameClassicalAcceleration(model, data, fa, LWA).linear[:2]
                acc_b = pin.getFrameClassicalAcceleration(model, data, fb, LWA).linear[:2]
                acc_rel = acc_b - acc_a
            if s.type in ("revolute", "weld"):
                phi += list(pb - pa)
                rows += [Jrel[0], Jrel[1]]
                if need_bias:
                    bias += list(acc_rel)
            if s.type == "prismatic":
                n = Ra[:2, :2] @ _perp(np.asarray(s.axis) / np.linalg.norm(s.axis))
                t = _perp(n)
                r = pb - pa
                w_a = pin.getFrameVelocity(model, data, fa, LWA).angular[2]
                rdot = pin.getFrameVelocity(model, data, fb, LWA).linear[:2] \
                    - pin.getFrameVelocity(model, data, fa, LWA).linear[:2]
                phi.append(n @ r)
                rows.append(n @ Jrel + (t @ r) * Ja[5])
                if need_bias:
                    bias.append(-w_a ** 2 * (n @ r) + 2 * w_a * (t @ rdot) + n @ acc_rel)
            if s.type in ("prismatic", "weld"):
                phi.append(math.atan2(math.sin(th_rel - s.angle), math.cos(th_rel - s.angle)))
                rows.append(Jang)
                if need_bias:
                    bias.append(0.0)
        nv = model.nv
        return (np.array(phi), np.array(rows).reshape(len(rows), nv),
                np.array(bias) if need_bias else None)


@dataclass(frozen=True)
class Drives:
    """Prescribed coordinates q_j = f_j(t), polynomials in t."""

    joints: tuple[str, ...]
    index: tuple[int, ...]
    coefficients: tuple[np.ndarray, ...]

    def __post_init__(self):
        # coefficients of f, f', f'' (low order first), evaluated by Horner's rule
        derivs = []
        for c in self.coefficients:
            c0 = [float(x) for x in c]
            c1 = [k * c0[k] for k in range(1, len(c0))] or [0.0]
            c2 = [k * c1[k] for k in range(1, len(c1))] or [0.0]
            derivs.append((c0, c1, c2))
        object.__setattr__(self, "_derivs", tuple(derivs))

    @property
    def size(self) -> int:
        return len(self.joints)

    def values(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(f, f', f'') at ``t``; the last time asked is remembered (a right-hand side asks for all
        three at one time, several times)."""
        last = self.__dict__.get("_last")
        if last is None or last[0] != t:
            last = (t, (self.value(t), self.value(t, 1), self.value(t, 2)))
            object.__setattr__(self, "_last", last)
        return last[1]

    def value(self, t, order=0) -> np.ndarray:
        out = np.empty(len(self.joints))
        for i, d in enumerate(self._derivs):
            acc = 0.0
            for c in reversed(d[order]):
                acc = acc * t + c
            out[i] = acc
        return out


#: the largest change (rad or m) the warm start of a loop's Newton solve is extrapolated by
PREDICT_MAX = 0.05


def _max_abs(x: np.ndarray) -> float:
    """``max |x_i|`` of a short vector (0 when empty), from Python floats: a fifth of the cost of
    numpy's ``max(abs(x))`` on a loop's few residuals, which every Newton iteration tests.  A
    vector whose sum is not finite (a NaN, an inf, or an overflow) is left to numpy, whose
    ``max`` propagates a NaN where Python's would skip it."""
    xs = x.tolist()
    if not xs:
        return 0.0
    if not math.isfinite(sum(xs)):
        return float(np.max(np.abs(x)))
    return max(map(abs, xs))


def solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.solve`` for the small dense systems of a loop, by LAPACK's dgesv directly
    (numpy's wrapper costs four times the solve at this size); LinAlgError when A is singular."""
    if A.ndim != 2 or A.shape[0] != A.shape[1] or A.shape[0] != b.shape[0]:
        raise np.linalg.LinAlgError(f"a {A.shape} system with a {b.shape} right-hand side is not square")
    if A.size == 0:
        return np.zeros(b.shape)
    _, _, x, info = dgesv(A, b)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular matrix (dgesv info {info})" if info > 0 else
                                    f"dgesv rejected argument {-info}")
    return x


def _det(A: np.ndarray) -> float:
    """Determinant of a small square block: by cofactors up to 3 x 3 (numpy's det costs ten
    times these few products from Python), by LU above."""
    n = A.shape[0]
    if n == 0:
        return 1.0
    if n == 1:
        return float(A[0, 0])
    if n == 2:
        return float(A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0])
    if n == 3:
        (a, b, c), (d, e, f), (g, h, i) = A.tolist()
        return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    return float(np.linalg.det(A))


@functools.lru_cache(maxsize=None)
def _strictly_lower(n: int) -> np.ndarray:
    return np.tril(np.ones((n, n), dtype=bool), -1)


def constrained_accelerations(cfg: Configuration, q, v, J, bias, extra=None):
    """Solve ``M a + h = Q + J^T lam``, ``J a + bias = 0`` (the multipliers are the
    constraint forces: cut-joint reactions on b, driving moments, contact forces).

    Pinocchio's ``forwardDynamics`` with the constraint rows solves the KKT system
    ``[M J^T; J 0] [a; -lam] = [Q - h; -bias]`` in one call (2.7 us for Example 2's loop, where
    the same Schur complement from Python cost 11 us).  Where it fails (a Cholesky of a
    rank-deficient ``J M^-1 J^T``: redundant rows) or answers a non-finite value, the Schur
    complement on Pinocchio's O(n) algorithms decides, and raises numpy's ``LinAlgError`` for a
    singular system: the free acceleration ``a0 = M^-1 (Q - h)`` is one ``aba``, ``M^-1`` one
    ``computeMinverse``; then ``(J M^-1 J^T) lam = -bias - J a0`` and ``a = a0 + M^-1 J^T lam``.
    (The mass matrix is positive definite: the URDF check demands mass and a positive-definite
    inertia of every moving link.)"""
    if cfg.nv == 0:
        return np.zeros(0), np.zeros(J.shape[0])
    qp = cfg.to_pin(q)
    tau = cfg.forces.generalized(q, v)
    if extra is not None:
        tau = tau + extra
    if J.shape[0] == 0:
        return pin.aba(cfg.model, cfg.data, qp, v, tau), np.zeros(0)
    try:
        a = pin.forwardDynamics(cfg.model, cfg.data, qp, v, tau, J, bias)
        lam = cfg.data.lambda_c.copy()
        if math.isfinite(sum(a.tolist()) + sum(lam.tolist())):
            return a, lam
    except RuntimeError:
        pass
    a0 = pin.aba(cfg.model, cfg.data, qp, v, tau)
    Minv = pin.computeMinverse(cfg.model, cfg.data, qp)
    Minv = np.where(_strictly_lower(cfg.nv), Minv.T, Minv)  # Pinocchio's C++ fills the upper triangle
    MiJt = Minv @ J.T
    lam = solve(J @ MiJt, -bias - J @ a0)
    return a0 + MiJt @ lam, lam


class _Replayable:
    """What both coordinate strategies share for a trajectory's lazy series: the state of an
    accepted segment (its partition) kept, and restored around a later re-reading of it."""

    def frozen_state(self) -> dict:
        """The partition a segment is integrated in, and the anchors of its cut joints anchored at
        entry (a configuration entered again later holds its point elsewhere), restored by
        :meth:`restored`."""
        out = {"I": getattr(self, "I", None), "D": getattr(self, "D", None), "ny": getattr(self, "ny", None)}
        closure = getattr(self, "closure", None)
        if closure is not None and closure.anchors:
            out["anchors"] = {k: np.array(a, float) for k, a in closure.anchors.items()}
        return out

    @contextlib.contextmanager
    def restored(self, frozen: dict, q_start, steps=None):
        """Re-read an accepted segment: its partition, its anchors, its warm start, no conditioning
        checks; everything as it was afterwards.  ``steps = (t, y)`` are the segment's accepted
        steps: a loop's Newton solves then start from the step at or before the instant asked for
        (:meth:`PartitionedCoordinates._follow`), however far it lies from the last one solved."""
        saved = dict(self.__dict__)
        anchors = frozen.get("anchors")
        saved_anchors = dict(self.closure.anchors) if anchors is not None else None
        self.__dict__.update({k: x for k, x in frozen.items() if k != "anchors"})
        if anchors is not None:
            self.closure.anchors.clear()
            self.closure.anchors.update(anchors)
        self.seed(q_start)
        if steps is not None and hasattr(self, "_trail"):
            self._trail = (np.asarray(steps[0], float), np.asarray(steps[1], float)[:self.ny])
            self._reached = {0: None}  # the start: seed's q_start
        self.checking = False
        try:
            yield self
        finally:
            self.__dict__.clear()
            self.__dict__.update(saved)
            if saved_anchors is not None:
                self.closure.anchors.clear()
                self.closure.anchors.update(saved_anchors)

    def fresh_rhs(self):
        """A right-hand side bound to the configuration's current data (the tree's closure holds
        the data it was built with)."""
        return self._make_rhs() if hasattr(self, "_make_rhs") else self.rhs


class TreeCoordinates(_Replayable):
    """A tree with no loops and no drives: ``y = [q, v]``, accelerations by ABA
    (satisfies :class:`~pcmm.coordinates.Coordinates`)."""

    constrained = False
    position_noise = 0.0  # coordinates are the integrator's own

    def __init__(self, cfg: Configuration):
        self.cfg = cfg
        self.nv = cfg.nv
        self.ny = 2 * cfg.nv
        self.labels: list[str] = []
        self.rhs = self._make_rhs()

    def _make_rhs(self):
        """The right-hand side as a closure over prebound names: per call one
        matrix-vector product for the force elements (into a buffer the closure
        owns: ``aba`` reads it and returns a new array), one ``aba`` and one new
        array out (integrators keep the arrays they are given); no Python
        attribute look-ups or planar conversions unless needed."""
        cfg, nv = self.cfg, self.nv
        self.evaluations = "python: not compiled: " + (
            "nothing to integrate" if nv == 0 else "point springs" if cfg.forces.points is not None else "a planar joint")
        if nv == 0:
            return lambda t, y: y
        model, data, aba = cfg.model, cfg.data, pin.aba
        Q0, KD = cfg.forces.Q0, cfg.forces.KD
        tau = np.empty(nv)
        dot, subtract, concatenate = np.dot, np.subtract, np.concatenate
        if cfg.forces.points is not None:  # point springs: their Jacobians at every evaluation
            to_pin, qdot, points = cfg.to_pin, cfg.qdot, cfg.forces.points

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
        return fast or rhs

    def forces_changed(self):
        """The right-hand side holds the force elements' Q0 and KD: built again."""
        self.rhs = self._make_rhs()

    def pack(self, t, q, v):
        return np.concatenate([q, v])

    def unpack(self, t, y):
        return y[:self.nv], y[self.nv:]

    def derivative(self, t, q, v, extra):
        """State derivative at a full (q, v) with an extra generalized force (contact laws)."""
        cfg = self.cfg
        tau = cfg.forces.generalized(q, v) + extra
        return np.concatenate([cfg.qdot(q, v), pin.aba(cfg.model, cfg.data, cfg.to_pin(q), v, tau)])

    def accelerations(self, t, q, v):
        if self.nv == 0:
            return np.zeros(0), np.zeros(0)
        tau = self.cfg.forces.generalized(q, v)
        return pin.aba(self.cfg.model, self.cfg.data, self.cfg.to_pin(q), v, tau), np.zeros(0)

    def rhs_with_power(self, t, y):
        """``y`` is the state with the work so far appended; the state derivative with one more component: the power of the force elements
        (every applied force but gravity, which the potential energy accounts for)."""
        q, v = self.unpack(t, y[:-1])
        if self.nv == 0:
            return np.zeros(1)
        tau = self.cfg.forces.generalized(q, v)
        a = pin.aba(self.cfg.model, self.cfg.data, self.cfg.to_pin(q), v, tau)
        return np.concatenate([self.cfg.qdot(q, v), a, [tau @ v]])

    def equality(self, t, model, data):
        return np.zeros((0, model.nv))

    def rows(self, t, q, v):
        return np.zeros((0, self.nv)), np.zeros(0)

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


class PartitionedCoordinates(_Replayable):
    """Loops and/or drives: independent coordinates and their rates ``y = [q_I, q'_I]``
    (satisfies :class:`~pcmm.coordinates.Coordinates`).  ``q'`` is ``v`` but for a planar joint's
    (x', y'), which are world-frame where its ``v`` is body-frame (:meth:`Configuration.qdot`): the
    dependent positions and rates then solve one block, ``dPhi/dq`` at the posture."""

    constrained = True
    position_noise = 4 * np.finfo(float).eps  # dependent coordinates: Newton plus one polishing step

    def __init__(self, cfg: Configuration, closure: ClosureRows, drives: Drives):
        self.cfg = cfg
        self.closure = closure
        self.drives = drives
        self.nv = cfg.nv
        self.m = closure.size + drives.size
        self.labels = closure.labels() + [f"{j}.drive" for j in drives.joints]
        self.I = None
        self.D = None
        self.ny = 0  # 2 len(I), set with the partition (pack, project)
        self._qD = None
        self._recent: list[tuple[float, np.ndarray]] = []
        # a re-read segment's accepted steps (t, y) and the solutions reached along them, by step
        # (restored, _follow); None while integrating
        self._trail = None
        self._reached: dict[int, tuple | None] = {}
        self._zeros = np.zeros(self.nv)
        self.checking = True  # conditioning checks (off while recording an accepted segment)
        self._cache = None  # the last unpack: guards and the right-hand side ask for the same point
        self.max_residual = 0.0  # largest loop residual a Newton solve accepted (the recorded drift's bound)
        self._driven = np.array(drives.index, dtype=int)
        self._drive_rows = np.zeros((drives.size, self.nv))
        self._drive_rows[np.arange(drives.size), self._driven] = 1.0
        # revolute cut joints' rows in one compiled call where that is the same function (pcmm.compiled)
        if not closure.specs:
            fast, why = None, "not compiled: drives only"
        elif cfg.has_planar or not closure.revolute_only or closure.anchored:
            fast, why = None, "not compiled: " + ("a planar joint" if cfg.has_planar else "a cut joint anchored at entry"
                                                  if closure.anchored else "prismatic or weld cut joints")
        else:
            fast = compiled.closure_kinematics(cfg.model, closure.frames_a, closure.frames_b,
                                               self._python_point_rows, self._python_point_rows_and_bias)
            why = compiled.why_not() or "not compiled"
        self._point_rows = fast.point_rows if fast else self._python_point_rows
        self._point_rows_and_bias_at = fast.point_rows_and_bias if fast else self._python_point_rows_and_bias
        self.evaluations = "compiled" if fast else f"python: {why}"

    def forces_changed(self):
        """Nothing to rebuild: every evaluation reads ``cfg.forces``."""

    # -- constraint evaluation on the tree
    def _kinematics(self, qp, v=None) -> None:
        """One kinematics pass on the configuration's data through the Python binding: frame
        placements and joint Jacobians at ``qp``, and with ``v`` also the velocities and the
        accelerations at a = 0 (what the bias terms read), the Jacobians taken from them."""
        cfg = self.cfg
        if v is None:
            pin.computeJointJacobians(cfg.model, cfg.data, qp)  # computes the placements itself
        else:
            pin.forwardKinematics(cfg.model, cfg.data, qp, v, self._zeros)
            pin.computeJointJacobians(cfg.model, cfg.data)
        pin.updateFramePlacements(cfg.model, cfg.data)

    def _python_point_rows(self, qp):
        """(Phi, Phi_q) of revolute cut joints at Pinocchio's ``qp``, through the Python binding."""
        self._kinematics(qp)
        return self.closure.point_rows(self.cfg.model, self.cfg.data)

    def _python_point_rows_and_bias(self, qp, v):
        """(Phi_q, bias) of revolute cut joints at (``qp``, v) in one kinematics pass."""
        self._kinematics(qp, v)
        cfg = self.cfg
        _, Jq = self.closure.point_rows(cfg.model, cfg.data)
        return Jq, self.closure.point_bias(cfg.model, cfg.data)

    def _phi(self, t, q, need_bias=False, v=None):
        cfg = self.cfg
        qp = cfg.to_pin(q)
        if self.closure.revolute_only and not need_bias:
            phi, Jq = self._point_rows(qp)
            bias = None
        else:
            self._kinematics(qp, v if need_bias else None)
            phi, Jq, bias = self.closure.evaluate(cfg.model, cfg.data, need_bias)
        if self.drives.size:  # the rheonomic rows q_j - f_j(t): their Jacobian rows are constant
            f, _, f2 = self.drives.values(t)
            phi = np.concatenate((phi, q[self._driven] - f))
            Jq = np.concatenate((Jq, self._drive_rows))
            if need_bias:
                bias = np.concatenate((bias, -f2))
        return phi, Jq, bias

    def _point_rows_and_bias(self, t, q, v):
        """(Phi_q, bias) of revolute cut joints and drives at an assembled (q, v) in one kinematics
        pass (placements, velocities and accelerations at a = 0, then the Jacobians from them).
        The rows are taken at the returned q itself, not reused from the Newton solve's last
        iterate: near a change point the last correction is large enough to matter."""
        Jq, bias = self._point_rows_and_bias_at(self.cfg.to_pin(q), v)
        if self.drives.size:
            Jq = np.concatenate((Jq, self._drive_rows))
            bias = np.concatenate((bias, -self.drives.values(t)[2]))
        return Jq, bias

    def _phi_t(self, t):
        """``dPhi/dt``: zero for the loops, minus each drive's rate."""
        out = np.zeros(self.m)
        out[self.closure.size:] = self.drives.values(t)[1]
        return np.negative(out, out=out)

    def equality(self, t, model, data):
        """Velocity rows of all constraints on ``model`` (the tree or its cut system);
        kinematics must be computed on ``data``."""
        _, Jq, _ = self.closure.evaluate(model, data, False)
        if self.drives.size:
            Jd = np.zeros((self.drives.size, model.nv))
            for i, name in enumerate(self.drives.joints):
                Jd[i, model.joints[model.getJointId(name)].idx_v] = 1.0
            Jq = np.vstack([Jq, Jd])
        return Jq

    def _position_rows(self, t, q):
        """``dPhi/dq`` at ``q``: the derivative in pcmm's coordinates that a Newton solve of the
        positions, the partition and its conditioning need (not the velocity Jacobian, whose
        planar-joint columns are in the body frame: :meth:`Configuration.position_jacobian`)."""
        return self.cfg.position_jacobian(q, self._phi(t, q)[1])

    def residual(self, t, q) -> float:
        phi, _, _ = self._phi(t, q)
        return float(np.max(np.abs(phi))) if phi.size else 0.0

    # -- partition
    def partition(self, t, q, prefer_independent=()):
        """Choose dependent coordinates: driven joints, then the best-conditioned
        columns of the loop rows (QR with column pivoting).  Coordinates in
        ``prefer_independent`` are kept independent when the rest allows it."""
        Jq = self._position_rows(t, q)
        self.D = self._best_dependent(Jq, keep=prefer_independent)
        self.I = np.array([i for i in range(self.nv) if i not in self.D], dtype=int)
        self.ny = 2 * len(self.I)
        JD = Jq[:, self.D]
        cond = np.linalg.cond(JD) if JD.size else 1.0
        if not np.isfinite(cond) or cond > SINGULAR_COND:
            raise SimulationError(
                f"configuration '{self.cfg.name}': the constraints are singular at t = {t:.6g} s "
                f"(condition number {cond:.3g}): the loop is at or near a singular posture "
                "(e.g. a slider-crank at dead centre) or the cut joints are redundant")

    def _solve_dependent(self, t, qI, guess):
        """Dependent coordinates closing the loop at ``qI`` (Newton from ``guess``) and the
        constraint Jacobians there: ``(q, Phi_q per unit velocity, dPhi/dq)``.  Newton steps with
        ``dPhi/dq`` (the two differ in a planar joint's columns, which are body-frame in the
        first).

        Once the residual is below NEWTON_TOL one more correction is taken with the Jacobian
        already at hand: Newton converges quadratically, so that step leaves an error of
        order NEWTON_TOL squared, i.e. round-off.  Without it the dependent coordinates carry
        up to 1e-13 of solver noise that depends on the warm start, so the same state gives
        guard values that differ by 1e-13 m from one call to the next; a bounce of 1e-6 m/s
        rises only 5e-14 m, so that noise decided whether a tiny flight was seen at all."""
        q = guess.copy()
        q[self.I] = qI
        position = self.cfg.position_jacobian
        for _ in range(30):
            phi, Jq, _ = self._phi(t, q)
            Jp = position(q, Jq)
            res = _max_abs(phi)
            if res < NEWTON_TOL:
                self.max_residual = max(self.max_residual, res)
                self._check_conditioning(t, Jp)
                if phi.size:  # one more correction with this Jacobian: exact to round-off, whatever the start
                    try:
                        q[self.D] -= solve(Jp[:, self.D], phi)
                    except np.linalg.LinAlgError:
                        pass  # the posture check above has already judged the block
                return q, Jq, Jp
            try:
                q[self.D] -= solve(Jp[:, self.D], phi)
            except np.linalg.LinAlgError:
                break
        phi, Jq, _ = self._phi(t, q)
        Jp = position(q, Jq)
        if np.max(np.abs(phi)) < 1e-9:
            self.max_residual = max(self.max_residual, float(np.max(np.abs(phi))))
            return q, Jq, Jp
        if len(self.I) == 0 and self.drives.size:
            err = SimulationError(
                f"configuration '{self.cfg.name}': the loop cannot be closed at t = {t:.9g} s "
                f"(residual {np.max(np.abs(phi)):.3g}): it has no free coordinate, and its drives "
                f"({', '.join(self.drives.joints)}) prescribe a motion its locked joints cannot follow "
                "(the lock jams the driven loop). A lock that must give way is a release: a stop-merge "
                "with unmerge = true, or a transition of type 'release' before this instant")
        else:
            start = position(guess, self._phi(t, guess)[1])  # near the last posture solved
            cond = self._cond(start)
            err = SimulationError(
                f"configuration '{self.cfg.name}': the loop cannot be closed at t = {t:.9g} s "
                f"(residual {np.max(np.abs(phi)):.3g} after 30 Newton steps; the constraint Jacobian's "
                f"condition number is {cond:.3g} at the warm start, {self._cond(Jp):.3g} at the last "
                "iterate): " + (
                    "the mechanism is at or beyond a singular posture, or the initial state is far from "
                    "an assembled one" if not math.isfinite(cond) or cond > SINGULAR_COND else
                    "the constraints are well conditioned where the solve started, so it started too far "
                    "from the assembly (a pcmm defect: please report it with the scene)"))
        err.at = t  # the instant of the failing solve (a trial instant of a step, for the run loop)
        raise err

    @staticmethod
    def _cond(J) -> float:
        """The condition number of a constraint Jacobian (1 without rows)."""
        return float(np.linalg.cond(J)) if J.size else 1.0

    def _best_dependent(self, Jq, keep=()):
        """Dependent columns for ``Jq``: driven joints, then the best-conditioned columns of the
        loop rows (QR with column pivoting), never one of ``keep``."""
        driven = list(self.drives.index)
        rest = [i for i in range(self.nv) if i not in driven and i not in keep]
        dep = list(driven)
        if self.closure.size:
            _, _, piv = sla.qr(Jq[:self.closure.size][:, rest], pivoting=True)
            dep += [rest[i] for i in piv[:self.closure.size]]
        return np.array(sorted(dep), dtype=int)

    def _scaled_det(self, Jq):
        """det(J_D) / (||J||_F / sqrt(m))^m: signed, continuous, at most 1 in magnitude for any
        number m of rows (Hadamard's bound and the mean of the squared row norms), and small when
        the dependent block degenerates or when the whole Jacobian loses rank (a row scaled by
        its own norm would hide a row that vanishes, as at a change point).  Without the sqrt(m)
        the measure fell as m^(-m/2) with the number of loops: three well-conditioned loops
        already read as singular at t = 0."""
        JD = Jq[:, self.D]
        m = JD.shape[0]
        if JD.shape[0] != JD.shape[1]:
            raise SimulationError(
                f"configuration '{self.cfg.name}': its {m} constraint rows cannot be solved for "
                f"{JD.shape[1]} dependent coordinates: the cut joints are redundant (a cut joint given "
                "twice, or more loops than the tree has joints to close them)")
        flat = Jq.ravel()
        return float(_det(JD) / max((math.sqrt(flat @ flat) / math.sqrt(max(m, 1))) ** m, 1e-300))

    def _check_conditioning(self, t, Jq):
        """A dependent block drifting towards singularity asks for a new partition; when the
        current one is already the best, the loop itself is at a singular posture."""
        if not self.checking:
            return
        ratio = abs(self._scaled_det(Jq))
        if ratio > 1e-4:
            return
        if not np.array_equal(self._best_dependent(Jq), self.D):
            raise Repartition(t)
        raise SimulationError(
            f"configuration '{self.cfg.name}': the loop reaches a singular posture at t = {t:.9g} s "
            f"(its best constraint block has a scaled determinant of {ratio:.2g}): at a dead centre or "
            "change point the motion is not determined by the constraints and drives; pcmm stops "
            "rather than pick a branch")

    def seed(self, q):
        """Start the Newton solve of the dependent coordinates from ``q``."""
        self._qD = q.copy()
        self._recent = []
        self._cache = None

    def _guess(self, t):
        """The warm start for a solve at ``t``: the recent solution nearest in time, carried to
        ``t`` along its own velocity (a first-order prediction: the start is off by O(dt^2)
        rather than O(dt), which saves a Newton iteration in most solves).  Nearest in time
        because an event search goes back and forth within a step; starting from the step's far
        end near a branch point could land on the mirrored assembly and make a guard's value
        depend on the order of the calls."""
        if self._trail is not None:
            near = self._follow(t)
            if near is not None and (not self._recent or abs(near[0] - t) < min(abs(r[0] - t) for r in self._recent)):
                tr, q, qd = near
                step = (t - tr) * qd
                return q + step if _max_abs(step) <= PREDICT_MAX else q
        if not self._recent:
            return self._qD
        tr, q, qd = min(self._recent, key=lambda r: abs(r[0] - t))
        step = (t - tr) * qd
        # a long extrapolation is no better a start than the solution itself (and could carry the
        # start past a branch point): beyond PREDICT_MAX the nearest solution is the start
        return q + step if _max_abs(step) <= PREDICT_MAX else q

    def _follow(self, t):
        """While a segment is re-read (:meth:`restored` with its steps): the solution at the
        accepted step at or before ``t`` (``(t_k, q, q')``), the steps before it solved one after
        the other from the last one reached.  A dense-output instant, a resampled time or a
        saved series may ask for any instant of the segment; a Newton solve started from the
        last instant solved, which may lie several turns of a crank back, lands on another
        assembly or on none (a four-bar's crank 30 rad on: residual 0.45), where one started
        from the neighbouring step converges as it did in the run.  None at the segment's first
        step (its start is the seed) or when ``t`` is the step being solved."""
        ts, ys = self._trail
        k = int(np.searchsorted(ts, t, side="right")) - 1
        if k < len(ts) and k >= 0 and ts[k] == t:
            k -= 1  # that step is the one being solved: start from the one before
        k = min(k, len(ts) - 1)
        if k <= 0:
            return None
        if k not in self._reached:
            start = max(j for j in self._reached if j < k)
            for j in range(start + 1, k + 1):
                if j not in self._reached:
                    self.unpack(ts[j], ys[:, j])  # registers step j (unpack)
        return self._reached.get(k)

    def pack(self, t, q, v):
        """State vector at an assembled (q, v); the partition is re-chosen here,
        at the start of every segment, so it follows the posture."""
        self.partition(t, q)
        self.seed(q)
        return np.concatenate([q[self.I], self.cfg.qdot(q, v)[self.I]])

    def at_degenerate_partition(self, t, q):
        """Where the singularity guard fired: if the whole constraint Jacobian keeps its rank a
        new partition goes on (the next segment picks it); if it loses rank the loop itself is
        at a singular posture (a dead centre, a change point) and the run stops."""
        Jq = self._position_rows(t, q)
        s = np.linalg.svd(Jq, compute_uv=False)
        if s[-1] <= 1e-6 * s[0] or np.array_equal(self._best_dependent(Jq), self.D):
            # rank lost, or no partition does better than the one that degenerated
            raise SimulationError(
                f"configuration '{self.cfg.name}': the loop reaches a singular posture at t = {t:.9g} s "
                f"(constraint Jacobian singular values {s[0]:.3g} ... {s[-1]:.3g}): at a dead centre or "
                "change point the motion is not determined by the constraints and drives; pcmm stops "
                "rather than pick a branch")

    def guards(self) -> list:
        """The singularity guard when there are loops (drives alone never degenerate)."""
        return [self.singularity_guard()] if self.closure.size else []

    def at_guard(self, guard, t, q):
        """The singularity guard fired: a new partition goes on, or the loop is singular (raises)."""
        self.at_degenerate_partition(t, q)

    @contextlib.contextmanager
    def recording(self):
        """No conditioning checks while an accepted segment is re-read for the trajectory."""
        self.checking = False
        try:
            yield
        finally:
            self.checking = True

    def cut_joint_frames(self) -> tuple:
        """(spec, frame of point a, frame of point b) of every loop cut joint."""
        return tuple(zip(self.closure.specs, self.closure.frames_a, self.closure.frames_b))

    def loop_rows(self, q) -> tuple[np.ndarray, np.ndarray]:
        """``(Phi, Phi_q)`` of the loop-closure rows alone at the posture ``q`` (drives are
        functions of time, not of the posture)."""
        cfg = self.cfg
        if not self.closure.size:
            return np.zeros(0), np.zeros((0, cfg.nv))
        pin.computeJointJacobians(cfg.model, cfg.data, cfg.to_pin(q))
        pin.updateFramePlacements(cfg.model, cfg.data)
        phi, Jq, _ = self.closure.evaluate(cfg.model, cfg.data, False)
        return phi, Jq

    def singularity_guard(self):
        """A guard on the determinant of the dependent block (scaled by its rows' norms): it
        changes sign where the current partition degenerates, which a step can jump over."""
        def g(t, y):
            self.unpack(t, y)
            return self._scaled_det(self._last_Jp)

        def rate(t, y, f):
            """Its time derivative from the state alone: a central difference along q' (two
            Jacobians, no Newton solve and no right-hand side)."""
            q, v = self.unpack(t, y)
            qd = self.cfg.qdot(q, v)
            eps = 1e-7 / max(1.0, float(np.max(np.abs(qd))))
            ahead, behind = (self._scaled_det(self._position_rows(t, q + s * eps * qd)) for s in (1.0, -1.0))
            return (ahead - behind) / (2 * eps)
        return Guard(f"configuration '{self.cfg.name}': the loop's partition of its coordinates degenerates",
                     g, 0, "repartition", rate=rate, rate_from_state=True)

    def unpack(self, t, y):
        if self._cache is not None and self._cache[0] == t and np.array_equal(self._cache[1], y):
            return self._cache[2]
        out = self._unpack(t, y)
        self._cache = (t, y.copy(), out)
        if self._trail is not None:  # a re-read segment: keep the solutions at its accepted steps
            ts, ys = self._trail
            k = int(np.searchsorted(ts, t, side="left"))
            if k < len(ts) and ts[k] == t and k not in self._reached and np.array_equal(ys[:, k], y):
                self._reached[k] = self._recent[-1]
        return out

    def _unpack(self, t, y):
        k = len(self.I)
        q, Jq, Jp = self._solve_dependent(t, y[:k], self._guess(t))
        self._qD = q
        self._last_Jp = Jp
        # the state's second half is the independent coordinates' rates q'_I (a planar joint's
        # world-frame x', y', not its body-frame velocity): the dependent rates then solve the
        # same block as the positions, dPhi/dq q' = -Phi_t, and v follows from q'
        rates = np.empty(self.nv)
        rates[self.I] = y[k:]
        rhs = -(Jp[:, self.I] @ y[k:] + self._phi_t(t))
        rates[self.D] = solve(Jp[:, self.D], rhs)
        v = self.cfg.velocity(q, rates)
        self._recent.append((t, q, rates))
        if len(self._recent) > 8:
            del self._recent[0]
        return q, v

    def project(self, t, q, v, prefer_independent=()):
        """Assemble (q, v) onto the constraints keeping the independent coordinates
        (a new partition is chosen at q, preferring ``prefer_independent``)."""
        self.partition(t, q, prefer_independent)
        self.seed(q)
        return self.unpack(t, np.concatenate([q[self.I], self.cfg.qdot(q, v)[self.I]]))

    def rows(self, t, q, v):
        """(Phi_q, bias) of every constraint at (q, v): ``Phi_q a + bias = 0``."""
        _, Jq, bias = self._phi(t, q, need_bias=True, v=v)
        return Jq, bias

    def accelerations(self, t, q, v, extra=None):
        """(a, lam): ``M a + h = Q + extra + Phi_q^T lam`` with ``Phi_q a + bias = 0``."""
        Jq, bias = self.rows(t, q, v)
        return constrained_accelerations(self.cfg, q, v, Jq, bias, extra)

    def derivative(self, t, q, v, extra):
        """State derivative at an assembled (q, v) with an extra generalized force (contact laws)."""
        a, _ = self.accelerations(t, q, v, extra)
        return np.concatenate([self.cfg.qdot(q, v)[self.I], self.cfg.qddot(q, v, a)[self.I]])

    def _solved_accelerations(self, t, q, v):
        """(a, lam) at an assembled (q, v): with revolute cut joints the rows and bias come from
        one kinematics pass (:meth:`_point_rows_and_bias`); otherwise :meth:`accelerations`."""
        if self.closure.revolute_only:
            return constrained_accelerations(self.cfg, q, v, *self._point_rows_and_bias(t, q, v))
        return self.accelerations(t, q, v)

    def rhs(self, t, y):
        q, v = self.unpack(t, y)
        a, _ = self._solved_accelerations(t, q, v)
        qd = self.cfg.qdot(q, v)
        return np.concatenate((qd[self.I], self.cfg.qddot(q, v, a)[self.I]))

    def rhs_with_power(self, t, y):
        """``y`` is the state with the work so far appended; the state derivative with one more component: the power of the force elements and
        of the drives.  A constraint's generalized force ``Phi_q^T lam`` has the power
        ``lam . Phi_q v = -lam . Phi_t``: zero for the loops (scleronomic), the motor's
        ``mu f'(t)`` for a drive."""
        q, v = self.unpack(t, y[:-1])
        a, lam = self._solved_accelerations(t, q, v)
        power = float(self.cfg.forces.generalized(q, v) @ v - lam @ self._phi_t(t))
        qd = self.cfg.qdot(q, v)
        return np.concatenate([qd[self.I], self.cfg.qddot(q, v, a)[self.I], [power]])


def coordinates_for(cfg: Configuration) -> TreeCoordinates | PartitionedCoordinates:
    """The coordinate strategy a configuration needs: plain tree, or partitioned."""
    scene = cfg.scene
    specs = cfg.spec.cut_joints
    drives = scene.drives_in(cfg.name)
    if not specs and not drives:
        return TreeCoordinates(cfg)
    closure = ClosureRows(
        specs=specs,
        frames_a=tuple(cfg.point(s.a, s.point_a).frame_id for s in specs),
        frames_b=tuple(cfg.point(s.b, s.point_b).frame_id for s in specs),
        links_a=tuple(cfg.link_frame[s.a] for s in specs),
        links_b=tuple(cfg.link_frame[s.b] for s in specs))
    dr = Drives(joints=tuple(d.joint for d in drives),
                index=tuple(cfg.joint_slice[d.joint].start for d in drives),
                coefficients=tuple(np.array(d.coefficients) for d in drives))
    return PartitionedCoordinates(cfg, closure, dr)
