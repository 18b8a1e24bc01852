"""Builders of the test suite's URDFs and scenes: the one place tests write models and TOML.

Every test states only its numbers; the functions here write the small URDFs
(a chain of bars on revolute joints, a free bar on a URDF ``planar`` joint, a
ball on a prismatic joint, loops ...) and the scene documents around them.
Scenes are built as dicts and written by ``tomli_w`` (the TOML writer of the
ecosystem), so a test never formats TOML by hand.

Conventions (the closed-form expressions in the tests are written against them):

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
import tomli_w

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
URDF_DIR = ROOT / "urdf"
G = 9.81
LIMIT = '    <limit lower="-1e6" upper="1e6" effort="1e6" velocity="1e6"/>\n'


# ---- URDF text -------------------------------------------------------------------------
def _num(x: float) -> str:
    return repr(float(x))


def link_xml(name: str, mass: float | str | None = None, com=(0.0, 0.0), izz: float | str = 1.0,
             ixx: float | str | None = None, iyy: float | str | None = None, visual: str = "") -> str:
    """A ``<link>``; ``mass=None`` gives a link without ``<inertial>``; a string value is
    written as given (to build malformed URDFs); ``visual`` is copied in verbatim.

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
            f'{visual}'
            f'  </link>\n')


def solid_xml(name: str, mass: float, izz: float, com=(0.0, 0.0)) -> str:
    """A link whose inertia tensor is ``izz`` about every axis (positive definite and
    satisfying the triangle inequality at every scale)."""
    return link_xml(name, mass, com, izz, ixx=izz, iyy=izz)


def bar_xml(name: str, L: float, m: float) -> str:
    """A uniform slender bar along +x: centroid at (L/2, 0), Izz = m L^2 / 12 (tensor isotropic)."""
    return solid_xml(name, m, m * L * L / 12, com=(L / 2, 0.0))


def joint_xml(name: str, jtype: str, parent: str, child: str, xyz=(0.0, 0.0), yaw: float = 0.0,
              axis=(0.0, 0.0, 1.0)) -> str:
    """A ``<joint>`` at ``xyz`` (rotated by ``yaw`` about z) in the parent's frame."""
    limit = LIMIT if jtype in ("revolute", "prismatic") else ""
    ax = f'    <axis xyz="{" ".join(_num(a) for a in axis)}"/>\n' if jtype != "fixed" else ""
    return (f'  <joint name="{name}" type="{jtype}">\n'
            f'    <parent link="{parent}"/>\n'
            f'    <child link="{child}"/>\n'
            f'    <origin xyz="{_num(xyz[0])} {_num(xyz[1])} 0" rpy="0 0 {_num(yaw)}"/>\n'
            f'{ax}{limit}'
            f'  </joint>\n')


def robot_xml(name: str, *parts: str) -> str:
    """A whole URDF from its ``<link>`` and ``<joint>`` parts."""
    return f'<?xml version="1.0"?>\n<robot name="{name}">\n' + "".join(parts) + "</robot>\n"


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
    return robot_xml(name, link_xml("frame"), joint_xml("P", "planar", "frame", "bar"), link_xml("bar", mass, com, izz))


# ---- scene documents ----------------------------------------------------------------------
def _plain(obj):
    """numpy scalars and tuples as the Python numbers and lists a TOML writer takes."""
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    return obj


def dump_toml(doc: dict) -> str:
    """A scene document as TOML text (``tomli_w``)."""
    return tomli_w.dumps(_plain(doc))


def scene_doc(configurations: dict, q0: dict, v0: dict, *, initial: str | None = None, gravity=(0.0, -G),
              t_end: float = 1.0, forces=(), transitions=(), drives=(), solver=None,
              cut_joints: dict[str, list] | None = None, independent=None, name: str = "test") -> dict:
    """A scene document; ``configurations`` maps a configuration name to its URDF file name
    (or to its whole table); the first one is the initial configuration unless ``initial``."""
    doc = {"scene": {"name": name, "gravity": list(gravity), "t_end": t_end,
                     "initial_configuration": initial or next(iter(configurations))}}
    if solver:
        doc["solver"] = dict(solver)
    doc["configurations"] = {}
    for cname, urdf in configurations.items():
        table = {"urdf": urdf} if isinstance(urdf, str) else dict(urdf)
        if cut_joints and cname in cut_joints:
            table["cut_joints"] = cut_joints[cname]
        doc["configurations"][cname] = table
    doc["initial"] = {"q": q0, "v": v0}
    if independent is not None:
        doc["initial"]["independent"] = list(independent)
    for key, items in (("forces", forces), ("transitions", transitions), ("drives", drives)):
        if items:
            doc[key] = list(items)
    return doc


def write_scene(folder: Path, doc: dict, urdfs: dict[str, str], name: str = "scene.toml") -> Path:
    """Write the URDFs and the scene into ``folder``; return the scene's path."""
    folder.mkdir(parents=True, exist_ok=True)
    for fname, text in urdfs.items():
        (folder / fname).write_text(text)
    path = folder / name
    path.write_text(dump_toml(doc))
    return path


