"""Self-tests of issue 24's independent references (no pcmm): each reference is checked against
closed forms, conservation laws and a second algorithm, so the references can later judge pcmm.

* :mod:`reference_rimless_wheel`: McGeer's strike ratio against a direct impulse solve of the hub
  as a free planar body pinned at the new foot; the energy-balance fixed point; the strike
  sequence by quadrature against an ODE with event location; the old foot separating.
* :mod:`reference_compass_gait`: the hand-derived swing equations against Lagrange's equations
  built from the point masses alone; the Q+/Q- heel-strike map against a floating-base impulse
  solve (Drake's route); both angular momenta conserved; the period-one gait against the published
  one (Goswami et al. 1998).
* :mod:`reference_rod_friction`: the Delassus matrix against unit impulses on the body; momentum,
  angular momentum and energy balances; stick and slide outcomes against hand-derived closed forms
  on both sides of the critical mu; the critical mu against a bisection on Routh's process;
  Newton / Poisson / Stronge; the Painleve cases.
"""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

import reference_compass_gait as cg
import reference_rimless_wheel as rw
import reference_rod_friction as rf


# ======================================================================================= rimless wheel
W = rw.ISSUE


def test_issue_wheel_numbers_by_hand():
    # N = 6: alpha = pi/6, cos 2 alpha = 1/2: r = (0.05 + 0.5) / 1.05
    assert W.alpha == pytest.approx(math.pi / 6, abs=1e-15)
    assert W.r == pytest.approx(0.55 / 1.05, abs=1e-15)
    # the issue's formula, written out literally, against the reference's energy balance
    m, l, I, g, gam, a = 1.0, 1.0, 0.05, 9.81, 0.2, math.pi / 6
    r = (I + m * l * l * math.cos(2 * a)) / (I + m * l * l)
    issue = r * math.sqrt(4 * m * g * l * math.sin(gam) * math.sin(a) / ((I + m * l * l) * (1 - r * r)))
    wp, wm = W.fixed_point()
    assert wp == pytest.approx(issue, rel=1e-15)
    assert (wp, wm) == pytest.approx((1.1847806767776679, 2.26185401930282), rel=1e-13)
    assert W.rolls_over(wp)


@pytest.mark.parametrize("N,I,omega", [(6, 0.05, 2.0), (6, 0.05, 0.7), (4, 0.0, 1.3), (9, 0.3, 3.1), (3, 0.01, 5.0)])
def test_strike_ratio_equals_direct_pin_impulse(N, I, omega):
    """McGeer's r from angular momentum about the new foot, against the impulse of a pin at the
    new foot on the hub as a free body (x, y, psi), M = diag(m, m, I)."""
    wheel = rw.RimlessWheel(N=N, I=I)
    out = wheel.strike_impulse(omega)
    assert out["omega_plus"] / omega == pytest.approx(wheel.r, abs=1e-14)
    np.testing.assert_allclose(out["v_new_foot_after"], 0.0, atol=1e-14)  # pinned: no slip, no bounce
    assert out["H_after"] == pytest.approx(out["H_before"], abs=1e-14)
    # plastic: energy lost, in the ratio r^2 of the rates (KE = J w^2 / 2 before and after about a foot)
    assert out["ke_after"] == pytest.approx(wheel.r ** 2 * out["ke_before"], rel=1e-13)
    assert out["P"][1] > 0  # compressive


def test_old_foot_separates_and_the_two_contact_lcp_has_one_solution():
    """At a strike the old foot (at rest, closed) is a unilateral contact too.  Active set
    {new pin}: the old foot leaves with a positive normal speed.  Active set {new pin, old foot
    normal}: its normal impulse comes out tensile.  So the complementarity problem's only solution
    leaves the old foot without impulse: it lifts off *because* the new foot's impulse separates it."""
    out = W.strike_impulse(2.0)
    assert out["v_old_foot_after"][1] > 0.5  # slope axes: y is the outward normal
    M, Jn, Jo = out["M"], out["J_new"], out["J_old"]
    v = out["v_before"]
    _, P = rw.kkt_impulse(M, np.vstack([Jn, Jo[1:2]]), v)
    assert P[2] < 0  # the old foot would have to pull: not admissible
    # and the old foot's impulse-free answer is the unique one: v_n,old after > 0 with P_old = 0


