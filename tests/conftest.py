"""Shared builders for the pcmm test suite.

Every test states only its numbers: the helpers here write small URDFs (a
chain of bars on revolute joints, a free bar on a URDF ``planar`` joint) and a
scene TOML around them into ``tmp_path``.

Conventions of the builders (so that the closed-form expressions in the tests
can be written against them):

* every link frame has its origin on the joint that carries the link; a bar of
  length ``L`` lies along its frame's +x axis, the next joint sits at ``(L, 0)``;
* ``com`` is the centroid in the link frame, ``izz`` the moment of inertia
  about the centroid (normal to the plane); ``m L^2 / 12`` for a uniform bar;
* gravity is ``(0, -g)`` in the xy plane unless a test says otherwise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from extreme_models import toml_key, toml_value  # the one TOML writer of the tests

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
URDF_DIR = ROOT / "urdf"
G = 9.81


# ---- URDF text -------------------------------------------------------------------------
@dataclass(frozen=True)
class Bar:
    """One link of a chain, hung on the joint ``joint`` (revolute, fixed or planar)."""

    length: float
    mass: float
    com: tuple[float, float] | None = None  # default: (length / 2, 0)
    izz: float | None = None  # about the centroid; default m L^2 / 12
    yaw: float = 0.0  # rotation about z of the joint origin in the parent frame
    joint: str = "revolute"  # "revolute" | "fixed" | "planar" | "prismatic"
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)

    @property
    def c(self) -> tuple[float, float]:
        return self.com if self.com is not None else (self.length / 2, 0.0)

    @property
    def I(self) -> float:  # noqa: E743 - the usual symbol
        return self.izz if self.izz is not None else self.mass * self.length ** 2 / 12


def _num(x: float) -> str:
    return repr(float(x))


def link_xml(name: str, mass: float | str | None = None, com=(0.0, 0.0), izz: float | str = 1.0,
             ixx: float | str | None = None, iyy: float | str | None = None) -> str:
    """A ``<link>``; ``mass=None`` gives a link without ``<inertial>``.

    ``ixx``/``iyy`` default to a thin-plate-consistent pair (positive definite,
    triangle inequality satisfied); they do not enter planar dynamics.
    """
    if mass is None:
        return f'  <link name="{name}"/>\n'
    izz_f = float(izz) if not isinstance(izz, str) else 1.0
    ixx = ixx if ixx is not None else izz_f * 0.01 + 1e-9
    iyy = iyy if iyy is not None else izz_f * 1.0 + 1e-9
    fmt = lambda v: v if isinstance(v, str) else _num(v)  # noqa: E731
    return (f'  <link name="{name}">\n'
            f'    <inertial>\n'
            f'      <origin xyz="{_num(com[0])} {_num(com[1])} 0" rpy="0 0 0"/>\n'
            f'      <mass value="{fmt(mass)}"/>\n'
            f'      <inertia ixx="{fmt(ixx)}" ixy="0" ixz="0" iyy="{fmt(iyy)}" iyz="0" izz="{fmt(izz)}"/>\n'
            f'    </inertial>\n'
            f'  </link>\n')


def joint_xml(name: str, jtype: str, parent: str, child: str, xyz=(0.0, 0.0), yaw: float = 0.0,
              axis=(0.0, 0.0, 1.0)) -> str:
    limit = ('    <limit lower="-1e6" upper="1e6" effort="1e6" velocity="1e6"/>\n'
             if jtype in ("revolute", "prismatic") else "")
    ax = f'    <axis xyz="{" ".join(_num(a) for a in axis)}"/>\n' if jtype != "fixed" else ""
    return (f'  <joint name="{name}" type="{jtype}">\n'
            f'    <parent link="{parent}"/>\n'
            f'    <child link="{child}"/>\n'
            f'    <origin xyz="{_num(xyz[0])} {_num(xyz[1])} 0" rpy="0 0 {_num(yaw)}"/>\n'
            f'{ax}{limit}'
            f'  </joint>\n')


def robot_xml(name: str, body: str) -> str:
    return f'<?xml version="1.0"?>\n<robot name="{name}">\n{body}</robot>\n'


def chain_urdf(bars: list[Bar], name: str = "chain", first_xyz=(0.0, 0.0)) -> str:
    """Frame ``frame``; links ``link1..n`` on joints ``J1..Jn``; joint k+1 at the tip
    ``(L_k, 0)`` of link k (the first at ``first_xyz`` on the frame)."""
    body = link_xml("frame")
    parent, xyz = "frame", first_xyz
    for k, b in enumerate(bars, start=1):
        body += joint_xml(f"J{k}", b.joint, parent, f"link{k}", xyz=xyz, yaw=b.yaw, axis=b.axis)
        body += link_xml(f"link{k}", b.mass, b.c, b.I)
        parent, xyz = f"link{k}", (b.length, 0.0)
    return robot_xml(name, body)


def pendulum_urdf(length: float, mass: float, **bar) -> str:
    """A compound pendulum: one bar ``link1`` on the revolute ``J1`` at the frame's origin."""
    return chain_urdf([Bar(length, mass, **bar)], name="pendulum")


