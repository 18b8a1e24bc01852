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

import functools
import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
import scipy.linalg as sla
from scipy.linalg.lapack import dgesv

from .configuration import frame_jacobian
from .errors import Repartition, SimulationError

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
NEWTON_TOL = 1e-13
SINGULAR_COND = 1e9


def _perp(n):
    return np.array([-n[1], n[0]])


@dataclass(frozen=True)
class ClosureRows:
    """Point frames and link frames of one configuration's cut joints."""

    specs: tuple
    frames_a: tuple[int, ...]
    frames_b: tuple[int, ...]
    links_a: tuple[int, ...]
    links_b: tuple[int, ...]

    @property
    def size(self) -> int:
        return sum({"revolute": 2, "prismatic": 2, "weld": 3}[s.type] for s in self.specs)

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
        for s, fa, fb, la, lb in zip(self.specs, self.frames_a, self.frames_b, self.links_a, self.links_b):
            pa, pb = data.oMf[fa].translation[:2], data.oMf[fb].translation[:2]
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

    def value(self, t, order=0) -> np.ndarray:
        out = np.empty(len(self.joints))
        for i, d in enumerate(self._derivs):
            acc = 0.0
            for c in reversed(d[order]):
                acc = acc * t + c
            out[i] = acc
        return out


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


@functools.lru_cache(maxsize=None)
def _strictly_lower(n: int) -> np.ndarray:
    return np.tril(np.ones((n, n), dtype=bool), -1)


def constrained_accelerations(cfg, q, v, J, bias, extra=None):
    """Solve ``M a + h = Q + J^T lam``, ``J a + bias = 0`` (the multipliers are the
    constraint forces: cut-joint reactions on b, driving moments, contact forces).

    By the Schur complement on Pinocchio's O(n) algorithms: the free acceleration
    ``a0 = M^-1 (Q - h)`` is one ``aba``, ``M^-1`` one ``computeMinverse``; then
    ``(J M^-1 J^T) lam = -bias - J a0`` and ``a = a0 + M^-1 J^T lam``.  (The mass matrix
    is positive definite: the URDF check demands mass and a positive-definite inertia
    of every moving link.)"""
    if cfg.nv == 0:
        return np.zeros(0), np.zeros(J.shape[0])
    qp = cfg.to_pin(q)
    tau = cfg.forces.generalized(q, v)
    if extra is not None:
        tau = tau + extra
    a0 = pin.aba(cfg.model, cfg.data, qp, v, tau)
    if J.shape[0] == 0:
        return a0, np.zeros(0)
    Minv = pin.computeMinverse(cfg.model, cfg.data, qp)
    Minv = np.where(_strictly_lower(cfg.nv), Minv.T, Minv)  # Pinocchio's C++ fills the upper triangle
    MiJt = Minv @ J.T
    lam = solve(J @ MiJt, -bias - J @ a0)
    return a0 + MiJt @ lam, lam


class TreeCoordinates:
    """A tree with no loops and no drives: ``y = [q, v]``, accelerations by ABA."""

    constrained = False
    checking = True
    position_noise = 0.0  # coordinates are the integrator's own

    def __init__(self, cfg):
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
        if nv == 0:
            return lambda t, y: y
        model, data, aba = cfg.model, cfg.data, pin.aba
        Q0, KD = cfg.forces.Q0, cfg.forces.KD
        tau = np.empty(nv)
        dot, subtract, concatenate = np.dot, np.subtract, np.concatenate
        if cfg.has_planar:
            to_pin, qdot = cfg.to_pin, cfg.qdot

            def rhs_planar(t, y):
                q, v = y[:nv], y[nv:]
                return concatenate((qdot(q, v), aba(model, data, to_pin(q), v, subtract(Q0, dot(KD, y, tau), tau))))
            return rhs_planar

        def rhs(t, y):
            v = y[nv:]
            return concatenate((v, aba(model, data, y[:nv], v, subtract(Q0, dot(KD, y, tau), tau))))
        return rhs

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


