"""A mechanism the integrator wrote from the README and docs/point_impacts.md alone (2026-11-29,
a new user's try): Housner's rocking block (Bull. Seism. Soc. Am. 53, 1963).  A uniform block,
2b = 0.2 m wide and 2h = 0.6 m tall, 1 kg, on a floating planar joint, rocks on its bottom corners:
one `pin` configuration per corner (the corner pinned where it lands, held by compression only),
one `pin` transition per corner strike, the old corner lifting off because the new one's impulse
separates it.  Released at rest tilted 0.2 rad on its right corner.

Checked against Housner's closed forms, derived here without pcmm: about a corner the block is a
pendulum of I_O = (4/3) m R^2 (R = sqrt(b^2 + h^2), alpha = atan(b/h)) whose centre of mass stands at
R cos(alpha - phi); a strike keeps the angular momentum about the new corner, so
omega+ / omega- = r = 1 - (3/2) sin^2 alpha = 0.85 and the kinetic energy keeps r^2; the time between
strikes is twice the pendulum's quarter swing from its top tilt, by quadrature.  What made the try
stumble: nothing in the scene; the figures' run without impact pinned silently with the impulse of
the run with impact (identical curves under a "without considering impact" legend), now said once.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

import pcmm

M, B, H, G = 1.0, 0.1, 0.3, 9.81
R, ALPHA = math.hypot(B, H), math.atan2(B, H)
I_O = 4.0 / 3.0 * M * R * R
TILT = 0.2

URDF = """<?xml version="1.0"?>
<robot name="rocking_block">
  <link name="ground"/>
  <joint name="base" type="planar">
    <parent link="ground"/>
    <child link="block"/>
    <origin xyz="0 0 0" rpy="0 0 0"/>
    <axis xyz="0 0 1"/>
  </joint>
  <link name="block">
    <inertial>
      <origin xyz="0 0 0" rpy="0 0 0"/>
      <mass value="1.0"/>
      <inertia ixx="0.0333333333333333" ixy="0" ixz="0" iyy="0.0333333333333333" iyz="0"
               izz="0.03333333333333333"/>
    </inertial>
    <visual>
      <origin xyz="0 0 0" rpy="0 0 0"/>
      <geometry><box size="0.2 0.6 0.05"/></geometry>
    </visual>
  </link>
</robot>
"""

SCENE = """# Housner's rocking block: 0.2 m x 0.6 m, 1 kg, released from a tilt of 0.2 rad on its right corner.
[scene]
name = "rocking_block"
gravity = [0.0, -9.81]
t_end = 2.0
initial_configuration = "on_right"

[solver]
rtol = 1e-12
atol = 1e-13

[configurations.on_right]
urdf = "block.urdf"
cut_joints = [ { name = "right", type = "revolute", a = "ground", point_a = "entry", b = "block", point_b = [0.1, -0.3], contact = { normal = [0.0, 1.0], friction = "stick" } } ]

[configurations.on_left]
urdf = "block.urdf"
cut_joints = [ { name = "left", type = "revolute", a = "ground", point_a = "entry", b = "block", point_b = [-0.1, -0.3], contact = { normal = [0.0, 1.0], friction = "stick" } } ]

[initial]
# the right corner at the origin: the centre of mass at -R(theta) (b, -h), theta = -0.2
q = { base = ["-(0.1*cos(-0.2) + 0.3*sin(-0.2))", "-(0.1*sin(-0.2) - 0.3*cos(-0.2))", -0.2] }
v = { base = [0.0, 0.0, 0.0] }

[[transitions]]
name = "left strikes"
type = "pin"
from = "on_right"
to = "on_left"
contact = { a = "ground", point_a = [0.0, 0.0], b = "block", point_b = [-0.1, -0.3], normal = [0.0, 1.0], friction = "stick" }
guard = { type = "gap", value = 0.0, direction = "decreasing" }