def free_bar_urdf(mass: float, length: float, com=(0.0, 0.0), izz: float | None = None,
                  name: str = "free_bar") -> str:
    """A bar ``bar`` on a URDF ``planar`` joint ``P`` (x, y, theta) from the frame."""
    izz = mass * length ** 2 / 12 if izz is None else izz
    body = link_xml("frame")
    body += joint_xml("P", "planar", "frame", "bar")
    body += link_xml("bar", mass, com, izz)
    return robot_xml(name, body)


# ---- scene TOML text ----------------------------------------------------------------------
def toml_table(header: str, table: dict) -> str:
    return f"[{header}]\n" + "".join(f"{toml_key(k)} = {toml_value(v)}\n" for k, v in table.items()) + "\n"


def toml_array_item(header: str, table: dict) -> str:
    return f"[[{header}]]\n" + "".join(f"{toml_key(k)} = {toml_value(v)}\n" for k, v in table.items()) + "\n"


def scene_toml(configurations: dict[str, str], q0: dict, v0: dict, *, initial: str | None = None,
               gravity=(0.0, -G), t_end: float = 1.0, forces=(), transitions=(), solver=None,
               cut_joints: dict[str, list] | None = None, name: str = "test") -> str:
    """Scene text; ``configurations`` maps a configuration name to its URDF file name."""
    text = toml_table("scene", {"name": name, "gravity": list(gravity), "t_end": t_end,
                                "initial_configuration": initial or next(iter(configurations))})
    if solver:
        text += toml_table("solver", solver)
    for cname, urdf in configurations.items():
        table = {"urdf": urdf}
        if cut_joints and cname in cut_joints:
            table["cut_joints"] = cut_joints[cname]
        text += toml_table(f"configurations.{cname}", table)
    text += toml_table("initial", {"q": q0, "v": v0})
    for f in forces:
        text += toml_array_item("forces", f)
    for t in transitions:
        text += toml_array_item("transitions", t)
    return text


@pytest.fixture
def make_scene(tmp_path):
    """``make_scene(urdfs={file: text}, **scene_toml kwargs) -> Path`` of the scene file.

    ``configurations`` defaults to one configuration ``c1`` per URDF in order.
    """
    counter = {"n": 0}

    def make(urdfs: dict[str, str], configurations: dict[str, str] | None = None, **kw) -> Path:
        counter["n"] += 1
        folder = tmp_path / f"scene{counter['n']}"
        folder.mkdir()
        for fname, text in urdfs.items():
            (folder / fname).write_text(text)
        if configurations is None:
            configurations = {f"c{i + 1}": f for i, f in enumerate(urdfs)}
        path = folder / "scene.toml"
        path.write_text(scene_toml(configurations, **kw))
        return path
    return make


@pytest.fixture
def configuration(make_scene):
    """``configuration(urdfs, name="c1", **scene kwargs) -> (scene, Configuration)``."""
    import pcmm
    from pcmm.configuration import Mechanism

    def build(urdfs, name="c1", **kw):
        scene = pcmm.load_scene(make_scene(urdfs, **kw))
        return scene, Mechanism(scene)[name]
    return build


def copy_example(tmp_path: Path, scene_name: str = "three_bar.toml", scene_text: str | None = None,
                 urdf_texts: dict[str, str] | None = None) -> Path:
    """Copy an example scene and both three-bar URDFs into ``tmp_path`` (flat), with the
    scene's URDF paths rewritten; optional replacement texts for the scene and URDFs."""
    urdf_texts = urdf_texts or {}
    for f in ("three_bar_config1.urdf", "three_bar_config2.urdf"):
        (tmp_path / f).write_text(urdf_texts.get(f, (URDF_DIR / f).read_text()))
    text = scene_text if scene_text is not None else example_text(scene_name)
    path = tmp_path / scene_name
    path.write_text(text)
    return path


def example_text(scene_name: str = "three_bar.toml") -> str:
    return (EXAMPLES / scene_name).read_text().replace('"../urdf/', '"')


def rot(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def cross2(a, b) -> float:
    return float(a[0] * b[1] - a[1] * b[0])
