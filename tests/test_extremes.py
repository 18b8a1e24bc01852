"""Numerical extremes: every case checks the laws, not just "no crash".

Laws checked at every impact (``assert_impact_laws``):
  * Newton's restitution on the contact normal: ``vn+ = -e vn-`` (``vn+ = 0`` for a merge);
  * the work of the impulse: ``KE+ - KE- = P (vn- + vn+) / 2`` and ``KE+ <= KE-``;
plus, per scene, the momentum that must be conserved (angular momentum about the only
pivot, linear and angular momentum of free bodies), the closure error of loops
(``traj.stats["constraint_drift_max"]``) and finite numbers in every trajectory array.

Scenes are written by ``builders`` into ``tmp_path``.  Cases that show a pcmm bug
are ``xfail(strict=True)`` with the bug in the reason.
"""
from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest
from scipy.integrate import quad

import builders
import suite_checks
import pcmm
from pcmm.cli import main as cli_main

G = builders.G
ACC_SPEED = 1e-6  # pcmm's default solver.accumulation_speed
ACC_INTERVAL = 1e-9  # pcmm's default solver.accumulation_interval
# After a bounce pcmm re-arms a stop's guard only once the gap has opened by a band of
# 1e-12 m (pcmm.events.guards.REARM_BAND, relative to max(1, |value|)); a ball whose bounce stays
# inside that band lands on the band instead of the floor: its next pre-impact speed is
# sqrt(v^2 + 2 g band), e.g. 45 % above the series for v = 4e-6 m/s.  Analytic impact times
# and speeds are checked only while the bounces clear the band with a wide margin.
REARM_BAND = 1e-12


def band_speed(g=G):
    return math.sqrt(2 * g * REARM_BAND)


# ---- helpers ---------------------------------------------------------------------------------
def run(path, **options):
    return pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(**options))


assert_finite = suite_checks.assert_finite


def assert_merge_rule(events, e, speed=ACC_SPEED, interval=ACC_INTERVAL):
    """A stop merges exactly when its impacts accumulate: post-impact speed e |vn-| <= speed
    or the impact follows the previous one of the same stop within ``interval``."""
    last = {}
    for ev in events:
        slow = e * abs(ev["normal_velocity"]["before"]) <= speed
        soon = ev["name"] in last and ev["t"] - last[ev["name"]] <= interval
        assert ev["merge"] == (slow or soon), (f"event '{ev['name']}' at t = {ev['t']!r}: merge = {ev['merge']} "
                                               f"with post-impact speed {e * abs(ev['normal_velocity']['before']):.3g}")
        last[ev["name"]] = ev["t"]


def assert_impact_laws(ev, e, rel=1e-9):
    """Restitution (or merge), impulse work and no energy gain at one impact event."""
    vb, va = ev["normal_velocity"]["before"], ev["normal_velocity"]["after"]
    P = ev["impulse"]["normal"]
    ke_b, ke_a = ev["kinetic_energy_before"], ev["kinetic_energy_after"]
    where = f"event '{ev['name']}' at t = {ev['t']:.12g} s"
    assert vb < 0, f"{where}: the contact is not approaching (vn- = {vb})"
    if ev["merge"]:
        assert abs(va) <= rel * abs(vb) + 1e-15, f"{where}: merge with vn+ = {va} (must be 0)"
    else:
        assert va == pytest.approx(-e * vb, rel=rel, abs=1e-15), \
            f"{where}: restitution residual vn+ + e vn- = {va + e * vb:.3g} (e = {e})"
    assert P >= 0, f"{where}: tensile impulse P = {P}"
    assert ke_a <= ke_b * (1 + 1e-12) + 1e-300, f"{where}: kinetic energy rises {ke_b!r} -> {ke_a!r}"
    assert ke_a - ke_b == pytest.approx(P * (vb + va) / 2, rel=1e-7, abs=1e-10 * ke_b + 1e-300), \
        f"{where}: KE+ - KE- = {ke_a - ke_b:.6g} but the impulse's work P (vn- + vn+)/2 = {P * (vb + va) / 2:.6g}"


def cross2(a, b):
    return float(a[0] * b[1] - a[1] * b[0])


def rot(th):
    c, s = math.cos(th), math.sin(th)
    return np.array([[c, -s], [s, c]])


def coords_at_end(traj, k):
    """{coordinate: value} at the end of segment k (the pre-impact state of event k)."""
    s = traj.segments[k]
    return dict(zip(s.coordinates, s.q[-1]))


deadline = suite_checks.deadline


# ---- closed forms ------------------------------------------------------------------------------
# Compound pendulum (uniform bar m, L on a pivot): I_O = m L^2 / 3, K = m g (L/2) / I_O = 1.5 g / L.
def pendulum_fall(q0, qs, L, g=G):
    """(t, omega-) from rest at q0 down to qs: t = int dq / |omega|, with q = q0 - s^2."""
    K = 1.5 * g / L
    f = lambda s: 2 * s / math.sqrt(2 * K * (math.sin(q0) - math.sin(q0 - s * s)))  # noqa: E731
    t, err = quad(f, 0.0, math.sqrt(q0 - qs), epsabs=1e-14, epsrel=1e-13, limit=200)
    assert err < 1e-10 * max(1.0, t)
    return t, -math.sqrt(2 * K * (math.sin(q0) - math.sin(qs)))


def ball_times(e, h, g=G):
    """Bouncing ball: t1 = sqrt(2h/g), v1 = sqrt(2gh), t_k = t1 + sum_{j<k} 2 e^j v1 / g,
    t_inf = t1 + 2 e v1 / (g (1 - e))."""
    t1, v1 = math.sqrt(2 * h / g), math.sqrt(2 * g * h)
    t_inf = t1 + 2 * e * v1 / (g * (1 - e)) if e < 1 else math.inf
    return t1, v1, t_inf


