"""Drives without a loop are prescribed coordinates (issue 26 items 1 and 2): the driven joints take
``f(t)`` and ``f'(t)`` outright, with no Newton solve, and that is the state the Newton route of a
loop reaches to the last bit (its polishing step lands on ``f(t)``)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import pcmm
from pcmm.model.mechanism import Mechanism

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def open_three_bar():
    """The working cycle's three-bar with O1 driven, theta1 = pi t, and O2, O3 free: no loop."""
    return Mechanism(pcmm.load_scene(ROOT / "examples" / "three_bar_cycle.toml"))["open"]


def _newton_route(coords, t, y):
    """(q, v) by the loop's route: a Newton solve of the rows from a guess off the drive, then the
    dependent rates from dPhi/dq q' = -Phi_t."""
    k = len(coords.I)
    guess = coords._qD.copy()
    guess[coords.D] += 0.3  # far off the drive's value: Newton must move it
    q, _, Jp = coords._solve_dependent(t, y[:k], guess)
    rates = np.empty(coords.nv)
    rates[coords.I] = y[k:]
    rates[coords.D] = np.linalg.solve(Jp[:, coords.D], -(Jp[:, coords.I] @ y[k:] + coords._phi_t(t)))
    return q, coords.cfg.velocity(q, rates)


def test_a_driven_joint_is_prescribed_to_the_bit(open_three_bar):
    cfg = open_three_bar
    coords = cfg.coords
    assert coords.closure.size == 0 and coords.drives.joints == ("O1",)
    O1, O2, O3 = (cfg.joint_slice[j].start for j in ("O1", "O2", "O3"))
    rng = np.random.default_rng(26)
    for t in (0.0, 0.37, 1.199, 5.2, 7.5):
        q0 = rng.uniform(-3.0, 3.0, cfg.nv)
        v0 = rng.uniform(-2.0, 2.0, cfg.nv)
        q0[O1], v0[O1] = math.pi * t, math.pi  # assembled: on the drive
        y = coords.pack(t, q0, v0)
        assert list(coords.D) == [O1] and len(y) == 4  # O2, O3 and their rates
        q, v = coords.unpack(t, y)
        # closed form: theta1 = pi t, theta1' = pi; the free joints are the state's
        assert q[O1] == math.pi * t and v[O1] == math.pi
        assert (q[O2], q[O3], v[O2], v[O3]) == (y[0], y[1], y[2], y[3])
        assert coords.residual(t, q) == 0.0
        qn, vn = _newton_route(coords, t, y)
        assert qn.tobytes() == q.tobytes() and vn.tobytes() == v.tobytes()


def test_no_newton_solve_and_no_kinematics_pass_for_drives_alone(open_three_bar, monkeypatch):
    """The prescribed route neither solves nor runs a kinematics pass (before issue 26 each unpack
    of this configuration did both: 31,370 of them in the cycle's run)."""
    cfg = open_three_bar
    coords = cfg.coords
    t = 0.81
    q0, v0 = np.array([math.pi * t, 1.4, 3.0]), np.array([math.pi, -0.5, 0.7])
    y = coords.pack(t, q0, v0)

    def forbidden(*args, **kwargs):
        raise AssertionError("a Newton solve or a kinematics pass for a configuration with drives alone")
    monkeypatch.setattr(coords, "_solve_dependent", forbidden)
    monkeypatch.setattr(coords, "_kinematics", forbidden)
    q, v = coords.unpack(t + 1e-3, y)
    assert q.tolist() == [math.pi * (t + 1e-3), 1.4, 3.0] and v.tolist() == [math.pi, -0.5, 0.7]
    a, lam = coords.accelerations(t + 1e-3, q, v)
    assert a[0] == 0.0  # the drive's f'' = 0: the crank turns at a constant rate