def stop(name, source, e, guard, contact, merge_to=None, cut=(), **extra) -> dict:
    """A ``stop`` transition table."""
    tr = {"name": name, "type": "stop", "from": source, "restitution": e, "cut": list(cut),
          "guard": guard, "contact": contact, **extra}
    if merge_to is not None:
        tr["merge_to"] = merge_to
    return tr


def base_doc(name, initial, configs: dict, q, v, g=G, t_end=1.0, solver=None, **more) -> dict:
    """A scene document with gravity (0, -g); ``more`` adds top-level tables (forces, transitions, drives)."""
    doc = scene_doc(configs, q, v, initial=initial, gravity=(0.0, -g), t_end=t_end, solver=solver, name=name)
    doc.update(more)
    return doc


# ---- the examples ---------------------------------------------------------------------------
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


# ---- scenes of the extremes and fuzz suites ---------------------------------------------------------------------------------------
def ball(folder: Path, e: float, h: float = 1.0, g: float = G, mass: float = 1.0, v0: float = 0.0,
         t_end: float = 1.0, merge: bool = True, solver=None, **law) -> Path:
    """A point mass on a vertical prismatic joint Y (q = height) above the floor y = 0;
    a stop with restitution e (gap guard) that merges into 'rest' (Y fixed at 0).  ``law``
    (``law``, ``stiffness``, ``exponent``) makes the stop a continuous contact law."""
    ball_link = solid_xml("ball", mass, 1e-3 * mass)
    free = robot_xml("ball", link_xml("frame"), joint_xml("Y", "prismatic", "frame", "ball", axis=(0, 1, 0)), ball_link)
    rest = robot_xml("ball_rest", link_xml("frame"), joint_xml("Y", "fixed", "frame", "ball"), ball_link)
    tr = stop("floor", "free", e, {"type": "gap", "value": 0.0, "direction": "decreasing"},
              {"a": "frame", "point_a": [0.0, 0.0], "b": "ball", "point_b": [0.0, 0.0], "normal": [0.0, 1.0]},
              merge_to="rest" if merge else None, **law)
    doc = base_doc("ball", "free", {"free": "free.urdf", "rest": "rest.urdf"}, {"Y": h}, {"Y": v0}, g=g,
                   t_end=t_end, solver=solver, transitions=[tr])
    return write_scene(folder, doc, {"free.urdf": free, "rest.urdf": rest})


def endless_ball(folder: Path) -> Path:
    """A ball bouncing with e = 1 for ever (a merged ball is not integrated), for runs that must
    outlast the signals a test sends them: t_end 1e6 s and an event budget to match (t_end 5000 s
    was over in 6.5 s once the right-hand side was compiled, before a signal at 9 s)."""
    return ball(folder, 1.0, t_end=1e6, solver={"max_events": 100_000_000})


def pendulum(folder: Path, e: float, L: float = 0.6, m: float = 1.5, qs: float = -math.pi / 2,
             q0: float = 0.0, w0: float = 0.0, g: float = G, t_end: float = 1.0, d: float | None = None,
             direction: str = "decreasing", k: float | None = None, rest_angle: float = 0.0,
             solver=None, merge: bool = True, spring_configurations=None) -> Path:
    """A uniform bar (m, L) on revolute J1 at the origin (q = angle from +x) and a stop on
    the frame where the bar's point at distance d from the pivot arrives at q = qs.
    Moving towards the stop means q decreasing (direction 'decreasing') or increasing.
    ``spring_configurations``: the configurations the spring ``k`` acts in (default: all)."""
    d = L if d is None else d
    s = 1.0 if direction == "decreasing" else -1.0
    normal = [-s * math.sin(qs), s * math.cos(qs)]  # frame -> bar, along the bar's approach
    urdfs = {"p.urdf": robot_xml("pend", link_xml("frame"), joint_xml("J1", "revolute", "frame", "link1"), bar_xml("link1", L, m)),
             "rest.urdf": robot_xml("pend_rest", link_xml("frame"), joint_xml("J1", "fixed", "frame", "link1", yaw=qs),
                                bar_xml("link1", L, m))}
    tr = stop("stop", "c1", e, {"type": "coordinate", "measure": {"joint": "J1"}, "value": qs,
                                "direction": direction},
              {"a": "frame", "point_a": [d * math.cos(qs), d * math.sin(qs)], "b": "link1",
               "point_b": [d, 0.0], "normal": normal}, merge_to="rest" if merge else None)
    forces = []
    if k is not None:
        forces.append({"name": "spring", "type": "spring", "on": {"joint": "J1"}, "measure": {"joint": "J1"},
                       "k": k, "rest": rest_angle})
        if spring_configurations is not None:
            forces[-1]["configurations"] = list(spring_configurations)
    doc = base_doc("pendulum", "c1", {"c1": "p.urdf", "rest": "rest.urdf"}, {"J1": q0}, {"J1": w0}, g=g,
                   t_end=t_end, solver=solver, transitions=[tr] if e is not None else [], forces=forces)
    return write_scene(folder, doc, urdfs)


