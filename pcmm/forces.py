"""Force elements of a configuration, compiled to matrices (paper Eq. 1: tau_a + tau_c).

Every element is ``f = value - k (x - rest) - c x'`` where ``x = C q + d`` is a
joint coordinate, a link's absolute angle or a relative angle, and acts on the
generalized coordinates through a column ``B`` (a joint's unit vector, or a
link's angular-velocity row transposed: a torque from the frame on the link).
The total generalized force folds into ``Q = Q0 - K q - Dv v``: two
matrix-vector products per right-hand-side evaluation.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import ForceSpec


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

    def generalized(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Generalized force vector tau_a + tau_c of Eq. 1."""
        return self.Q0 - self.K @ q - self.Dv @ v

    def element_values(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Each element's scalar output ``f`` (N or N m), e.g. the moments of Eq. 44."""
        return self.f0 - self.k * (self.C @ q + self.d - self.rest) - self.c * (self.C @ v)

    def potential_energy(self, q: np.ndarray) -> float:
        x = self.C @ q + self.d - self.rest
        return float(0.5 * np.sum(self.k * x * x))


def compile_forces(specs: tuple[ForceSpec, ...], measure_row, target_column, nv: int) -> ForceField:
    """Build a :class:`ForceField`; ``measure_row(Measure) -> (row, offset)`` and
    ``target_column(Target) -> column`` come from the configuration."""
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
        names=tuple(f.name for f in specs), B=B, C=C, d=d, f0=f0, k=k, rest=rest, c=c,
        Q0=B @ (f0 - k * (d - rest)), K=B @ (k[:, None] * C), Dv=B @ (c[:, None] * C),
        KD=np.hstack([B @ (k[:, None] * C), B @ (c[:, None] * C)]))