def test_strike_friction_needed():
    """The no-slip strike needs mu >= |P_t| / P_n; for this wheel, by hand from the pin solve:
    P = (JM^-1J^T)^-1 applied to the foot velocity; it does not depend on omega."""
    a = [W.strike_impulse(w)["P"] for w in (0.5, 2.0, 4.0)]
    ratios = [abs(p[0]) / p[1] for p in a]
    assert ratios == pytest.approx([ratios[0]] * 3, rel=1e-13)
    assert ratios[0] == pytest.approx(0.5412658773652739, rel=1e-12)


def test_strike_sequence_quadrature_against_ode_and_fixed_point_convergence():
    seq = W.strikes(1.5, 12)
    ode = W.strikes_ode(1.5, 12)
    for (t, wm, wp), (t2, wm2, wp2) in zip(seq, ode):
        assert t == pytest.approx(t2, abs=1e-10)
        assert (wm, wp) == pytest.approx((wm2, wp2), abs=1e-11)
        assert wp / wm == pytest.approx(W.r, abs=1e-15)
    wp_star, wm_star = W.fixed_point()
    assert abs(seq[9][2] - wp_star) < 1e-6  # the issue's 1e-6 after 10 strikes, from 1.5 rad/s
    # the step map w -> r sqrt(w^2 + c) contracts at the fixed point by r w+*/w-* = r^2
    errs = [s[2] - wp_star for s in seq]
    assert errs[8] / errs[7] == pytest.approx(W.r ** 2, rel=1e-5)
    # a stance from the fixed point returns to it
    assert W.strikes(wp_star, 1)[0][2] == pytest.approx(wp_star, abs=1e-14)


def test_stance_forces_match_the_hub_acceleration_and_stay_compressive():
    """The ground force at the pinned foot, F = m a - m g, against central differences of the ODE's
    hub positions; over the fixed-point stance it stays compressive (no lift-off)."""
    from scipy.integrate import solve_ivp
    wp, _ = W.fixed_point()
    sol = solve_ivp(W.rhs, (0, W.stance_time(wp)), [-W.alpha, wp], method="DOP853", rtol=1e-13, atol=1e-14,
                    dense_output=True)
    hub = lambda t: W.l * np.array([math.sin(sol.sol(t)[0]), math.cos(sol.sol(t)[0])])  # noqa: E731
    gvec = W.g * np.array([math.sin(W.gamma), -math.cos(W.gamma)])
    worst = 0.0
    ratios = []
    for t in np.linspace(0.05, sol.t[-1] - 0.05, 9):
        h = 1e-4
        acc = (hub(t + h) - 2 * hub(t) + hub(t - h)) / h ** 2
        Ft, Fn = W.stance_forces(*sol.sol(t))
        worst = max(worst, float(np.max(np.abs(W.m * acc - W.m * gvec - [Ft, Fn]))))
        assert Fn > 0
        ratios.append(abs(Ft) / Fn)
    assert worst < 1e-5
    # the stance's ends: the friction a no-slip stance needs is largest at its start
    Ft0, Fn0 = W.stance_forces(-W.alpha, wp)
    assert abs(Ft0) / Fn0 == pytest.approx(0.5525, abs=1e-4) and abs(Ft0) / Fn0 > max(ratios)


