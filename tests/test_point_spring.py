"""Point springs: a linear spring-damper along the line between two points.

Every number is derived by hand:

* a slider on a vertical guide hanging from a frame point: the spring stays on the guide, so
  the motion is the linear oscillator, static equilibrium ``L = rest + m g / k``, frequency
  ``sqrt(k/m)``, and with damping the closed-form underdamped response;
* a bar pinned at one end, pulled outwards along its length by a pre-stretched spring: its
  small oscillations come only from the spring's change of direction (geometric stiffness),
  ``omega^2 = k (D - rest) l (l + D) / (D I_O)``, which no force element linear in q has;
* a free bar (URDF planar joint) on a spring to a frame point: a central force, so energy
  (c = 0) and angular momentum about that point are conserved.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import pcmm
from builders import G, Bar, chain_urdf, free_bar_urdf, pendulum_urdf

ANCHOR_Y = 1.0  # the frame point the slider hangs from
M_SLIDER, K, REST = 0.5, 200.0, 0.6


def _slider_scene(make_scene, y0, c=0.0, t_end=1.0, value=None):
    urdf = chain_urdf([Bar(0.1, M_SLIDER, com=(0.0, 0.0), joint="prismatic", axis=(0.0, 1.0, 0.0))],
                      name="slider")
    spring = {"name": "spring", "type": "point_spring", "a": "link1", "point_a": [0.0, 0.0],
              "b": "frame", "point_b": [0.0, ANCHOR_Y], "k": K, "rest": REST}
    if c:
        spring["c"] = c
    if value is not None:
        spring["value"] = value
    return pcmm.load_scene(make_scene({"slider.urdf": urdf}, q0={"J1": y0}, v0={"J1": 0.0}, t_end=t_end,
                                      forces=[spring], solver={"rtol": 1e-11, "atol": 1e-13}))


def _equilibrium():
    """k (L - rest) = m g with L = ANCHOR_Y - y: the slider's rest position."""
    return ANCHOR_Y - REST - M_SLIDER * G / K


def test_slider_rests_at_the_static_equilibrium(make_scene):
    from pcmm.model.mechanism import Mechanism
    y_eq = _equilibrium()
    scene = _slider_scene(make_scene, y_eq)
    cfg = Mechanism(scene)["c1"]
    q, v = np.array([y_eq]), np.zeros(1)
    a, _ = cfg.coords.accelerations(0.0, q, v)
    assert abs(a[0]) < 1e-12
    # f is the force along the line, > 0 pushing the points apart: the stretched spring pulls
    assert cfg.forces.element_values(q, v)[0] == pytest.approx(-M_SLIDER * G, rel=1e-13)
    # a preload value adds to the pull: at the same position the slider then accelerates by value/m
    cfg2 = Mechanism(_slider_scene(make_scene, y_eq, value=1.5))["c1"]
    assert cfg2.coords.accelerations(0.0, q, v)[0][0] == pytest.approx(-1.5 / M_SLIDER, rel=1e-12)


def test_slider_oscillates_at_sqrt_k_over_m_and_conserves_energy(make_scene):
    y_eq = _equilibrium()
    amp = 0.05
    traj = pcmm.simulate(_slider_scene(make_scene, y_eq + amp, t_end=1.0))
    seg = traj.segments[0]
    omega = math.sqrt(K / M_SLIDER)
    y_exact = y_eq + amp * np.cos(omega * seg.t)
    assert np.max(np.abs(seg.q[:, 0] - y_exact)) < 1e-9
    # potential energy: gravity m g y plus the spring's k (L - rest)^2 / 2
    L = ANCHOR_Y - seg.q[:, 0]
    assert np.allclose(seg.potential, M_SLIDER * G * seg.q[:, 0] + 0.5 * K * (L - REST) ** 2, rtol=0, atol=1e-12)
    energy = seg.kinetic + seg.potential
    assert np.max(np.abs(energy - energy[0])) < 1e-10 * abs(energy[0])
    # reported over time like every force element: f = -k (L - rest) - c L'
    assert np.allclose(traj.series("forces", "spring"), -K * (L - REST), rtol=0, atol=1e-10)