def spring_pendulum(folder: Path, k: float, I_c: float, m: float = 1.0, q0: float = 0.1,
                    t_end: float = 1.0, solver=None) -> Path:
    """A body (mass m, centroid on the pivot, inertia I_c) on revolute J1 with a torsion
    spring k, no gravity: q(t) = q0 cos(sqrt(k / I_c) t)."""
    urdf = robot_xml("sp", link_xml("frame"), joint_xml("J1", "revolute", "frame", "body"), solid_xml("body", m, I_c))
    doc = base_doc("spring_pendulum", "c1", {"c1": "sp.urdf"}, {"J1": q0}, {"J1": 0.0}, g=0.0, t_end=t_end,
                   solver=solver, forces=[{"name": "spring", "type": "spring", "on": {"joint": "J1"},
                                           "measure": {"joint": "J1"}, "k": k}])
    return write_scene(folder, doc, {"sp.urdf": urdf})


def two_link(folder: Path, e: float, m1: float, m2: float, L1: float = 0.5, L2: float = 0.5,
             I1: float | None = None, I2: float | None = None, w1: float = 0.0, w2: float = -3.0,
             q2_0: float = 0.0, q2_stop: float = -0.3, t_end: float = 1.0, solver=None) -> Path:
    """Two bars on J1 (frame) and J2 (tip of link1), no gravity.  Link 2 swings about J2
    (q2 decreasing) until it strikes a stop on link 1 at q2 = q2_stop: a mobile impact
    between the links; its contact is link 2's tip against link 1's point where that tip is."""
    I1 = m1 * L1 * L1 / 12 if I1 is None else I1
    I2 = m2 * L2 * L2 / 12 if I2 is None else I2
    urdf = robot_xml("two", link_xml("frame"), joint_xml("J1", "revolute", "frame", "link1"), solid_xml("link1", m1, I1, (L1 / 2, 0)),
                 joint_xml("J2", "revolute", "link1", "link2", xyz=(L1, 0.0)), solid_xml("link2", m2, I2, (L2 / 2, 0)))
    tip = [L1 + L2 * math.cos(q2_stop), L2 * math.sin(q2_stop)]  # in link1's frame
    normal = [-math.sin(q2_stop), math.cos(q2_stop)]  # link1 -> link2, against link 2's approach
    tr = stop("hit", "c1", e, {"type": "coordinate", "measure": {"joint": "J2"}, "value": q2_stop,
                               "direction": "decreasing"},
              {"a": "link1", "point_a": tip, "b": "link2", "point_b": [L2, 0.0], "normal": normal})
    doc = base_doc("two_link", "c1", {"c1": "two.urdf"}, {"J1": 0.0, "J2": q2_0}, {"J1": w1, "J2": w2},
                   g=0.0, t_end=t_end, solver=solver, transitions=[tr])
    return write_scene(folder, doc, {"two.urdf": urdf})


def two_free_bodies(folder: Path, e: float, m1: float, m2: float, I1: float, I2: float,
                    gap: float = 0.1, v1=(1.0, 0.0), v2=(-1.0, 0.0), w1: float = 0.0, w2: float = 0.0,
                    offset: float = 0.05, t_end: float = 0.2, solver=None) -> Path:
    """Two bodies on URDF planar joints A and B, no gravity.  Body a's contact point (0.1, 0)
    on its local +x face meets body b's point (-0.1, offset) (normal +x of a): a mobile
    impact between free bodies (linear and angular momentum are conserved)."""
    urdf = robot_xml("two_free", link_xml("frame"), joint_xml("A", "planar", "frame", "a"), solid_xml("a", m1, I1),
                 joint_xml("B", "planar", "frame", "b"), solid_xml("b", m2, I2))
    tr = stop("bump", "c1", e, {"type": "gap", "value": 0.0, "direction": "decreasing"},
              {"a": "a", "point_a": [0.1, 0.0], "b": "b", "point_b": [-0.1, offset], "normal": [1.0, 0.0]})
    doc = base_doc("two_free", "c1", {"c1": "free.urdf"}, {"A": [0.0, 0.0, 0.0], "B": [0.2 + gap, -offset, 0.0]},
                   {"A": [v1[0], v1[1], w1], "B": [v2[0], v2[1], w2]}, g=0.0, t_end=t_end, solver=solver,
                   transitions=[tr])
    return write_scene(folder, doc, {"free.urdf": urdf})


