"""Independent reference: a planar kneed walker (numpy/scipy only, no pcmm, no Pinocchio).

McGeer (1990), "Passive walking with knees", and Hsu Chen (2007, MIT thesis): a hip, two legs of a
thigh and a shank each, on a slope gamma.  Here every segment is a rigid bar with its own mass
and centroidal inertia, and a point mass sits at the hip.

Coordinates and conventions (those of the pcmm scene the test writes)
--------------------------------------------------------------------
The frame is the slope's: x downhill along it, y its outward normal, gravity
g (sin gamma, -cos gamma).  Each segment's absolute angle phi is counter-clockwise; its direction
from its upper end to its lower end is d(phi) = (sin phi, -cos phi) (the leg points along -y of
its frame at phi = 0).  The walker walks towards +x, so a swinging leg turns with phi' > 0 and a
flexed knee has its shank behind its thigh: knee = phi_shank - phi_thigh < 0.

Every point of the walker is base + sum_j c_j d(theta_j) over the coordinates theta (angles),
with base either a fixed point (the stance foot) or two more coordinates (the hip, floating).
Velocities: J[:, j] = c_j d'(theta_j), d' = (cos, sin); accelerations add
sum_j c_j theta_j'^2 d''(theta_j), d'' = -d.  So the mass matrix and the bias are
M = sum m J^T J + I e e^T and h = sum m J^T (sum c_j theta_j'^2 (-d_j) - g) (Lagrange's equations
of a chain written in absolute angles, derived by hand: no library).

Phases (the stance leg's knee straight, so the stance leg is one bar at phi_s):
* swing:  theta = (phi_s, phi_t, phi_k): stance leg, swing thigh, swing shank (3 DOF);
* locked: theta = (phi_s, phi_w): stance leg, swing leg with its knee locked straight (2 DOF).

Impacts are solved in the floating coordinates q = (x_h, y_h, phi_ta, phi_sa, phi_tb, phi_sb)
with the target's rows A (a pinned foot: 2 rows; a locked knee: 1 row):
M (v+ - v-) = A^T P,  A v+ = 0, a KKT solve.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp


def d(phi):
    return np.array([np.sin(phi), -np.cos(phi)])


def dd(phi):
    return np.array([np.cos(phi), np.sin(phi)])


@dataclass(frozen=True)
class Walker:
    m_hip: float = 0.5
    m_thigh: float = 0.5
    m_shank: float = 0.05
    l_thigh: float = 0.5
    l_shank: float = 0.5
    c_thigh: float = 0.175     # thigh centroid below the hip (m)
    c_shank: float = 0.125     # shank centroid below the knee (m)
    i_thigh: float = 0.5 * 0.5 ** 2 / 12
    i_shank: float = 0.05 * 0.5 ** 2 / 12
    gamma: float = 0.0504
    g0: float = 9.81

    @property
    def leg(self):
        return self.l_thigh + self.l_shank

    @property
    def g(self):
        return self.g0 * np.array([np.sin(self.gamma), -np.cos(self.gamma)])

    # -- bodies: (mass, inertia, {coordinate index: coefficient}, angle index) ---------------
    def floating_bodies(self):
        """Floating coordinates (x_h, y_h, phi_ta, phi_sa, phi_tb, phi_sb); base = hip."""
        lt, ct, cs = self.l_thigh, self.c_thigh, self.c_shank
        return [
            (self.m_hip, 0.0, {}, None),
            (self.m_thigh, self.i_thigh, {2: ct}, 2),
            (self.m_shank, self.i_shank, {2: lt, 3: cs}, 3),
            (self.m_thigh, self.i_thigh, {4: ct}, 4),
            (self.m_shank, self.i_shank, {4: lt, 5: cs}, 5),
        ]

    def foot(self, leg):
        """The foot of leg 'a' or 'b' in floating coordinates: {index: coefficient}."""
        t = 2 if leg == "a" else 4
        return {t: self.l_thigh, t + 1: self.l_shank}

    def swing_bodies(self):
        """theta = (phi_s, phi_t, phi_k), base = the stance foot (fixed)."""
        L, lt, ct, cs, ls = self.leg, self.l_thigh, self.c_thigh, self.c_shank, self.l_shank
        return [
            (self.m_hip, 0.0, {0: -L}, None),
            (self.m_thigh, self.i_thigh, {0: ct - L}, 0),
            (self.m_shank, self.i_shank, {0: -(ls - cs)}, 0),
            (self.m_thigh, self.i_thigh, {0: -L, 1: ct}, 1),
            (self.m_shank, self.i_shank, {0: -L, 1: lt, 2: cs}, 2),
        ]

    def locked_bodies(self):
        """theta = (phi_s, phi_w): the swing leg's knee locked straight."""
        out = []
        for m, i, c, a in self.swing_bodies():
            c2 = {}
            for j, cj in c.items():
                k = min(j, 1)
                c2[k] = c2.get(k, 0.0) + cj
            out.append((m, i, c2, None if a is None else min(a, 1)))
        return out