def test_slope_frame_state_of_the_wheel():
    """The scene's initial state: spoke 0's tip on the slope, spoke 1's tip on the slope exactly
    when phi reaches alpha, and the hub's speed l omega."""
    q, v = rw.slope_frame_state(W, -W.alpha, 1.5)
    R = lambda p: np.array([[math.cos(p), -math.sin(p)], [math.sin(p), math.cos(p)]])  # noqa: E731
    tip = lambda q, k: q[:2] + R(q[2]) @ rw.spoke_tip(W, k)  # noqa: E731
    np.testing.assert_allclose(tip(q, 0), 0.0, atol=1e-15)
    assert tip(q, 5)[1] == pytest.approx(0.0, abs=1e-15)  # the old foot, just left behind at the strike
    assert min(tip(q, k)[1] for k in (1, 2, 3, 4)) > 0.49
    assert np.linalg.norm(v[:2]) == pytest.approx(1.5 * W.l, rel=1e-15)
    q, _ = rw.slope_frame_state(W, W.alpha, 1.5)
    assert tip(q, 1)[1] == pytest.approx(0.0, abs=1e-15)  # the next strike: spoke 1
    assert tip(q, 1)[0] - tip(q, 0)[0] == pytest.approx(2 * W.l * math.sin(W.alpha), abs=1e-15)  # step length


# ======================================================================================= compass gait
C = cg.DRAKE


@pytest.mark.parametrize("seed", range(5))
def test_swing_equations_against_point_mass_lagrangian(seed):
    rng = np.random.default_rng(seed)
    q, v = rng.uniform(-1, 1, 2), rng.uniform(-3, 3, 2)
    np.testing.assert_allclose(C.accelerations(q, v), C.generic_accelerations(q, v), rtol=0, atol=1e-7)
    Js = C.point_jacobians(q)[:3]
    M = sum(m * J.T @ J for m, J in zip(C.masses(), Js))
    np.testing.assert_allclose(C.mass_matrix(q), M, atol=1e-13)


def test_swing_conserves_energy():
    from scipy.integrate import solve_ivp
    y0 = C.section([-0.22, 1.09, 0.38])
    sol = solve_ivp(C.rhs, (0, 0.7), y0, method="DOP853", rtol=1e-12, atol=1e-13, dense_output=True)
    E = [C.energy(sol.sol(t)) for t in np.linspace(0, 0.7, 15)]
    assert max(E) - min(E) < 1e-9 * abs(E[0])


@pytest.mark.parametrize("alpha,vs,vw", [(0.2, 2.0, -1.0), (0.27, 1.09, 0.38), (0.35, 0.7, -0.4)])
def test_heel_strike_closed_form_against_floating_base_impulse(alpha, vs, vw):
    y = np.array([C.gamma + alpha, C.gamma - alpha, vs, vw])
    a = C.strike(y)
    b, P, v_old = C.strike_floating_base(y)
    np.testing.assert_allclose(a, b, atol=1e-12)
    # the two angular momenta the map is built from, recomputed from the point masses
    pf = C.points(y[:2])[3]
    H_before = C.angular_momentum(y[:2], y[2:], about=pf)
    H_after = C.angular_momentum(a[:2], a[2:], about=pf, base=pf)
    assert H_after == pytest.approx(H_before, abs=1e-12)
    hip = C.points(y[:2])[1]
    trail_before = C.angular_momentum(y[:2], y[2:], about=hip, which=(0,))  # old stance leg's mass
    trail_after = C.angular_momentum(a[:2], a[2:], about=hip, base=pf, which=(2,))  # now the swing leg's
    assert trail_after == pytest.approx(trail_before, abs=1e-12)
    # impulse-momentum for the whole walker: Delta(linear momentum) = P
    Js = C.point_jacobians(y[:2])
    Jn = C.point_jacobians(a[:2])
    vel_before = [J @ y[2:] for J in Js[:3]]
    vel_after = [J @ a[2:] for J in Jn[:3]][::-1]  # new (stance mass, hip, swing mass) = old (swing, hip, stance)
    dp = sum(m * (va - vb) for m, va, vb in zip(C.masses(), vel_after, vel_before))
    np.testing.assert_allclose(dp, P, atol=1e-12)


