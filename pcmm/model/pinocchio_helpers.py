"""Thin helpers over Pinocchio's algorithms, shared by every layer above.

Pure functions over a Pinocchio ``(model, data)`` pair, in Pinocchio's own
style: nothing here knows about scenes, configurations or transitions, so any
module may import it without creating a cycle.

* :func:`frame_jacobian`, :func:`joint_jacobian`: 6 x nv Jacobians that are
  always 2-D (eigenpy returns a 1-D array when nv = 1) and never reach
  Pinocchio with nv = 0 (Pinocchio 4.1 crashes on such a model);
* :func:`mass_matrix`: ``D(q)`` of paper Eq. 1 by CRBA, symmetrized;
* :func:`cholesky`: its factor, or a clear :class:`~pcmm.errors.SimulationError`.
"""
from __future__ import annotations

import functools

import numpy as np
import pinocchio as pin

from ..errors import SimulationError

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
LOCAL = pin.ReferenceFrame.LOCAL


def frame_jacobian(model, data, frame_id: int, ref=LWA) -> np.ndarray:
    """6 x nv frame Jacobian (eigenpy returns a 1-D array when nv = 1; Pinocchio
    4.1 crashes on a model with nv = 0, so that case never reaches it)."""
    if model.nv == 0:
        return np.zeros((6, 0))
    return np.asarray(pin.getFrameJacobian(model, data, frame_id, ref)).reshape(6, model.nv)


def joint_jacobian(model, data, joint_id: int, ref) -> np.ndarray:
    """6 x nv joint Jacobian in ``ref`` (same shape guarantees as :func:`frame_jacobian`)."""
    if model.nv == 0:
        return np.zeros((6, 0))
    return np.asarray(pin.getJointJacobian(model, data, joint_id, ref)).reshape(6, model.nv)


def mass_matrix(model, data, q_pin) -> np.ndarray:
    """D(q) of Eq. 1 by CRBA, symmetrized (CRBA fills the upper triangle only)."""
    M = pin.crba(model, data, q_pin)
    # triu(M) + triu(M, 1).T, bit for bit (x + 0.0 is x, and turns -0.0 into 0.0 as that sum did),
    # without building two triangular masks per call
    return np.where(_upper(M.shape[0]), M, M.T) + 0.0


@functools.lru_cache(maxsize=None)
def _upper(n: int) -> np.ndarray:
    """The upper triangle with the diagonal, as a boolean mask."""
    return np.triu(np.ones((n, n), dtype=bool))


def cholesky(M: np.ndarray, configuration: str):
    """Cholesky factor of a mass matrix, or a clear error when it is not positive definite.
    (scipy.linalg is imported here, on this checked path only: importing it costs 0.3 s at
    start-up; the event path calls LAPACK directly, :func:`pcmm.events.impulse._inverse_mass`.)"""
    import scipy.linalg as sla
    try:
        return sla.cho_factor(M)
    except np.linalg.LinAlgError:
        raise SimulationError(
            f"configuration '{configuration}': the mass matrix is not positive definite (a link without "
            "mass or inertia?); every moving link needs <inertial> with mass > 0") from None