[[transitions]]
name = "right strikes"
type = "pin"
from = "on_left"
to = "on_right"
contact = { a = "ground", point_a = [0.0, 0.0], b = "block", point_b = [0.1, -0.3], normal = [0.0, 1.0], friction = "stick" }
guard = { type = "gap", value = 0.0, direction = "decreasing" }
"""


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rocking")
    (folder / "block.urdf").write_text(URDF)
    (folder / "rocking.toml").write_text(SCENE)
    return pcmm.load_scene(folder / "rocking.toml")


def _half_swing(top: float) -> float:
    """Time for the block to fall from tilt ``top`` at rest to upright about one corner (quadrature)."""
    # phi = top - u^2 takes the 1/sqrt singularity at the top away: cos(alpha - top) - cos(alpha - phi)
    # = 2 sin(alpha - top + u^2/2) sin(u^2/2), and dphi = -2u du
    def dt(u):
        drop = 2 * math.sin(ALPHA - top + u * u / 2) * math.sin(u * u / 2)
        return 2.0 / math.sqrt(2 * M * G * R * math.sin(ALPHA - top + u * u / 2) / I_O) if u == 0 else \
            2 * u / math.sqrt(2 * M * G * R * drop / I_O)
    return quad(dt, 0.0, math.sqrt(top), limit=200, epsabs=1e-14, epsrel=1e-13)[0]


def _housner(strikes: int):
    """(times, rates before) of the first ``strikes`` strikes, by hand."""
    r = 1 - 1.5 * math.sin(ALPHA) ** 2
    t = _half_swing(TILT)
    w = math.sqrt(2 * M * G * R * (math.cos(ALPHA - TILT) - math.cos(ALPHA)) / I_O)
    times, rates = [t], [w]
    for _ in range(strikes - 1):
        w *= r  # the rate after, rising about the new corner
        top = ALPHA - math.acos(math.cos(ALPHA) + 0.5 * I_O * w * w / (M * G * R))
        t += 2 * _half_swing(top)
        times.append(t)
        rates.append(w)
    return np.array(times), np.array(rates)


def test_the_block_rocks_as_housner_said(scene):
    traj = pcmm.simulate(scene)
    assert [e["name"] for e in traj.events] == ["left strikes", "right strikes"] * 3 + ["left strikes"]
    times, rates = _housner(7)
    assert np.abs(np.array([e["t"] for e in traj.events]) - times).max() < 1e-9
    r = 1 - 1.5 * (B * B / (B * B + H * H))
    assert r == pytest.approx(0.85, abs=1e-15)
    for e, w in zip(traj.events, rates):
        assert abs(e["omega_before"]["block"]) == pytest.approx(w, rel=1e-9)
        assert e["omega_after"]["block"] / e["omega_before"]["block"] == pytest.approx(r, abs=1e-10)
        assert e["kinetic_energy_after"] / e["kinetic_energy_before"] == pytest.approx(r * r, abs=1e-10)
        assert e["kinetic_energy_before"] == pytest.approx(0.5 * I_O * w * w, rel=1e-9)


def test_the_first_strike_by_hand(scene):
    """At the first strike the block is upright, turning at w- about its right corner (x = 0, as the
    scene puts it); after, at r w- about its left corner (-2b, 0).  The impulse is the change of the
    centre of mass's momentum; the angular momentum about the new corner is kept; the right corner
    leaves at 2b r w-."""
    e = pcmm.simulate(scene, pcmm.RunOptions(t_end=0.5)).events[0]
    w = _housner(1)[1][0]
    r = 1 - 1.5 * math.sin(ALPHA) ** 2
    v_minus = w * np.array([-H, -B])       # w x (c - right corner), c - right = (-b, h)
    v_plus = r * w * np.array([-H, B])     # r w x (c - left corner), c - left = (b, h)
    P = M * (v_plus - v_minus)
    assert e["impulse"]["vector"] == pytest.approx(P.tolist(), abs=1e-10)
    assert (e["impulse"]["tangential"], e["impulse"]["normal"]) == pytest.approx((P[0], P[1]), abs=1e-10)
    assert e["anchor"]["left"] == pytest.approx([-2 * B, 0.0], abs=1e-12)
    I_c = M * (4 * B * B + 4 * H * H) / 12

    def about_left(v, omega):  # I_c omega + m (c - left) x v_c
        return I_c * omega + M * (B * v[1] - H * v[0])
    assert about_left(v_plus, r * w) == pytest.approx(about_left(v_minus, w), rel=1e-14)  # the hand model's own
    assert e["v_after"]["base"][:2] == pytest.approx(v_plus.tolist(), abs=1e-10)  # upright: body = world axes
    assert e["released"]["right"]["normal_velocity_after"] == pytest.approx(2 * B * r * w, rel=1e-9)
    assert e["released"]["right"]["impulse"] == 0.0
    assert e["friction"]["energy_lost"]["tangential"] == pytest.approx(0.0, abs=1e-15)  # no slip before


def test_the_run_without_impact_says_that_a_pin_takes_its_impulse(scene):
    """A pin cannot switch without an impulse (the struck corner must stop): the comparison run
    takes the same plastic impulse, and says so once, at its first pin."""
    with_impact = pcmm.simulate(scene, pcmm.RunOptions(t_end=1.2))
    without = pcmm.simulate(scene, pcmm.RunOptions(t_end=1.2, impact=False))
    assert [e["t"] for e in without.events] == [e["t"] for e in with_impact.events]
    said = [w for e in without.events for w in e.get("warnings", ())]
    assert len(said) == 1 and "a pin has no switch without impulse" in said[0] and "'left strikes'" in said[0]
    assert not [w for e in with_impact.events for w in e.get("warnings", ())]