def test_period_one_gait_and_published_values():
    x, ystar, T, eig = C.fixed_point()
    np.testing.assert_allclose(C.step_map(x), x, atol=1e-10)
    assert np.all(np.abs(eig) < 1)  # stable
    assert T == pytest.approx(0.73446, abs=1e-5)
    # energy balance of the period-one gait: what the strike takes is what the step's descent gives,
    # (2 m + mh) g d sin(gamma) with d = 2 l sin(alpha) the step length along the slope
    _, yb, ya = C.step(ystar)
    ke = lambda y: 0.5 * y[2:] @ C.mass_matrix(y[:2]) @ y[2:]  # noqa: E731
    d = 2 * C.l * math.sin((yb[0] - yb[1]) / 2)
    assert ke(yb) - ke(ya) == pytest.approx((2 * C.m + C.mh) * C.g * d * math.sin(C.gamma), rel=1e-9)
    np.testing.assert_allclose(ya, ystar, atol=1e-10)
    # Goswami, Thuilot & Espiau (1998), mu = mh/m = 2, beta = b/a = 1, phi = 3 deg: the stable
    # symmetric gait starts (just after heel strike) at (theta_ns, theta_s, theta_ns', theta_s')
    # = (-0.3234, 0.2187, -0.3772, -1.0918) rad, rad/s in their (counter-clockwise) convention.
    # Those velocities correspond to g = 9.8 (they scale as sqrt(g)); our Drake-convention angles are
    # their negatives, ordered (stance, swing).
    x, y, _, _ = cg.CompassGait(gamma=math.radians(3.0), g=9.8).fixed_point()
    goswami = np.array([-y[1], -y[0], -y[3], -y[2]])
    np.testing.assert_allclose(goswami, [-0.3234, 0.2187, -0.3772, -1.0918], atol=6e-5)


def test_drake_initial_condition_walks_onto_the_fixed_point():
    """Drake's simulate.cc starts at stance = swing = 0, stancedot = 0.4, swingdot = -2.0."""
    y = np.array([0.0, 0.0, 0.4, -2.0])
    for _ in range(30):
        _, _, y = C.step(y)
    _, ystar, _, _ = C.fixed_point()
    np.testing.assert_allclose(y, ystar, atol=1e-6)


def test_trailing_foot_lifts_off_at_the_fixed_point():
    """The compass gait assumes the old stance foot leaves without an impulse: after the strike its
    velocity along the slope normal must be positive, and with it held as a unilateral contact too
    its normal impulse would come out tensile."""
    _, ystar, _, _ = C.fixed_point()
    _, yb, _ = C.step(ystar)
    _, P, v_old = C.strike_floating_base(yb)
    t, n = C.slope_axes()
    assert n @ v_old == pytest.approx(0.3935, abs=1e-3)
    M, Jf, Js = C.floating_base(yb[:2])
    A = np.vstack([Jf, n @ Js])
    V = np.concatenate([[0.0, 0.0], yb[2:]])
    Minv = np.linalg.inv(M)
    lam = -np.linalg.solve(A @ Minv @ A.T, A @ V)
    assert lam[2] < 0
    # the friction the no-slip heel strike needs, |t.P| / n.P, with P the walker's change of linear
    # momentum (P = Delta p is checked in test_heel_strike_closed_form_against_floating_base_impulse)
    assert n @ P > 0
    assert abs(t @ P) / (n @ P) == pytest.approx(0.24579, abs=1e-5)


def test_slope_frame_state_of_the_walker():
    """The slope-frame view a scene uses: both feet where the reference puts them (rotated by gamma),
    and the hip velocity consistent."""
    _, ystar, _, _ = C.fixed_point()
    st = cg.slope_frame_state(C, ystar)
    Rg = np.array([[math.cos(C.gamma), -math.sin(C.gamma)], [math.sin(C.gamma), math.cos(C.gamma)]])  # world -> slope
    pts = C.points(ystar[:2])
    leg = lambda psi: np.array([math.sin(psi), -math.cos(psi)]) * C.l  # noqa: E731
    np.testing.assert_allclose(st["hip"], Rg @ pts[1], atol=1e-15)
    np.testing.assert_allclose(st["hip"] + leg(st["psi_stance"]), 0.0, atol=1e-15)
    np.testing.assert_allclose(st["hip"] + leg(st["psi_swing"]), Rg @ pts[3], atol=1e-15)
    np.testing.assert_allclose(st["hip_velocity"], Rg @ (C.point_jacobians(ystar[:2])[1] @ ystar[2:]), atol=1e-14)
    assert st["hip_joint"] == pytest.approx(st["psi_swing"] - st["psi_stance"], abs=1e-15)