class PartitionedCoordinates:
    """Loops and/or drives: independent coordinates ``y = [q_I, v_I]``."""

    constrained = True
    position_noise = 10 * NEWTON_TOL  # dependent coordinates are solved to the Newton tolerance

    def __init__(self, cfg, closure: ClosureRows, drives: Drives):
        self.cfg = cfg
        self.closure = closure
        self.drives = drives
        self.nv = cfg.nv
        self.m = closure.size + drives.size
        self.labels = closure.labels() + [f"{j}.drive" for j in drives.joints]
        self.I = None
        self.D = None
        self._qD = None
        self._zeros = np.zeros(self.nv)
        self.checking = True  # conditioning checks (off while recording an accepted segment)
        self._cache = None  # the last unpack: guards and the right-hand side ask for the same point
        self._driven = np.array(drives.index, dtype=int)
        self._drive_rows = np.zeros((drives.size, self.nv))
        self._drive_rows[np.arange(drives.size), self._driven] = 1.0

    # -- constraint evaluation on the tree
    def _phi(self, t, q, need_bias=False, v=None):
        cfg = self.cfg
        qp = cfg.to_pin(q)
        if need_bias:  # placements, velocities and accelerations at a = 0, then Jacobians from them
            pin.forwardKinematics(cfg.model, cfg.data, qp, v, self._zeros)
            pin.computeJointJacobians(cfg.model, cfg.data)
        else:  # computes the placements itself
            pin.computeJointJacobians(cfg.model, cfg.data, qp)
        pin.updateFramePlacements(cfg.model, cfg.data)
        phi, Jq, bias = self.closure.evaluate(cfg.model, cfg.data, need_bias)
        if self.drives.size:  # the rheonomic rows q_j - f_j(t): their Jacobian rows are constant
            phi = np.concatenate((phi, q[self._driven] - self.drives.value(t)))
            Jq = np.concatenate((Jq, self._drive_rows))
            if need_bias:
                bias = np.concatenate([bias, -self.drives.value(t, 2)])
        return phi, Jq, bias

    def _phi_t(self, t):
        return np.concatenate([np.zeros(self.closure.size), -self.drives.value(t, 1)])

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

    def residual(self, t, q) -> float:
        phi, _, _ = self._phi(t, q)
        return float(np.max(np.abs(phi))) if phi.size else 0.0

    # -- partition
    def partition(self, t, q, prefer_independent=()):
        """Choose dependent coordinates: driven joints, then the best-conditioned
        columns of the loop rows (QR with column pivoting).  Coordinates in
        ``prefer_independent`` are kept independent when the rest allows it."""
        _, Jq, _ = self._phi(t, q)
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
        q = guess.copy()
        q[self.I] = qI
        for _ in range(30):
            phi, Jq, _ = self._phi(t, q)
            if phi.size == 0 or np.max(np.abs(phi)) < NEWTON_TOL:
                self._check_conditioning(t, Jq)
                return q, Jq
            JD = Jq[:, self.D]
            try:
                q[self.D] -= solve(JD, phi)
            except np.linalg.LinAlgError:
                break
        phi, Jq, _ = self._phi(t, q)
        if np.max(np.abs(phi)) < 1e-9:
            return q, Jq
        raise SimulationError(
            f"configuration '{self.cfg.name}': the loop cannot be closed at t = {t:.6g} s "
            f"(residual {np.max(np.abs(phi)):.3g}): the mechanism is at or beyond a singular "
            "posture, or the initial state is far from an assembled one")

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
        """det(J_D) / ||J||_F^m: signed, continuous, and of the order of sigma_min / sigma_max --
        small when the dependent block degenerates or when the whole Jacobian loses rank (a row
        scaled by its own norm would hide a row that vanishes, as at a change point)."""
        JD = Jq[:, self.D]
        return float(np.linalg.det(JD) / max(np.linalg.norm(Jq) ** JD.shape[0], 1e-300))

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
        self._cache = None

    def pack(self, t, q, v):
        """State vector at an assembled (q, v); the partition is re-chosen here,
        at the start of every segment, so it follows the posture."""
        self.partition(t, q)
        self.seed(q)
        return np.concatenate([q[self.I], v[self.I]])

    def at_degenerate_partition(self, t, q):
        """Where the singularity guard fired: if the whole constraint Jacobian keeps its rank a
        new partition goes on (the next segment picks it); if it loses rank the loop itself is
        at a singular posture (a dead centre, a change point) and the run stops."""
        _, Jq, _ = self._phi(t, q)
        s = np.linalg.svd(Jq, compute_uv=False)
        if s[-1] <= 1e-6 * s[0] or np.array_equal(self._best_dependent(Jq), self.D):
            # rank lost, or no partition does better than the one that degenerated
            raise SimulationError(
                f"configuration '{self.cfg.name}': the loop reaches a singular posture at t = {t:.9g} s "
                f"(constraint Jacobian singular values {s[0]:.3g} ... {s[-1]:.3g}): at a dead centre or "
                "change point the motion is not determined by the constraints and drives; pcmm stops "
                "rather than pick a branch")

    def singularity_guard(self):
        """A guard on the determinant of the dependent block (scaled by its rows' norms): it
        changes sign where the current partition degenerates, which a step can jump over."""
        def g(t, y):
            self.unpack(t, y)
            return self._scaled_det(self._last_Jq)

        def rate(t, y, f):
            """Its time derivative from the state alone: a central difference along q' (two
            Jacobians, no Newton solve and no right-hand side)."""
            q, v = self.unpack(t, y)
            qd = self.cfg.qdot(q, v)
            eps = 1e-7 / max(1.0, float(np.max(np.abs(qd))))
            ahead, behind = (self._scaled_det(self._phi(t, q + s * eps * qd)[1]) for s in (1.0, -1.0))
            return (ahead - behind) / (2 * eps)
        g.rate = rate
        g.rate_from_state = True
        g.terminal = True
        g.direction = 0
        g.singular = True
        return g

    def unpack(self, t, y):
        if self._cache is not None and self._cache[0] == t and np.array_equal(self._cache[1], y):
            return self._cache[2]
        out = self._unpack(t, y)
        self._cache = (t, y.copy(), out)
        return out

    def _unpack(self, t, y):
        k = len(self.I)
        q, Jq = self._solve_dependent(t, y[:k], self._qD)
        self._qD = q
        self._last_Jq = Jq
        v = np.empty(self.nv)
        v[self.I] = y[k:]
        rhs = -(Jq[:, self.I] @ y[k:] + self._phi_t(t))
        v[self.D] = solve(Jq[:, self.D], rhs)
        return q, v

    def project(self, t, q, v, prefer_independent=()):
        """Assemble (q, v) onto the constraints keeping the independent coordinates
        (a new partition is chosen at q, preferring ``prefer_independent``)."""
        self.partition(t, q, prefer_independent)
        self.seed(q)
        return self.unpack(t, np.concatenate([q[self.I], v[self.I]]))

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
        return np.concatenate([self.cfg.qdot(q, v)[self.I], a[self.I]])

    def rhs(self, t, y):
        q, v = self.unpack(t, y)
        a, _ = self.accelerations(t, q, v)
        qd = self.cfg.qdot(q, v)
        return np.concatenate([qd[self.I], a[self.I]])


def coordinates_for(cfg):
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
