"""Read and validate a URDF for a planar scene, before Pinocchio sees it.

Pinocchio accepts many URDFs that make no sense for a planar mechanism (a
massless link, a tilted axis) and fails on others with bare C++ messages.  This
module reads the XML itself, reports every problem at once (file, element,
value, what is allowed), and only then lets Pinocchio build the model.
"""
from __future__ import annotations

import difflib
import math
import xml.etree.ElementTree as ET
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ModelError

#: URDF joint types pcmm models; each keeps nq = nv in pcmm's own coordinates.
MOVABLE = ("revolute", "prismatic", "planar")
ALLOWED = MOVABLE + ("fixed",)
_TOL = 1e-12


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    type: str
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    axis: tuple[float, float, float]
    limits: tuple[float, float] | None = None  # <limit lower upper> (pcmm does not enforce them)


@dataclass(frozen=True)
class UrdfInfo:
    """What a scene needs to know about a URDF without building a model."""

    path: Path
    robot: str
    root: str
    links: tuple[str, ...]
    joints: dict[str, UrdfJoint] = field(default_factory=dict)

    @property
    def movable_joints(self) -> tuple[str, ...]:
        return tuple(n for n, j in self.joints.items() if j.type in MOVABLE)


def _floats(text: str | None, n: int, default: tuple) -> tuple | None:
    if text is None:
        return default
    try:
        vals = tuple(float(x) for x in text.split())
    except ValueError:
        return None
    return vals if len(vals) == n and all(math.isfinite(x) for x in vals) else None


def dynamics_xml(path: str | Path, text: str | None = None) -> str:
    """The URDF (the file ``path``, or its ``text`` if given) as the dynamics needs it: without
    ``<visual>``, ``<collision>`` and ``<material>`` (pcmm's replay reads the visuals itself).
    urdfdom would otherwise parse them too and print its own errors for a visual it cannot read,
    before any message of pcmm's."""
    root = ET.fromstring(text) if text is not None else ET.parse(path).getroot()
    for parent in root.iter():
        for child in [c for c in parent if c.tag in ("visual", "collision", "material")]:
            parent.remove(child)
    return ET.tostring(root, encoding="unicode")


def _nearby(path: Path) -> str:
    """A hint naming the URDF files in the same folder whose names are closest to ``path``'s."""
    try:
        names = sorted(p.name for p in path.parent.glob("*.urdf")) if path.parent.is_dir() else []
    except OSError:
        return ""
    close = difflib.get_close_matches(path.name, names, n=3, cutoff=0.6)
    return f" (did you mean {' or '.join(close)}?)" if close else ""


def undrawn_links(path: str | Path) -> list[tuple[str, str]]:
    """The links of the (valid) URDF ``path`` that move (a joint moves them, or they are welded to a
    link that moves) but have no ``<box>`` or ``<sphere>`` visual, each with a ``<visual>`` to paste:
    a bar along the link's frame from its origin to its farthest child joint (or, with none, to twice
    its centre of mass; a sphere for a point mass on its joint). The 2D drawing, the video and the
    replay page draw a link by its visuals alone (its joints by their symbols), so such a link does
    not show."""
    def xy(el) -> tuple[float, float]:
        origin = el.find("origin") if el is not None else None
        v = _floats(origin.get("xyz") if origin is not None else None, 3, (0.0, 0.0, 0.0))
        return (v[0], v[1]) if v else (0.0, 0.0)

    root = ET.parse(path).getroot()
    parent_of, ends = {}, {}  # link -> (its parent link, its joint's type); link -> its joints' origins
    for j in root.findall("joint"):
        parent, child = j.find("parent"), j.find("child")
        if parent is not None and child is not None:
            parent_of[child.get("link")] = (parent.get("link"), j.get("type"))
            ends.setdefault(parent.get("link"), []).append(xy(j))

    def moves(link: str) -> bool:  # a joint moves it, or it is welded to a link that moves
        seen = set()
        while link in parent_of and link not in seen:
            seen.add(link)
            link, kind = parent_of[link]
            if kind in MOVABLE:
                return True
        return False
    out = []
    for el in root.findall("link"):
        name = el.get("name")
        shapes = [g[0].tag for v in el.findall("visual") for g in [v.find("geometry")] if g is not None and len(g)]
        if not moves(name) or any(s in ("box", "sphere") for s in shapes):
            continue
        cx, cy = xy(el.find("inertial"))
        far = max(ends.get(name, []), key=lambda p: math.hypot(*p), default=(2 * cx, 2 * cy))
        length = math.hypot(*far)
        if length > 0:
            yaw = math.atan2(far[1], far[0])
            visual = (f'<visual><origin xyz="{far[0] / 2:.6g} {far[1] / 2:.6g} 0" rpy="0 0 {yaw:.6g}"/>'
                      f'<geometry><box size="{length:.6g} 0.012 0.012"/></geometry></visual>')
        else:
            visual = '<visual><geometry><sphere radius="0.02"/></geometry></visual>'
        out.append((name, visual))
    return out


