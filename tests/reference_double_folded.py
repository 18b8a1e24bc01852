"""Independent reference model of Example 2 of Song et al. (Shock and Vibration 2020, 8837838):
the planar double-folded metamorphic mechanism (Figs. 10-17, Table 2).

Plain numpy/scipy; it imports neither pcmm nor pinocchio, so it can be used to check them.
The geometry is a reconstruction (the drawing of Fig. 11 is lost); every assumption is listed in
docs/example2_reconstruction.md.  Summary of the reconstruction:

    A (0, 0) frame pivot of the driven crank 1 (A-B), theta1 = pi + (pi/5) t.
    B-C coupler 2, C-D component 3 (the folding plate), D revolute + torsion spring between 3 and the
    slider 4, E = reference point of the slider on its horizontal guide y = -L_AEy.
    D and E both lie on the guide line; E is d_DE = 0.1418 m ahead (+x) of D on the slider.
    At t = 0 the angle C-D-E (link 3 against the slider, measured from the +x direction D->E) is
    theta0 = 1.095 rad and the spring is relaxed.  The stop is reached when x_E = 0.3195 m.

Model (Newton-Euler with Lagrange multipliers, maximal coordinates): each of the 4 bodies has the
coordinates (x_G, y_G, phi) of its mass centre and orientation; 11 holonomic constraints (revolutes
A, B, C, D: 2 rows each; driver phi1 - theta1(t): 1 row; prismatic E: y_G4 = const, phi4 = 0: 2 rows)
leave one degree of freedom in configuration 1.  Equations:

    M qdd + Phi_q^T lam = Q(q, qd),     Phi_q qdd = gamma - 2 a Phid - b^2 Phi   (Baumgarte, a=b=10)

The driving moment is M_A = -lam_driver (generalized constraint force -Phi_q^T lam on phi1).

Body frames (also the URDF frames recommended in the doc):
    link1: origin A, x axis A->B;  link2: origin B, x axis B->C;
    link3: origin D, x axis D->C (so its angle is the spring angle theta when the slider does not turn);
    slider: origin E, axes parallel to the frame's.
"""

import math

import numpy as np
from scipy.integrate import solve_ivp

# ----------------------------------------------------------------------------------------------
# Geometry and inertia
# ----------------------------------------------------------------------------------------------


def _build_geometry():
    L_AB, L_BC, L_CD, L_AEy = 0.08, 0.2, 0.09, 0.1425
    theta0 = 1.095
    theta1_0 = math.pi
    y_guide = -L_AEy
    d_DE = 0.1418  # fitted: the only free length (first impact at ~3.0039 s at x_E = 0.3195)
    # closed assembly at t = 0 (spring relaxed: angle of D->C is theta0, C above and right of D)
    B0 = (L_AB * math.cos(theta1_0), L_AB * math.sin(theta1_0))
    yC0 = y_guide + L_CD * math.sin(theta0)
    xC0 = B0[0] + math.sqrt(L_BC**2 - (yC0 - B0[1]) ** 2)  # C to the right of B
    D0 = (xC0 - L_CD * math.cos(theta0), y_guide)
    E0 = (D0[0] + d_DE, y_guide)
    m1, m2, m3, m4 = 0.075, 0.165, 0.162, 0.455
    J1, J_BC, J_DC = 6.3818e-5, 2.32e-3, 8.83e-4
    com1, com2, com3 = 0.5 * L_AB, 0.5 * L_BC, 0.5 * L_CD  # mass centres at mid-length (assumed)
    I1 = J1                                   # Table 2: about the mass centre
    I2 = J_BC - m2 * (L_BC - com2) ** 2       # Table 2 gives it about C (parallel-axis theorem)
    I3 = J_DC - m3 * (L_CD - com3) ** 2       # Table 2 gives it about C; com3 is measured from D
    slider_len, slider_h = d_DE, 0.04         # slider block from D to E (assumed; irrelevant to the dynamics)
    I4 = m4 * (slider_len**2 + slider_h**2) / 12.0
    return {
        # Table 2 / paper
        "L_AB": L_AB, "L_BC": L_BC, "L_CD": L_CD, "L_AEy": L_AEy,
        "m1": m1, "m2": m2, "m3": m3, "m4": m4,
        "J1": J1, "J_BC": J_BC, "J_DC": J_DC,
        "k": 3.24 / math.pi, "c": 0.18 / math.pi, "theta0": theta0,
        "g": 9.81,
        "theta1_0": theta1_0, "omega1": math.pi / 5.0,
        "x_stop": 0.3195,            # x of E when the slider is at the stop (Fig. 13)
        # reconstruction
        "A": (0.0, 0.0),
        "y_guide": y_guide,          # guide line of the slider: y of D and of E
        "d_DE": d_DE,                # E is d_DE ahead (+x) of D on the slider
        "B0": B0, "C0": (xC0, yC0), "D0": D0, "E0": E0,
        "x_E0": E0[0],
        "D_stop": (0.3195 - d_DE, y_guide),
        # mass centres in each body's own frame (see module docstring for the frames)
        "com_link1": (com1, 0.0), "com_link2": (com2, 0.0), "com_link3": (com3, 0.0),
        "com_slider": (-0.5 * d_DE, 0.0),
        # rotational inertias about the mass centres
        "I1": I1, "I2": I2, "I3": I3, "I4": I4,
        # initial absolute angles (rad): link1 (A->B), link2 (B->C), link3 (D->C), slider
        "phi1_0": theta1_0,
        "phi2_0": math.atan2(yC0 - B0[1], xC0 - B0[0]),
        "phi3_0": theta0,
        "phi4_0": 0.0,
        # suggested restitution for the stop (not given by the paper)
        "e_stop": 0.8,
    }


