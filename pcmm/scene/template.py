"""Scene templates (``pcmm new NAME``): a scene and its URDFs that run as they are.

* open (default): a chain of ``links`` bars on revolute joints ``J1 .. JN`` hung from the frame,
  with a motor on the last joint; that joint latches at 30 degrees (an elbow stop): the second
  configuration's URDF fixes it there.
* closed (``--closed``): a crank-rocker four-bar (frame 0.3 m, crank 0.1 m, coupler 0.3 m,
  rocker 0.2 m) driven by a motor moment on the crank; the loop is closed by the cut joint ``J4``
  between the rocker and the frame, and the coupler latches onto the rocker (joint ``J3`` locks).

The geometry that must agree (contact points, normals, guard values) is written with
expressions (``"30 deg"``, ``"0.3 + 0.05*cos(30 deg)"``), so it agrees exactly.  Every
template passes ``pcmm check`` and runs (tests/test_template.py).
"""
from __future__ import annotations

import math
from pathlib import Path

from ..errors import UsageError

BAR = 0.2  # m, the open chain's bar length
DENSITY = 2.0  # kg/m of bar
LIMIT = '<limit lower="-1e6" upper="1e6" effort="1e6" velocity="1e6"/>'


def _bar_link(name: str, length: float) -> str:
    m = DENSITY * length
    izz = m * length ** 2 / 12
    return (f'  <link name="{name}">\n'
            f'    <!-- uniform bar: L = {length!r} m, m = {m!r} kg, Izz = m L^2 / 12 about the centroid -->\n'
            f'    <inertial>\n      <origin xyz="{length / 2!r} 0 0" rpy="0 0 0"/>\n      <mass value="{m!r}"/>\n'
            f'      <inertia ixx="{izz / 100!r}" ixy="0" ixz="0" iyy="{izz!r}" iyz="0" izz="{izz!r}"/>\n'
            f'    </inertial>\n'
            f'    <visual>\n      <origin xyz="{length / 2!r} 0 0" rpy="0 0 0"/>\n'
            f'      <geometry><box size="{length!r} 0.012 0.012"/></geometry>\n    </visual>\n'
            f'  </link>\n')


def _joint(name: str, parent: str, child: str, x: float, yaw: float | None = None) -> str:
    """A revolute joint at (x, 0) of the parent, or a fixed one rotated by ``yaw``."""
    if yaw is not None:
        return (f'  <joint name="{name}" type="fixed">\n    <parent link="{parent}"/>\n    <child link="{child}"/>\n'
                f'    <origin xyz="{x!r} 0 0" rpy="0 0 {yaw!r}"/>\n  </joint>\n')
    return (f'  <joint name="{name}" type="revolute">\n    <parent link="{parent}"/>\n    <child link="{child}"/>\n'
            f'    <origin xyz="{x!r} 0 0" rpy="0 0 0"/>\n    <axis xyz="0 0 1"/>\n    {LIMIT}\n  </joint>\n')


def _robot(name: str, comment: str, body: str) -> str:
    assert "--" not in comment  # XML comments cannot hold "--"
    return (f'<?xml version="1.0"?>\n<!-- {comment} -->\n<robot name="{name}">\n  <link name="frame"/>\n'
            f'{body}</robot>\n')


def _chain(name: str, lengths: list[float], locked: tuple[int, float] | None) -> str:
    body = ""
    parent, x = "frame", 0.0
    for i, L in enumerate(lengths, start=1):
        yaw = locked[1] if locked and locked[0] == i else None
        body += _joint(f"J{i}", parent, f"link{i}", x, yaw) + _bar_link(f"link{i}", L)
        parent, x = f"link{i}", L
    return body


def _head(name: str, description: str) -> str:
    """The [scene] table and the first configuration of a template."""
    return (f'[scene]\nname = "{name}"\ndescription = "{description}"\ngravity = [0.0, -9.81]\nt_end = 1.0\n'
            f'initial_configuration = "open"\n\n[configurations.open]\nurdf = "{name}_open.urdf"\n')


