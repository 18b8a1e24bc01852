"""Andrews' squeezing mechanism (examples/andrews.toml): the published benchmark with closed loops,
a motor torque and a point spring.

The reference solution at t = 0.03 s is the IVP test set's (F. Mazzia, C. Magherini et al., Test
Set for IVP Solvers, University of Bari, https://archimede.uniba.it/~testset/, problem "andrews",
file andrews.f, subroutine solut: computed with PSIDE at rtol = atol = 1e-14), for the model of
Hairer & Wanner, Solving Ordinary Differential Equations II, section VII.7. Its initial values
(consistent, given to 30 digits) and the initial accelerations and multipliers are the test set's
too. ``reference_andrews.py`` is a second, independent model (Lagrange's equations in the seven
angles with multipliers, no Pinocchio), integrated by scipy.
"""
from __future__ import annotations

import numpy as np
import pytest

import pcmm
import reference_andrews as ref_model
from builders import EXAMPLES

ANGLES = ("beta", "Theta", "gamma", "Phi", "delta", "Omega", "epsilon")
# test set, andrews.f, solut: y(1..7) and y(8..14) at t = 0.03 s
PUBLISHED_Q = (0.1581077119629904e+2, -0.1575637105984298e+2, 0.4082224013073101e-1, -0.5347301163226948e+0,
               0.5244099658805304e+0, 0.5347301163226948e+0, 0.1048080741042263e+1)
PUBLISHED_V = (0.1139920302151208e+4, -0.1424379294994111e+4, 0.1103291221937134e+2, 0.1929337464421385e+2,
               0.5735699284790808e+0, -0.1929337464421385e+2, 0.3231791658026955e+0)
# test set, andrews.f, init: the consistent accelerations and multipliers at t = 0
PUBLISHED_A0 = (14222.4439199541138705911625887, -10666.8329399655854029433719415, 0, 0, 0, 0, 0)
PUBLISHED_LAM0 = (98.5668703962410896057654982170, -6.12268834425566265503114393122, 0, 0, 0, 0)
MOM = 0.033


@pytest.fixture(scope="module")
def scene():
    return pcmm.load_scene(EXAMPLES / "andrews.toml")


@pytest.fixture(scope="module")
def run(scene):
    traj = pcmm.simulate(scene)
    seg = traj.segments[-1]
    cols = [seg.coordinates.index(a) for a in ANGLES]
    return traj, seg.q[-1, cols], seg.v[-1, cols]


@pytest.fixture(scope="module")
def independent():
    return ref_model.solve()


def test_matches_the_published_reference_at_t_003_in_every_angle(run):
    traj, q, _ = run
    assert traj.segments[-1].t[-1] == 0.03 and traj.status == "complete"
    rel = np.abs(q - PUBLISHED_Q) / np.abs(PUBLISHED_Q)
    assert np.all(rel < 1e-8), dict(zip(ANGLES, rel))
    # the crank has turned about 2.5 times: the mechanism really ran, not a few steps
    assert q[0] > 15.0


def test_matches_the_independent_lagrangian_model(run, independent):
    """The independent model lands 7e-11 ... 2.7e-10 (relative) from the published positions
    too, and pcmm on it far closer: the remaining difference to the published digits is the
    reference's own accuracy, not the model."""
    _, q, v = run
    q_ind, v_ind = independent
    assert np.all(np.abs(q - q_ind) <= 1e-10 * np.abs(q_ind)), (q - q_ind) / q_ind
    assert np.all(np.abs(v - v_ind) <= 1e-8 * np.abs(v_ind)), (v - v_ind) / v_ind
    # both agree with the published velocities to 1e-7 (the published ones are the least accurate)
    assert np.all(np.abs(v - PUBLISHED_V) <= 1e-7 * np.abs(PUBLISHED_V))
    assert np.all(np.abs(v_ind - PUBLISHED_V) <= 1e-7 * np.abs(PUBLISHED_V))


def test_initial_accelerations_and_pin_forces_are_the_published_ones(scene):
    """The multipliers are the pin forces on body 3, 4 and 6 at P (world x, y); the test set's
    lambda multiplies the rows P_crank - P_other, pcmm's the rows P_other - P_crank with
    M a = Q + J^T lam, so the two are the same numbers."""
    from pcmm.model.mechanism import Mechanism
    cfg = Mechanism(scene)["squeezer"]
    q = cfg.vector(scene.q0)
    a, lam = cfg.coords.accelerations(0.0, q, np.zeros(cfg.nv))
    a = np.array([a[cfg.joint_slice[j].start] for j in ANGLES])
    assert np.allclose(a, PUBLISHED_A0, rtol=1e-12, atol=1e-9)
    assert np.allclose(lam, PUBLISHED_LAM0, rtol=1e-12, atol=1e-12)
    assert cfg.coords.labels == ["P3.fx", "P3.fy", "P4.fx", "P4.fy", "P6.fx", "P6.fy"]


def test_energy_balance_and_loop_closure_along_the_run(run):
    """No damping: kinetic + spring energy grows by exactly the motor's work mom (beta - beta0)."""
    traj, _, _ = run
    seg = traj.segments[-1]
    beta = seg.q[:, seg.coordinates.index("beta")]
    balance = seg.kinetic + seg.potential - MOM * (beta - beta[0])
    assert np.ptp(balance) < 1e-10 * balance[0]
    assert traj.stats["constraint_drift_max"] < 1e-12
    # the spring's force is reported over time: f = -c0 (L - l0), pushing D and C apart when > 0
    # with L from gamma: D = B + R(gamma) (sd, -sc) on body 3, C = (xc, yc) on the frame
    gamma = seg.q[:, seg.coordinates.index("gamma")]
    dx = ref_model.XB + ref_model.SD * np.cos(gamma) + ref_model.SC * np.sin(gamma) - ref_model.XC
    dy = ref_model.YB + ref_model.SD * np.sin(gamma) - ref_model.SC * np.cos(gamma) - ref_model.YC
    spring = traj.series("forces", "spring")
    assert np.allclose(spring, -ref_model.C0 * (np.hypot(dx, dy) - ref_model.L0), rtol=1e-12, atol=0)
    assert spring[0] == pytest.approx(114.05400202, rel=1e-9) and spring.min() < 64.0  # compressed, then less