GEOMETRY = _build_geometry()

_S = np.array([[0.0, -1.0], [1.0, 0.0]])


def _R(p):
    c, s = math.cos(p), math.sin(p)
    return np.array([[c, -s], [s, c]])


def _crank_pin(theta1, G):
    return np.array([G["L_AB"] * math.cos(theta1), G["L_AB"] * math.sin(theta1)])


def _circle_intersections(P, r_p, Q, r_q):
    """Both intersections of circle(P, r_p) and circle(Q, r_q); (left, right) of the line P->Q."""
    d_vec = Q - P
    d = float(np.hypot(*d_vec))
    if d > r_p + r_q or d < abs(r_p - r_q):
        raise ValueError("loop cannot close: |PQ| = %.5f outside [%.5f, %.5f]" % (d, abs(r_p - r_q), r_p + r_q))
    a = (r_p**2 - r_q**2 + d**2) / (2 * d)
    h = math.sqrt(max(r_p**2 - a**2, 0.0))
    u = d_vec / d
    n = np.array([-u[1], u[0]])
    base = P + a * u
    return base + h * n, base - h * n


# ----------------------------------------------------------------------------------------------
# Positions
# ----------------------------------------------------------------------------------------------


def _positions(theta1, x_E, G):
    """Joint positions for a crank angle and a slider position (C on the assembly branch of t = 0:
    C to the left of the directed line B->D, i.e. above it)."""
    A = np.array(G["A"], dtype=float)
    B = _crank_pin(theta1, G)
    E = np.array([x_E, G["y_guide"]])
    D = E - np.array([G["d_DE"], 0.0])
    C_left, _ = _circle_intersections(B, G["L_BC"], D, G["L_CD"])
    return {"A": A, "B": B, "C": C_left, "D": D, "E": E, "slider": E.copy()}


def closed_form_positions(theta1, geometry=None):
    """Configuration 2 (slider locked at the stop, x_E = x_stop): the closed four-bar A-B-C-D with
    D fixed at D_stop.  Closed form: B on the crank circle, C the intersection of circle(B, L_BC) and
    circle(D_stop, L_CD) on the branch of the first impact (C left of the directed line B->D).
    Returns a dict of 2-vectors A, B, C, D, E (E = 'slider', the slider's reference point)."""
    G = GEOMETRY if geometry is None else geometry
    return _positions(theta1, G["x_stop"], G)


def config1_positions(theta1, x_E, geometry=None):
    """Configuration 1 positions for a given crank angle and slider position (same branch)."""
    G = GEOMETRY if geometry is None else geometry
    return _positions(theta1, x_E, G)


# ----------------------------------------------------------------------------------------------
# Newton-Euler model with Lagrange multipliers
# ----------------------------------------------------------------------------------------------


