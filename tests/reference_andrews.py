"""An independent model of Andrews' squeezing mechanism (numpy and scipy only).

Lagrange's equations in the seven published angles q = (beta, Theta, gamma, Phi, delta, Omega,
epsilon) with multipliers for the three pins at P, written from the mechanism's geometry
(Hairer & Wanner, Solving ODEs II, section VII.7; data of the IVP test set's problem "andrews"):

* every point used (mass centres, the pin P seen from each chain, the spring's end D) is a
  fixed base point plus rotating arms ``R(theta_k) a_k``, with each body angle
  ``theta_k = s_k . q`` linear in q; so its Jacobian is ``sum_k R(theta_k) J a_k s_k`` and its
  velocity-product acceleration ``-sum_k R(theta_k) a_k (s_k . q')^2`` (J the quarter turn);
* ``M = sum m J_c^T J_c + i s s^T``, and ``M q'' + sum m J_c^T b_c = Q + G^T lam`` with
  ``G q'' + b_G = 0`` for the pin rows ``P_crank - P_other = 0``.

No Pinocchio, no partitioning, no cut joints: the index-1 system in all seven angles,
integrated by scipy's DOP853.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

# Geometry (m), masses (kg), inertias about the mass centres (kg m^2), motor (N m), spring
XA, YA, XB, YB, XC, YC = -0.06934, -0.00227, -0.03635, 0.03273, 0.014, 0.072
D, DA, E, EA, RR, RA = 28e-3, 115e-4, 2e-2, 1421e-5, 7e-3, 92e-5
SS, SA, SB, SC, SD = 35e-3, 1874e-5, 1043e-5, 18e-3, 2e-2
TA, TB, U, UA, UB, ZF, ZT, FA = 2308e-5, 916e-5, 4e-2, 1228e-5, 449e-5, 2e-2, 4e-2, 1421e-5
MASS = (0.04325, 0.00365, 0.02373, 0.00706, 0.07050, 0.00706, 0.05498)
INERTIA = (2.194e-6, 4.410e-7, 5.255e-6, 5.667e-7, 1.169e-5, 5.667e-7, 1.912e-5)
MOM, C0, L0 = 0.033, 4530.0, 0.07785

COORDINATES = ("beta", "Theta", "gamma", "Phi", "delta", "Omega", "epsilon")
Q0 = np.array([-0.0617138900142764496358948458001, 0.0, 0.455279819163070380255912382449,
               0.222668390165885884674473185609, 0.487364979543842550225598953530,
               -0.222668390165885884674473185609, 1.23054744454982119249735015568])


def _s(*idx):
    row = np.zeros(7)
    row[list(idx)] = 1.0
    return row


# body angles as rows over q: body k's absolute angle is s . q
S1, S2, S3, S4, S5, S6, S7 = _s(0), _s(0, 1), _s(2), _s(3, 4), _s(4), _s(5, 6), _s(6)
O, A, B = np.zeros(2), np.array([XA, YA]), np.array([XB, YB])
# (base, [(angle row, arm in that body's frame), ...])
COM = [
    (O, [(S1, (RA, 0.0))]),
    (O, [(S1, (RR, 0.0)), (S2, (-DA, 0.0))]),
    (B, [(S3, (SB, -SA))]),
    (A, [(S5, (ZT, 0.0)), (S4, (0.0, -(E - EA)))]),
    (A, [(S5, (TA, TB))]),
    (A, [(S7, (0.0, -U)), (S6, (ZF - FA, 0.0))]),
    (A, [(S7, (UB, -UA))]),
]
BODY_ANGLE = (S1, S2, S3, S4, S5, S6, S7)
P_CRANK = (O, [(S1, (RR, 0.0)), (S2, (-D, 0.0))])
P_OTHERS = [(B, [(S3, (0.0, -SS))]),
            (A, [(S5, (ZT, 0.0)), (S4, (0.0, -E))]),
            (A, [(S7, (0.0, -U)), (S6, (ZF, 0.0))])]
SPRING_D = (B, [(S3, (SD, -SC))])
_INDEX = {id(row): list(np.flatnonzero(row)) for row in BODY_ANGLE}  # the coordinates in each angle


def _point(spec, q, qd):
    """Position, 2 x 7 Jacobian and velocity-product acceleration of a point (q, qd as lists)."""
    base, arms = spec
    px, py = base
    jac, bx, by = np.zeros((2, 7)), 0.0, 0.0
    for row, arm in arms:
        idx = _INDEX[id(row)]
        th, w = sum(q[i] for i in idx), sum(qd[i] for i in idx)
        c, s = math.cos(th), math.sin(th)
        rx, ry = c * arm[0] - s * arm[1], s * arm[0] + c * arm[1]
        px, py = px + rx, py + ry
        jac[0, idx] -= ry
        jac[1, idx] += rx
        bx, by = bx - rx * w * w, by - ry * w * w
    return np.array([px, py]), jac, np.array([bx, by])


def accelerations(q, qd):
    """(q'', lam) of Lagrange's equations with the pin multipliers."""
    q, qd = list(q), list(qd)
    M = np.zeros((7, 7))
    rhs = np.zeros(7)
    rhs[0] = MOM
    for m, inertia, spec, row in zip(MASS, INERTIA, COM, BODY_ANGLE):
        _, jac, bias = _point(spec, q, qd)
        M += m * jac.T @ jac + inertia * np.outer(row, row)
        rhs -= m * jac.T @ bias
    d, jd, _ = _point(SPRING_D, q, qd)
    r = d - np.array([XC, YC])
    length = np.hypot(*r)
    rhs += jd.T @ (-C0 * (length - L0) * r / length)
    p1, j1, b1 = _point(P_CRANK, q, qd)
    G, bG = [], []
    for spec in P_OTHERS:
        _, jo, bo = _point(spec, q, qd)
        G.append(j1 - jo)
        bG.append(b1 - bo)
    G, bG = np.vstack(G), np.concatenate(bG)
    kkt = np.block([[M, G.T], [G, np.zeros((6, 6))]])
    sol = np.linalg.solve(kkt, np.concatenate([rhs, -bG]))
    return sol[:7], sol[7:]


def closure(q) -> float:
    """Largest pin-position error (m)."""
    q, qd = list(q), [0.0] * 7
    p1 = _point(P_CRANK, q, qd)[0]
    return max(float(np.max(np.abs(p1 - _point(s, q, qd)[0]))) for s in P_OTHERS)


def solve(t_end=0.03, rtol=1e-13, atol=1e-15):
    """(q, q') at t_end from the test set's consistent initial values, at rest."""
    def f(t, y):
        return np.concatenate([y[7:], accelerations(y[:7], y[7:])[0]])
    sol = solve_ivp(f, (0.0, t_end), np.concatenate([Q0, np.zeros(7)]), method="DOP853", rtol=rtol, atol=atol)
    return sol.y[:7, -1], sol.y[7:, -1]