def test_stance_foot_force_compressive_over_the_gait():
    """The stance foot's ground force against the rate of change of the walker's linear momentum
    along the integrated step (central differences of the ODE's dense output): it stays
    compressive (no lift-off in stance) and needs mu >= 0.2744 to stick."""
    from scipy.integrate import solve_ivp
    _, ystar, T, _ = C.fixed_point()
    sol = solve_ivp(C.rhs, (0, T), ystar, method="DOP853", rtol=1e-13, atol=1e-14, dense_output=True)

    def momentum(t):
        y = sol.sol(t)
        return sum(m * J @ y[2:] for m, J in zip(C.masses(), C.point_jacobians(y[:2])[:3]))
    t_, n_ = C.slope_axes()
    ratios, normals = [], []
    for t in np.linspace(0.01, T - 0.01, 40):
        F = C.stance_foot_force(sol.sol(t))
        h = 1e-4
        dp = (momentum(t + h) - momentum(t - h)) / (2 * h)
        np.testing.assert_allclose(F, dp - sum(C.masses()) * np.array([0.0, -C.g]), atol=1e-5)
    for t in np.linspace(0.0, T, 201):
        F = C.stance_foot_force(sol.sol(t))
        normals.append(n_ @ F)
        ratios.append(abs(t_ @ F) / (n_ @ F))
    assert min(normals) > 135.0
    assert max(ratios) == pytest.approx(0.2744, abs=1e-4)


def test_foot_scuffing_at_mid_stance():
    """Along the period-one step the swing foot dips below the slope while the swing leg is still
    behind the stance leg (theta_w > theta_s); Drake's guard ignores that crossing and fires only at
    the heel strike, where theta_w < theta_s."""
    from scipy.integrate import solve_ivp
    _, ystar, T, _ = C.fixed_point()
    sol = solve_ivp(C.rhs, (0, T), ystar, method="DOP853", rtol=1e-12, atol=1e-13, dense_output=True)
    ts = np.linspace(1e-3, T - 1e-3, 2000)
    h = np.array([C.swing_foot_height(sol.sol(t)[:2]) for t in ts])
    below = h < 0
    assert below.any()
    ys = sol.sol(ts[below])
    assert np.all(ys[1] > ys[0] - 1e-9)  # scuffing only while the swing leg is behind
    yT = sol.sol(T)
    assert yT[1] < yT[0] and C.swing_foot_height(yT[:2]) == pytest.approx(0.0, abs=1e-10)


# ======================================================================================= rod
R = rf.UNIFORM


@pytest.mark.parametrize("theta", [0.2, 0.7, 1.2, 2.0])
def test_delassus_against_unit_impulses(theta):
    for k, P in enumerate(np.eye(2)):
        vG, w = R.apply(theta, (0.0, 0.0), 0.0, P)
        np.testing.assert_allclose(R.contact_velocity(theta, vG, w), R.delassus(theta)[:, k], atol=1e-15)
    s, c = math.sin(theta), math.cos(theta)
    np.testing.assert_allclose(R.delassus(theta), [[1 + 3 * s * s, -3 * s * c], [-3 * s * c, 1 + 3 * c * c]], atol=1e-15)
    assert np.linalg.det(R.delassus(theta)) == pytest.approx(4.0, rel=1e-14)


CASES = [dict(theta=th, vG=vg, omega=w, mu=mu, e=e)
         for th, vg, w, mu, e in itertools.product([0.3, 0.9, 1.3], [(0.0, -2.0), (0.4, -1.0), (-0.7, -1.5)],
                                                   [0.0, 2.5], [0.1, 0.5, 1.2], [0.0, 0.6, 1.0])]


