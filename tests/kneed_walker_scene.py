"""The kneed walker's URDF and scene, written as a new user writes them (see test_newcomer3_walker.py)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

import reference_kneed_walker as kw
from builders import dump_toml


def _bar(name, mass, com_y, izz, length):
    return f"""  <link name="{name}">
    <inertial><origin xyz="0 {com_y!r} 0" rpy="0 0 0"/><mass value="{mass!r}"/>
      <inertia ixx="{izz!r}" ixy="0" ixz="0" iyy="{izz!r}" iyz="0" izz="{izz!r}"/></inertial>
    <visual><origin xyz="0 {-length / 2!r} 0" rpy="0 0 0"/><geometry><box size="0.02 {length!r} 0.02"/></geometry></visual>
  </link>
"""


def _rev(name, parent, child, y=0.0):
    return f"""  <joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>
    <origin xyz="0 {y!r} 0" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-1e6" upper="1e6" effort="1e6" velocity="1e6"/></joint>
"""


def walker_urdf(w: kw.Walker) -> str:
    """A planar base on thigh a (the hip mass fixed to it), the hip to thigh b, a knee in each leg.

    Each segment's frame sits at its upper joint with the segment along -y."""
    return f"""<?xml version="1.0"?>
<robot name="kneed_walker">
  <link name="frame"/>
  <joint name="base" type="planar"><parent link="frame"/><child link="thigh_a"/>
    <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/></joint>
{_bar("thigh_a", w.m_thigh, -w.c_thigh, w.i_thigh, w.l_thigh)}  <joint name="pelvis" type="fixed"><parent link="thigh_a"/><child link="hip_mass"/>
    <origin xyz="0 0 0" rpy="0 0 0"/></joint>
  <link name="hip_mass">
    <inertial><origin xyz="0 0 0" rpy="0 0 0"/><mass value="{w.m_hip!r}"/>
      <inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>
    <visual><origin xyz="0 0 0" rpy="0 0 0"/><geometry><sphere radius="0.03"/></geometry></visual>
  </link>
{_rev("hip", "thigh_a", "thigh_b")}{_bar("thigh_b", w.m_thigh, -w.c_thigh, w.i_thigh, w.l_thigh)}{_rev("knee_a", "thigh_a", "shank_a", -w.l_thigh)}{_bar("shank_a", w.m_shank, -w.c_shank, w.i_shank, w.l_shank)}{_rev("knee_b", "thigh_b", "shank_b", -w.l_thigh)}{_bar("shank_b", w.m_shank, -w.c_shank, w.i_shank, w.l_shank)}</robot>
"""


def foot_pin(leg, w):
    return {"name": f"foot_{leg}", "type": "revolute", "a": "frame", "point_a": "entry", "b": f"shank_{leg}",
            "point_b": [0.0, -w.l_shank], "contact": {"normal": [0.0, 1.0], "friction": "stick"}}


def initial_state(w, theta, omega, foot=(0.0, 0.0)):
    """pcmm's q, v (a_swing: foot a pinned at ``foot``) from the reference's swing coordinates."""
    q, v = kw.floating_state(w, "a", theta, omega, foot)
    x, y, ta, sa, tb, sb = q
    c, s = np.cos(ta), np.sin(ta)
    vb = [c * v[0] + s * v[1], -s * v[0] + c * v[1], v[2]]      # the planar joint's body-frame velocity
    return ({"base": [float(x), float(y), float(ta)], "hip": float(tb - ta), "knee_b": float(sb - tb)},
            {"base": [float(a) for a in vb], "hip": float(v[4] - v[2]), "knee_b": float(v[5] - v[4])})


def unlock_on_entry(stance):
    """The trailing knee's release after a heel strike: on entering the strike's configuration."""
    return {"type": "entry"}


def write_walker(folder: Path, w: kw.Walker, theta, omega, t_end=1.2, release=None,
                 solver=None, foot=(0.0, 0.0), hold_references=False, knee_cut=True) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "kneed_walker.urdf").write_text(walker_urdf(w))
    q0, v0 = initial_state(w, theta, omega, foot)
    g = [f"9.81*sin({w.gamma!r})", f"-9.81*cos({w.gamma!r})"]
    configs = {
        "flight": {"urdf": "kneed_walker.urdf"},
        "a_swing": {"from": "flight", "lock": {"knee_a": 0.0}, "cut_joints": [foot_pin("a", w)]},
        "a_locked": {"from": "flight", "lock": {"knee_a": 0.0, "knee_b": 0.0}, "cut_joints": [foot_pin("a", w)]},
        "b_swing": {"from": "flight", "lock": {"knee_b": 0.0}, "cut_joints": [foot_pin("b", w)]},
        "b_locked": {"from": "flight", "lock": {"knee_a": 0.0, "knee_b": 0.0}, "cut_joints": [foot_pin("b", w)]},
        # just after a heel strike: both knees still locked, the new foot pinned
        "b_strike": {"from": "flight", "lock": {"knee_a": 0.0, "knee_b": 0.0}, "cut_joints": [foot_pin("b", w)]},
        "a_strike": {"from": "flight", "lock": {"knee_a": 0.0, "knee_b": 0.0}, "cut_joints": [foot_pin("a", w)]},
    }
    if hold_references:  # where the knees' holding moments are solved: each stance with its knee free
        for leg, other in (("a", "b"), ("b", "a")):  # (its swing knee locked), and with both knees free
            configs[f"{leg}_knee_free"] = {"from": "flight", "lock": {f"knee_{other}": 0.0}, "cut_joints": [foot_pin(leg, w)]}
            configs[f"{leg}_knees_free"] = {"urdf": "kneed_walker.urdf", "cut_joints": [foot_pin(leg, w)]}
    transitions = []
    for stance, swing in (("a", "b"), ("b", "a")):
        transitions.append({
            "name": f"knee strike {swing}", "type": "latch", "from": f"{stance}_swing", "to": f"{stance}_locked",
            "cut": [f"knee_{swing}"] if knee_cut else [],
            "guard": {"type": "coordinate", "measure": {"joint": f"knee_{swing}"}, "value": 0.0,
                      "direction": "increasing"},
            "contact": {"joint": f"knee_{swing}"}})
        ahead = {"above": 0.0} if swing == "b" else {"below": 0.0}
        transitions.append({
            "name": f"heel strike {swing}", "type": "pin", "from": f"{stance}_locked",
            "to": f"{swing}_strike",
            "contact": {"a": "frame", "point_a": [0.0, 0.0], "b": f"shank_{swing}", "point_b": [0.0, -w.l_shank],
                        "normal": [0.0, 1.0], "friction": "stick"},
            "guard": {"type": "gap", "value": 0.0, "direction": "decreasing",
                      "when": {"measure": {"joint": "hip"}, **ahead}}})
        if release is not None:
            transitions.append({"name": f"knee {stance} unlocks", "type": "release", "from": f"{swing}_strike",
                                "to": f"{swing}_swing", "guard": release(stance)})
    doc = {"scene": {"name": "kneed_walker", "description": "a passive kneed walker (McGeer 1990)",
                     "gravity": g, "t_end": t_end, "initial_configuration": "a_swing"},
           "solver": solver or {"rtol": 1e-12, "atol": 1e-13},
           "configurations": configs, "initial": {"q": q0, "v": v0}, "transitions": transitions}
    path = folder / "kneed_walker.toml"
    path.write_text(dump_toml(doc))
    return path