def test_damped_slider_follows_the_closed_form(make_scene):
    y_eq, amp, c = _equilibrium(), 0.05, 2.0
    traj = pcmm.simulate(_slider_scene(make_scene, y_eq + amp, c=c, t_end=1.0))
    seg = traj.segments[0]
    omega = math.sqrt(K / M_SLIDER)
    zeta = c / (2 * math.sqrt(K * M_SLIDER))
    wd = omega * math.sqrt(1 - zeta ** 2)
    t = seg.t
    y_exact = y_eq + amp * np.exp(-zeta * omega * t) * (np.cos(wd * t) + zeta * omega / wd * np.sin(wd * t))
    assert np.max(np.abs(seg.q[:, 0] - y_exact)) < 1e-9
    L, Ldot = ANCHOR_Y - seg.q[:, 0], -seg.v[:, 0]
    assert np.allclose(seg.forces[:, 0], -K * (L - REST) - c * Ldot, rtol=0, atol=1e-10)
    # the damper only dissipates: the energy never rises
    energy = seg.kinetic + seg.potential
    assert np.all(np.diff(energy) < 1e-12)
    assert energy[-1] < 0.5 * energy[0] + 0.5 * (M_SLIDER * G * y_eq + 0.5 * K * (ANCHOR_Y - y_eq - REST) ** 2)


def test_pre_stretched_spring_stiffens_a_pendulum_by_its_change_of_direction(make_scene):
    """Zero gravity; the bar (length l, I_O = m l^2 / 3) points along +x, its tip pulled towards
    (l + D, 0) by a spring of rest length < D. The torque comes only from the rotation of the
    spring's line: V = k (L - rest)^2 / 2 with L^2 = (l + D)^2 - 2 l (l + D) cos(theta) + l^2,
    so L' = 0 and L'' = l (l + D) / D at theta = 0, and V'' = k (D - rest) l (l + D) / D."""
    length, mass, D, rest, k = 0.3, 0.8, 0.2, 0.15, 400.0
    inertia_o = mass * length ** 2 / 3
    omega = math.sqrt(k * (D - rest) * length * (length + D) / (D * inertia_o))
    theta0 = 1e-4
    period = 2 * math.pi / omega
    path = make_scene({"pendulum.urdf": pendulum_urdf(length, mass)}, q0={"J1": theta0}, v0={"J1": 0.0},
                      gravity=(0.0, 0.0), t_end=period,
                      forces=[{"name": "spring", "type": "point_spring", "a": "link1", "point_a": [length, 0.0],
                               "b": "frame", "point_b": [length + D, 0.0], "k": k, "rest": rest}],
                      solver={"rtol": 1e-12, "atol": 1e-16})
    seg = pcmm.simulate(pcmm.load_scene(path)).segments[0]
    assert seg.t[-1] == pytest.approx(period, rel=1e-14)
    # the amplitude-dependent correction is O(theta0^2) relative: 1e-8
    assert np.max(np.abs(seg.q[:, 0] - theta0 * np.cos(omega * seg.t))) < 1e-6 * theta0