def two_balls(folder: Path, e1: float, e2: float, h: float = 0.5, t_end: float = 0.5) -> Path:
    """Two independent point masses on vertical prismatic joints Y1, Y2 (at x = 0 and x = 1)
    dropped from the same height: both floor contacts close at the same instant."""
    urdf = robot_xml("balls", link_xml("frame"), joint_xml("Y1", "prismatic", "frame", "b1", axis=(0, 1, 0)),
                 solid_xml("b1", 1.0, 1e-3), joint_xml("Y2", "prismatic", "frame", "b2", xyz=(1.0, 0.0), axis=(0, 1, 0)),
                 solid_xml("b2", 2.0, 1e-3))
    trs = [stop(f"floor{i}", "c1", e, {"type": "gap", "value": 0.0, "direction": "decreasing"},
                {"a": "frame", "point_a": [x, 0.0], "b": f"b{i}", "point_b": [0.0, 0.0], "normal": [0.0, 1.0]})
           for i, (e, x) in enumerate([(e1, 0.0), (e2, 1.0)], start=1)]
    doc = base_doc("two_balls", "c1", {"c1": "balls.urdf"}, {"Y1": h, "Y2": h}, {"Y1": 0.0, "Y2": 0.0},
                   t_end=t_end, transitions=trs)
    return write_scene(folder, doc, {"balls.urdf": urdf})


def flat_bar(folder: Path, e: float, L: float = 1.0, m: float = 1.0, h: float = 0.2, t_end: float = 0.5,
             solver=None) -> Path:
    """A uniform bar on a URDF planar joint, centroid at the joint, horizontal, dropped from
    height h onto two stops under its ends (x = -L/2 and +L/2): two contacts close at once."""
    urdf = robot_xml("flat", link_xml("frame"), joint_xml("P", "planar", "frame", "bar"), solid_xml("bar", m, m * L * L / 12))
    trs = [stop(name, "c1", e, {"type": "gap", "value": 0.0, "direction": "decreasing"},
                {"a": "frame", "point_a": [x, 0.0], "b": "bar", "point_b": [x, 0.0], "normal": [0.0, 1.0]})
           for name, x in (("left", -L / 2), ("right", L / 2))]
    doc = base_doc("flat_bar", "c1", {"c1": "flat.urdf"}, {"P": [0.0, h, 0.0]}, {"P": [0.0, 0.0, 0.0]},
                   t_end=t_end, solver=solver, transitions=trs)
    return write_scene(folder, doc, {"flat.urdf": urdf})


def slider_crank_slider_driven(folder: Path, coefficients, a=0.1, b=0.3, theta0=0.5, t_end=1.0) -> Path:
    """Slider-crank (crank a on A, rod b on B at the crank tip, slider on prismatic P along x,
    cut joint C closes rod tip to slider) with the slider DRIVEN: x(t) = poly(coefficients).
    The crank is at dead centre (crank and rod collinear) when x = a + b."""
    urdf = robot_xml("sc", link_xml("frame"), joint_xml("A", "revolute", "frame", "crank"), bar_xml("crank", a, 0.5),
                 joint_xml("B", "revolute", "crank", "rod", xyz=(a, 0.0)), bar_xml("rod", b, 0.8),
                 joint_xml("P", "prismatic", "frame", "slider", axis=(1, 0, 0)), solid_xml("slider", 2.0, 1e-3))
    phi = math.asin(-a * math.sin(theta0) / b)
    x0 = a * math.cos(theta0) + b * math.cos(phi)
    cfg = {"urdf": "sc.urdf", "cut_joints": [{"name": "C", "type": "revolute", "a": "rod", "point_a": [b, 0.0],
                                                "b": "slider", "point_b": [0.0, 0.0]}]}
    doc = base_doc("slider_crank", "c", {"c": cfg}, {"A": theta0, "B": phi - theta0, "P": x0},
                   {"A": 0.0, "B": 0.0, "P": 0.0}, g=0.0, t_end=t_end,
                   drives=[{"joint": "P", "coefficients": list(coefficients)}])
    return write_scene(folder, doc, {"sc.urdf": urdf})


def parallelogram(folder: Path, theta0: float, omega: float, a=0.1, b=0.3, t_end=1.0, solver=None) -> Path:
    """Parallelogram four-bar (crank a on A at the origin, coupler b on B, rocker a on D at
    (b, 0), cut joint C), no gravity.  On the parallelogram branch the rocker stays parallel
    to the crank and the coupler horizontal; every half turn (theta = 0, pi) all links are
    collinear: the loop Jacobian loses rank (a bifurcation into the anti-parallelogram)."""
    urdf = robot_xml("pg", link_xml("frame"), joint_xml("A", "revolute", "frame", "crank"), bar_xml("crank", a, 1.0),
                 joint_xml("B", "revolute", "crank", "coupler", xyz=(a, 0.0)), bar_xml("coupler", b, 1.0),
                 joint_xml("D", "revolute", "frame", "rocker", xyz=(b, 0.0)), bar_xml("rocker", a, 1.0))
    cfg = {"urdf": "pg.urdf", "cut_joints": [{"name": "C", "type": "revolute", "a": "coupler",
                                                "point_a": [b, 0.0], "b": "rocker", "point_b": [a, 0.0]}]}
    doc = base_doc("parallelogram", "c", {"c": cfg}, {"A": theta0, "B": -theta0, "D": theta0},
                   {"A": omega, "B": -omega, "D": omega}, g=0.0, t_end=t_end, solver=solver)
    doc["initial"]["independent"] = ["A"]
    return write_scene(folder, doc, {"pg.urdf": urdf})