class _Model:
    def __init__(self, G, lock_slider=False):
        self.G = G
        self.lock = lock_slider
        L1, L2, L3 = G["L_AB"], G["L_BC"], G["L_CD"]
        c1, c2, c3 = G["com_link1"][0], G["com_link2"][0], G["com_link3"][0]
        cs = np.array(G["com_slider"])
        # joint points relative to the mass centre, in body axes
        s1A = np.array([-c1, 0.0]); s1B = np.array([L1 - c1, 0.0])
        s2B = np.array([-c2, 0.0]); s2C = np.array([L2 - c2, 0.0])
        s3D = np.array([-c3, 0.0]); s3C = np.array([L3 - c3, 0.0])       # link3 frame: origin D, x -> C
        s4D = np.array([-G["d_DE"], 0.0]) - cs                           # slider frame: origin E
        self.sE = -cs
        self.joints = [(0, s1A, None, None), (0, s1B, 1, s2B), (1, s2C, 2, s3C), (2, s3D, 3, s4D)]
        self.mdiag = np.array([G["m1"], G["m1"], G["I1"], G["m2"], G["m2"], G["I2"],
                               G["m3"], G["m3"], G["I3"], G["m4"], G["m4"], G["I4"]])
        self.nc = 12 if lock_slider else 11
        self.y4 = G["y_guide"] + cs[1]
        self.x4_lock = G["x_stop"] + cs[0]

    # q = [x1 y1 p1  x2 y2 p2  x3 y3 p3  x4 y4 p4] (mass centres)
    def q_from_points(self, P, phi1):
        G = self.G
        p2 = math.atan2(*(P["C"] - P["B"])[::-1])
        p3 = math.atan2(*(P["C"] - P["D"])[::-1])
        q = np.zeros(12)
        q[0:2] = P["A"] + _R(phi1) @ np.array(G["com_link1"]); q[2] = phi1
        q[3:5] = P["B"] + _R(p2) @ np.array(G["com_link2"]); q[5] = p2
        q[6:8] = P["D"] + _R(p3) @ np.array(G["com_link3"]); q[8] = p3
        q[9:11] = P["E"] + np.array(G["com_slider"]); q[11] = 0.0
        return q

    def phi(self, q, t):
        G = self.G
        r = [q[3 * i:3 * i + 2] for i in range(4)]
        p = [q[3 * i + 2] for i in range(4)]
        out = []
        for (i, si, j, sj) in self.joints:
            v = r[i] + _R(p[i]) @ si
            v = v - (r[j] + _R(p[j]) @ sj) if j is not None else v - np.array(G["A"])
            out.extend(v)
        out.append(p[0] - (G["theta1_0"] + G["omega1"] * t))
        out.append(q[10] - self.y4)
        out.append(q[11])
        if self.lock:
            out.append(q[9] - self.x4_lock)
        return np.array(out)

    def jac(self, q):
        J = np.zeros((self.nc, 12))
        p = [q[3 * i + 2] for i in range(4)]
        row = 0
        for (i, si, j, sj) in self.joints:
            J[row:row + 2, 3 * i:3 * i + 2] = np.eye(2)
            J[row:row + 2, 3 * i + 2] = _R(p[i]) @ _S @ si
            if j is not None:
                J[row:row + 2, 3 * j:3 * j + 2] = -np.eye(2)
                J[row:row + 2, 3 * j + 2] = -_R(p[j]) @ _S @ sj
            row += 2
        J[8, 2] = 1.0
        J[9, 10] = 1.0
        J[10, 11] = 1.0
        if self.lock:
            J[11, 9] = 1.0
        return J

    def gamma(self, q, v):
        """Right-hand side of Phi_q qdd = gamma (the driver is at constant speed: 0)."""
        gm = np.zeros(self.nc)
        p = [q[3 * i + 2] for i in range(4)]
        w = [v[3 * i + 2] for i in range(4)]
        row = 0
        for (i, si, j, sj) in self.joints:
            gg = _R(p[i]) @ si * w[i] ** 2
            if j is not None:
                gg = gg - _R(p[j]) @ sj * w[j] ** 2
            gm[row:row + 2] = gg
            row += 2
        return gm

    def spring_torque(self, q, v):
        G = self.G
        theta = q[8] - q[11]
        return -G["k"] * (theta - G["theta0"]) - G["c"] * (v[8] - v[11])

    def forces(self, q, v):
        Q = np.zeros(12)
        for i in range(4):
            Q[3 * i + 1] = -self.mdiag[3 * i] * self.G["g"]
        tau = self.spring_torque(q, v)
        Q[8] += tau
        Q[11] -= tau
        return Q

    def kkt(self, q):
        J = self.jac(q)
        K = np.zeros((12 + self.nc, 12 + self.nc))
        K[:12, :12] = np.diag(self.mdiag)
        K[:12, 12:] = J.T
        K[12:, :12] = J
        return K, J

    def accel(self, t, q, v, alpha=10.0, beta=10.0):
        K, J = self.kkt(q)
        ph = self.phi(q, t)
        dph = J @ v
        dph[8] -= self.G["omega1"]
        rhs = np.concatenate([self.forces(q, v), self.gamma(q, v) - 2 * alpha * dph - beta**2 * ph])
        sol = np.linalg.solve(K, rhs)
        return sol[:12], sol[12:]

    def velocity(self, q, free_row):
        """Velocities satisfying the constraints plus one extra row (free_row . v = 0)."""
        J = self.jac(q)
        b = np.zeros(self.nc)
        b[8] = self.G["omega1"]
        if free_row is None:
            return np.linalg.solve(J, b)
        return np.linalg.solve(np.vstack([J, free_row]), np.append(b, 0.0))

    def energy(self, q, v):
        G = self.G
        T = 0.5 * float(np.sum(self.mdiag * v**2))
        V = G["g"] * float(sum(self.mdiag[3 * i] * q[3 * i + 1] for i in range(4)))
        V += 0.5 * G["k"] * (q[8] - q[11] - G["theta0"]) ** 2
        return T, V