# ======================================================================================
# 1. restitution from 0 to 1
# ======================================================================================
RESTITUTIONS = [0.0, 1e-12, 0.5, 1 - 1e-12, 1.0]


@pytest.mark.parametrize("e", RESTITUTIONS)
def test_restitution_bouncing_ball(tmp_path, e):
    """A 2 kg ball dropped from 1 m.  e = 0 and e = 1e-12 merge at the first impact
    (post-impact speed e v1 <= 1e-6 m/s, the accumulation tolerance); e = 0.5 bounces
    geometrically and merges near t_inf; e = 1 - 1e-12 and 1 never accumulate."""
    h, m, t_end = 1.0, 2.0, 2.6
    t1, v1, t_inf = ball_times(e, h)
    traj = run(builders.ball(tmp_path, e, h=h, mass=m, t_end=t_end))
    assert_finite(traj)
    assert traj.events, "no impact"
    for k, ev in enumerate(traj.events):
        assert_impact_laws(ev, e)
        # linear momentum: m (v+ - v-) = P along the floor normal (+y)
        dv = ev["v_after"]["Y"] - ev["v_before"]["Y"]
        assert m * dv == pytest.approx(ev["impulse"]["normal"], rel=1e-10)
        # pre-impact speed of impact k+1 is e^k v1 (exact for a parabola between impacts)
        if v1 * e ** k >= 10 * band_speed():
            assert -ev["normal_velocity"]["before"] == pytest.approx(v1 * e ** k, rel=1e-8)
    assert_merge_rule(traj.events, e)
    if e * v1 <= ACC_SPEED:
        assert len(traj.events) == 1 and traj.events[0]["t"] == pytest.approx(t1, abs=1e-12)
        assert traj.segments[-1].configuration == "rest"
        np.testing.assert_allclose(traj.segments[-1].xy[:, -1], 0.0, atol=1e-12)
    elif e < 1 - 1e-6:
        last = traj.events[-1]
        assert last["merge"] and traj.segments[-1].configuration == "rest"
        assert abs(t_inf - last["t"]) <= 2 * max(ACC_SPEED, band_speed()) / (G * (1 - e)) + 1e-9
    else:
        period = 2 * v1 / G
        assert not any(ev["merge"] for ev in traj.events)
        assert len(traj.events) == math.floor((t_end - t1) / period) + 1
        energy = traj.series("kinetic") + traj.series("potential")
        assert np.ptp(energy) <= 1e-9 * m * G * h, f"energy drift {np.ptp(energy) / (m * G * h):.3g} (relative)"


@pytest.mark.parametrize("e", RESTITUTIONS)
def test_restitution_compound_pendulum(tmp_path, e):
    """A bar (1.5 kg, 0.6 m) released horizontal onto a stop at the vertical (its tip hits).
    At each impact the pivot impulse has no moment about the pivot, so the angular momentum
    about it jumps by the contact impulse's moment: I_O (w+ - w-) = (r x n) P."""
    m, L, qs = 1.5, 0.6, -math.pi / 2
    I_O = m * L * L / 3
    t_hit, w_minus = pendulum_fall(0.0, qs, L)
    traj = run(builders.pendulum(tmp_path, e, L=L, m=m, qs=qs, t_end=1.2))
    assert_finite(traj)
    first = traj.events[0]
    assert first["t"] == pytest.approx(t_hit, abs=1e-9)
    assert first["v_before"]["J1"] == pytest.approx(w_minus, rel=1e-8)
    for ev in traj.events:
        assert_impact_laws(ev, e)
        w_b, w_a = ev["v_before"]["J1"], ev["v_after"]["J1"]
        moment = cross2(ev["contact_point"], ev["normal"]) * ev["impulse"]["normal"]
        assert I_O * (w_a - w_b) == pytest.approx(moment, rel=1e-9)
    assert_merge_rule(traj.events, e)
    if e * L * abs(w_minus) <= ACC_SPEED:
        assert len(traj.events) == 1 and traj.segments[-1].configuration == "rest"
    if e == 1.0:  # elastic: the energy of the whole run is conserved
        energy = traj.series("kinetic") + traj.series("potential")
        scale = m * G * L / 2
        assert np.ptp(energy) <= 1e-8 * scale, f"energy drift {np.ptp(energy) / scale:.3g} (relative)"


# ======================================================================================
# 2. mass / inertia ratios 1e-6 .. 1e6 and lengths 1e-4 .. 1e2 m
# ======================================================================================
RATIOS = [1e-6, 1e-3, 1.0, 1e3, 1e6]


def two_link_momentum(q1, q2, w1, w2, m1, m2, L1, L2, I1, I2):
    """Angular momentum about the frame pivot J1 of two bars (centroids at mid-length):
    H = sum I_c omega + m r_c x v_c, by hand."""
    e = lambda a: np.array([math.cos(a), math.sin(a)])  # noqa: E731
    ep = lambda a: np.array([-math.sin(a), math.cos(a)])  # noqa: E731
    th2, W2 = q1 + q2, w1 + w2
    r1, v1 = L1 / 2 * e(q1), L1 / 2 * w1 * ep(q1)
    r2, v2 = L1 * e(q1) + L2 / 2 * e(th2), L1 * w1 * ep(q1) + L2 / 2 * W2 * ep(th2)
    terms = [I1 * w1, m1 * cross2(r1, v1), I2 * W2, m2 * cross2(r2, v2)]
    return sum(terms), sum(abs(x) for x in terms)


