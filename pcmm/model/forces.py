"""Force elements of a configuration, compiled to matrices (paper Eq. 1: tau_a + tau_c).

Every element is ``f = value - k (x - rest) - c x'`` where ``x = C q + d`` is a
joint coordinate, a link's absolute angle or a relative angle, and acts on the
generalized coordinates through a column ``B`` (a joint's unit vector, or a
link's angular-velocity row transposed: a torque from the frame on the link).
The total generalized force folds into ``Q = Q0 - K q - Dv v``: two
matrix-vector products per right-hand-side evaluation.

A ``point_spring`` is the one element that is not linear in ``q``: ``x`` is the distance
``L = |p_b - p_a|`` between two points fixed on links, and ``f`` is the generalized force
conjugate to it, as for every element: it pushes the points apart along
``u = (p_b - p_a) / L`` when positive (a stretched spring pulls, ``f < 0``), so
``Q += (J_b - J_a)^T u f``, the virtual work ``f dL`` with ``dL = u . (J_b - J_a) dq``.
The points are operational frames; their Jacobians are evaluated on a Pinocchio ``Data``
of the elements' own, so the evaluation never disturbs the kinematics a caller holds.  A configuration without
point springs has ``points = None`` and keeps the two products above.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..errors import SimulationError
from ..scene.spec import ForceSpec

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@dataclass(frozen=True)
class PointSprings:
    """Spring-dampers along the line between two points: ``f = value - k (L - rest) - c L'``
    (N, > 0 pushing the points apart), ``L`` their distance; potential energy ``k (L - rest)^2 / 2``."""

    names: tuple[str, ...]
    model: object  # the configuration's Pinocchio model (points registered as frames)
    data: object  # a Data of the elements' own
    to_pin: object  # pcmm coordinates -> Pinocchio configuration
    frames_a: tuple[int, ...]
    frames_b: tuple[int, ...]
    f0: np.ndarray
    k: np.ndarray
    rest: np.ndarray
    c: np.ndarray

    def geometry(self, q: np.ndarray):
        """(L, u, Jrel): each element's length, unit vector a -> b (world) and the 2 x nv
        Jacobian of p_b - p_a."""
        model, data = self.model, self.data
        pin.computeJointJacobians(model, data, self.to_pin(q))
        pin.updateFramePlacements(model, data)
        out = []
        for name, fa, fb in zip(self.names, self.frames_a, self.frames_b):
            r = data.oMf[fb].translation[:2] - data.oMf[fa].translation[:2]
            length = float(np.hypot(r[0], r[1]))
            if not length > 1e-12:
                raise SimulationError(
                    f"force element '{name}': its two points coincide (distance {length:.3g} m), so the "
                    "direction of a point spring is undefined; give the points distinct positions")
            Jrel = (pin.getFrameJacobian(model, data, fb, LWA)[:2]
                    - pin.getFrameJacobian(model, data, fa, LWA)[:2]).reshape(2, model.nv)
            out.append((length, r / length, Jrel))
        return out

    def evaluate(self, q: np.ndarray, v: np.ndarray):
        """(f, Q): each element's force f and their generalized force on the coordinates."""
        f = np.empty(len(self.names))
        Q = np.zeros(self.model.nv)
        for i, (length, u, Jrel) in enumerate(self.geometry(q)):
            uJ = u @ Jrel  # dL/dq
            f[i] = self.f0[i] - self.k[i] * (length - self.rest[i]) - self.c[i] * float(uJ @ v)
            Q += f[i] * uJ
        return f, Q

    def generalized(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        return self.evaluate(q, v)[1]

    def potential_energy(self, q: np.ndarray) -> float:
        lengths = np.array([g[0] for g in self.geometry(q)])
        return float(0.5 * np.sum(self.k * (lengths - self.rest) ** 2))


@dataclass(frozen=True)
class ForceField:
    names: tuple[str, ...]
    B: np.ndarray  # nv x ne
    C: np.ndarray  # ne x nv
    d: np.ndarray  # ne
    f0: np.ndarray
    k: np.ndarray
    rest: np.ndarray
    c: np.ndarray
    Q0: np.ndarray  # nv
    K: np.ndarray  # nv x nv
    Dv: np.ndarray  # nv x nv
    KD: np.ndarray  # nv x 2nv, [K Dv]: Q = Q0 - KD @ [q, v] in one product
    points: PointSprings | None = None  # the nonlinear point-to-point elements, if any

    def generalized(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Generalized force vector tau_a + tau_c of Eq. 1."""
        Q = self.Q0 - self.K @ q - self.Dv @ v
        if self.points is None:
            return Q
        return Q + self.points.generalized(q, v)

    def element_values(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Each element's scalar output ``f`` (N or N m), e.g. the moments of Eq. 44; point
        springs (N, > 0 pushing the points apart) come after the linear elements, as in ``names``."""
        f = self.f0 - self.k * (self.C @ q + self.d - self.rest) - self.c * (self.C @ v)
        if self.points is None:
            return f
        return np.concatenate([f, self.points.evaluate(q, v)[0]])

    def potential_energy(self, q: np.ndarray) -> float:
        x = self.C @ q + self.d - self.rest
        energy = float(0.5 * np.sum(self.k * x * x))
        if self.points is None:
            return energy
        return energy + self.points.potential_energy(q)


def compile_point_springs(specs: tuple[ForceSpec, ...], model, to_pin, point_frame) -> PointSprings | None:
    """The point springs among ``specs`` (None if there are none); ``point_frame(link, xy) ->
    frame id`` is the configuration's point registry."""
    specs = tuple(f for f in specs if f.points is not None)
    if not specs:
        return None
    return PointSprings(
        names=tuple(f.name for f in specs), model=model, data=model.createData(), to_pin=to_pin,
        frames_a=tuple(point_frame(f.points.a, f.points.point_a) for f in specs),
        frames_b=tuple(point_frame(f.points.b, f.points.point_b) for f in specs),
        f0=np.array([f.value for f in specs], dtype=float), k=np.array([f.k for f in specs], dtype=float),
        rest=np.array([f.rest for f in specs], dtype=float), c=np.array([f.c for f in specs], dtype=float))


def compile_forces(specs: tuple[ForceSpec, ...], measure_row, target_column, nv: int,
                   points: PointSprings | None = None) -> ForceField:
    """Build a :class:`ForceField` from the linear elements of ``specs`` plus ``points``;
    ``measure_row(Measure) -> (row, offset)`` and ``target_column(Target) -> column`` come
    from the configuration."""
    specs = tuple(f for f in specs if f.points is None)
    ne = len(specs)
    B = np.zeros((nv, ne))
    C = np.zeros((ne, nv))
    d = np.zeros(ne)
    for i, f in enumerate(specs):
        B[:, i] = target_column(f.on)
        if f.measure is not None:
            C[i], d[i] = measure_row(f.measure)
    f0 = np.array([f.value for f in specs], dtype=float)
    k = np.array([f.k for f in specs], dtype=float)
    rest = np.array([f.rest for f in specs], dtype=float)
    c = np.array([f.c for f in specs], dtype=float)
    return ForceField(
        names=tuple(f.name for f in specs) + (points.names if points is not None else ()),
        B=B, C=C, d=d, f0=f0, k=k, rest=rest, c=c,
        Q0=B @ (f0 - k * (d - rest)), K=B @ (k[:, None] * C), Dv=B @ (c[:, None] * C),
        KD=np.hstack([B @ (k[:, None] * C), B @ (c[:, None] * C)]), points=points)