def read_urdf(path: str | Path) -> UrdfInfo:
    """Parse and validate ``path``; raise :class:`ModelError` listing every problem."""
    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise ModelError(f"{where}: URDF file not found{_nearby(path)}")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise ModelError(f"{where}: malformed URDF XML: {exc}") from None
    if root.tag != "robot":
        raise ModelError(f"{where}: root element is <{root.tag}>, a URDF needs <robot>")
    problems: list[str] = []
    links = [el.get("name") for el in root.findall("link")]
    if not links or any(not n for n in links):
        problems.append(f"{where}: every <link> needs a name, and a URDF needs at least one link")
    counts = Counter(links)  # sets and counts: validation stays linear in the number of links
    link_set = set(links)
    dup = sorted(n for n, c in counts.items() if c > 1 and n)
    if dup:
        problems.append(f"{where}: duplicate link names {dup}")
    joints: dict[str, UrdfJoint] = {}
    children = set()
    for el in root.findall("joint"):
        j = _read_joint(el, where, problems)
        if j is None:
            continue
        if j.name in joints:
            problems.append(f"{where}: joint '{j.name}': duplicate joint name")
        for role, link in (("parent", j.parent), ("child", j.child)):
            if link not in link_set:
                problems.append(f"{where}: joint '{j.name}': {role} link '{link}' is not a <link> of this file")
        if j.child in children:
            problems.append(f"{where}: link '{j.child}' is the child of two joints: a URDF is a tree; "
                            "close loops with cut_joints in the scene")
        children.add(j.child)
        joints[j.name] = j
    roots = [n for n in links if n and n not in children]
    if len(roots) != 1:
        problems.append(f"{where}: expected exactly one root link (the frame), found {roots}")
    moving_children = {j.child for j in joints.values() if j.type in MOVABLE}
    for el in root.findall("link"):
        name = el.get("name")
        _check_inertial(el, name, where, required=name in moving_children, problems=problems)
    if problems:
        raise ModelError(problems)
    return UrdfInfo(path=path, robot=root.get("name", ""), root=roots[0], links=tuple(links),
                    joints=joints)


