"""Continuous contact laws against closed-form contact mechanics.

A ball (point mass on a prismatic joint) dropped on the frame, the stop resolved by a
continuous law F = k delta^n (1 + D(e) delta'/v-) instead of the impulse.
"""
from __future__ import annotations

import math

import pytest

import builders
import pcmm

G = 9.81


def ball(tmp_path, law, k, e, m=1.0, h=1.0, n=1.5, gravity=G):
    """The first contact of a ball of mass m dropped from h, resolved by ``law``."""
    path = builders.ball(tmp_path, e, h=h, g=gravity, mass=m, t_end=math.sqrt(2 * h / G) + 0.05, merge=False,
                   law=law, stiffness=k, exponent=n)
    traj = pcmm.simulate(pcmm.load_scene(path))
    assert traj.events, "the ball never touched the floor"
    return traj.events[0]


def test_elastic_hertz_contact_duration_and_restitution(tmp_path):
    """Hunt-Crossley with e = 1 has no damping: Hertz's elastic impact.  Energy balance
    m v^2 / 2 = k delta_max^(5/2) / (5/2) gives delta_max = (5 m v^2 / (4 k))^(2/5), and the
    contact lasts t_c = 2.9432 delta_max / v (Johnson, Contact Mechanics, 11.4)."""
    m, k, h = 1.0, 1e10, 1.0
    ev = ball(tmp_path, "hunt_crossley", k, 1.0, m=m, h=h)
    v = math.sqrt(2 * G * h)
    delta_max = (5 * m * v * v / (4 * k)) ** 0.4
    assert ev["duration"] == pytest.approx(2.9432 * delta_max / v, rel=2e-3)  # gravity: O(g t_c / v) = 2e-5
    assert -ev["normal_velocity"]["after"] / ev["normal_velocity"]["before"] == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("law", ["hunt_crossley", "lankarani_nikravesh", "flores"])
def test_momentum_balance_and_hertz_scaling(tmp_path, law):
    """Over the contact, m (v+ - v-) = P - m g t_c; the duration scales as k^(-2/5) (Hertz,
    the damping term is dimensionless in delta'/v-); the post-impact speed converges as k grows
    and dissipates energy."""
    events = {k: ball(tmp_path, law, k, 0.8) for k in (1e8, 1e10)}
    for ev in events.values():
        vb, va = ev["normal_velocity"]["before"], ev["normal_velocity"]["after"]
        assert ev["impulse"]["normal"] == pytest.approx(1.0 * (va - vb) + 1.0 * G * ev["duration"], rel=1e-9)
        assert ev["kinetic_energy_after"] < ev["kinetic_energy_before"]
    ratio = events[1e8]["duration"] / events[1e10]["duration"]
    assert ratio == pytest.approx(100 ** 0.4, rel=5e-3)
    e_eff = {k: -ev["normal_velocity"]["after"] / ev["normal_velocity"]["before"] for k, ev in events.items()}
    assert e_eff[1e8] == pytest.approx(e_eff[1e10], abs=1e-3)


def test_each_law_has_its_own_effective_restitution(tmp_path):
    """As k grows the continuous laws tend to the impulse solution but with their own effective
    restitution: Flores et al. (2011) is built to give ~e for any e; Hunt-Crossley's D = 3(1-e)/2
    and Lankarani-Nikravesh's 3(1-e^2)/4 assume e near 1 and overshoot at e = 0.8."""
    e = 0.8
    eff = {law: -ev["normal_velocity"]["after"] / ev["normal_velocity"]["before"]
           for law in ("hunt_crossley", "lankarani_nikravesh", "flores")
           for ev in [ball(tmp_path, law, 1e10, e)]}
    assert abs(eff["flores"] - e) < 0.02
    assert eff["hunt_crossley"] > e and eff["lankarani_nikravesh"] > eff["hunt_crossley"]
    assert eff["lankarani_nikravesh"] < 0.9


def test_continuous_law_needs_its_parameters(tmp_path):
    latch = {"name": "t", "type": "latch", "from": "c", "to": "c", "law": "flores", "cut": [],
             "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"},
             "contact": {"a": "frame", "point_a": [0.0, 0.0], "b": "frame", "point_b": [0.0, 0.0], "normal": [0.0, 1.0]}}
    doc = builders.scene_doc({"c": "b.urdf"}, {}, {}, name="x", transitions=[latch])
    builders.write_scene(tmp_path, doc, {"b.urdf": builders.robot_xml("x", builders.link_xml("frame"))}, "s.toml")
    with pytest.raises(pcmm.SceneError) as info:
        pcmm.load_scene(tmp_path / "s.toml")
    msg = info.value.text()
    assert "transitions[0] (t).law" in msg and "latch" in msg
    assert "transitions[0] (t).stiffness" in msg and "transitions[0] (t).exponent" in msg