def slider_crank_stop(folder: Path, e: float, torque: float = 0.5, theta0: float = -2.0, theta_stop: float = -1.0,
                      a: float = 0.1, b: float = 0.3, g: float = G, t_end: float = 1.0, solver=None,
                      **stop_extra) -> Path:
    """Torque-driven slider-crank (crank a on A, rod b on B, slider on prismatic P along x, cut
    joint C) whose slider strikes a stop on its guide at the x it has for crank angle
    ``theta_stop`` (restitution e); constant loads only: a constant torque on A and gravity.
    For theta in (-pi, 0) the slider moves +x as the crank turns positive.  The stop merges
    into 'locked' (the slider welded to the frame at the stop: a zero-DOF loop)."""
    def slider_x(th):
        return a * math.cos(th) + math.sqrt(b * b - (a * math.sin(th)) ** 2)
    x_stop = slider_x(theta_stop)
    parts = (link_xml("frame"), joint_xml("A", "revolute", "frame", "crank"), bar_xml("crank", a, 0.5),
             joint_xml("B", "revolute", "crank", "rod", xyz=(a, 0.0)), bar_xml("rod", b, 0.8))
    free = robot_xml("scs", *parts, joint_xml("P", "prismatic", "frame", "slider", axis=(1, 0, 0)), solid_xml("slider", 2.0, 1e-3))
    locked = robot_xml("scs_locked", *parts, joint_xml("P", "fixed", "frame", "slider", xyz=(x_stop, 0.0)),
                   solid_xml("slider", 2.0, 1e-3))
    cut = [{"name": "C", "type": "revolute", "a": "rod", "point_a": [b, 0.0], "b": "slider", "point_b": [0.0, 0.0]}]
    phi = math.asin(-a * math.sin(theta0) / b)
    tr = stop("stop", "free", e, {"type": "coordinate", "measure": {"joint": "P"}, "value": x_stop,
                                  "direction": "increasing"},
              {"a": "frame", "point_a": [x_stop, 0.0], "b": "slider", "point_b": [0.0, 0.0], "normal": [-1.0, 0.0]},
              merge_to="locked", cut=["P"], **stop_extra)
    doc = base_doc("slider_crank_stop", "free", {"free": {"urdf": "free.urdf", "cut_joints": cut},
                                                 "locked": {"urdf": "locked.urdf", "cut_joints": cut}},
                   {"A": theta0, "B": phi - theta0, "P": slider_x(theta0)}, {"A": 0.0, "B": 0.0, "P": 0.0},
                   g=g, t_end=t_end, solver=solver, transitions=[tr],
                   forces=[{"name": "motor", "type": "torque", "on": {"joint": "A"}, "value": torque}])
    doc["initial"]["independent"] = ["A"]
    return write_scene(folder, doc, {"free.urdf": free, "locked.urdf": locked})


def four_bar_rocker_stop(folder: Path, e: float, rocker_stop: float, torque: float = 1.0,
                         theta0: float = 1.0, rocker0: float = 2.0, g: float = G, t_end: float = 2.0,
                         solver=None, a=0.1, b=0.3, c=0.25, d=0.3, **stop_extra) -> Path:
    """Four-bar (crank a on A at the origin, coupler b on B, rocker c on D at (d, 0), cut joint C
    closing coupler tip to rocker tip) driven by a constant torque on A under gravity, whose
    rocker strikes a stop on the frame at rocker angle ``rocker_stop`` (approaching with D
    decreasing) and merges into 'locked' (rocker welded to the frame there: a zero-DOF loop)."""
    parts = (link_xml("frame"), joint_xml("A", "revolute", "frame", "crank"), bar_xml("crank", a, 1.0),
             joint_xml("B", "revolute", "crank", "coupler", xyz=(a, 0.0)), bar_xml("coupler", b, 2.0))
    free = robot_xml("fb", *parts, joint_xml("D", "revolute", "frame", "rocker", xyz=(d, 0.0)), bar_xml("rocker", c, 1.5))
    locked = robot_xml("fb_locked", *parts, joint_xml("D", "fixed", "frame", "rocker", xyz=(d, 0.0), yaw=rocker_stop),
                   bar_xml("rocker", c, 1.5))
    cut = [{"name": "C", "type": "revolute", "a": "coupler", "point_a": [b, 0.0], "b": "rocker", "point_b": [c, 0.0]}]
    tip = (d + c * math.cos(rocker_stop), c * math.sin(rocker_stop))
    # D decreasing moves the tip along -(−sin, cos); the normal from the stop (a) to the rocker (b)
    # is the tip's direction of increasing D, which the approach opposes
    normal = [-math.sin(rocker_stop), math.cos(rocker_stop)]
    tr = stop("rocker stop", "free", e, {"type": "coordinate", "measure": {"joint": "D"}, "value": rocker_stop,
                                         "direction": "decreasing"},
              {"a": "frame", "point_a": list(tip), "b": "rocker", "point_b": [c, 0.0], "normal": normal},
              merge_to="locked", cut=["D"], **stop_extra)
    doc = base_doc("four_bar_stop", "free", {"free": {"urdf": "free.urdf", "cut_joints": cut},
                                             "locked": {"urdf": "locked.urdf", "cut_joints": cut}},
                   {"A": theta0, "B": 0.5, "D": rocker0}, {"A": 0.0, "B": 0.0, "D": 0.0},
                   g=g, t_end=t_end, solver=solver, transitions=[tr],
                   forces=[{"name": "motor", "type": "torque", "on": {"joint": "A"}, "value": torque}])
    doc["initial"]["independent"] = ["A"]
    return write_scene(folder, doc, {"free.urdf": free, "locked.urdf": locked})