def open_chain(name: str, links: int) -> tuple[str, dict[str, str]]:
    """(scene text, {file name: URDF text}) of the open template."""
    n = links
    lengths = [BAR] * n
    free = _robot(f"{name}_open", f"pcmm new: {n} bars, every joint free", _chain(name, lengths, None))
    latched = _robot(f"{name}_latched", f"pcmm new: {n} bars, J{n} latched at 30 degrees",
                     _chain(name, lengths, (n, math.radians(30.0))))
    q = ", ".join(f'J{i} = "0 deg"' for i in range(1, n + 1))
    v = ", ".join(f"J{i} = 0.0" for i in range(1, n + 1))
    r = 0.5 * BAR  # the contact sits half a bar from the latching joint
    scene = f'''# {name}: written by `pcmm new {name} --links {n}`. Edit it, then `pcmm check {name}.toml`.
# A chain of {n} bars hung from the frame; a motor opens the last joint J{n}, which latches
# (locks) when link{n} stands at 30 degrees to link{n - 1}.

{_head(name, f"{n}-bar chain whose last joint latches at 30 degrees")}
[configurations.latched]
urdf = "{name}_latched.urdf"      # J{n} is a fixed joint there, at rpy = 30 degrees

[initial]
q = {{ {q} }}
v = {{ {v} }}

[[forces]]                          # the motor: a moment between link{n - 1} and link{n}
name = "elbow motor"
type = "torque"
on = {{ joint = "J{n}" }}
value = 0.5
configurations = ["open"]           # J{n} is fixed once latched

[[transitions]]
name = "J{n} latches"
type = "latch"
from = "open"
to = "latched"
cut = ["J{n}"]                      # the metamorphic joint, cut to solve the impulse
guard = {{ type = "coordinate", measure = {{ between = ["link{n - 1}", "link{n}"] }}, value = "30 deg", direction = "increasing" }}
# The point {r!r} m along link{n} meets the stop on link{n - 1} when the guard fires; the normal is in
# link{n - 1}'s frame, from link{n - 1} towards link{n}, perpendicular to the lever from J{n}.
contact = {{ a = "link{n - 1}", point_a = ["{BAR!r} + {r!r}*cos(30 deg)", "{r!r}*sin(30 deg)"], b = "link{n}", point_b = [{r!r}, 0.0], normal = ["sin(30 deg)", "-cos(30 deg)"] }}
'''
    return scene, {f"{name}_open.urdf": free, f"{name}_latched.urdf": latched}


# four-bar: frame d, crank a, coupler b, rocker c (crank-rocker: a + b <= c + d)
FOUR_BAR = {"d": 0.3, "a": 0.1, "b": 0.3, "c": 0.2}
LATCH_DEG = -90  # J3 = theta_rocker - theta_coupler where the coupler latches onto the rocker


def four_bar_angles(phi: float) -> tuple[float, float]:
    """(J2, J3) of the four-bar at crank angle ``phi`` on the template's branch (closed form:
    B from the circles about A (radius b) and D (radius c))."""
    d, a, b, c = (FOUR_BAR[k] for k in "dabc")
    ax, ay = a * math.cos(phi), a * math.sin(phi)
    ex, ey = d - ax, -ay
    e = math.hypot(ex, ey)
    k = (b * b - c * c + e * e) / (2 * e)
    h = math.sqrt(b * b - k * k)
    bx, by = ax + (k * ex - h * ey) / e, ay + (k * ey + h * ex) / e  # the elbow-up branch
    coupler = math.atan2(by - ay, bx - ax)
    rocker = math.atan2(-by, d - bx)  # from B towards D
    wrap = lambda x: (x + math.pi) % (2 * math.pi) - math.pi  # noqa: E731
    return wrap(coupler - phi), wrap(rocker - coupler)