@pytest.mark.parametrize("ratio", RATIOS)
@pytest.mark.parametrize("e", [0.5, 1.0])
def test_mass_ratio_mobile_impact_in_a_chain(tmp_path, ratio, e):
    """Two bars on J1 (frame) and J2, no gravity; link 2 (mass ratio x link 1, inertia
    likewise) strikes a stop on link 1: a mobile impact between the links.  J1 is the only
    pivot, so the angular momentum about it is conserved through the impact and the run."""
    m1, m2, L1, L2 = 1.0, ratio, 0.5, 0.5
    I1, I2 = m1 * L1 ** 2 / 12, m2 * L2 ** 2 / 12
    traj = run(builders.two_link(tmp_path, e, m1, m2, L1=L1, L2=L2, t_end=0.5))
    assert_finite(traj)
    assert traj.events and traj.events[0]["kind"] == "mobile"
    for k, ev in enumerate(traj.events):
        assert_impact_laws(ev, e)
        q = coords_at_end(traj, k)
        H_b, scale = two_link_momentum(q["J1"], q["J2"], ev["v_before"]["J1"], ev["v_before"]["J2"],
                                       m1, m2, L1, L2, I1, I2)
        H_a, _ = two_link_momentum(q["J1"], q["J2"], ev["v_after"]["J1"], ev["v_after"]["J2"],
                                   m1, m2, L1, L2, I1, I2)
        assert abs(H_a - H_b) <= 1e-10 * scale, f"angular momentum about J1 jumps by {H_a - H_b:.3g} (scale {scale:.3g})"
    H = [two_link_momentum(*q, *v, m1, m2, L1, L2, I1, I2) for q, v in
         zip(zip(traj.series("q", "J1"), traj.series("q", "J2")), zip(traj.series("v", "J1"), traj.series("v", "J2")))]
    H0, scale = H[0]
    drift = max(abs(h - H0) for h, _ in H)
    assert drift <= 1e-8 * scale, f"angular momentum drift over the run {drift / scale:.3g} (relative)"


@pytest.mark.parametrize("ratio", RATIOS)
@pytest.mark.parametrize("what", ["mass", "inertia"])
@pytest.mark.parametrize("e", [0.5, 1.0])
def test_mass_ratio_free_bodies(tmp_path, ratio, what, e):
    """Two bodies on URDF planar joints collide off-centre (no gravity): body b's mass (or
    only its inertia) is ratio x body a's.  Linear momentum and angular momentum about the
    origin are conserved through the impact."""
    m1, I1 = 1.0, 1e-2
    m2, I2 = (ratio, I1 * ratio) if what == "mass" else (1.0, I1 * ratio)
    # t_end just after the impact: a body spun fast by the impact would later sweep its contact
    # point across the other body's contact plane far from the contact point (not a contact)
    traj = run(builders.two_free_bodies(tmp_path, e, m1, m2, I1, I2, t_end=0.052))
    assert_finite(traj)
    assert len(traj.events) == 1, [ev["t"] for ev in traj.events]
    ev = traj.events[0]
    assert ev["kind"] == "mobile" and ev["t"] == pytest.approx(0.05, abs=1e-12)
    assert_impact_laws(ev, e)
    q = coords_at_end(traj, 0)

    def momenta(vel):
        p, H, scale = np.zeros(2), 0.0, 0.0
        for body, m, I in (("A", m1, I1), ("B", m2, I2)):
            vx, vy, w = vel[body]
            v = rot(q[f"{body}.theta"]) @ np.array([vx, vy])  # planar joint velocity is in the body frame
            r = np.array([q[f"{body}.x"], q[f"{body}.y"]])
            p += m * v
            H += I * w + m * cross2(r, v)
            scale += m * np.linalg.norm(v) * (1 + np.linalg.norm(r)) + abs(I * w)
        return p, H, scale
    p_b, H_b, scale = momenta(ev["v_before"])
    p_a, H_a, _ = momenta(ev["v_after"])
    assert np.max(np.abs(p_a - p_b)) <= 1e-10 * scale, f"linear momentum jumps by {p_a - p_b}"
    assert abs(H_a - H_b) <= 1e-10 * scale, f"angular momentum jumps by {H_a - H_b:.3g}"


LENGTHS = [1e-4, 1e-2, 1.0, 1e2]


@pytest.mark.parametrize("L", LENGTHS)
def test_length_scale_pendulum_impact_time_scales_like_sqrt_L_over_g(tmp_path, L):
    """Bar of length L released horizontal onto a stop at the vertical: the dimensionless
    impact time t sqrt(g/L) and speed omega sqrt(L/g) = -sqrt(3) do not depend on L."""
    e = 0.5
    tau, w_star = pendulum_fall(0.0, -math.pi / 2, 1.0, g=1.0)  # L = g = 1
    s = math.sqrt(L / G)
    traj = run(builders.pendulum(tmp_path, e, L=L, m=1.0, t_end=1.5 * tau * s))
    assert_finite(traj)
    ev = traj.events[0]
    assert_impact_laws(ev, e)
    assert ev["t"] / s == pytest.approx(tau, rel=1e-9)
    assert ev["v_before"]["J1"] * s == pytest.approx(w_star, rel=1e-8)
    assert w_star == pytest.approx(-math.sqrt(3), rel=1e-12)


