"""A configuration without a free coordinate (every joint locked or driven) is not integrated:
its state is a known function of time, evaluated at samples, and a guard crossing is located on
that function itself.

The fully driven slider-crank (crank a, rod b, slider driven x(t) = x0 + c t): the crank angle
follows from the law of cosines, x = a cos(theta) + sqrt(b^2 - a^2 sin^2(theta)), so the time at
which the crank reaches theta* is t* = (x(theta*) - x0) / c in closed form.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import builders
import pcmm
from pcmm.model.mechanism import Mechanism
from pcmm.run.loop import KNOWN_MOTION_SAMPLES, _known_motion, initial_state, resolve

A, B, TH0 = 0.1, 0.3, 0.5


def x_of(theta):
    return A * math.cos(theta) + math.sqrt(B * B - (A * math.sin(theta)) ** 2)


@pytest.fixture
def driven(tmp_path):
    x0 = x_of(TH0)
    c = 0.02  # m/s: the crank turns towards theta = 0 (dead centre at x = a + b, t = 0.80 s)
    scene = pcmm.load_scene(builders.slider_crank_slider_driven(tmp_path, [x0, c], theta0=TH0, t_end=0.4))
    return scene, x0, c


def test_guard_crossing_is_located_on_the_motion_itself(driven):
    scene, x0, c = driven
    cfg = Mechanism(scene)["c"]
    q, v, _ = initial_state(scene, cfg)
    y0 = cfg.coords.pack(0.0, q, v)
    assert y0.size == 0  # nothing to integrate
    theta_star = 0.4
    t_star = (x_of(theta_star) - x0) / c
    col = cfg.joint_slice["A"].start

    def guard(t, y):
        qq, _ = cfg.coords.unpack(t, y)
        return qq[col] - theta_star
    guard.terminal, guard.direction = True, -1
    seg = _known_motion(cfg, 0.0, y0, [guard], resolve(scene, pcmm.RunOptions()))
    assert seg.event == 0
    assert seg.t[-1] == pytest.approx(t_star, abs=1e-12)
    # samples, not milliseconds: at most KNOWN_MOTION_SAMPLES over the stay
    assert 2 <= len(seg.t) <= KNOWN_MOTION_SAMPLES + 2
    assert np.all(np.diff(seg.t) > 0)


def test_driven_stay_is_sampled_and_exact_at_every_sample(driven):
    scene, x0, c = driven
    traj = pcmm.simulate(scene)
    seg = traj.segments[0]
    assert len(seg.t) == KNOWN_MOTION_SAMPLES + 1 and traj.stats["rhs_evals"] <= 5 * len(seg.t)
    x, theta = traj.series("q", "P"), traj.series("q", "A")
    np.testing.assert_allclose(x, x0 + c * traj.t, rtol=0, atol=1e-14)
    np.testing.assert_allclose([x_of(th) for th in theta], x, rtol=0, atol=1e-13)
    # velocities from the velocity equation: d/dt of the closed form
    dx_dth = [-A * math.sin(th) - A * A * math.sin(th) * math.cos(th) / math.sqrt(B * B - (A * math.sin(th)) ** 2)
              for th in theta]
    np.testing.assert_allclose(traj.series("v", "A") * np.array(dx_dth), c, rtol=1e-10)