def four_bar_latch(folder: Path, torque: float = 0.6, t_end: float = 1.2) -> Path:
    """A four-bar (crank 0.06, coupler 0.18, rocker 0.12 m as the chain J1-J2-J3 of steel bars; the
    rocker's end pinned to the frame at (0.2, 0) by the cut joint D), driven by ``torque`` on J1
    with a little damping, whose coupler latches onto the rocker at J3 = -1.5 (a joint stop, into
    'latched' derived by locking J3) and is let go by a timer at t = 0.8 s."""
    urdf = chain_urdf([Bar(0.06, 0.0936), Bar(0.18, 0.2808), Bar(0.12, 0.1872)])
    cut = [{"name": "D", "type": "revolute", "a": "frame", "point_a": [0.2, 0.0], "b": "link3", "point_b": [0.12, 0.0]}]
    doc = scene_doc({"open": {"urdf": "fb.urdf", "cut_joints": cut}, "latched": {"from": "open", "lock": ["J3"]}},
                    {"J1": 0.0, "J2": 0.7287, "J3": -2.2519}, {"J1": 0.0, "J2": 0.0, "J3": 0.0},
                    t_end=t_end, independent=["J1"],
                    forces=[{"name": "motor", "type": "linear", "on": {"joint": "J1"},
                             "measure": {"joint": "J1"}, "value": torque, "c": 0.002}],
                    transitions=[{"name": "latch", "type": "latch", "from": "open", "to": "latched", "cut": ["J3"],
                                  "guard": {"type": "coordinate", "measure": {"joint": "J3"}, "value": -1.5,
                                            "direction": "increasing"},
                                  "contact": {"joint": "J3", "arm": 0.05}},
                                 {"name": "let go", "type": "release", "from": "latched", "to": "open",
                                  "guard": {"type": "time", "at": 0.8}}])
    doc["initial"]["branch"] = {"joint": "J3", "sign": "-"}
    return write_scene(folder, doc, {"fb.urdf": urdf})


# ---- planar geometry of hand derivations ------------------------------------------------------------
def arm_mass_matrix(q2: float, m1: float, l1: float, m2: float, l2: float) -> np.ndarray:
    """The mass matrix of two uniform bars (m1, l1 on J1 at the frame; m2, l2 on J2 at link 1's tip)
    in (J1, J2), J1 absolute and J2 relative, by hand (Lagrange; centroids at mid-length)."""
    I1, I2 = m1 * l1 * l1 / 12, m2 * l2 * l2 / 12
    c = math.cos(q2)
    m22 = I2 + m2 * (l2 / 2) ** 2
    m12 = m22 + m2 * l1 * (l2 / 2) * c
    m11 = I1 + m1 * (l1 / 2) ** 2 + I2 + m2 * (l1 * l1 + (l2 / 2) ** 2 + l1 * l2 * c)
    return np.array([[m11, m12], [m12, m22]])


def arm_free_rates(y, m1: float, l1: float, m2: float, l2: float, k: float = 0.0, c: float = 0.0) -> list:
    """d/dt (q1, q2, w1, w2) of the free two-bar arm of :func:`arm_mass_matrix`, no gravity, with a
    torsion spring k and a damper c on J2: M q'' + c(q, q') = (0, -k q2 - c q2') (Lagrange, by hand)."""
    _, q2, w1, w2 = y
    h = m2 * l1 * (l2 / 2) * math.sin(q2)
    rhs = np.array([h * (2 * w1 * w2 + w2 * w2), -h * w1 * w1 - k * q2 - c * w2])
    return [w1, w2, *np.linalg.solve(arm_mass_matrix(q2, m1, l1, m2, l2), rhs)]


