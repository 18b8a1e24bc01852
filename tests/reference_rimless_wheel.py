"""Independent reference: the rimless wheel of issue 24 (numpy/scipy only, no pcmm).

Model (McGeer 1990, "Passive dynamic walking", Int. J. Robotics Research 9(2), 62-82, section on
the rimless wheel; also Coleman, Chatterjee & Ruina 1997, "Motions of a rimless spoked wheel: a
simple three-dimensional system with impacts", Dynamics and Stability of Systems 12(3)):
N massless spokes of length l, equally spaced by 2 alpha (alpha = pi / N), a hub point mass m with
rotational inertia I about the hub, rolling down a slope of angle gamma under gravity g.

Coordinates and frame
---------------------
The *slope frame*: x along the slope, pointing downhill, y along the slope's outward normal.
Gravity there is g (sin gamma, -cos gamma) (the "rotated gravity" a pcmm scene would use).
phi is the stance spoke's angle from the slope normal, positive when the hub is downhill of the
foot: hub = foot + l (sin phi, cos phi).  phi' > 0 while the wheel rolls downhill; the wheel's own
(counter-clockwise) angle then decreases, psi' = -phi'.  theta = phi + gamma is the same angle
measured from the vertical (Tedrake's "Underactuated Robotics", ch. "Simple models of walking").

Stance (a pinned foot: an inverted pendulum about the foot)
------------------------------------------------------------
The only forces are gravity and the foot's reaction, whose moment about the foot is zero, so
the angular momentum about the foot, J phi' with J = I + m l^2, changes by gravity's moment:

    J phi'' = m g l sin(phi + gamma)                                                     (1)

and the energy  E = J phi'^2 / 2 + m g l cos(phi + gamma)  is constant.  A stance starts at
phi = -alpha (just after a strike) and ends when the next spoke's tip reaches the slope,
phi = +alpha (the chord between two tips is perpendicular to their bisector, which is at phi
from the normal: the chord lies along the slope iff phi = alpha).  The time between strikes is
the quadrature  t = integral dphi / sqrt(omega0^2 + (2 m g l / J)(cos(phi0 + gamma) - cos(phi + gamma))).

Strike (plastic, no slip: the new foot is pinned where it lands)
-----------------------------------------------------------------
The only impulse acts at the new foot, so the wheel's angular momentum about the new foot is
conserved (gravity is finite; the old foot carries no impulse: it separates, see
:func:`strike_impulse`).  Before: the hub moves with speed l omega- perpendicular to the old
spoke; the new spoke makes 2 alpha with the old one, so the hub's momentum has moment arm
l cos 2 alpha about the new foot:  H- = (I + m l^2 cos 2 alpha) omega-.  After: the wheel turns
about the new foot, H+ = (I + m l^2) omega+.  Hence (McGeer 1990)

    omega+ = r omega-,   r = (I + m l^2 cos 2 alpha) / (I + m l^2).                       (2)

Fixed point (energy balance)
----------------------------
From phi = -alpha to +alpha the hub drops by l (cos(gamma - alpha) - cos(gamma + alpha))
= 2 l sin(gamma) sin(alpha), so  omega-^2 = omega+^2 + 4 m g l sin(gamma) sin(alpha) / J.
A period-one gait has omega+ = r omega- with the same omega- each step:

    omega-*^2 (1 - r^2) = 4 m g l sin(gamma) sin(alpha) / J
    omega+* = r sqrt(4 m g l sin(gamma) sin(alpha) / ((I + m l^2)(1 - r^2)))              (3)

This is the issue's formula: derived here independently, it agrees.  It exists only if the wheel
passes over the top of each stance (phi = -gamma when gamma < alpha):
J omega+*^2 / 2 > m g l (1 - cos(alpha - gamma)) (:meth:`RimlessWheel.rolls_over`).

Issue 24's wheel: N = 6, l = 1 m, m = 1 kg, I = 0.05 kg m^2, gamma = 0.2 rad, g = 9.81 m/s^2:
r = 0.55 / 1.05 = 0.523809..., omega-* = 2.2625 rad/s, omega+* = 1.1852 rad/s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import quad, solve_ivp


@dataclass(frozen=True)
class RimlessWheel:
    N: int = 6
    l: float = 1.0
    m: float = 1.0
    I: float = 0.05
    gamma: float = 0.2
    g: float = 9.81

    # ---- constants
    @property
    def alpha(self) -> float:
        """Half the angle between two spokes, pi / N."""
        return math.pi / self.N

    @property
    def J(self) -> float:
        """Moment of inertia about the stance foot, I + m l^2."""
        return self.I + self.m * self.l ** 2

    @property
    def r(self) -> float:
        """McGeer's strike ratio omega+/omega-, Eq. (2)."""
        return (self.I + self.m * self.l ** 2 * math.cos(2 * self.alpha)) / self.J

    @property
    def energy_gain(self) -> float:
        """omega-^2 - omega+^2 over one stance: 4 m g l sin(gamma) sin(alpha) / J."""
        return 4 * self.m * self.g * self.l * math.sin(self.gamma) * math.sin(self.alpha) / self.J

    def fixed_point(self) -> tuple[float, float]:
        """(omega+*, omega-*) of the period-one gait, Eq. (3)."""
        wm = math.sqrt(self.energy_gain / (1 - self.r ** 2))
        return self.r * wm, wm

    def rolls_over(self, omega_plus: float) -> bool:
        """Does a stance that starts at phi = -alpha with rate omega_plus pass the top?"""
        top = -self.gamma if self.gamma < self.alpha else -self.alpha
        need = 2 * self.m * self.g * self.l * (math.cos(top + self.gamma) - math.cos(self.gamma - self.alpha)) / self.J
        return omega_plus ** 2 > need

    # ---- stance
    def rhs(self, t, y):
        """Eq. (1) as a first-order system y = (phi, phi')."""
        phi, w = y
        return [w, self.m * self.g * self.l * math.sin(phi + self.gamma) / self.J]

    def omega_at(self, phi: float, phi0: float, omega0: float) -> float:
        """phi' at phi from energy conservation (the rolling branch, phi' > 0)."""
        w2 = omega0 ** 2 + 2 * self.m * self.g * self.l * (math.cos(phi0 + self.gamma) - math.cos(phi + self.gamma)) / self.J
        if w2 <= 0:
            raise ValueError(f"the wheel does not reach phi = {phi} from phi0 = {phi0} at {omega0} rad/s")
        return math.sqrt(w2)

    def stance_time(self, omega0: float, phi0: float | None = None, phi1: float | None = None) -> float:
        """Time from phi0 (default -alpha) to phi1 (default +alpha), by quadrature of 1/phi'."""
        phi0 = -self.alpha if phi0 is None else phi0
        phi1 = self.alpha if phi1 is None else phi1
        val, err = quad(lambda p: 1.0 / self.omega_at(p, phi0, omega0), phi0, phi1, epsabs=1e-14, epsrel=1e-13,
                        limit=200)
        return val

    def stance_forces(self, phi: float, omega: float) -> tuple[float, float]:
        """(F_t, F_n): the ground's force on the wheel at the pinned foot, slope axes.
        The hub's acceleration is l phi'' (cos phi, -sin phi) - l phi'^2 (sin phi, cos phi), and
        F = m a - m g_vec with g_vec = g (sin gamma, -cos gamma)."""
        acc = self.m * self.g * self.l * math.sin(phi + self.gamma) / self.J
        a = self.l * acc * np.array([math.cos(phi), -math.sin(phi)]) - self.l * omega ** 2 * np.array(
            [math.sin(phi), math.cos(phi)])
        F = self.m * a - self.m * self.g * np.array([math.sin(self.gamma), -math.cos(self.gamma)])
        return float(F[0]), float(F[1])

    # ---- strike
    def strike_impulse(self, omega_minus: float):
        """A second route to Eq. (2): the hub as a free planar body (x, y, psi), M = diag(m, m, I),
        with the new foot pinned (two rows, plastic normal and no slip) at phi = alpha, solved as
        the KKT system of :func:`kkt_impulse` (so I = 0, a point mass, is allowed: M is singular
        but positive definite on the motions the pin allows).

        Returns dict: omega_plus (= -psi'+), P (2-vector impulse on the wheel at the new foot,
        slope axes), v_old_foot_after (velocity of the old foot after the strike: its normal
        component must be > 0, the old foot separates), H_before / H_after (angular momentum about
        the new foot), ke_before / ke_after."""
        a, l = self.alpha, self.l
        M = np.diag([self.m, self.m, self.I])
        # hub at phi = alpha relative to the old foot; hub velocity l phi' (cos phi, -sin phi)
        v = np.array([l * omega_minus * math.cos(a), -l * omega_minus * math.sin(a), -omega_minus])
        r_new = l * np.array([math.sin(a), -math.cos(a)])  # new foot - hub
        r_old = l * np.array([-math.sin(a), -math.cos(a)])  # old foot - hub
        Jn = np.array([[1.0, 0.0, -r_new[1]], [0.0, 1.0, r_new[0]]])  # v_foot = v_hub + psi' z x r
        Jo = np.array([[1.0, 0.0, -r_old[1]], [0.0, 1.0, r_old[0]]])
        v_after, P = kkt_impulse(M, Jn, v)

        def H_new_foot(vel):  # about the new foot: hub at -r_new from it
            rh = -r_new
            return self.I * vel[2] + self.m * (rh[0] * vel[1] - rh[1] * vel[0])

        return {
            "omega_plus": float(-v_after[2]), "P": P, "v_after": v_after, "v_before": v,
            "v_old_foot_after": Jo @ v_after, "v_new_foot_after": Jn @ v_after,
            "H_before": H_new_foot(v), "H_after": H_new_foot(v_after),
            "ke_before": 0.5 * v @ M @ v, "ke_after": 0.5 * v_after @ M @ v_after,
            "M": M, "J_new": Jn, "J_old": Jo,
        }

    # ---- a run of strikes
    def strikes(self, omega0: float, n: int = 10, phi0: float | None = None, t0: float = 0.0):
        """The first ``n`` strikes from a stance at phi0 (default -alpha) with rate omega0 > 0.
        Each entry: (t, omega_minus, omega_plus) with t from the stance-time quadrature and the
        rates from energy conservation and Eq. (2)."""
        phi0 = -self.alpha if phi0 is None else phi0
        out = []
        t, w, p = t0, omega0, phi0
        for _ in range(n):
            t += self.stance_time(w, p, self.alpha)
            wm = self.omega_at(self.alpha, p, w)
            wp = self.r * wm
            out.append((t, wm, wp))
            w, p = wp, -self.alpha
        return out

    def strikes_ode(self, omega0: float, n: int = 10, phi0: float | None = None, rtol: float = 1e-12):
        """The same run by integrating Eq. (1) with scipy's DOP853 and locating phi = alpha as
        an event (a second, independent route to :meth:`strikes`)."""
        phi0 = -self.alpha if phi0 is None else phi0
        ev = lambda t, y: y[0] - self.alpha  # noqa: E731
        ev.terminal, ev.direction = True, 1.0
        out, t, y = [], 0.0, [phi0, omega0]
        for _ in range(n):
            sol = solve_ivp(self.rhs, (t, t + 100.0), y, method="DOP853", rtol=rtol, atol=1e-14, events=ev)
            t, wm = float(sol.t_events[0][0]), float(sol.y_events[0][0][1])
            wp = self.r * wm
            out.append((t, wm, wp))
            y = [-self.alpha, wp]
        return out