def _balances(case, out):
    m, I = R.m, R.inertia
    vG0, w0 = np.array(case["vG"]), case["omega"]
    np.testing.assert_allclose(m * (out.vG_after - vG0), out.P, atol=1e-13)
    r = R.offset(case["theta"])
    assert I * (out.omega_after - w0) == pytest.approx(r[0] * out.P[1] - r[1] * out.P[0], abs=1e-13)
    HA = lambda vG, w: I * w + m * (-r[0] * vG[1] + r[1] * vG[0])  # about A: G - A = -r  # noqa: E731
    assert HA(out.vG_after, out.omega_after) == pytest.approx(HA(vG0, w0), abs=1e-13)
    dKE = R.kinetic_energy(out.vG_after, out.omega_after) - R.kinetic_energy(vG0, w0)
    assert dKE == pytest.approx(out.W_n + out.W_t, abs=1e-13)
    assert out.W_t <= 1e-15  # friction never does positive work
    assert abs(out.P[0]) <= case["mu"] * out.P[1] * (1 + 1e-12)  # inside the cone
    return dKE


@pytest.mark.parametrize("case", CASES)
def test_routh_balances_and_restitution(case):
    out = rf.routh(R, **case)
    _balances(case, out)
    assert out.v_contact_after[1] == pytest.approx(-case["e"] * out.v_contact_before[1], abs=1e-13)
    if out.final == "stick":  # the final contact velocity (0, -e vn-) fixes the impulse
        np.testing.assert_allclose(out.P, rf.stick_impulse(R, case["theta"], case["vG"], case["omega"], case["e"]),
                                   atol=1e-13)


@pytest.mark.parametrize("theta", [math.radians(d) for d in (15, 30, 45, 60, 75)])
@pytest.mark.parametrize("e", [0.0, 0.5, 1.0])
def test_rod_falling_in_translation_closed_form(theta, e):
    """A rod falling with speed v, no spin, no slip before: derived by hand (module text).
    Sticks iff mu >= mu_c = 3 s c / (1 + 3 s^2); then P = (m/4)(1+e) v (3 s c, 1 + 3 s^2).
    Slides (A moving away from G's side) below it: P_n = m (1+e) v / (1 + 3 c^2 - 3 mu s c),
    P_t = mu P_n.  Post-impact: vG = (P_t, -v + P_n)/m, omega = 6 (s P_t - c P_n)/(m L)."""
    v, m, L = 2.0, R.m, R.L
    s, c = math.sin(theta), math.cos(theta)
    mu_c = 3 * s * c / (1 + 3 * s * s)
    assert rf.critical_mu(R, theta, (0.0, -v), 0.0, e) == pytest.approx(mu_c, abs=1e-15)
    for mu in (0.5 * mu_c, 0.999 * mu_c, 1.001 * mu_c, 2 * mu_c):
        out = rf.routh(R, theta, (0.0, -v), 0.0, mu, e)
        if mu >= mu_c:
            P = m / 4 * (1 + e) * v * np.array([3 * s * c, 1 + 3 * s * s])
            assert out.final == "stick" and len(out.phases) <= 2
        else:
            Pn = m * (1 + e) * v / (1 + 3 * c * c - 3 * mu * s * c)
            P = np.array([mu * Pn, Pn])
            assert out.final == "slide" and {p.sigma for p in out.phases} == {-1}
        np.testing.assert_allclose(out.P, P, rtol=0, atol=1e-12)
        np.testing.assert_allclose(out.vG_after, [P[0] / m, -v + P[1] / m], atol=1e-12)
        assert out.omega_after == pytest.approx(6 * (s * P[0] - c * P[1]) / (m * L), abs=1e-12)
        dKE = _balances(dict(theta=theta, vG=(0.0, -v), omega=0.0, mu=mu, e=e), out)
        assert dKE <= 1e-15
        # energy lost to the normal and tangential parts
        if mu >= mu_c:  # stick: no slip ever, so no friction work; normal work -(1-e^2) v^2 det/(2 W_tt)
            assert out.W_t == pytest.approx(0.0, abs=1e-15)
            assert out.W_n == pytest.approx(-(1 - e * e) * v * v * m / (2 * (4 / (1 + 3 * s * s))), abs=1e-12)
        else:
            assert out.W_n == pytest.approx(-(1 - e * e) * v * v * m / (2 * (1 + 3 * c * c - 3 * mu * s * c)), abs=1e-12)