@pytest.mark.parametrize("L", LENGTHS)
def test_length_scale_ball_drop(tmp_path, L):
    """Ball dropped from h = L: t1 / sqrt(2h/g) = 1 and vn / sqrt(2gh) = -1 at every scale."""
    e = 0.5
    t1, v1, _ = ball_times(e, L)
    traj = run(builders.ball(tmp_path, e, h=L, t_end=1.5 * t1))
    assert_finite(traj)
    ev = traj.events[0]
    assert_impact_laws(ev, e)
    assert ev["t"] / t1 == pytest.approx(1.0, rel=1e-12)
    assert ev["normal_velocity"]["before"] / v1 == pytest.approx(-1.0, rel=1e-12)


# ======================================================================================
# 3. grazing impacts and guards touched without crossing
# ======================================================================================
# The bar swings up from the bottom (q0 = -pi/2) with w0 chosen so that its apex is
# q_max = qs + eps; the stop (direction "increasing") is at qs = -0.5.
#   w(q)^2 = w0^2 - 2 K (sin q - sin q0),  vn- = L w(qs) = L sqrt(2 K (sin q_max - sin qs)).
GRAZE_BUG = ("pcmm misses grazing impacts: solve_ivp events only compare the guard's sign at step ends; "
             "when the guard goes positive and back within one integrator step (DOP853 steps ~0.05 s here) "
             "no event fires and the bar passes through the stop (pcmm/integrators.py ScipyMethod.integrate)")


@pytest.mark.parametrize("eps", [
    1e-2,
    pytest.param(5e-3),
    pytest.param(1e-4),
    pytest.param(1e-6),
])
def test_grazing_impact_fires_with_the_analytic_approach_speed(tmp_path, eps):
    """Apex eps rad beyond the stop: exactly one impact with vn- = -L w(qs) -> 0+ as eps -> 0
    (0.39 m/s for eps = 1e-2, 0.004 m/s for 1e-6): the restitution law holds as usual."""
    m, L, qs, q0, e = 1.5, 0.6, -0.5, -math.pi / 2, 0.5
    K = 1.5 * G / L
    w0 = math.sqrt(2 * K * (math.sin(qs + eps) - math.sin(q0)))
    vn = L * math.sqrt(2 * K * (math.sin(qs + eps) - math.sin(qs)))
    traj = run(builders.pendulum(tmp_path, e, L=L, m=m, qs=qs, q0=q0, w0=w0, direction="increasing", t_end=0.8))
    assert_finite(traj)
    assert len(traj.events) == 1, (f"apex {eps} rad beyond the stop: expected one impact at vn- = -{vn:.3g} m/s, "
                                   f"got {len(traj.events)} events")
    ev = traj.events[0]
    assert_impact_laws(ev, e)
    assert ev["normal_velocity"]["before"] == pytest.approx(-vn, rel=1e-3)


@pytest.mark.parametrize("eps", [-1e-3, -1e-6, -1e-9])
def test_guard_touched_without_crossing_fires_nothing(tmp_path, eps):
    """Apex |eps| rad short of the stop: the guard approaches zero and turns back; no event."""
    m, L, qs, q0 = 1.5, 0.6, -0.5, -math.pi / 2
    K = 1.5 * G / L
    w0 = math.sqrt(2 * K * (math.sin(qs + eps) - math.sin(q0)))
    traj = run(builders.pendulum(tmp_path, 0.5, L=L, m=m, qs=qs, q0=q0, w0=w0, direction="increasing", t_end=0.8))
    assert_finite(traj)
    assert traj.events == []
    assert traj.series("q", "J1").max() <= qs


@pytest.mark.parametrize("v_approach", [1e-2, 1e-5, 1e-7, 1e-9])
def test_grazing_gap_approach_speed_to_zero(tmp_path, v_approach):
    """Gravity-free ball drifting onto the floor at vn- = -v (down to 1e-9 m/s): a bounce
    with vn+ = e v when e v > 1e-6 m/s (the accumulation tolerance), else an immediate merge."""
    e, t_hit = 0.5, 0.01
    traj = run(builders.ball(tmp_path, e, h=v_approach * t_hit, g=0.0, v0=-v_approach, t_end=0.02))
    assert_finite(traj)
    ev = traj.events[0]
    assert ev["t"] == pytest.approx(t_hit, rel=1e-9)
    assert ev["normal_velocity"]["before"] == pytest.approx(-v_approach, rel=1e-9)
    assert_impact_laws(ev, e)
    assert_merge_rule(traj.events, e)
    assert ev["merge"] == (e * v_approach <= ACC_SPEED)
    assert len(traj.events) == 1


# ======================================================================================
# 4. two contacts closing at the same instant
# ======================================================================================
# What a user should expect (issue 24, item 3, pcmm/events/simultaneous.py): the contacts
# closed at one instant take one impulse together, one complementarity solve (each held with its
# own restitution, or separating), in one event whose `simultaneous` block gives each contact's
# outcome; no contact is ever passed through; the kinetic energy does not rise.  (Until issue 24
# they were resolved by sequential impulses at the same instant, in scene order.)

def assert_contact_law(c, e, name):
    """One contact of a simultaneous impact: held with Newton's law, a compressive impulse."""
    vb, va = c["normal_velocity"]["before"], c["normal_velocity"]["after"]
    assert vb < 0 and c["mode"] == "hold", name
    assert va == pytest.approx(-e * vb, rel=1e-9, abs=1e-15), name
    assert c["impulse"]["normal"] >= 0 and c["impulse"]["tangential"] == 0.0, name