def _read_joint(el, where, problems) -> UrdfJoint | None:
    name, jtype = el.get("name"), el.get("type")
    if not name:
        problems.append(f"{where}: a <joint> has no name")
        return None
    loc = f"{where}: joint '{name}'"
    if jtype not in ALLOWED:
        hint = (" (continuous joints have nq = 2: use type=\"revolute\" with a wide <limit>;"
                " limits are not enforced by pcmm)") if jtype == "continuous" else ""
        problems.append(f"{loc}: type = {jtype!r} is not allowed in a planar scene; "
                        f"allowed: {', '.join(ALLOWED)}{hint}")
        return None
    parent, child = el.find("parent"), el.find("child")
    if parent is None or child is None or not parent.get("link") or not child.get("link"):
        problems.append(f"{loc}: needs <parent link=...> and <child link=...>")
        return None
    origin = el.find("origin")
    xyz = _floats(origin.get("xyz") if origin is not None else None, 3, (0.0, 0.0, 0.0))
    rpy = _floats(origin.get("rpy") if origin is not None else None, 3, (0.0, 0.0, 0.0))
    axis_el = el.find("axis")
    axis = _floats(axis_el.get("xyz") if axis_el is not None else None, 3, (1.0, 0.0, 0.0))
    for label, val in (("origin xyz", xyz), ("origin rpy", rpy), ("axis xyz", axis)):
        if val is None:
            problems.append(f"{loc}: {label} must be three finite numbers")
    if xyz is None or rpy is None or axis is None:
        return None
    if abs(rpy[0]) > _TOL or abs(rpy[1]) > _TOL:
        problems.append(f"{loc}: origin rpy = {rpy}: a planar scene allows a rotation about z only (roll = pitch = 0)")
    norm = math.sqrt(sum(a * a for a in axis))
    if jtype in ("revolute", "planar") and (norm == 0 or abs(abs(axis[2]) - norm) > _TOL * max(norm, 1)):
        problems.append(f"{loc}: axis = {axis} is not normal to the xy plane; a planar scene allows (0 0 1)")
    if jtype == "revolute" and axis[2] < 0:
        problems.append(f"{loc}: axis = {axis}: use (0 0 1) and flip the sign of the angle instead "
                        "(Pinocchio models (0 0 -1) as a slower unaligned joint)")
    if jtype == "prismatic" and (norm == 0 or abs(axis[2]) > _TOL * max(norm, 1)):
        problems.append(f"{loc}: axis = {axis} must lie in the xy plane (z = 0) for a planar slider")
    for tag, attrs in (("dynamics", ("damping", "friction")), ("mimic", None)):
        sub = el.find(tag)
        if sub is None:
            continue
        if attrs is None:
            problems.append(f"{loc}: <mimic joint={sub.get('joint')!r}> is not modelled by pcmm (the joint would "
                            "move freely); couple the joints with a cut joint or a drive in the scene instead")
            continue
        for attr in attrs:
            text = sub.get(attr)
            try:
                value = float(text) if text is not None else 0.0
            except ValueError:
                value = math.nan
            if value != 0.0:
                problems.append(f"{loc}: <dynamics {attr}={text!r}> is not modelled by pcmm and would be "
                                f"ignored; remove it, and for {attr} model a force element in the scene "
                                + ("(type = \"damper\", c = ..., on and measure = { joint = ... })"
                                   if attr == "damping" else "(pcmm has no Coulomb friction)"))
    if jtype in ("revolute", "prismatic") and el.find("limit") is None:
        problems.append(f"{loc}: a {jtype} joint needs a <limit> tag for the URDF parser "
                        "(pcmm does not enforce it; model stops as transitions)")
    lim = el.find("limit")
    bounds = (_floats(lim.get("lower", "0"), 1, (0.0,)), _floats(lim.get("upper", "0"), 1, (0.0,))) \
        if lim is not None else (None, None)
    limits = (bounds[0][0], bounds[1][0]) if None not in bounds else None
    return UrdfJoint(name, jtype, parent.get("link"), child.get("link"), xyz, rpy, axis, limits)


def _check_inertial(el, name, where, required, problems) -> None:
    loc = f"{where}: link '{name}'"
    inertial = el.find("inertial")
    if inertial is None:
        if required:
            problems.append(f"{loc}: has no <inertial>; a link moved by a joint needs mass > 0 "
                            "and a positive-definite inertia (a massless link makes the mass matrix singular)")
        return
    origin = inertial.find("origin")
    if origin is not None:
        for attr in ("xyz", "rpy"):
            if _floats(origin.get(attr), 3, (0.0, 0.0, 0.0)) is None:
                problems.append(f"{loc}: <inertial><origin {attr}={origin.get(attr)!r}> must be three finite numbers "
                                "(the URDF parser would silently drop the whole <inertial>)")
    mass_el = inertial.find("mass")
    try:
        mass = float(mass_el.get("value")) if mass_el is not None else None
    except (TypeError, ValueError):
        mass = None
    if mass is None or not math.isfinite(mass) or mass <= 0:
        shown = mass_el.get("value") if mass_el is not None else "missing"
        problems.append(f"{loc}: <mass value={shown!r}>: mass must be a finite number > 0")
    inertia = inertial.find("inertia")
    names = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    try:
        vals = {n: float(inertia.get(n)) for n in names} if inertia is not None else None
    except (TypeError, ValueError):
        vals = None
    if vals is None or not all(math.isfinite(v) for v in vals.values()):
        problems.append(f"{loc}: <inertia> must give six finite numbers {', '.join(names)}")
        return
    m = np.array([[vals["ixx"], vals["ixy"], vals["ixz"]],
                  [vals["ixy"], vals["iyy"], vals["iyz"]],
                  [vals["ixz"], vals["iyz"], vals["izz"]]])
    eig = np.linalg.eigvalsh(m)
    if not m.any():
        return  # a point mass: accepted where the configuration's mass matrix stays positive definite
    if eig.min() <= 0:
        problems.append(f"{loc}: inertia tensor is not positive definite (eigenvalues {np.round(eig, 15).tolist()})")
    elif not (eig[0] + eig[1] >= eig[2] * (1 - 1e-9)):
        problems.append(f"{loc}: inertia violates the triangle inequality "
                        f"(principal moments {eig.tolist()}): no rigid body has it")