# ----------------------------------------------------------------------------------------------
# Public API
# ----------------------------------------------------------------------------------------------


def initial_state(geometry=None, initial_velocity="locked_spring"):
    """(q0, v0) at t = 0.  initial_velocity: 'locked_spring' (default: components 3 and 4 relatively
    at rest, i.e. d(theta)/dt = 0, the slider starts with the slider-crank velocity 0.0166 m/s) or
    'slider_at_rest'."""
    G = GEOMETRY if geometry is None else geometry
    m = _Model(G)
    P = _positions(G["theta1_0"], G["x_E0"], G)
    q0 = m.q_from_points(P, G["theta1_0"])
    row = np.zeros(12)
    if initial_velocity == "locked_spring":
        row[8] = 1.0
    elif initial_velocity == "slider_at_rest":
        row[9] = 1.0
    else:
        raise ValueError(initial_velocity)
    return q0, m.velocity(q0, row)


def simulate_config1(t_end=4.0, rtol=1e-10, geometry=None, initial_velocity="locked_spring",
                     stop_at_impact=True, max_step=0.005):
    """Configuration 1 (slider free on its guide, spring at D) from t = 0 until the slider reaches the
    stop (x_E = x_stop) or t_end.  Returns a dict of arrays t, x_slider (x of E), v_slider,
    driving_moment (moment of the motor at A on the crank, N m), theta (spring angle C-D-E),
    kinetic_energy, potential_energy (gravity + spring), constraint_residual (max |Phi|), and
    t_impact (first time x_E = x_stop, or None), v_impact, peak_speed."""
    G = GEOMETRY if geometry is None else geometry
    m = _Model(G)
    q0, v0 = initial_state(G, initial_velocity)
    cs = G["com_slider"][0]

    def rhs(t, y):
        a, _ = m.accel(t, y[:12], y[12:])
        return np.concatenate([y[12:], a])

    def hit(t, y):
        return y[9] - cs - G["x_stop"]

    hit.terminal = bool(stop_at_impact)
    hit.direction = 1.0
    sol = solve_ivp(rhs, (0.0, t_end), np.concatenate([q0, v0]), method="DOP853", rtol=rtol,
                    atol=1e-12, events=hit, max_step=max_step)
    if sol.status < 0:
        raise RuntimeError(sol.message)
    t = sol.t
    Y = sol.y
    M = np.empty_like(t)
    T = np.empty_like(t)
    V = np.empty_like(t)
    res = np.empty_like(t)
    for k, tk in enumerate(t):
        q, v = Y[:12, k], Y[12:, k]
        M[k] = -m.accel(tk, q, v)[1][8]
        T[k], V[k] = m.energy(q, v)
        res[k] = np.abs(m.phi(q, tk)).max()
    t_imp = float(sol.t_events[0][0]) if len(sol.t_events[0]) else None
    v_sl = Y[21].copy()
    return {
        "t": t,
        "x_slider": Y[9] - cs,
        "v_slider": v_sl,
        "driving_moment": M,
        "theta": Y[8] - Y[11],
        "kinetic_energy": T,
        "potential_energy": V,
        "constraint_residual": res,
        "t_impact": t_imp,
        "v_impact": float(sol.y_events[0][0][21]) if t_imp is not None else None,
        "peak_speed": float(np.max(np.abs(v_sl))),
        "state_at_end": Y[:, -1].copy(),
    }