def test_two_independent_contacts_at_the_same_instant(tmp_path):
    """Two balls (1 kg, e = 0.5 and 2 kg, e = 0.8) dropped from the same height: one event at t1
    with both contacts, each by its own law (the Delassus matrix is diagonal: the balls are
    independent, so P_i = m_i (1 + e_i) v1 by hand); the balls never go below the floor."""
    h = 0.5
    t1, v1, _ = ball_times(0.5, h)
    traj = run(builders.two_balls(tmp_path, 0.5, 0.8, h=h, t_end=t1 + 0.05))
    assert_finite(traj)
    first = [ev for ev in traj.events if abs(ev["t"] - t1) < 1e-9]
    assert len(first) == 1 and set(first[0]["simultaneous"]) == {"floor1", "floor2"}
    for name, e, m in (("floor1", 0.5, 1.0), ("floor2", 0.8, 2.0)):
        c = first[0]["simultaneous"][name]
        assert_contact_law(c, e, name)
        assert c["normal_velocity"]["before"] == pytest.approx(-v1, rel=1e-10)
        assert c["impulse"]["normal"] == pytest.approx(m * (1 + e) * v1, rel=1e-10)
    assert first[0]["kinetic_energy_after"] <= first[0]["kinetic_energy_before"]
    assert traj.series("q", "Y1").min() >= -1e-12 and traj.series("q", "Y2").min() >= -1e-12


@pytest.mark.parametrize("e", [0.5, 1.0])
def test_bar_falling_flat_onto_two_stops(tmp_path, e):
    """A uniform bar falling flat onto stops under both ends: one event, both ends held by the
    same law; by symmetry (by hand) each end takes m (1 + e) v / 2 and the bar leaves translating
    upward at e v without spin.  Neither end goes below the floor."""
    L, h, m = 1.0, 0.2, 1.0
    t_hit = math.sqrt(2 * h / G)
    v = G * t_hit
    traj = run(builders.flat_bar(tmp_path, e, L=L, h=h, t_end=t_hit + 0.1))
    assert_finite(traj)
    y, th = traj.series("q", "P.y"), traj.series("q", "P.theta")
    lowest = min((y - L / 2 * np.sin(th)).min(), (y + L / 2 * np.sin(th)).min())
    assert lowest >= -1e-9, f"an end of the bar is {-lowest:.3g} m below the floor"
    burst = [ev for ev in traj.events if abs(ev["t"] - t_hit) < 1e-9]
    assert len(burst) == 1 and set(burst[0]["simultaneous"]) == {"left", "right"}
    for name, c in burst[0]["simultaneous"].items():
        assert_contact_law(c, e, name)
        assert c["impulse"]["normal"] == pytest.approx(m * (1 + e) * v / 2, rel=1e-9)
    ev = burst[0]
    assert ev["kinetic_energy_after"] <= ev["kinetic_energy_before"] * (1 + 1e-12)
    vx, vy, omega = ev["v_after"]["P"]  # the bar is horizontal: body frame = world frame
    assert vy == pytest.approx(e * v, rel=1e-9) and abs(omega) <= 1e-9 * v and abs(vx) <= 1e-12


# ======================================================================================
# 5. closed loops at or near singular postures
# ======================================================================================
def test_slider_driven_past_dead_centre_is_a_clean_error(tmp_path):
    """Slider-crank (a = 0.1, b = 0.3) whose slider is driven linearly to x = a + b (dead
    centre, crank and rod collinear) at t = 0.5 s and beyond, where the loop cannot close:
    pcmm must stop with a SimulationError naming the singular posture, never NaN."""
    a, b, th0 = 0.1, 0.3, 0.5
    x0 = a * math.cos(th0) + b * math.cos(math.asin(-a * math.sin(th0) / b))
    path = builders.slider_crank_slider_driven(tmp_path, [x0, (a + b - x0) / 0.5], theta0=th0, t_end=1.0)
    with pytest.raises(pcmm.SimulationError, match="singular posture") as info:
        run(path)
    partial = info.value.partial
    assert partial is not None and partial.status == "partial"
    if partial.segments:
        assert_finite(partial)


def test_error_mid_segment_keeps_the_samples_before_it(tmp_path):
    a, b, th0 = 0.1, 0.3, 0.5
    x0 = a * math.cos(th0) + b * math.cos(math.asin(-a * math.sin(th0) / b))
    path = builders.slider_crank_slider_driven(tmp_path, [x0, (a + b - x0) / 0.5], theta0=th0, t_end=1.0)
    with pytest.raises(pcmm.SimulationError) as info:
        run(path)
    partial = info.value.partial
    assert partial.segments, "no samples kept"
    assert partial.t[-1] >= 0.45, f"samples end at t = {partial.t[-1]:.3g} s, the failure is at 0.5 s"
    assert_finite(partial)


def test_slider_driven_to_touch_dead_centre(tmp_path):
    """The slider touches x = a + b at t = 0.5 s (x(t) = a + b - c (t - 0.5)^2) and returns:
    a defined result (the crank reaches theta = 0 and turns back, or goes through) with the
    loop closed, or a clean singular-posture error; never NaN."""
    a, b, th0 = 0.1, 0.3, 0.5
    x0 = a * math.cos(th0) + b * math.cos(math.asin(-a * math.sin(th0) / b))
    c = (a + b - x0) / 0.25
    coeffs = [a + b - 0.25 * c, c, -c]
    path = builders.slider_crank_slider_driven(tmp_path, coeffs, theta0=th0, t_end=1.0)
    try:
        traj = run(path)
    except pcmm.SimulationError as exc:
        assert "singular" in str(exc)
        return
    assert_finite(traj)
    assert traj.stats["constraint_drift_max"] <= 1e-9
    t = traj.t
    x = traj.series("q", "P")
    np.testing.assert_allclose(x, np.polynomial.Polynomial(coeffs)(t), atol=1e-12)
    # law of cosines: b^2 = a^2 + x^2 - 2 a x cos(theta)
    cos_th = (a * a + x * x - b * b) / (2 * a * x)
    np.testing.assert_allclose(np.cos(traj.series("theta", "crank")), cos_th, atol=1e-7)