def test_free_bar_on_a_central_spring_conserves_energy_and_angular_momentum(make_scene):
    """A planar joint (x, y, theta; initial velocities in the body frame, recorded rates in world
    axes: docs/planar_joints.md) and a spring from the frame's
    origin to a point off the bar's centre of mass: the only external force passes through the
    origin, so the angular momentum about it is constant; with c = 0 so is the energy."""
    mass, length, k, rest = 2.0, 0.4, 50.0, 0.3
    izz = mass * length ** 2 / 12
    path = make_scene({"bar.urdf": free_bar_urdf(mass, length)}, q0={"P": [0.5, 0.0, 0.3]},
                      v0={"P": [0.0, 0.8, 1.5]}, gravity=(0.0, 0.0), t_end=2.0,
                      forces=[{"name": "spring", "type": "point_spring", "a": "frame", "point_a": [0.0, 0.0],
                               "b": "bar", "point_b": [0.1, 0.0], "k": k, "rest": rest}],
                      solver={"rtol": 1e-12, "atol": 1e-14})
    scene = pcmm.load_scene(path)
    traj = pcmm.simulate(scene)
    seg = traj.segments[0]
    rates = seg.v  # the recorded rates of a planar joint are world-axes (x', y', theta')
    x, y = seg.q[:, 0], seg.q[:, 1]
    momentum = mass * (x * rates[:, 1] - y * rates[:, 0]) + izz * rates[:, 2]
    assert np.ptp(momentum) < 1e-10 * abs(momentum[0])
    energy = seg.kinetic + seg.potential
    assert np.ptp(energy) < 1e-10 * abs(energy[0])
    # the motion is not trivial: the spring's length swings and the bar's spin changes
    lengths = np.hypot(x + 0.1 * np.cos(seg.q[:, 2]), y + 0.1 * np.sin(seg.q[:, 2]))
    assert np.ptp(lengths) > 0.1 and np.ptp(rates[:, 2]) > 0.1
    # potential energy is the spring's alone (no gravity)
    assert np.allclose(seg.potential, 0.5 * k * (lengths - rest) ** 2, rtol=0, atol=1e-12)


def test_scenes_without_point_springs_keep_the_linear_fast_path():
    from pcmm.model.mechanism import Mechanism
    cfg = Mechanism(pcmm.load_scene("examples/three_bar.toml"))["config1"]
    assert cfg.forces.points is None
    assert cfg.coords.rhs.__name__ != "rhs_points"  # the closure with one product and one aba, no Jacobians


def test_coinciding_points_stop_with_a_message(make_scene):
    path = make_scene({"slider.urdf": chain_urdf([Bar(0.1, 1.0, com=(0.0, 0.0), joint="prismatic",
                                                      axis=(0.0, 1.0, 0.0))], name="slider")},
                      q0={"J1": 0.0}, v0={"J1": 0.0},
                      forces=[{"name": "tie", "type": "point_spring", "a": "link1", "point_a": [0.0, 0.0],
                               "b": "frame", "point_b": [0.0, 0.0], "k": 10.0, "rest": 0.0}])
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(pcmm.load_scene(path))
    assert "'tie'" in info.value.text() and "coincide" in info.value.text()


BASE = {"name": "spring", "type": "point_spring", "a": "link1", "point_a": [0.1, 0.0], "b": "frame",
        "point_b": [0.0, 1.0], "k": 10.0, "rest": 0.5}


@pytest.mark.parametrize("change,drop,fragments", [
    ({}, "point_b", ["forces[0] (spring).point_b", "missing", "a, point_a, b and point_b"]),
    ({}, "rest", ["forces[0] (spring).rest", "missing", "rest length"]),
    ({"rest": -0.1}, None, ["forces[0] (spring).rest", "-0.1", ">= 0"]),
    ({"k": -1.0}, None, ["forces[0] (spring).k", "-1.0", ">= 0"]),
    ({"b": "link1"}, None, ["forces[0] (spring).b", "'link1'", "same link"]),
    ({"b": "lnk1"}, None, ["forces[0] (spring).b", "'lnk1'", "did you mean 'link1'?"]),
    ({"point_a": [0.1]}, None, ["forces[0] (spring).point_a", "[0.1]", "2 finite numbers"]),
    ({"on": {"joint": "J1"}}, None, ["forces[0] (spring).on", "not used by a 'point_spring'"]),
    ({"type": "spring", "measure": {"joint": "J1"}}, None,
     ["forces[0] (spring).a", "only used by a 'point_spring'", "forces[0] (spring).on", "missing"]),
])
def test_point_spring_errors_name_file_field_value(make_scene, change, drop, fragments):
    force = {k: v for k, v in BASE.items() if k != drop}
    force.update(change)
    path = make_scene({"pendulum.urdf": pendulum_urdf(0.2, 1.0)}, q0={"J1": 0.0}, v0={"J1": 0.0},
                      forces=[force])
    with pytest.raises(pcmm.SceneError) as info:
        pcmm.load_scene(path)
    text = info.value.text()
    for frag in [str(path)] + fragments:
        assert frag in text, f"{frag!r} not in:\n{text}"
