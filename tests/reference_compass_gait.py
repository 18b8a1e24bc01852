"""Independent reference: the passive compass-gait walker (numpy/scipy only, no pcmm).

Model: Goswami, Thuilot & Espiau, "A study of the passive gait of a compass-like biped robot:
symmetry and chaos", Int. J. Robotics Research 17(12), 1282-1301, 1998 (and the longer INRIA
report RR-2996, "Compass-like biped robot Part I: stability and bifurcation of passive gaits",
1996).  Two kneeless legs of length l = a + b, each a point mass m at a from its foot (b from the
hip), a point mass mh at the hip, walking down a slope gamma.  Parameters of Drake's example
(RobotLocomotion/drake, examples/compass_gait/compass_gait_params_named_vector.yaml): mass_hip
mh = 10 kg, mass_leg m = 5 kg, length_leg l = 1 m, center_of_mass_leg b = 0.5 m (from the hip),
gravity 9.81, slope 0.0525 rad.  Goswami et al.'s normalized parameters are mu = mh/m = 2 and
beta = b/a = 1; their slope is phi = 3 deg = 0.05236 rad.

Coordinates (Drake's, examples/compass_gait/compass_gait.cc)
-------------------------------------------------------------
World axes: x horizontal (downhill), y up; the slope surface through the stance foot is
y = -x tan(gamma).  Each leg's angle theta is measured from the upward vertical with the leg
direction hip -> foot equal to -(sin theta, cos theta); ``stance`` = theta_s (positive: the hip
is downhill of the stance foot), ``swing`` = theta_w (negative: the swing foot is ahead).
Positions with the stance foot at the origin, e(theta) = (sin theta, cos theta):

    stance leg mass  p1 = a e(theta_s),  hip  ph = l e(theta_s),
    swing leg mass   p2 = ph - b e(theta_w),  swing foot  pf = ph - l e(theta_w).

Goswami et al. measure the same angles with the opposite sign (counter-clockwise positive, the
walker moving towards -x): theta_G = -theta_Drake.  Their state is ordered (theta_ns, theta_s).

Swing phase (Lagrange, derived by hand; :func:`generic_accelerations` is the second route)
------------------------------------------------------------------------------------------
With c = cos(theta_s - theta_w), s = sin(theta_s - theta_w):

    M = [[m a^2 + (mh + m) l^2, -m l b c], [-m l b c, m b^2]]
    M q'' + h = 0,  h = [-m l b s theta_w'^2 - (mh l + m (a + l)) g sin theta_s,
                          m l b s theta_s'^2 + m b g sin theta_w]
    E = q'^T M q' / 2 + g ((m a + mh l + m l) cos theta_s - m b cos theta_w)   (constant)

Heel strike
-----------
The swing foot is on the slope when the walker forms an isosceles triangle with it:
theta_s + theta_w = 2 gamma (the foot's height above the slope is
l (cos(theta_s - gamma) - cos(theta_w - gamma))).  The strike is plastic and the new foot does not
slip; the old stance foot leaves the ground without an impulse.  Two angular momenta are then
conserved (Goswami et al. 1998, Eq. (5); McGeer 1990):

* of the whole walker about the new stance foot (the only impulse acts there);
* of the trailing leg (the old stance leg) about the hip (its impulses act at the hip and, none,
  at its foot).

With alpha the half inter-leg angle (c = cos 2 alpha) and the legs swapped (the new stance leg is
the old swing leg), Q+ (theta_s'+, theta_w'+) = Q- (theta_s'-, theta_w'-):

    Q- = [[m a b - (mh l^2 + 2 m a l) c,  m a b], [m a b, 0]]
    Q+ = [[m b l c - m a^2 - (mh + m) l^2,  m b (l c - b)], [m b l c, -m b^2]]

(Goswami's Q matrices, with their column order (ns, s) and opposite sign of every angle; derived
here from H = sum m_i (p_i - P) x p_i'.)  :func:`strike_floating_base` is the second route:
a four-coordinate floating-base model (stance-foot position and the two angles) with the swing
foot pinned (two rows), v+ = v- - M^-1 J^T (J M^-1 J^T)^-1 J v-, which is how Drake's
``CollisionDynamics`` computes it.

Foot scuffing
-------------
With equal legs the swing foot passes through the slope near mid-stance: its height
l (cos(theta_s - gamma) - cos(theta_w - gamma)) is negative while |theta_w - gamma| < |theta_s -
gamma| with the swing leg behind the stance leg (theta_w > theta_s).  Goswami et al. neglect this
"foot scuffing" (a real walker shortens its swing leg: McGeer's knees or foot retraction); Drake's
witness function is max(2 gamma - theta_s - theta_w, theta_w - theta_s), i.e. a heel strike counts
only once the swing leg is ahead of the stance leg (theta_w < theta_s).  :func:`step` does the same.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import fsolve


@dataclass(frozen=True)
class CompassGait:
    mh: float = 10.0
    m: float = 5.0
    a: float = 0.5  # foot to leg mass
    b: float = 0.5  # hip to leg mass
    gamma: float = 0.0525
    g: float = 9.81

    @property
    def l(self) -> float:
        return self.a + self.b

    # ---- swing phase, by hand
    def mass_matrix(self, q):
        ts, tw = q
        c = math.cos(ts - tw)
        m, mh, a, b, l = self.m, self.mh, self.a, self.b, self.l
        return np.array([[m * a * a + (mh + m) * l * l, -m * l * b * c], [-m * l * b * c, m * b * b]])

    def bias(self, q, v):
        ts, tw = q
        vs, vw = v
        s = math.sin(ts - tw)
        m, mh, a, b, l, g = self.m, self.mh, self.a, self.b, self.l, self.g
        return np.array([-m * l * b * s * vw * vw - (mh * l + m * (a + l)) * g * math.sin(ts),
                         m * l * b * s * vs * vs + m * b * g * math.sin(tw)])

    def accelerations(self, q, v):
        return np.linalg.solve(self.mass_matrix(q), -self.bias(q, v))

    def rhs(self, t, y):
        return np.concatenate([y[2:], self.accelerations(y[:2], y[2:])])

    def energy(self, y):
        q, v = y[:2], y[2:]
        m, mh, a, b, l, g = self.m, self.mh, self.a, self.b, self.l, self.g
        V = g * ((m * a + mh * l + m * l) * math.cos(q[0]) - m * b * math.cos(q[1]))
        return 0.5 * v @ self.mass_matrix(q) @ v + V

    # ---- the point masses (a second route to everything above)
    def points(self, q, base=(0.0, 0.0)):
        """World positions of (stance-leg mass, hip, swing-leg mass, swing foot, stance foot);
        works on complex q (complex-step derivatives)."""
        ts, tw = q[0], q[1]
        e = lambda th: np.array([np.sin(th), np.cos(th)])  # noqa: E731
        o = np.asarray(base)
        ph = o + self.l * e(ts)
        return [o + self.a * e(ts), ph, ph - self.b * e(tw), ph - self.l * e(tw), o + 0 * ts]

    def masses(self):
        return [self.m, self.mh, self.m]

    def point_jacobians(self, q):
        """2 x 2 Jacobians of the three masses and the swing foot, by complex step (exact)."""
        h = 1e-30
        out = [np.zeros((2, 2)) for _ in range(4)]
        for k in range(2):
            dq = np.array(q, dtype=complex)
            dq[k] += 1j * h
            for i, p in enumerate(self.points(dq)[:4]):
                out[i][:, k] = p.imag / h
        return out

    def generic_accelerations(self, q, v, h=1e-5):
        """Lagrange's equations from the point masses alone: M = sum m J^T J, the velocity
        product sum m J^T (J' v) with J' v by central differences of the complex-step Jacobians
        along v, gravity sum J^T m g.  Independent of the closed forms above (accurate to ~1e-9)."""
        Js = self.point_jacobians(q)[:3]
        M = sum(mi * J.T @ J for mi, J in zip(self.masses(), Js))
        Jp = self.point_jacobians(np.asarray(q) + h * np.asarray(v))[:3]
        Jm = self.point_jacobians(np.asarray(q) - h * np.asarray(v))[:3]
        cor = sum(mi * J.T @ ((A - B) / (2 * h) @ v) for mi, J, A, B in zip(self.masses(), Js, Jp, Jm))
        grav = sum(mi * J.T @ np.array([0.0, -self.g]) for mi, J in zip(self.masses(), Js))
        return np.linalg.solve(M, grav - cor)

    def angular_momentum(self, q, v, about, base=(0.0, 0.0), which=(0, 1, 2)):
        """sum m_i (p_i - about) x p_i' over the masses ``which`` (0 stance-leg mass, 1 hip,
        2 swing-leg mass), with absolute velocities, stance foot at ``base``."""
        pts = self.points(q, base)
        Js = self.point_jacobians(q)
        H = 0.0
        for i in which:
            r = pts[i] - np.asarray(about)
            vel = Js[i] @ v
            H += self.masses()[i] * (r[0] * vel[1] - r[1] * vel[0])
        return float(H)

    def stance_foot_force(self, y, h=1e-6):
        """The ground's force on the walker at the stance foot during a swing (world axes):
        F = sum m_i a_i - sum m_i g, with a_i = J_i q'' + J_i' q' (J_i' q' by central differences
        of the complex-step Jacobians along q')."""
        q, v = np.asarray(y[:2], float), np.asarray(y[2:], float)
        a = self.accelerations(q, v)
        Js, Jp, Jm = (self.point_jacobians(x)[:3] for x in (q, q + h * v, q - h * v))
        F = np.zeros(2)
        for mi, J, A, B in zip(self.masses(), Js, Jp, Jm):
            F += mi * (J @ a + (A - B) / (2 * h) @ v) - mi * np.array([0.0, -self.g])
        return F

    # ---- heel strike
    def swing_foot_height(self, q):
        """Height of the swing foot above the slope (along the slope normal)."""
        return self.l * (math.cos(q[0] - self.gamma) - math.cos(q[1] - self.gamma))

    def strike_matrices(self, q):
        """(Q-, Q+) at the pre-impact pose q = (theta_s, theta_w), closed form."""
        m, mh, a, b, l = self.m, self.mh, self.a, self.b, self.l
        c = math.cos(q[0] - q[1])
        Qm = np.array([[m * a * b - (mh * l * l + 2 * m * a * l) * c, m * a * b], [m * a * b, 0.0]])
        Qp = np.array([[m * b * l * c - m * a * a - (mh + m) * l * l, m * b * (l * c - b)], [m * b * l * c, -m * b * b]])
        return Qm, Qp

    def strike(self, y):
        """Heel strike and leg swap by Q+ v+ = Q- v-: the post-impact state (new stance =
        old swing)."""
        q, v = y[:2], y[2:]
        Qm, Qp = self.strike_matrices(q)
        v_new = np.linalg.solve(Qp, Qm @ v)
        return np.array([q[1], q[0], v_new[0], v_new[1]])

    def floating_base(self, q):
        """(M, J_swing_foot, J_stance_foot) of the four-coordinate floating-base walker
        (x, y of the stance foot, theta_s, theta_w), from the point masses."""
        Js = self.point_jacobians(q)
        blocks = []
        for J in Js:
            blocks.append(np.hstack([np.eye(2), J]))  # d p / d (x, y, theta_s, theta_w)
        M = sum(mi * B.T @ B for mi, B in zip(self.masses(), blocks[:3]))
        J_foot = blocks[3]
        J_stance = np.hstack([np.eye(2), np.zeros((2, 2))])
        return M, J_foot, J_stance

    def strike_floating_base(self, y):
        """Second route to :meth:`strike`: the impulse on the floating-base model with the swing
        foot pinned; returns (post-impact swapped state, impulse on the walker at the new foot
        (world axes), the old stance foot's velocity after (world axes))."""
        q, v = y[:2], y[2:]
        M, Jf, Js = self.floating_base(q)
        V = np.concatenate([[0.0, 0.0], v])
        Minv = np.linalg.inv(M)
        P = -np.linalg.solve(Jf @ Minv @ Jf.T, Jf @ V)
        Va = V + Minv @ Jf.T @ P
        return np.array([q[1], q[0], Va[3], Va[2]]), P, Js @ Va

    def slope_axes(self):
        """(tangent downhill, outward normal) of the slope, world axes."""
        return (np.array([math.cos(self.gamma), -math.sin(self.gamma)]),
                np.array([math.sin(self.gamma), math.cos(self.gamma)]))

    # ---- one step and the fixed point
    def guard(self, t, y):
        """Drake's witness: max(2 gamma - theta_s - theta_w, theta_w - theta_s) crossing to <= 0."""
        return max(2 * self.gamma - y[0] - y[1], y[1] - y[0])

    def step(self, y0, rtol=1e-12, atol=1e-13, t_max=10.0):
        """Swing from y0 to the heel strike and through it: (t_strike, state before, state after)."""
        ev = lambda t, y: self.guard(t, y)  # noqa: E731
        ev.terminal, ev.direction = True, -1.0
        sol = solve_ivp(self.rhs, (0.0, t_max), y0, method="DOP853", rtol=rtol, atol=atol, events=ev)
        if not sol.t_events[0].size:
            raise RuntimeError("no heel strike within t_max (the walker fell or stopped)")
        y = sol.y_events[0][0]
        return float(sol.t_events[0][0]), y, self.strike(y)

    def section(self, x):
        """The state just after a heel strike from the section's coordinates
        x = (theta_s, theta_s', theta_w'), theta_w = 2 gamma - theta_s."""
        return np.array([x[0], 2 * self.gamma - x[0], x[1], x[2]])

    def step_map(self, x, **kw):
        _, _, y = self.step(self.section(x), **kw)
        return np.array([y[0], y[2], y[3]])

    def fixed_point(self, guess=(-0.2187, 1.0918, 0.3772), **kw):
        """The period-one gait on the post-impact section, by scipy's fsolve (MINPACK hybrd)
        on P(x) - x; returns (x*, the state after the strike, step period, eigenvalues of the
        step map's Jacobian by central differences)."""
        x = fsolve(lambda x: self.step_map(x, **kw) - x, np.asarray(guess, float), xtol=1e-13)
        T, _, _ = self.step(self.section(x), **kw)
        eps = 1e-6
        Jm = np.column_stack([(self.step_map(x + eps * e, **kw) - self.step_map(x - eps * e, **kw)) / (2 * eps)
                              for e in np.eye(3)])
        return x, self.section(x), T, np.linalg.eigvals(Jm)


def slope_frame_state(walker: CompassGait, y):
    """A scene's view of the Drake-convention state y = (theta_s, theta_w, rates), stance foot at
    the origin of the *slope* frame (x downhill along the slope, y its normal; gravity there is
    g (sin gamma, -cos gamma)).  Each leg is a link whose frame sits at the hip with the leg along
    its -y axis, so its absolute angle is psi = -(theta - gamma).  Returns a dict: hip (x, y) and
    hip velocity, psi_stance, psi_swing, their rates, and the hip joint's angle psi_swing - psi_stance."""
    ps, pw = y[0] - walker.gamma, y[1] - walker.gamma  # angles from the slope normal
    hip = walker.l * np.array([math.sin(ps), math.cos(ps)])
    vhip = walker.l * y[2] * np.array([math.cos(ps), -math.sin(ps)])
    return {"hip": hip, "hip_velocity": vhip, "psi_stance": -ps, "psi_swing": -pw,
            "psi_stance_rate": -y[2], "psi_swing_rate": -y[3], "hip_joint": ps - pw, "hip_joint_rate": y[2] - y[3]}


DRAKE = CompassGait()  # Drake's compass_gait parameters (slope 0.0525)
GOSWAMI = CompassGait(gamma=math.radians(3.0))  # Goswami et al. 1998: mu = 2, beta = 1, phi = 3 deg