PARALLELOGRAM_BUG = ("parallelogram four-bar through its change point (all links collinear, loop Jacobian "
                     "rank 1): pcmm keeps the coordinate partition chosen at the segment start and never "
                     "checks the conditioning during the segment (pcmm/constraints.py "
                     "PartitionedCoordinates.unpack / _solve_dependent)")


@pytest.mark.parametrize("theta0,omega,t_end", [
    pytest.param(1.0, 2.0, 0.5, id="away-from-singular"),
    pytest.param(1e-3, 2.0, 0.5, id="start-1e-3-rad-from-change-point"),
    pytest.param(0.5, 2.0, 2.0, id="through-theta-pi"),
    pytest.param(math.pi / 2, 5.0, 1.0, id="through-theta-pi-fast"),
])
@pytest.mark.parametrize("method", ["DOP853", "DOP853F"])  # the Fortran one must stop on a repartition too
def test_parallelogram_change_point(tmp_path, theta0, omega, t_end, method):
    """Gravity-free parallelogram (crank = rocker = 0.1 m, coupler = frame = 0.3 m): on its
    branch the rocker stays parallel to the crank, the coupler horizontal and omega constant
    (the kinetic energy (2/3 m a^2 + m a^2) omega^2 / 2 is constant).  At theta = 0 and pi
    the loop is singular.  Expected: that motion, or a SimulationError naming the singular
    posture; never a branch switch, an energy change, NaN or a hang."""
    path = builders.parallelogram(tmp_path, theta0, omega, t_end=t_end)
    try:
        with deadline(60.0, "parallelogram run"):
            traj = run(path, method=method)
    except pcmm.SimulationError as exc:
        assert "singular" in str(exc)
        return
    assert_finite(traj)
    assert traj.stats["constraint_drift_max"] <= 1e-9
    A, D, C = (traj.series("theta", n) for n in ("crank", "rocker", "coupler"))
    assert np.max(np.abs(D - A)) <= 1e-7, f"rocker leaves the crank's angle by {np.max(np.abs(D - A)):.3g} rad"
    assert np.max(np.abs(C)) <= 1e-7, f"coupler turns by {np.max(np.abs(C)):.3g} rad"
    w = traj.series("omega", "crank")
    assert np.max(np.abs(w - omega)) <= 1e-7 * omega, f"omega ranges over {w.min():.6g} .. {w.max():.6g}"
    ke = traj.series("kinetic")
    assert np.ptp(ke) <= 1e-8 * ke[0], f"kinetic energy changes by {np.ptp(ke) / ke[0]:.3g} (relative)"


def test_closed_loop_impact_keeps_the_loop_closed(tmp_path):
    """A closed loop that bounces on a stop: each restart re-chooses the partition; the loop
    must stay closed (drift) and every impact obey its laws with the loop's constraint rows."""
    path = builders.parallelogram(tmp_path, 1.0, 2.0, t_end=0.6)
    doc = tomllib.loads(path.read_text())
    # a stop on the crank at theta = 1.8 rad (moving up), tip against the frame
    qs, a = 1.8, 0.1
    doc["transitions"] = [builders.stop("stop", "c", 0.7, {"type": "coordinate", "measure": {"joint": "A"}, "value": qs,
                                                       "direction": "increasing"},
                                  {"a": "frame", "point_a": [a * math.cos(qs), a * math.sin(qs)], "b": "crank",
                                   "point_b": [a, 0.0], "normal": [math.sin(qs), -math.cos(qs)]})]
    path.write_text(builders.dump_toml(doc))
    traj = run(path)
    assert_finite(traj)
    assert traj.events, "no impact"
    for ev in traj.events:
        assert_impact_laws(ev, 0.7)
    assert traj.stats["constraint_drift_max"] <= 1e-9
    A, D = traj.series("theta", "crank"), traj.series("theta", "rocker")
    assert np.max(np.abs(D - A)) <= 1e-7


# ======================================================================================
# 6. very stiff springs
# ======================================================================================
I_SPRING = 1e-2  # kg m^2


@pytest.mark.parametrize("k", [1e2, 1e4, 1e6])
@pytest.mark.parametrize("method", ["Radau", "LSODA", "DOP853"])
def test_stiff_spring_frequency(tmp_path, k, method):
    """Body on a pivot with a torsion spring k (I = 1e-2, no gravity), 5 periods:
    q(t) = q0 cos(sqrt(k/I) t).  The stiff methods and the default explicit one must give
    the frequency sqrt(k/I) (a frequency error dw shows as q0 dw t) and keep the energy."""
    q0 = 0.1
    w = math.sqrt(k / I_SPRING)
    T = 2 * math.pi / w
    traj = run(builders.spring_pendulum(tmp_path, k, I_SPRING, q0=q0, t_end=5 * T), method=method)
    assert_finite(traj)
    t, q = traj.t, traj.series("q", "J1")
    err = np.max(np.abs(q - q0 * np.cos(w * t)))
    assert err <= 1e-6 * q0, (f"{method}, k = {k:g}: |q - q0 cos(wt)| up to {err:.3g} rad "
                              f"(frequency error about {err / (q0 * 5 * T):.3g} rad/s of {w:.6g})")
    energy = traj.series("kinetic") + traj.series("potential")
    assert np.ptp(energy) <= 1e-6 * energy[0]