def stop_impact(q, v, e=None, geometry=None):
    """Impact of the slider on the stop (stable impact: the crank keeps its prescribed speed).
    Solves [M Phi_q^T; Phi_q 0][dv; Lam] = [e_x4 P; 0] with v_x4+ = -e v_x4-.  Returns
    (v_plus, P, m_eff): P < 0 is the impulse of the stop on the slider (N s), m_eff the effective
    mass of the mechanism seen at the slider along x."""
    G = GEOMETRY if geometry is None else geometry
    e = G["e_stop"] if e is None else e
    m = _Model(G)
    K, _ = m.kkt(q)
    rhs = np.zeros(K.shape[0])
    rhs[9] = 1.0
    unit = np.linalg.solve(K, rhs)[:12]     # velocity change per unit impulse
    m_eff = 1.0 / unit[9]
    P = -(1.0 + e) * v[9] * m_eff
    return v + P * unit, P, m_eff


def config2_inverse_dynamics(t, geometry=None):
    """Configuration 2 with E locked at the stop (a closed-form four-bar driven by the crank): returns
    (driving moment at A, x-force of the stop on the slider, spring angle theta) at time t, from the
    same Newton-Euler equations with the extra constraint x_E = x_stop."""
    G = GEOMETRY if geometry is None else geometry
    m = _Model(G, lock_slider=True)
    th1 = G["theta1_0"] + G["omega1"] * t
    q = m.q_from_points(closed_form_positions(th1, G), th1)
    v = m.velocity(q, None)
    a, lam = m.accel(t, q, v, alpha=0.0, beta=0.0)
    return -lam[8], -lam[11], q[8] - q[11]


def macro_impact(e=None, geometry=None, v_lock=1e-4, dt_lock=1e-4, max_impacts=200):
    """Macro-impact at the stop: impact (stop_impact), free flight in configuration 1, impact, ...
    until the rebound speed falls below v_lock or two impacts are closer than dt_lock (the impacts
    accumulate; the slider is then taken as merged with the frame).  Returns a list of
    (t, P, v_before, v_after) per impact."""
    G = GEOMETRY if geometry is None else geometry
    e = G["e_stop"] if e is None else e
    m = _Model(G)
    cs = G["com_slider"][0]
    r = simulate_config1(t_end=10.0, geometry=G)
    if r["t_impact"] is None:
        return []
    t = r["t_impact"]
    y = r["state_at_end"]
    q, v = y[:12].copy(), y[12:].copy()

    def rhs(tt, yy):
        a, _ = m.accel(tt, yy[:12], yy[12:])
        return np.concatenate([yy[12:], a])

    def hit(tt, yy):
        return yy[9] - cs - G["x_stop"]

    hit.terminal = True
    hit.direction = 1.0
    impacts = []
    while len(impacts) < max_impacts:
        v_before = v[9]
        v, P, _ = stop_impact(q, v, e, G)
        impacts.append((t, P, v_before, v[9]))
        if abs(v[9]) < v_lock:
            break
        # leave the stop for a short event-free interval (a gap of exactly 0 would re-trigger)
        t_sep = t + 1e-6
        pre = solve_ivp(rhs, (t, t_sep), np.concatenate([q, v]), method="DOP853", rtol=1e-10,
                        atol=1e-13)
        sol = solve_ivp(rhs, (t_sep, t + 2.0), pre.y[:, -1], method="DOP853", rtol=1e-10,
                        atol=1e-13, events=hit, max_step=0.005)
        if not len(sol.t_events[0]):
            break
        t_next = float(sol.t_events[0][0])
        q, v = sol.y_events[0][0][:12].copy(), sol.y_events[0][0][12:].copy()
        if t_next - t < dt_lock:
            t = t_next
            break
        t = t_next
    return impacts
