"""A fixed-step run ends on its t_end (h-audit2 found the pinned leg's known motion ending at
t = 0.9999999999999999 for t_end = 1.0: ten steps of 0.1 sum to one ulp less than 1.0, and the RK4
loop stopped there, so the summary's final time said so)."""
from __future__ import annotations

import math

import numpy as np
import pytest

import pcmm
from builders import pendulum


def test_ten_steps_of_a_tenth_end_on_one_second(tmp_path):
    assert sum([0.1] * 10) < 1.0  # the accumulated time an ulp short (why the loop must land on t_end)
    path = pendulum(tmp_path, None, q0=0.0, t_end=1.0, solver={"method": "RK4", "step": 0.1})
    traj = pcmm.simulate(pcmm.load_scene(path))
    assert traj.t[-1] == 1.0
    steps = np.unique(traj.t)
    assert len(steps) == 11 and np.allclose(np.diff(steps), 0.1, rtol=0, atol=1e-15)  # no sliver step
    # the state there is classical RK4's, stepped by hand on the bar's own equation
    # theta'' = -(3 g / (2 L)) cos(theta) (a uniform bar of length L = 0.6 about its end), the last
    # step the one that lands on 1.0
    def f(y):
        return np.array([y[1], -(3 * 9.81 / (2 * 0.6)) * math.cos(y[0])])
    t, y = 0.0, np.array([0.0, 0.0])
    while t < 1.0 - 1e-15:
        h = min(0.1, 1.0 - t)
        if 1.0 - (t + h) <= 1e-15:
            h = 1.0 - t
        k1 = f(y)
        k2 = f(y + h / 2 * k1)
        k3 = f(y + h / 2 * k2)
        k4 = f(y + h * k3)
        y, t = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), t + h
    assert traj.series("theta", "link1")[-1] == pytest.approx(y[0], abs=1e-12)
    assert traj.series("omega", "link1")[-1] == pytest.approx(y[1], abs=1e-11)