def jacobian(coeffs, theta, n, floating):
    J = np.zeros((2, n))
    if floating:
        J[0, 0] = J[1, 1] = 1.0
    for j, c in coeffs.items():
        J[:, j] += c * dd(theta[j])
    return J


def position(coeffs, theta, base):
    p = np.array(base, dtype=float)
    for j, c in coeffs.items():
        p = p + c * d(theta[j])
    return p


def mass_matrix(bodies, theta, floating):
    n = len(theta)
    M = np.zeros((n, n))
    for m, inertia, c, a in bodies:
        J = jacobian(c, theta, n, floating)
        M += m * J.T @ J
        if a is not None:
            M[a, a] += inertia
    return M


def accelerations(walker, bodies, theta, omega):
    """theta'' of a chain from a fixed stance foot (Lagrange, absolute angles)."""
    n = len(theta)
    M = mass_matrix(bodies, theta, False)
    rhs = np.zeros(n)
    for m, _, c, _ in bodies:
        J = jacobian(c, theta, n, False)
        centripetal = sum(cj * omega[j] ** 2 * (-d(theta[j])) for j, cj in c.items()) if c else 0.0
        rhs += m * J.T @ (walker.g - centripetal)
    return np.linalg.solve(M, rhs)


def flight(walker, bodies, theta0, omega0, t_end, events=(), rtol=1e-11, atol=1e-13, **kw):
    n = len(theta0)

    def f(t, y):
        return np.concatenate([y[n:], accelerations(walker, bodies, y[:n], y[n:])])

    return solve_ivp(f, (0.0, t_end), np.concatenate([theta0, omega0]), method="DOP853",
                     rtol=rtol, atol=atol, events=list(events), dense_output=True, **kw)


# -- the floating description of a phase's state -------------------------------------------
def floating_state(walker, stance, theta, omega, foot=(0.0, 0.0)):
    """(q, v) floating from a phase's theta: stance 'a' or 'b'; theta of length 3 or 2."""
    if len(theta) == 2:
        theta = np.array([theta[0], theta[1], theta[1]])
        omega = np.array([omega[0], omega[1], omega[1]])
    phi_s, phi_t, phi_k = theta
    w_s, w_t, w_k = omega
    hip = np.asarray(foot) - walker.leg * d(phi_s)
    v_hip = -walker.leg * w_s * dd(phi_s)
    if stance == "a":
        ang, rates = (phi_s, phi_s, phi_t, phi_k), (w_s, w_s, w_t, w_k)
    else:
        ang, rates = (phi_t, phi_k, phi_s, phi_s), (w_t, w_k, w_s, w_s)
    return np.concatenate([hip, ang]), np.concatenate([v_hip, rates])


def impact(walker, q, v, rows):
    """v+ and the impulses P (one per row) of M (v+ - v-) = A^T P, A v+ = 0 (floating)."""
    bodies = walker.floating_bodies()
    M = mass_matrix(bodies, q, True)
    A = []
    for row in rows:
        if row[0] == "foot":
            A.extend(jacobian(walker.foot(row[1]), q, 6, True))
        else:                                   # ("knee", leg): phi_shank - phi_thigh locked
            t = 2 if row[1] == "a" else 4
            r = np.zeros(6)
            r[t], r[t + 1] = -1.0, 1.0
            A.append(r)
    A = np.array(A)
    k = len(A)
    K = np.block([[M, -A.T], [A, np.zeros((k, k))]])
    sol = np.linalg.solve(K, np.concatenate([M @ v, np.zeros(k)]))
    return sol[:6], sol[6:]


def kinetic(walker, q, v):
    return 0.5 * v @ mass_matrix(walker.floating_bodies(), q, True) @ v


