"""A newcomer's mechanism, written from the README and the scene format alone (2026-11-28): a
uniform bar hinged at one end falls from horizontal onto a frame stop at vertical (e = 0.5). Every
number is closed form: the fall time of a physical pendulum released at 90 degrees, the impact
speed from energy, Newton's restitution and the impulse moment from the hinge's angular momentum."""
import math

import pcmm

M, L, E = 3.0, 1.0, 0.5
I_C = M * L * L / 12  # about the centroid
I_O = M * L * L / 3  # about the hinge
G = 9.81

LINK = f"""  <link name="door">
    <inertial>
      <origin xyz="{L / 2} 0 0" rpy="0 0 0"/> <mass value="{M}"/>
      <inertia ixx="1e-4" ixy="0" ixz="0" iyy="{I_C}" iyz="0" izz="{I_C}"/>
    </inertial>
  </link>"""

OPEN = f"""<?xml version="1.0"?>
<robot name="door">
  <link name="frame"/>
  <joint name="hinge" type="revolute">
    <parent link="frame"/> <child link="door"/>
    <origin xyz="0 0 0" rpy="0 0 0"/> <axis xyz="0 0 1"/>
    <limit lower="-1e6" upper="1e6" effort="1e6" velocity="1e6"/>
  </joint>
{LINK}
</robot>
"""

SHUT = f"""<?xml version="1.0"?>
<robot name="door_shut">
  <link name="frame"/>
  <joint name="hinge" type="fixed">
    <parent link="frame"/> <child link="door"/>
    <origin xyz="0 0 0" rpy="0 0 -1.5707963267948966"/>
  </joint>
{LINK}
</robot>
"""

SCENE = """[scene]
name = "trapdoor"
gravity = [0.0, -9.81]
t_end = 1.4
initial_configuration = "open"

[configurations.open]
urdf = "door.urdf"

[configurations.shut]
urdf = "door_shut.urdf"

[initial]
q = { hinge = 0.0 }
v = { hinge = 0.0 }

[[transitions]]
name = "stop"
type = "stop"
from = "open"
restitution = 0.5
merge_to = "shut"
cut = []
guard = { type = "coordinate", measure = { joint = "hinge" }, value = -1.5707963267948966, direction = "decreasing" }
contact = { joint = "hinge", arm = 1.0 }
"""


def test_a_trapdoor_falls_strikes_and_rebounds_as_closed_form_says(tmp_path):
    (tmp_path / "door.urdf").write_text(OPEN)
    (tmp_path / "door_shut.urdf").write_text(SHUT)
    (tmp_path / "door.toml").write_text(SCENE)
    traj = pcmm.simulate(pcmm.load_scene(tmp_path / "door.toml"))
    first, second = traj.events[:2]
    # released at rest from horizontal: theta'^2 = (2 w^2) sin(fallen angle), w^2 = M g (L/2) / I_O;
    # the time to fall 90 degrees is int_0^{pi/2} d(phi) / sqrt(2 w^2 sin phi)
    #   = Gamma(1/4)^2 / (2 sqrt(2 pi)) / sqrt(2 w^2)
    w2 = M * G * (L / 2) / I_O
    fall = math.gamma(0.25) ** 2 / (2 * math.sqrt(2 * math.pi)) / math.sqrt(2 * w2)
    assert abs(first["t"] - fall) < 1e-9
    omega_minus = -math.sqrt(2 * w2)  # energy: M g L/2 = I_O omega^2 / 2
    assert abs(first["omega_before"]["door"] - omega_minus) < 1e-9
    assert abs(first["omega_after"]["door"] + E * omega_minus) < 1e-9  # Newton's restitution
    # the stop's moment impulse is the change of angular momentum about the hinge
    assert abs(first["impulse"]["moment"] - I_O * (1 + E) * -omega_minus) < 1e-8
    assert abs(first["kinetic_energy_after"] - E * E * first["kinetic_energy_before"]) < 1e-9
    # the rebound rises and falls back to the stop symmetrically: the second strike at speed e omega
    assert abs(second["omega_before"]["door"] - E * omega_minus) < 1e-8