def _bisect(pred, lo, hi, n=200):
    """The boundary of a predicate false at lo, true at hi."""
    assert not pred(lo) and pred(hi)
    for _ in range(n):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if pred(mid) else (mid, hi)
        if hi - lo < 1e-15:
            break
    return 0.5 * (lo + hi)


@pytest.mark.parametrize("theta", [0.3, 0.8, 1.3])
def test_critical_mu_closed_form_against_bisection(theta):
    # no initial slip: stick/slip decision
    mu_b = _bisect(lambda mu: rf.routh(R, theta, (0.0, -1.0), 0.0, mu, 0.5).final == "stick", 0.0, 5.0)
    assert mu_b == pytest.approx(rf.critical_mu(R, theta, (0.0, -1.0), 0.0, 0.5), abs=1e-12)
    # initial slip (A slipping away from G's side, sigma = -1): slides to the end below mu*
    vG = (-0.8, -1.0)
    stops = lambda mu: any(p.why_end == "slip stops" for p in rf.routh(R, theta, vG, 0.0, mu, 0.5).phases)  # noqa: E731
    mu_b = _bisect(stops, 0.0, 20.0)
    assert mu_b == pytest.approx(rf.critical_mu(R, theta, vG, 0.0, 0.5), abs=1e-12)


def test_slip_stopped_by_coupling_whatever_mu():
    """A small slip towards G's side (sigma = +1, W_tn < 0) is stopped by the normal impulse alone:
    mu* <= 0, and Routh's process stops it at every mu, even 0."""
    th, vG = math.radians(30), (0.3, -1.0)
    assert rf.critical_mu(R, th, vG, 0.0, 0.5) == pytest.approx(-0.4355, abs=1e-4)
    for mu in (0.0, 0.3, 0.8):
        assert any(p.why_end == "slip stops" for p in rf.routh(R, th, vG, 0.0, mu, 0.5).phases)


def test_routh_against_the_algebraic_problem():
    """Where they agree (no slip change; slip stops then sticks) and where they do not (the slip
    reverses: mu < |kappa| = 0.7423 at 30 deg)."""
    th = math.radians(30)
    same = [((0.0, -2.0), 0.3), ((0.0, -2.0), 0.9), ((1.0, -1.0), 0.5), ((0.05, -1.0), 0.8)]
    for vG, mu in same:
        out = rf.routh(R, th, vG, 0.0, mu, 0.5)
        sols = rf.newton_lcp_solutions(R, th, vG, 0.0, mu, 0.5)
        assert len(sols) == 1
        np.testing.assert_allclose(sols[0][1], out.P, atol=1e-13)
    # reversal: Routh's impulse lies strictly inside the cone; the algebraic problem answers a full
    # reversed slide (mu = 0.3) or a "stick" the contact cannot keep (mu = 0.7 >= mu* = 0.6977)
    out = rf.routh(R, th, (0.05, -1.0), 0.0, 0.3, 0.5)
    assert [p.sigma for p in out.phases] == [1, -1, -1] and abs(out.P[0]) < 0.3 * out.P[1] * 0.95
    (kind, P), = rf.newton_lcp_solutions(R, th, (0.05, -1.0), 0.0, 0.3, 0.5)
    assert kind == "slide -1" and abs(P[0] - out.P[0]) > 0.01
    out = rf.routh(R, th, (0.05, -1.0), 0.0, 0.7, 0.5)
    assert out.final == "slide" and out.phases[-1].sigma == -1
    (kind, P), = rf.newton_lcp_solutions(R, th, (0.05, -1.0), 0.0, 0.7, 0.5)
    assert kind == "stick"