def test_explicit_fixed_step_on_a_stiff_spring_is_an_error_not_nan(tmp_path):
    """k = 1e6, I = 1e-2, RK4 with the default step: a correct answer or a clear
    SimulationError that names the step (the setting to change) -- never NaN."""
    path = builders.spring_pendulum(tmp_path, 1e6, I_SPRING, q0=0.1, t_end=0.5)
    try:
        with np.errstate(all="ignore"):
            traj = run(path, method="RK4")
    except pcmm.SimulationError as exc:
        assert "step" in str(exc)
        return
    assert_finite(traj)
    w = math.sqrt(1e6 / I_SPRING)
    assert np.max(np.abs(traj.series("q", "J1") - 0.1 * np.cos(w * traj.t))) <= 1e-3


# ======================================================================================
# 7. a long conservative run and a Zeno accumulation
# ======================================================================================
@pytest.mark.slow  # more than 1000 impacts
def test_long_elastic_run_more_than_1000_impacts(tmp_path):
    """Ball, e = 1, no damping, dropped from 1 mm: 1001 impacts in 28.6 s.  Every impact
    is elastic, the impact times stay on t1 + k (2 t1), and the energy does not drift."""
    h, m = 1e-3, 1.0
    t1, v1, _ = ball_times(1.0, h)
    n = 1001
    traj = run(builders.ball(tmp_path, 1.0, h=h, mass=m, t_end=t1 + (n - 0.5) * 2 * t1))
    assert_finite(traj)
    assert len(traj.events) == n
    times = np.array([ev["t"] for ev in traj.events])
    assert np.max(np.abs(times - (t1 + 2 * t1 * np.arange(n)))) <= 1e-9
    for ev in traj.events:
        assert not ev["merge"]
        assert ev["normal_velocity"]["after"] == pytest.approx(-ev["normal_velocity"]["before"], rel=1e-12)
        assert ev["kinetic_energy_after"] == pytest.approx(ev["kinetic_energy_before"], rel=1e-12)
    vn = np.array([ev["normal_velocity"]["before"] for ev in traj.events])
    assert np.max(np.abs(vn + v1)) <= 1e-9 * v1
    energy = traj.series("kinetic") + traj.series("potential")
    drift = np.ptp(energy) / (m * G * h)
    assert drift <= 1e-9, f"energy drift over {n} impacts: {drift:.3g} (relative)"


@pytest.mark.parametrize("e,h,g,speed", [
    (0.3, 1.0, G, None), (0.5, 0.2, G, None), (0.8, 1.0, 1.62, None), (0.9, 0.08, G, None),
    (0.7, 1.0, G, 1e-3),
])
def test_zeno_accumulation_merges_at_t_infinity(tmp_path, e, h, g, speed):
    """Bouncing ball: impact k (k = 1, 2, ...) at t_k with pre-impact speed e^(k-1) v1; the
    first impact whose post-impact speed e^k v1 is below the accumulation tolerance merges,
    within 2 tol / (g (1 - e)) of t_inf = t1 + 2 e v1 / (g (1 - e)); the ball then rests.
    (Bounces inside the 1e-12 m re-arm band may shift the tail by the same time scale with
    tol = sqrt(2 g band), see REARM_BAND.)"""
    tol = ACC_SPEED if speed is None else speed
    t1, v1, t_inf = ball_times(e, h, g)
    opts = {} if speed is None else {"accumulation_speed": speed}
    traj = run(builders.ball(tmp_path, e, h=h, g=g, t_end=t_inf + 0.2), **opts)
    assert_finite(traj)
    k_merge = next(k for k in range(1, 10_000) if e ** k * v1 <= tol)
    in_band = e ** (k_merge - 1) * v1 < 10 * band_speed(g)
    # band landings add a few bounces at the end of the series
    assert k_merge <= len(traj.events) <= (k_merge + 10 if in_band else k_merge)
    expected_t = t1
    for k, ev in enumerate(traj.events):
        if e ** k * v1 >= 10 * band_speed(g):
            assert ev["t"] == pytest.approx(expected_t, abs=1e-9)
            assert -ev["normal_velocity"]["before"] == pytest.approx(e ** k * v1, rel=1e-8)
        assert_impact_laws(ev, e)
        expected_t += 2 * e ** (k + 1) * v1 / g
    assert_merge_rule(traj.events, e, speed=tol)
    last = traj.events[-1]
    assert last["merge"] and not any(ev["merge"] for ev in traj.events[:-1])
    assert abs(t_inf - last["t"]) <= 2 * max(tol, band_speed(g)) / (g * (1 - e)) + 1e-9, \
        f"merge at {last['t']!r}, t_inf = {t_inf!r}"
    rest = traj.segments[-1]
    assert rest.configuration == "rest" and rest.t[-1] == pytest.approx(t_inf + 0.2)
    np.testing.assert_allclose(rest.xy, 0.0, atol=1e-12)


# ======================================================================================
# 8. no lost results
# ======================================================================================
def test_interrupt_from_progress_at_a_segment_end_keeps_everything(tmp_path):
    """KeyboardInterrupt raised by the progress callback once t >= 0.5 s (a bouncing ball:
    progress is called at every segment end): SimulationError with a partial trajectory,
    status 'partial', samples and events up to the time of the interrupt."""
    scene = pcmm.load_scene(builders.ball(tmp_path, 0.8, t_end=5.0))
    calls = []

    def progress(t):
        calls.append(t)
        if t >= 0.5:
            raise KeyboardInterrupt
    with pytest.raises(pcmm.SimulationError, match="interrupted") as info:
        pcmm.simulate(scene, progress=progress)
    partial = info.value.partial
    assert partial is not None and partial.status == "partial"
    assert_finite(partial)
    assert partial.t[-1] == pytest.approx(calls[-1], abs=1e-12)
    assert all(ev["t"] <= calls[-1] for ev in partial.events) and partial.events
    assert np.all(np.diff(partial.t) >= 0)