def rot(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def cross2(a, b) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def driven_cart_pendulum(folder: Path, coefficients=(0.1, 0.2, 0.9, -0.4), e: float = 0.6, m: float = 0.8,
                         L: float = 0.5, m_cart: float = 1.3, q_stop: float = -1.2, t_end: float = 1.5,
                         solver=None, forces=()) -> Path:
    """A cart on the prismatic joint ``X`` (along x) DRIVEN: x(t) = poly(coefficients); a uniform bar
    (m, L) hangs on the revolute ``J1`` at the cart's origin (q = angle from +x), released horizontal
    and at rest, and falls onto a pin on the cart at q = q_stop (a joint stop, restitution e) whose
    bounces merge into 'rest' (J1 locked: every coordinate driven).  No loop: the drive prescribes X.
    With a = x''(t), the bar's pivot accelerates along x: (m L^2 / 3) q'' = -m g (L/2) cos q
    + m a (L/2) sin q, and the drive's force is (m_cart + m) a - m (L/2) (q'' sin q + q'^2 cos q)."""
    urdf = robot_xml("cart_pendulum", link_xml("frame"),
                     joint_xml("X", "prismatic", "frame", "cart", axis=(1.0, 0.0, 0.0)),
                     solid_xml("cart", m_cart, 0.05),
                     joint_xml("J1", "revolute", "cart", "link1"), bar_xml("link1", L, m))
    tr = stop("pin", "swing", e, {"type": "coordinate", "measure": {"joint": "J1"}, "value": q_stop,
                                  "direction": "decreasing"},
              {"joint": "J1", "arm": L / 2}, merge_to="rest", cut=["J1"])
    doc = base_doc("driven_cart_pendulum", "swing", {"swing": "cart.urdf", "rest": {"from": "swing", "lock": {"J1": q_stop}}},
                   {"X": float(coefficients[0]), "J1": 0.0}, {"X": float(coefficients[1]) if len(coefficients) > 1 else 0.0,
                                                              "J1": 0.0},
                   t_end=t_end, solver=solver, transitions=[tr], forces=list(forces),
                   drives=[{"joint": "X", "coefficients": [float(c) for c in coefficients]}])
    return write_scene(folder, doc, {"cart.urdf": urdf})


# ---- a run against its reference, within the reference's own round-off sensitivity --------------------------
# Two routes to one run (compiled and Python stepping, compiled and Python impulse) differ in round-off,
# which a run amplifies through its events.  The bound is the reference's own sensitivity: the same
# reference nudged by one ulp (its initial rate: nudged_scene; its post-impact velocities:
# nudge_impulses), and the other route within ten times what that nudge moves.
def nudged_scene(folder: Path, path: Path, old: str, new: str) -> Path:
    """A copy of the scene ``path`` in ``folder`` with the text ``old`` (an initial rate) replaced once by
    ``new`` (the same rate one ulp off), its URDF paths made absolute."""
    text = path.read_text().replace('"../urdf/', f'"{URDF_DIR}/')
    assert old in text, old
    out = folder / ("nudged_" + path.name)
    out.write_text(text.replace(old, new, 1))
    return out


#: each loop example's initial rate nudged by one machine epsilon (nudged_scene's old and new text)
EXAMPLE_NUDGES = {"double_folded.toml": ("v = { D = 0.0 }", "v = { D = 2.220446049250313e-16 }"),
                  "double_folded_cycle.toml": ("v = { D = 0.0 }", "v = { D = 2.220446049250313e-16 }"),
                  "andrews.toml": ("v = { beta = 0.0,", "v = { beta = 2.220446049250313e-16,")}


def nudge_impulses(m) -> None:
    """Inside the monkeypatch context ``m``: every post-impact velocity of the Python impulse solve
    (pcmm.events.impulse.solve_impulse_python) comes out one ulp larger."""
    from pcmm.events import impulse
    python = impulse.solve_impulse_python

    def nudged(*args, **kwargs):
        out = python(*args, **kwargs)
        out.v_after = out.v_after * (1.0 + 2.0 ** -52)
        return out
    m.setattr(impulse, "solve_impulse_python", nudged)


def run_differences(a, b) -> dict:
    """{quantity: its differences in time order} between the runs ``a`` and ``b``: each event's time,
    each segment's end time, q and v (the same events by name and kind, and the same configurations,
    asserted first)."""
    assert [(e["name"], e.get("kind")) for e in a.events] == [(e["name"], e.get("kind")) for e in b.events]
    assert [s.configuration for s in a.segments] == [s.configuration for s in b.segments]
    pairs = list(zip(a.segments, b.segments))
    return {"event times": np.array([abs(x["t"] - y["t"]) for x, y in zip(a.events, b.events)]),
            "segment ends": np.array([abs(x.t[-1] - y.t[-1]) for x, y in pairs]),
            "q": np.array([float(np.max(np.abs(x.q[-1] - y.q[-1]))) for x, y in pairs]),
            "v": np.array([float(np.max(np.abs(x.v[-1] - y.v[-1]))) for x, y in pairs])}


#: run_differences' floors: what two routes of one run may differ by without a nudged reference
RUN_FLOORS = {"event times": 1e-12, "segment ends": 1e-12, "q": 1e-10, "v": 1e-10}


def within_floors(apart: dict) -> bool:
    """Whether :func:`run_differences` ``apart`` are all within :data:`RUN_FLOORS`."""
    return all(d.max(initial=0) <= RUN_FLOORS[what] for what, d in apart.items())


def assert_within_nudge(apart: dict, own: dict, reference: str = "the Python run") -> None:
    """Each of :func:`run_differences` ``apart`` within its floor plus ten times what the nudged reference
    moved (``own``, its differences from the reference) up to that point in time."""
    for what, d in apart.items():
        bound = RUN_FLOORS[what] + 10 * np.maximum.accumulate(own[what])
        assert np.all(d <= bound), f"{what}: {d.max():.3g} apart, {reference} nudged {own[what].max():.3g}"


def lever_on_wall(folder: Path, theta_s: float, q0: float, friction: float | str | None = None, e: float = 0.5,
                  L: float = 0.25, m: float = 0.4, t_end: float = 0.4, kind: str = "stop", normal=(1.0, 0.0)) -> Path:
    """A uniform bar (m, L) on revolute J1 at the origin, released at rest at angle ``q0`` (from +x),
    swinging down until its tip strikes a vertical frame wall x = L cos(theta_s) at theta_s < 0: the
    wall's normal (1, 0) is oblique to the tip's path, at 90 deg - |theta_s| from it.  A gap guard;
    ``kind`` "stop" merges into 'seated' (J1 locked), "pin" pins the tip where it strikes; ``normal``
    in the frame's axes (a flipped one: (-1, 0))."""
    urdf = robot_xml("lever", link_xml("frame"), joint_xml("J1", "revolute", "frame", "link1"), bar_xml("link1", L, m))
    contact = {"a": "frame", "point_a": [L * math.cos(theta_s), L * math.sin(theta_s)], "b": "link1",
               "point_b": [L, 0.0], "normal": list(normal)}
    if friction is not None:
        contact["friction"] = friction
    guard = {"type": "gap", "value": 0.0, "direction": "decreasing"}
    configs = {"free": "lever.urdf", "seated": {"from": "free", "lock": ["J1"]}}
    if kind == "stop":
        tr = stop("tip strikes wall", "free", e, guard, contact, merge_to="seated")
    else:
        tr = {"name": "tip strikes wall", "type": "pin", "from": "free", "to": "pinned", "guard": guard,
              "contact": contact}
        cut = {"name": "tip", "type": "revolute", "a": "frame", "point_a": "entry", "b": "link1",
               "point_b": [L, 0.0], "contact": {k: v for k, v in contact.items() if k in ("normal", "friction")}}
        configs = {"free": "lever.urdf", "pinned": {"urdf": "lever.urdf", "cut_joints": [cut]}}
    doc = base_doc("lever", "free", configs, {"J1": q0}, {"J1": 0.0}, t_end=t_end, transitions=[tr])
    return write_scene(folder, doc, {"lever.urdf": urdf})


def compiled_and_python_impulses(cfg, t, q, v, contact, e, cut):
    """(compiled, Python) impulses of one contact at one state (pcmm.events.impulse): the compiled
    plan must be taken and must solve; the Python solve is the reference it is held to."""
    from pcmm.events import impulse
    from pcmm.events.impulse_compiled import compiled_impulse, reason
    plan = impulse._plan(cfg, contact, tuple(cut))
    fast = compiled_impulse(cfg, plan)
    assert fast is not None, reason(cfg, plan)
    got = impulse._compiled_solve(cfg, plan, fast, q, v, e)
    assert got is not None
    return got, impulse.solve_impulse_python(cfg, t, q, v, contact, e, tuple(cut))


def captured_impulse_solves(scene_path, monkeypatch):
    """(the run of ``scene_path``, every impulse solve it asked for as (cfg, t, q, v, contact, e,
    cut)): the states at which a test replays the compiled and Python solves."""
    import pcmm
    from pcmm.events import transitions
    calls = []
    solve = transitions.solve_impulse

    def capture(cfg, t, q, v, contact, e, cut, name=None):
        calls.append((cfg, t, q.copy(), v.copy(), contact, e, cut))
        return solve(cfg, t, q, v, contact, e, cut, name=name)
    monkeypatch.setattr(transitions, "solve_impulse", capture)
    # every bounce through the impulse solve (the bounce in one compiled call, which solves it itself, is
    # held to this route in tests/test_compiled_bounce.py)
    monkeypatch.setattr(transitions, "compiled_bounce", lambda cfg, tr: None)
    return pcmm.simulate(pcmm.load_scene(scene_path)), calls