def test_newton_poisson_stronge():
    """They coincide without slip change; with slip stopping during the impact Newton's law raises
    the kinetic energy (e = 1), Poisson's and Stronge's do not, and Stronge's normal work is
    exactly (1 - e^2) W_c = 0."""
    th = math.radians(30)
    for law in ("poisson", "energetic"):
        a, b = rf.routh(R, th, (0.0, -2.0), 0.0, 0.3, 0.6), rf.routh(R, th, (0.0, -2.0), 0.0, 0.3, 0.6, law=law)
        np.testing.assert_allclose(a.P, b.P, atol=1e-13)
    case = rf.ENERGY_GAIN
    KE0 = R.kinetic_energy(case["vG"], case["omega"])
    newton = rf.routh(R, **case)
    poisson = rf.routh(R, **case, law="poisson")
    stronge = rf.routh(R, **case, law="energetic")
    assert [p.kind for p in newton.phases] == ["slide", "stick", "stick"]
    assert newton.energy_change == pytest.approx(0.034375, abs=1e-12)  # +6.8 % of KE-: energy created
    assert newton.energy_change / KE0 > 0.06
    assert poisson.energy_change < 0 and stronge.energy_change < 0
    assert stronge.W_n == pytest.approx((1 - case["e"] ** 2) * stronge.W_compression, abs=1e-15)
    # by hand: Newton's stick outcome leaves (0, -e vn-) = (0, 1): Delta KE = (P_t vt- + P_n (1-e) vn-)/2
    P = rf.stick_impulse(R, case["theta"], case["vG"], 0.0, 1.0)
    assert newton.energy_change == pytest.approx(0.5 * P[0] * 0.1, abs=1e-14)


def test_energy_never_rises_without_initial_slip():
    rng = np.random.default_rng(24)
    for _ in range(300):
        th, mu, e, v = rng.uniform(0.05, 1.5), rng.uniform(0, 2), rng.uniform(0, 1), rng.uniform(0.1, 5)
        w = rng.uniform(-3, 3)
        # choose u so that the contact does not slip before: u = -w (L/2) sin theta
        vG = (-w * 0.5 * R.L * math.sin(th), -v - abs(w) * 0.5 * R.L * math.cos(th) - 0.1)
        case = dict(theta=th, vG=vG, omega=w, mu=mu, e=e)
        if R.contact_velocity(th, vG, w)[1] >= 0:
            continue
        out = rf.routh(R, **case)
        assert _balances(case, out) <= 1e-13


def test_painleve_threshold_and_ambiguity():
    # threshold (1 + 3c^2)/(3sc): its minimum 4/3 at tan(theta) = 2, against a dense scan
    ths = np.linspace(0.05, 1.52, 20001)
    vals = [rf.painleve_threshold(R, t) for t in ths]
    k = int(np.argmin(vals))
    assert vals[k] == pytest.approx(4 / 3, abs=1e-7) and ths[k] == pytest.approx(math.atan(2), abs=1e-4)
    d = rf.PAINLEVE
    sols = rf.newton_lcp_solutions(R, **d)
    assert [s[0] for s in sols] == ["none", "stick"]  # two answers: the impact law is ambiguous
    np.testing.assert_allclose(sols[1][1], [0.4, 0.3], atol=1e-14)  # P = W^-1 (1, 0): an impact without collision
    # the force level: a sliding rod in contact, K < 0
    K, b, lam = rf.sliding_contact_forces(R, d["theta"], 0.0, -1.0, d["mu"])
    assert K == pytest.approx(1 + 3 / 5 - 1.5 * 3 * 2 / 5, abs=1e-14) and K < 0
    assert b < 0 and lam == []  # inconsistent: no contact force works
    K, b, lam = rf.sliding_contact_forces(R, d["theta"], 6.0, -1.0, d["mu"])
    assert b > 0 and len(lam) == 2  # ambiguous: lift off, or a compressive force
    K, b, lam = rf.sliding_contact_forces(R, d["theta"], 0.0, -1.0, 1.0)  # below 4/3: unique
    assert K > 0 and len(lam) == 1
    # Routh's process through a Painleve slide: the normal speed keeps falling until the slip stops
    out = rf.routh(R, d["theta"], (-1.0, -0.01), 0.0, 1.5, 0.0)
    assert out.painleve and out.phases[0].why_end == "slip stops" and out.final == "stick"