def angular_momentum(walker, q, v, about, which=None):
    """About a point, of the bodies listed (indices into floating_bodies; all by default)."""
    bodies = walker.floating_bodies()
    total = 0.0
    for i, (m, inertia, c, a) in enumerate(bodies):
        if which is not None and i not in which:
            continue
        p = position(c, q, q[:2]) - np.asarray(about)
        u = jacobian(c, q, 6, True) @ v
        total += m * (p[0] * u[1] - p[1] * u[0]) + (inertia * v[a] if a is not None else 0.0)
    return total


def foot_position(walker, q, leg):
    return position(walker.foot(leg), q, q[:2])


def _rows(walker, q, v, rows):
    """The rows A and A' v of a set of constraints (floating coordinates)."""
    A, Adv = [], []
    for row in rows:
        if row[0] == "foot":
            c = walker.foot(row[1])
            A.extend(jacobian(c, q, 6, True))
            Adv.extend(sum(cj * v[j] ** 2 * (-d(q[j])) for j, cj in c.items()))
        else:
            t = 2 if row[1] == "a" else 4
            r = np.zeros(6)
            r[t], r[t + 1] = -1.0, 1.0
            A.append(r)
            Adv.append(0.0)
    return np.array(A), np.array(Adv)


def constrained_dynamics(walker, q, v, rows):
    """(q'', multipliers) of M q'' + h = A^T lam, A q'' + A' v = 0 (floating): a foot row's multiplier is
    the force on the foot (x, y), a knee row's the holding moment on the shank."""
    bodies = walker.floating_bodies()
    M = mass_matrix(bodies, q, True)
    rhs = np.zeros(6)
    for m, _, c, _ in bodies:
        J = jacobian(c, q, 6, True)
        centripetal = sum(cj * v[j] ** 2 * (-d(q[j])) for j, cj in c.items()) if c else 0.0
        rhs += m * J.T @ (walker.g - centripetal)
    A, Adv = _rows(walker, q, v, rows)
    k = len(A)
    K = np.block([[M, -A.T], [A, np.zeros((k, k))]])
    sol = np.linalg.solve(K, np.concatenate([rhs, -Adv]))
    return sol[:6], sol[6:]


# -- the step map on the section just after a heel strike (the new swing knee unlocked) -------------
def _knee_extends(t, y):
    return y[2] - y[1]


_knee_extends.terminal, _knee_extends.direction = True, 1


def step(walker, x, rtol=1e-11):
    """One step from x = (phi_s, omega_s, omega_w) just after a heel strike (stance foot at the
    origin, the swing leg straight, phi_w = -phi_s: both feet on the slope, the swing knee just
    unlocked): swing with the knee free to the knee strike (knee angle back to 0, plastic), then with
    the knee locked to the heel strike (the swing foot on the slope with the swing leg ahead, by 0.05
    rad at least: the mid-stance scuff of the locked leg is not a strike), the strike solved with both
    knees locked; the legs swap.  Returns (x+, t_knee, t_heel)."""
    phs, ws, ww = x
    swing = flight(walker, walker.swing_bodies(), np.array([phs, -phs, -phs]), np.array([ws, ww, ww]), 5.0,
                   events=[_knee_extends], first_step=1e-6, rtol=rtol)
    if swing.status != 1:
        raise RuntimeError("no knee strike")
    t_knee, y = swing.t_events[0][0], swing.y_events[0][0]
    q, v = floating_state(walker, "a", y[:3], y[3:])
    v, _ = impact(walker, q, v, [("foot", "a"), ("knee", "a"), ("knee", "b")])

    def heel(t, y):
        return walker.leg * (np.cos(y[0]) - np.cos(y[1])) if y[1] > y[0] + 0.05 else 1.0

    heel.terminal, heel.direction = True, -1
    locked = flight(walker, walker.locked_bodies(), np.array([q[2], q[4]]), np.array([v[2], v[4]]), 5.0,
                    events=[heel], rtol=rtol)
    if locked.status != 1:
        raise RuntimeError("no heel strike")
    y = locked.y_events[0][0]
    q, v = floating_state(walker, "a", y[:2], y[2:])
    v, _ = impact(walker, q, v, [("foot", "b"), ("knee", "a"), ("knee", "b")])
    return np.array([q[4], v[4], v[2]]), t_knee, t_knee + locked.t_events[0][0]
