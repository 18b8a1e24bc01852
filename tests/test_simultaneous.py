"""Issue 24, item 3: contacts closed at one instant take one complementarity solve, with friction.

A rod (m, half-length a, centroidal inertia I; k = m a^2 / I) lies flat and strikes two points at
once, A at its end -a and B at +a, with no gravity: G moves at (u, -V) and the rod turns at w0, so
A's normal velocity is -V - a w0 and B's -V + a w0.  By hand (impulses P on the rod at A and B,
normal n = (0, 1), tangent t = (1, 0)):

* the points lie on the rod's axis through G, so a tangential impulse makes no moment about G and
  the normal and tangential problems separate;
* normal: m dU_A = (1 + k) P_A + (1 - k) P_B, m dU_B = (1 - k) P_A + (1 + k) P_B; both held
  (Newton: dU = -(1 + e) U-) gives P_A = m [(1 + k) dU_A - (1 - k) dU_B] / (4 k) and the same
  with A, B swapped; valid while both are >= 0.  Otherwise A alone, P_A = m dU_A / (1 + k), and B
  separates with U_B+ = U_B- + (1 - k) P_A / m, valid while U_B+ >= -e U_B-;
* tangential: both points slip at u + (P_tA + P_tB) / m.  Stick (u+ = 0) needs |m u| <= mu (P_A +
  P_B): mu >= mu_c = m |u| / (P_A + P_B).  Below, both slide: P_t = -sign(u) mu P_n each and
  u+ = u - sign(u) mu (P_A + P_B) / m.  Sticking, only the sum P_tA + P_tB = -m u is determined.

These are the enumeration of the stick / slide / separate modes by hand; pcmm's solve
(:func:`pcmm.events.simultaneous.solve_contacts`) and a run of two ``stop`` transitions must give
them to 1e-12, with the energy never rising and every impulse inside its cone.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import pcmm
from builders import free_bar_urdf, rot
from pcmm.events.simultaneous import NoConsistentOutcome, solve_contacts

M, A_ = 1.3, 0.4  # mass, half-length
V, U = 1.7, 0.6  # G's velocity (U, -V)


def by_hand(k, UA, UB, e, mu, u=U):
    """(P_tA, P_nA, P_tB, P_nB, u_t+, U_A+, U_B+, modes) by the closed forms above."""
    dA, dB = -(1 + e) * UA, -(1 + e) * UB
    PA = M * ((1 + k) * dA - (1 - k) * dB) / (4 * k)
    PB = M * ((1 + k) * dB - (1 - k) * dA) / (4 * k)
    if PA >= 0 and PB >= 0:
        held = "AB"
    else:
        PA, PB, held = M * dA / (1 + k), 0.0, "A"
        assert UB + (1 - k) * PA / M >= -e * min(UB, 0.0)  # B separates
    UA_after = UA + ((1 + k) * PA + (1 - k) * PB) / M
    UB_after = UB + ((1 - k) * PA + (1 + k) * PB) / M
    total = PA + PB
    mu_c = M * abs(u) / total
    if mu is None:
        return 0.0, PA, 0.0, PB, u, UA_after, UB_after, mu_c
    if mu >= mu_c:  # stick: only the sum is known; the least-norm split is in proportion... equal
        Pt_total, ut = -M * u, 0.0
        share = (0.5, 0.5) if held == "AB" else (1.0, 0.0)
        return Pt_total * share[0], PA, Pt_total * share[1], PB, ut, UA_after, UB_after, mu_c
    s = math.copysign(1.0, u)
    return -s * mu * PA, PA, -s * mu * PB, PB, u - s * mu * total / M, UA_after, UB_after, mu_c


def delassus(k):
    """D in (t_A, n_A, t_B, n_B) for the flat rod: 1/m on the tangents (both), and the normal block."""
    I = M * A_ ** 2 / k
    D = np.zeros((4, 4))
    D[0, 0] = D[0, 2] = D[2, 0] = D[2, 2] = 1 / M
    D[1, 1] = D[3, 3] = 1 / M + A_ ** 2 / I
    D[1, 3] = D[3, 1] = 1 / M - A_ ** 2 / I
    return D


CASES = [(3.0, -1.8 * V, -0.2 * V),  # a uniform rod, both ends approaching: both held
         (3.0, -2.0 * V, 0.0),  # B closed at rest: A's impulse pushes it down, so it is held too
         (0.5, -1.8 * V, -0.2 * V)]  # a dumbbell (I = 2 m a^2): A's impulse lifts B, which separates


@pytest.mark.parametrize("k, UA, UB", CASES)
@pytest.mark.parametrize("e", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("side", [None, 0.5, 0.99, 1.01, 3.0, math.inf])  # mu as a multiple of mu_c
def test_solve_matches_the_mode_enumeration_by_hand(k, UA, UB, e, side):
    mu_c = by_hand(k, UA, UB, e, None)[-1]
    mu = None if side is None else side * mu_c
    PtA, PnA, PtB, PnB, ut, UA1, UB1, _ = by_hand(k, UA, UB, e, mu)
    D, u = delassus(k), np.array([U, UA, U, UB])
    sol = solve_contacts(D, u, [e, e], [mu, mu])
    np.testing.assert_allclose(sol.P[[1, 3]], [PnA, PnB], rtol=0, atol=1e-12)
    np.testing.assert_allclose(sol.P[0] + sol.P[2], PtA + PtB, rtol=0, atol=1e-12)
    if mu is None or mu < mu_c:  # slide (or frictionless): each contact's own tangential impulse
        np.testing.assert_allclose(sol.P[[0, 2]], [PtA, PtB], rtol=0, atol=1e-12)
    np.testing.assert_allclose(sol.u_after, [ut, UA1, ut, UB1], rtol=0, atol=1e-12)
    # the cone, the energy (the kinetic energy change is P . (u- + u+) / 2 in contact space)
    for i in (0, 1):
        Pt, Pn = sol.P[2 * i], sol.P[2 * i + 1]
        assert Pn >= -1e-14
        if mu is None:
            assert Pt == 0.0
        elif math.isfinite(mu):
            assert abs(Pt) <= mu * Pn + 1e-12
    assert float(sol.P @ (u + sol.u_after)) / 2 <= 1e-12
    if k == 0.5:
        assert sol.modes[1] == "separate" and sol.u_after[3] > -e * UB
    else:
        assert "separate" not in sol.modes
    if mu is not None and mu > mu_c and k == 3.0:
        assert not sol.unique_impulse  # sticking on one body: the split of P_t is not determined


def test_no_outcome_is_refused():
    """A contact whose normal Delassus entry is negative (an impulse that would pull it in, as in
    Painleve's cases): separating leaves it approaching at -1, holding needs P_n = -1 < 0, so
    no mode is admissible."""
    D = np.array([[1.0, 0.0], [0.0, -1.0]])
    with pytest.raises(NoConsistentOutcome, match="no combination"):
        solve_contacts(D, np.array([0.0, -1.0]), [0.0], [None])


def rod_run(make_scene, k, UA, UB, e, mu, t_hit=0.02):
    """Two `stop` transitions, A and B, on a free rod reaching the floor (y = 0) flat at t_hit:
    G at height V t_hit, the rod turning at w0 = (UB - UA) / (2 a) from -w0 t_hit."""
    w0 = (UB - UA) / (2 * A_)
    Vg = -(UA + UB) / 2  # G's downward speed
    th0 = -w0 * t_hit
    urdf = free_bar_urdf(M, 2 * A_, izz=M * A_ ** 2 / k)
    fr = {} if mu is None else {"friction": mu}
    trs = [{"name": name, "type": "stop", "from": "c1", "restitution": e, "cut": [],
            "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"},
            "contact": {"a": "frame", "point_a": [0.0, 0.0], "b": "bar", "point_b": [x, 0.0], "normal": [0.0, 1.0],
                        **fr}} for name, x in (("A", -A_), ("B", A_))]
    # A and B start above the floor: A at y_G - a sin(th), B at y_G + a sin(th)
    q0 = {"P": [-U * t_hit, Vg * t_hit, th0]}
    v0 = {"P": [*(rot(th0).T @ np.array([U, -Vg])), w0]}
    return make_scene({"rod.urdf": urdf}, q0=q0, v0=v0, gravity=(0.0, 0.0), t_end=1.5 * t_hit, transitions=trs,
                      solver={"rtol": 1e-12, "atol": 1e-13})


@pytest.mark.parametrize("k, UA, UB", [CASES[0], CASES[2]])
@pytest.mark.parametrize("side", [0.5, 2.0])
def test_a_run_resolves_both_contacts_in_one_event(make_scene, k, UA, UB, side):
    e = 0.5
    mu = side * by_hand(k, UA, UB, e, None)[-1]
    PtA, PnA, PtB, PnB, ut, UA1, UB1, _ = by_hand(k, UA, UB, e, mu)
    traj = pcmm.simulate(pcmm.load_scene(rod_run(make_scene, k, UA, UB, e, mu)))
    assert len(traj.events) == 1
    ev = traj.events[0]
    block = ev["simultaneous"]
    assert set(block) == {"A", "B"}
    assert block["A"]["impulse"]["normal"] == pytest.approx(PnA, abs=1e-9)
    assert block["B"]["impulse"]["normal"] == pytest.approx(PnB, abs=1e-9)
    assert block["A"]["impulse"]["tangential"] + block["B"]["impulse"]["tangential"] == pytest.approx(PtA + PtB, abs=1e-9)
    assert block["A"]["normal_velocity"]["after"] == pytest.approx(UA1, abs=1e-9)
    assert block["B"]["normal_velocity"]["after"] == pytest.approx(UB1, abs=1e-9)
    assert block["A"]["slip"]["after"] == pytest.approx(ut, abs=1e-9)
    assert (block["B"]["mode"] == "separate") == (k == 0.5)
    # the rod after: G's velocity and the turn rate, from the impulses by hand
    w0 = (UB - UA) / (2 * A_)
    I = M * A_ ** 2 / k
    w1 = w0 + A_ * (PnB - PnA) / I
    assert ev["omega_after"]["bar"] == pytest.approx(w1, abs=1e-9)
    assert ev["kinetic_energy_after"] <= ev["kinetic_energy_before"]
    for c in block.values():
        assert abs(c["impulse"]["tangential"]) <= mu * c["impulse"]["normal"] + 1e-12
