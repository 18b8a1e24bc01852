"""Constraint rows of a configuration's tree, and the small dense solves with them.

A scene names the joints that close loops (``cut_joints``); the URDF holds the spanning tree.
Each cut joint gives planar rows from frame Jacobians (:class:`ClosureRows`):

* revolute: 2 rows, ``p_b - p_a = 0`` (world x, y);
* prismatic: 2 rows, ``n . (p_b - p_a) = 0`` (n normal to the axis, fixed in a)
  and ``theta_b - theta_a = angle``;
* weld: 3 rows, the point rows and the angle row.

A driven joint adds the rheonomic row ``q_j - f(t) = 0`` (:class:`Drives`).  The multipliers are
the cut joints' reaction forces (on b, world axes) and the motor's moment, from the KKT system of
the constrained dynamics (paper Eq. 1 with the constraint rows, :func:`constrained_accelerations`).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from .._scipy import lapack

from .configuration import Configuration
from .pinocchio_helpers import LWA, frame_jacobian
from ..scene.spec import CutJointSpec


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

    @functools.cached_property
    def size(self) -> int:
        """The number of rows (the specs are fixed: counted once; every Newton step of the loop asks)."""
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
    #: the last time asked and its (f, f', f''): a cache of :meth:`values`, declared here, its owner
    _last: tuple | None = field(default=None, init=False, repr=False, compare=False)

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
        last = self._last
        if last is None or last[0] != t:
            # the three Horner sums of value(t, 0..2) in one pass, the same operations in the same order
            f, f1, f2 = [], [], []
            for d in self._derivs:
                for out, cs in zip((f, f1, f2), d):
                    acc = 0.0
                    for c in reversed(cs):
                        acc = acc * t + c
                    out.append(acc)
            last = (t, (np.array(f), np.array(f1), np.array(f2)))
            object.__setattr__(self, "_last", last)
        return last[1]

    def values_many(self, ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(f, f') at every time of ``ts``, one row per drive: Horner's rule on the array, the
        very operations :meth:`value` does on each time (numpy's elementwise products and sums
        round as Python's)."""
        f = np.empty((len(self.joints), len(ts)))
        f1 = np.empty_like(f)
        for i, d in enumerate(self._derivs):
            for out, cs in ((f, d[0]), (f1, d[1])):
                acc = np.zeros(len(ts))
                for c in reversed(cs):
                    acc = acc * ts + c
                out[i] = acc
        return f, f1

    def value(self, t, order=0) -> np.ndarray:
        out = np.empty(len(self.joints))
        for i, d in enumerate(self._derivs):
            acc = 0.0
            for c in reversed(d[order]):
                acc = acc * t + c
            out[i] = acc
        return out


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


def pivots(A: np.ndarray) -> np.ndarray:
    """The column order of A's QR factorization with column pivoting (LAPACK's dgeqp3, 0-based):
    ``scipy.linalg.qr(A, pivoting=True)[2]`` by the same calls (a workspace query, then the
    factorization), without importing scipy.linalg (0.3 s at start-up)."""
    A = np.asarray(A, float)
    if not np.isfinite(A).all():
        raise ValueError("array must not contain infs or NaNs")
    if A.size == 0:
        return np.arange(A.shape[1], dtype=np.int32)
    geqp3 = lapack().dgeqp3
    work, info = geqp3(A, lwork=-1, overwrite_a=False)[-2:]
    if info < 0:
        raise ValueError(f"illegal value in {-info}th argument of internal geqp3")
    _, jpvt, _, _, info = geqp3(A, lwork=work[0].real.astype(int), overwrite_a=False)
    if info < 0:
        raise ValueError(f"illegal value in {-info}th argument of internal geqp3")
    return jpvt - 1


def solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.solve`` for the small dense systems of a loop, by LAPACK's dgesv directly
    (numpy's wrapper costs four times the solve at this size); LinAlgError when A is singular."""
    if A.ndim != 2 or A.shape[0] != A.shape[1] or A.shape[0] != b.shape[0]:
        raise np.linalg.LinAlgError(f"a {A.shape} system with a {b.shape} right-hand side is not square")
    if A.size == 0:
        return np.zeros(b.shape)
    _, _, x, info = lapack().dgesv(A, b)
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


def constrained_accelerations(cfg: Configuration, q, v, J, bias, extra=None, forces=None):
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
    tau = (cfg.forces if forces is None else forces).generalized(q, v)  # a segment's own when given
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


#: a singular value of a configuration's rows at most this fraction of the largest is a redundancy (the
#: rows are dependent to round-off: a cut joint given twice, a drive on a joint a lock and a loop fix)
REDUNDANT_TOL = 1e-9


def left_null(J: np.ndarray, tol: float = REDUNDANT_TOL) -> np.ndarray:
    """The left null vectors ``y`` of the rows ``J`` (``y^T J = 0``), one per column, unit length,
    from the SVD: the directions along which the multipliers of ``J`` can be traded at will
    (``J^T (lam + c y) = J^T lam``); an empty (m, 0) array where the rows are independent."""
    m = J.shape[0]
    if m == 0:
        return np.zeros((0, 0))
    U, s, _ = np.linalg.svd(J)
    rank = int(np.sum(s > tol * max(float(s[0]), 1e-300))) if s.size else 0
    return U[:, rank:]


def indeterminate(null: np.ndarray) -> np.ndarray:
    """Which rows' multipliers some left null vector moves (:func:`left_null`): their forces are
    statically indeterminate (any split of the load between those rows balances it)."""
    if null.shape[1] == 0:
        return np.zeros(null.shape[0], bool)
    return np.max(np.abs(null), axis=1) > 1e-9


def determinate(J: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """``lam`` (a solution of ``J^T lam = f``) with NaN in every entry that the rows ``J`` leave
    statically indeterminate (:func:`indeterminate`); ``lam`` itself where the rows are independent.
    The entries kept are the same in every solution: they are the determinate forces."""
    bad = indeterminate(left_null(J))
    if not bad.any():
        return lam
    out = np.array(lam, float)
    out[bad] = np.nan
    return out


def independent_rows(J: np.ndarray, first: int = 0, tol: float = REDUNDANT_TOL) -> np.ndarray | None:
    """The indices of a maximal set of independent rows of ``J`` where its rows ``first:`` are
    dependent to round-off (``tol`` of their largest singular value), the rows before ``first``
    always kept (a configuration's drives, whose rows are unit rows on distinct coordinates: the
    remaining rows are judged on the columns the kept ones leave); None where they are independent.
    Rank-revealing: QR with column pivoting on the remaining rows' transpose picks, of the dependent
    ones, those best conditioned to keep."""
    rest_rows = np.arange(first, J.shape[0])
    if rest_rows.size == 0:
        return None
    head = J[:first]
    cols = np.flatnonzero(~np.any(head != 0.0, axis=0)) if first else np.arange(J.shape[1])
    block = J[rest_rows][:, cols]
    s = np.linalg.svd(block, compute_uv=False) if block.size else np.zeros(0)
    rank = int(np.sum(s > tol * max(float(s[0]), 1e-300))) if s.size else 0
    if rank == rest_rows.size:
        return None
    keep = np.sort(pivots(block.T)[:rank]) if rank else np.zeros(0, int)
    return np.concatenate([np.arange(first), rest_rows[keep]]).astype(int)