@pytest.mark.parametrize("method", ["DOP853", "DOP853F", "LSODA", "RK4"])
def test_interrupt_mid_segment_keeps_the_samples_computed(tmp_path, method):
    scene = pcmm.load_scene(builders.spring_pendulum(tmp_path, 1e2, I_SPRING, q0=0.1, t_end=5.0))
    raised = []

    def progress(t):
        if t >= 0.5 and not raised:
            raised.append(t)
            raise KeyboardInterrupt
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(scene, pcmm.RunOptions(method=method), progress=progress)
    partial = info.value.partial
    assert partial.status == "partial"
    assert partial.segments, "nothing kept"
    assert raised[0] - 0.05 <= partial.t[-1] <= raised[0] + 1e-9
    assert_finite(partial)


def _cli(args, capsys):
    rc = cli_main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


def test_cli_failed_run_saves_the_partial_trajectory_to_out(tmp_path, capsys, monkeypatch):
    """A stop without merge_to whose impacts accumulate: exit status 3, one 'pcmm: error:'
    message, the partial trajectory saved to --out and the path said on stderr."""
    monkeypatch.chdir(tmp_path)
    path = builders.ball(tmp_path / "scene", 0.5, t_end=5.0, merge=False)
    out = tmp_path / "run.npz"
    rc, _, err = _cli(["run", path, "--out", out, "--quiet"], capsys)
    assert rc == 3
    assert err.count("pcmm: error:") == 1 and "Traceback" not in err
    assert "accumulate" in err and str(out) in err
    saved = pcmm.Trajectory.load(out)
    assert saved.status == "partial" and "accumulate" in saved.message
    _, v1, t_inf = ball_times(0.5, 1.0)
    assert saved.events[-1]["t"] <= saved.t[-1] <= t_inf + 1e-6  # up to the impact that failed
    assert len(saved.events) >= 20
    assert_finite(saved)


def test_cli_failed_run_without_out_saves_in_the_working_folder(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = builders.ball(tmp_path / "scene", 0.5, t_end=5.0, merge=False)
    rc, _, err = _cli(["run", path, "--quiet"], capsys)
    assert rc == 3 and err.count("pcmm: error:") == 1
    saved = tmp_path / f"{path.stem}-partial.npz"  # named after the scene file, whatever its 'name' says
    assert saved.is_file() and saved.name in err
    assert pcmm.Trajectory.load(saved).status == "partial"


def test_cli_partial_save_with_a_path_like_scene_name(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = builders.ball(tmp_path / "scene", 0.5, t_end=5.0, merge=False)
    path.write_text(path.read_text().replace('name = "ball"', 'name = "sub/ball"'))
    rc, _, err = _cli(["run", path, "--quiet"], capsys)
    assert rc == 3, err
    assert "accumulate" in err and err.count("pcmm: error:") == 1
    assert list(tmp_path.glob("**/*partial*.npz")), "no partial trajectory saved"


def test_cli_never_overwrites_without_force(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = builders.ball(tmp_path / "scene", 0.5, t_end=0.5)
    out = tmp_path / "run.npz"
    out.write_bytes(b"precious")
    rc, _, err = _cli(["run", path, "--out", out, "--quiet"], capsys)
    assert rc != 0 and err.count("pcmm: error:") == 1 and "--force" in err and "Traceback" not in err
    assert out.read_bytes() == b"precious"
    # a failing run does not overwrite it either
    failing = builders.ball(tmp_path / "failing", 0.5, t_end=5.0, merge=False)
    rc, _, err = _cli(["run", failing, "--out", out, "--quiet"], capsys)
    assert rc != 0 and out.read_bytes() == b"precious"
    rc, _, err = _cli(["run", path, "--out", out, "--quiet", "--force"], capsys)
    assert rc == 0, err
    traj = pcmm.Trajectory.load(out)
    assert traj.status == "complete" and traj.t[-1] == pytest.approx(0.5)
    assert not list(tmp_path.glob(".run.npz.*.tmp")), "a temporary file was left behind"


def test_scene_paths_resolve_relative_to_the_scene_file(tmp_path, capsys, monkeypatch):
    """URDF paths in a scene are relative to the scene file, whatever the working folder."""
    path = builders.ball(tmp_path / "project" / "urdf", 0.5, t_end=0.5)
    scenes = tmp_path / "project" / "scenes"
    scenes.mkdir()
    scene_file = scenes / "ball.toml"
    scene_file.write_text(path.read_text().replace('"free.urdf"', '"../urdf/free.urdf"')
                          .replace('"rest.urdf"', '"../urdf/rest.urdf"'))
    path.unlink()
    elsewhere = tmp_path / "elsewhere" / "deeper"
    elsewhere.mkdir(parents=True)
    monkeypatch.chdir(elsewhere)
    rel = "../../project/scenes/ball.toml"
    scene = pcmm.load_scene(rel)
    assert scene.configurations["free"].urdf == (tmp_path / "project" / "urdf" / "free.urdf").resolve()
    traj = pcmm.simulate(scene)
    assert_finite(traj)
    rc, out, err = _cli(["check", rel], capsys)
    assert rc == 0, err
    rc, out, err = _cli(["run", rel, "--out", "r.npz", "--quiet"], capsys)
    assert rc == 0, err
    assert (elsewhere / "r.npz").is_file()
    monkeypatch.chdir(scenes)
    rc, out, err = _cli(["run", "ball.toml", "--quiet"], capsys)
    assert rc == 0, err