def spoke_tip(wheel: RimlessWheel, k: int) -> np.ndarray:
    """Spoke k's tip in the wheel's own frame, the numbering a scene would use: spoke 0 points
    down at psi = 0 and k counts counter-clockwise, so that spoke k + 1 is the next to strike when
    the wheel rolls downhill (+x, psi decreasing): l (sin 2 alpha k, -cos 2 alpha k)."""
    a = 2 * wheel.alpha * k
    return wheel.l * np.array([math.sin(a), -math.cos(a)])


def slope_frame_state(wheel: RimlessWheel, phi: float, omega: float, foot=(0.0, 0.0)):
    """(q, v) of the hub as a free planar body in the slope frame, (x, y, psi) and their rates,
    standing on spoke 0 at ``foot`` with stance angle phi and rate omega = phi' (psi = -phi)."""
    hub = np.asarray(foot, float) + wheel.l * np.array([math.sin(phi), math.cos(phi)])
    vel = wheel.l * omega * np.array([math.cos(phi), -math.sin(phi)])
    return np.array([hub[0], hub[1], -phi]), np.array([vel[0], vel[1], -omega])


def kkt_impulse(M, J, v_minus, target=None):
    """Impulsive KKT system  [[M, -J^T], [J, 0]] [v+; P] = [M v-; target]  (target 0: the rows
    J v+ = 0, plastic and no slip).  Returns (v+, P); P is the impulse along the rows.  Needs M
    positive definite on the null space of J only."""
    n, k = M.shape[0], J.shape[0]
    K = np.block([[M, -J.T], [J, np.zeros((k, k))]])
    rhs = np.concatenate([M @ v_minus, np.zeros(k) if target is None else target])
    sol = np.linalg.solve(K, rhs)
    return sol[:n], sol[n:]


ISSUE = RimlessWheel()