def four_bar(name: str) -> tuple[str, dict[str, str]]:
    d, a, b, c = (FOUR_BAR[k] for k in "dabc")
    alpha = math.radians(LATCH_DEG)
    body = (_joint("J1", "frame", "crank", 0.0) + _bar_link("crank", a)
            + _joint("J2", "crank", "coupler", a) + _bar_link("coupler", b))
    free = _robot(f"{name}_open", "pcmm new, closed: four-bar spanning tree (J4 is the scene's cut joint)",
                  body + _joint("J3", "coupler", "rocker", b) + _bar_link("rocker", c))
    latched = _robot(f"{name}_latched", f"pcmm new, closed: J3 latched at {LATCH_DEG} degrees",
                     body + _joint("J3", "coupler", "rocker", b, alpha) + _bar_link("rocker", c))
    j2, j3 = four_bar_angles(math.pi / 2)
    r = 0.05
    cut = f'cut_joints = [ {{ name = "J4", type = "revolute", a = "frame", point_a = [{d!r}, 0.0], b = "rocker", point_b = [{c!r}, 0.0] }} ]'
    scene = f'''# {name}: written by `pcmm new {name} --closed`. Edit it, then `pcmm check {name}.toml`.
# A crank-rocker four-bar: frame {d} m, crank {a} m, coupler {b} m, rocker {c} m. The URDF holds the
# spanning tree frame -J1- crank -J2- coupler -J3- rocker; the cut joint J4 closes the loop at the
# frame. A motor turns the crank; the coupler latches onto the rocker (J3 locks) at {LATCH_DEG} degrees,
# and the locked loop is a rigid triangle.

{_head(name, "four-bar whose coupler latches onto the rocker")}{cut}

[configurations.latched]
urdf = "{name}_latched.urdf"
{cut}

[initial]
# The crank angle is kept; J2 and J3 are rough guesses, solved so the loop closes. The branch
# (the sign of the coupler-rocker angle) picks the assembly, never the mirrored one.
q = {{ J1 = "90 deg", J2 = "{round(math.degrees(j2))} deg", J3 = "{round(math.degrees(j3))} deg" }}
v = {{ J1 = 0.0 }}                   # J2's and J3's velocities follow from the loop
independent = ["J1"]
branch = {{ between = ["coupler", "rocker"], sign = "-" }}

[[forces]]                          # the motor: a moment on the crank from the frame
name = "crank motor"
type = "linear"
on = {{ joint = "J1" }}
measure = {{ joint = "J1" }}
value = 1.5
c = 0.05

[[transitions]]
name = "coupler latches onto rocker"
type = "latch"
from = "open"
to = "latched"
cut = ["J3"]
guard = {{ type = "coordinate", measure = {{ between = ["coupler", "rocker"] }}, value = "{LATCH_DEG} deg", direction = "increasing" }}
# The point {r} m along the rocker meets the stop on the coupler when J3 = {LATCH_DEG} deg; the normal, in the
# coupler's frame, points from the coupler towards the rocker, perpendicular to the lever from J3.
contact = {{ a = "coupler", point_a = ["{b!r} + {r!r}*cos({LATCH_DEG} deg)", "{r!r}*sin({LATCH_DEG} deg)"], b = "rocker", point_b = [{r!r}, 0.0], normal = ["sin({LATCH_DEG} deg)", "-cos({LATCH_DEG} deg)"] }}
'''
    return scene, {f"{name}_open.urdf": free, f"{name}_latched.urdf": latched}


def write_template(name: str, folder: Path, links: int = 3, closed: bool = False, force: bool = False) -> list[Path]:
    """Write ``NAME.toml`` and its URDFs into ``folder``; returns the files written."""
    if not name or not all(ch.isalnum() or ch in "_-" for ch in name):
        raise UsageError(f"NAME = {name!r}: use letters, digits, '_' and '-' (it names the files)")
    if closed and links != 3:
        raise UsageError(f"--links {links} with --closed: the closed template is a four-bar (3 moving links)")
    if not closed and links < 2:
        raise UsageError(f"--links {links}: the open template needs at least 2 links (the last one latches "
                         "onto the one before)")
    if not folder.is_dir():
        raise UsageError(f"{folder}: folder does not exist")
    scene, urdfs = four_bar(name) if closed else open_chain(name, links)
    files = {folder / f"{name}.toml": scene, **{folder / k: v for k, v in urdfs.items()}}
    existing = [str(p) for p in files if p.exists()]
    if existing and not force:
        raise UsageError([f"{p}: exists; pass --force to overwrite it" for p in existing])
    for path, text in files.items():
        path.write_text(text, encoding="utf-8")
    return list(files)
