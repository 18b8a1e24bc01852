"""Configurations derived by locking joints.

A scene may declare a configuration as another one with some joints locked::

    [configurations.config2]
    from = "config1"
    lock = ["O3"]                        # at the values O3 has when the run enters config2
    # lock = { O3 = 3.141592653589793 }  # or at given values (fixed at load time)

Its model is the root URDF with each locked joint turned into a ``fixed`` joint whose origin
absorbs the joint's value, everything else identical, so the links it shares with its base are
placed identically by construction.  The result is ordinary URDF *text*: one URDF per
configuration, which ``pcmm derive`` writes out to inspect or reuse as a hand-written file.

* revolute (axis +z): the fixed origin's yaw is ``yaw + q``;
* prismatic (unit axis ``a`` in the joint frame): the fixed origin's position is
  ``xyz + Rz(yaw) a q``.

A planar joint (three coordinates) is not locked this way.  Cut joints of the base are
inherited unless the derived table gives its own ``cut_joints``.  Forces and drives are checked
against the derived configuration like any other: one that names a locked joint is refused at
load unless it lists the configurations it acts in.
"""
from __future__ import annotations

import difflib
import math
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np

from . import schema as S
from ..errors import SimulationError
from .spec import ConfigurationSpec, Derivation, Scene
from .urdf import UrdfInfo, UrdfJoint

#: joint types a derived configuration can lock (one coordinate each)
LOCKABLE = ("revolute", "prismatic")
#: two lock values closer than this are the same model (the same joint reached by two routes)
SAME_VALUE = 1e-12


# ---- the locked joint's geometry -------------------------------------------------------------
def _unit_axis(joint: UrdfJoint) -> np.ndarray:
    a = np.asarray(joint.axis[:2], float)
    return a / np.linalg.norm(a)


def _rot(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


def locked_origin(joint: UrdfJoint, value: float) -> tuple[tuple[float, float, float], float]:
    """(xyz, yaw) of the fixed joint that holds ``joint`` at ``value``: the child's frame
    relative to the parent's, ``origin * motion(value)``."""
    x, y, z = joint.xyz
    yaw = joint.rpy[2]
    if joint.type == "revolute":
        return (x, y, z), yaw + value
    dx, dy = _rot(yaw) @ _unit_axis(joint) * value
    return (x + float(dx), y + float(dy), z), yaw


def joint_value(joint: UrdfJoint, parent_pose, child_pose) -> float:
    """The value of ``joint`` from its parent's and child's link poses (x, y, theta): the
    inverse of :func:`locked_origin` (a joint the source configuration does not have)."""
    if joint.type == "revolute":
        return float(child_pose[2] - parent_pose[2] - joint.rpy[2])
    rel = _rot(parent_pose[2]).T @ (np.asarray(child_pose[:2]) - np.asarray(parent_pose[:2]))
    along = _rot(joint.rpy[2]).T @ (rel - np.asarray(joint.xyz[:2]))
    return float(_unit_axis(joint) @ along)


def locked_info(info: UrdfInfo, lock) -> UrdfInfo:
    """The root URDF's description with the locked joints fixed (names and links unchanged)."""
    joints = {n: replace(j, type="fixed") if n in lock else j for n, j in info.joints.items()}
    return replace(info, joints=joints)


def lock_urdf(path: Path, joints: dict[str, UrdfJoint], values: dict[str, float], name: str) -> str:
    """The URDF text of ``path`` with each joint of ``values`` made fixed at its value; every
    other element, attribute and comment is kept as written."""
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
    root = ET.parse(path, parser=parser).getroot()
    robot = root.get("name", "")
    root.set("name", f"{robot}_{name}" if robot else name)
    for el in root.findall("joint"):
        jname = el.get("name")
        if jname not in values:
            continue
        joint = joints[jname]
        xyz, yaw = locked_origin(joint, values[jname])
        el.set("type", "fixed")
        closing = el[-1].tail if len(el) else None  # the indentation before </joint>
        for child in [c for c in el if c.tag in ("axis", "limit", "dynamics", "mimic",
                                                  "safety_controller", "calibration")]:
            el.remove(child)
        origin = el.find("origin")
        if origin is None:
            origin = ET.SubElement(el, "origin")
        if joint.type == "revolute":
            origin.set("rpy", " ".join(repr(float(u)) for u in (joint.rpy[0], joint.rpy[1], yaw)))
        else:
            origin.set("xyz", " ".join(repr(float(u)) for u in xyz))
        el[-1].tail = closing
    locks = ", ".join(f"{j} = {values[j]!r} {'rad' if joints[j].type == 'revolute' else 'm'}" for j in values)
    note = ET.Comment(f" configuration '{name}' derived by pcmm from {path.name}: {locks} locked "
                      "(each made a fixed joint whose origin absorbs its value) ")
    note.tail = "\n  "
    root.insert(0, note)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def concrete(spec: ConfigurationSpec, values: dict[str, float]) -> ConfigurationSpec:
    """``spec`` with every locked joint's value known: its URDF text is generated."""
    der = spec.derivation
    full = {**dict(der.values), **values}
    ordered = {j: float(full[j]) for j in der.lock}
    return replace(spec, derivation=replace(der, values=tuple(ordered.items())),
                   xml=lock_urdf(spec.urdf, der.joints, ordered, spec.name))


# ---- values at entry ---------------------------------------------------------------------------
def entry_values(spec: ConfigurationSpec, src, q) -> dict[str, float]:
    """The locked joints' values when the run enters ``spec`` from configuration ``src`` at ``q``.

    A joint ``src`` has takes its coordinate (the state is mapped by joint name, as at every
    switch); one ``src`` has locked itself keeps that value; any other comes from its links'
    poses in ``src``."""
    der = spec.derivation
    out = dict(der.values)
    missing = der.at_entry
    if missing and src is None:
        raise SimulationError(
            f"configuration '{spec.name}' locks {', '.join(missing)} at the values they have when the run "
            "enters it, but it is used without being entered from another configuration; give the values "
            f"in the scene: lock = {{ {missing[0]} = value }}")
    src_locked = dict(src.spec.derivation.values) if missing and src.spec.derivation else {}
    poses = None
    for j in missing:
        sl = src.joint_slice.get(j)
        if sl is not None and sl.stop - sl.start == 1:
            out[j] = float(q[sl][0])
        elif j in src_locked:
            out[j] = src_locked[j]
        else:
            joint = der.joints[j]
            if joint.parent not in src.link_index or joint.child not in src.link_index:
                raise SimulationError(
                    f"entering '{spec.name}' from '{src.name}': the value of the locked joint '{j}' cannot be "
                    f"found, because '{src.name}' lacks its link '{joint.parent}' or '{joint.child}'")
            poses = src.link_poses(q) if poses is None else poses
            out[j] = joint_value(joint, poses[src.link_index[joint.parent]], poses[src.link_index[joint.child]])
    return out


def same_values(a: dict[str, float], b: dict[str, float]) -> bool:
    return a.keys() == b.keys() and all(abs(a[k] - b[k]) <= SAME_VALUE for k in a)


def guard_values(scene: Scene, name: str) -> dict[str, float]:
    """Locked joints of ``name`` whose value at entry a coordinate guard fixes: every transition
    into ``name`` (a latch's ``to``, a stop's ``merge_to``) watches that joint, or the relative angle
    of its two links, or its child's angle on the frame, and all of them agree."""
    spec = scene.configurations[name]
    der = spec.derivation
    found: dict[str, set] = {}
    into = [t for t in scene.transitions if name in (getattr(t, "target", None), getattr(t, "merge_to", None))]
    for j in der.at_entry:
        joint = der.joints[j]
        for t in into:
            found.setdefault(j, set()).add(_fixed_by(t.guard, joint, spec.info.root))
    return {j: vals.pop() for j, vals in found.items() if len(vals) == 1 and None not in vals}


def _fixed_by(guard, joint: UrdfJoint, root: str) -> float | None:
    """The joint's value at the guard's crossing, if the guard watches that joint alone."""
    m = guard.measure
    if guard.type != "coordinate" or m is None:
        return None
    if m.kind == "joint":
        return float(guard.value) if m.names[0] == joint.name else None
    if joint.type != "revolute":
        return None
    yaw = joint.rpy[2]
    if m.kind == "between" and tuple(m.names) == (joint.parent, joint.child):
        return float(guard.value - yaw)
    if m.kind == "between" and tuple(m.names) == (joint.child, joint.parent):
        return float(-guard.value - yaw)
    if m.kind == "link" and m.names[0] == joint.child and joint.parent == root:
        return float(guard.value - yaw)
    return None


# ---- loading -------------------------------------------------------------------------------------
def derive_configurations(tables: dict, plain: dict[str, ConfigurationSpec], problems: S.Problems,
                          cut_joints, declared=()) -> dict[str, ConfigurationSpec]:
    """Resolve the derived ``[configurations.NAME]`` tables (``{name: (checked, raw)}``) against
    the configurations read from URDFs, reporting every problem; chains resolve in order.
    ``declared`` names every configuration table, also those whose URDF failed (already reported)."""
    out: dict[str, ConfigurationSpec] = {}
    defined = list(declared) or sorted(set(plain) | set(tables))

    failed: set[str] = set()  # each derived configuration's problems are reported once

    def resolve(name: str, chain: tuple[str, ...]) -> ConfigurationSpec | None:
        if name in out or name in plain:
            return out.get(name) or plain[name]
        if name not in tables or name in failed:
            return None
        where = f"configurations.{name}"
        if name in chain:
            loop = " -> ".join(chain[chain.index(name):] + (name,))
            problems.add(f"{where}.from", f"{loop} is a cycle: a derived configuration must lead back to one "
                         "with a urdf")
            return None
        spec = derive_one(name, where, chain)
        if spec is None:
            failed.add(name)
        return spec

    def derive_one(name: str, where: str, chain: tuple[str, ...]) -> ConfigurationSpec | None:
        c, raw = tables[name]
        ok = True
        if "urdf" in raw:
            problems.add(where, "gives both urdf and from: a configuration is either a URDF or derived from "
                         "another by locking joints, not both")
            ok = False
        if c["from"] is None:
            if "from" not in raw:
                problems.add(f"{where}.from", "missing; a configuration with lock names the configuration it "
                             "derives from (from = NAME)")
            return None
        if "lock" not in raw:
            problems.add(f"{where}.lock", "missing; name the joints to lock: lock = [joints] (values at entry) "
                         "or lock = { joint = value }")
            return None
        base_name = c["from"]
        if base_name not in defined:
            problems.add(f"{where}.from", f"= {base_name!r}: no such configuration; defined: {', '.join(defined)}")
            return None
        base = resolve(base_name, chain + (name,))
        if base is None or c["lock"] is None:
            return None
        lock, values = _lock_entries(c["lock"], f"{where}.lock", problems)
        if lock is None:
            return None
        known = base.derivation.joints if base.derivation else {}
        joints = dict(known)
        for j in lock:
            jwhere = f"{where}.lock"
            if j in known:
                problems.add(jwhere, f"= {j!r}: already locked in '{base_name}'")
                ok = False
            elif j not in base.info.joints:
                close = difflib.get_close_matches(j, list(base.info.movable_joints), n=1, cutoff=0.5)
                hint = f" (did you mean '{close[0]}'?)" if close else ""
                problems.add(jwhere, f"= {j!r}: no joint of that name in configuration '{base_name}' "
                             f"({base.urdf.name}){hint}; movable joints: {', '.join(base.info.movable_joints)}")
                ok = False
            elif base.info.joints[j].type not in LOCKABLE:
                jt = base.info.joints[j].type
                why = ("a planar joint has three coordinates; pcmm locks revolute and prismatic joints only "
                       "(hold a planar body with a weld cut joint, or write its URDF)") if jt == "planar" \
                    else f"joint '{j}' is already fixed in '{base_name}'"
                problems.add(jwhere, f"= {j!r}: {why}")
                ok = False
            else:
                joints[j] = base.info.joints[j]
        if not ok:
            return None
        der = Derivation(base=base_name, lock=(base.derivation.lock if base.derivation else ()) + tuple(lock),
                         joints=joints,
                         values=(base.derivation.values if base.derivation else ()) + tuple(values.items()))
        cuts = cut_joints(c["cut_joints"], where) if "cut_joints" in raw else base.cut_joints
        spec = ConfigurationSpec(name=name, urdf=base.urdf, info=locked_info(base.info, der.lock),
                                 cut_joints=cuts, derivation=der)
        if not der.at_entry:
            spec = concrete(spec, {})
        out[name] = spec
        return spec

    for name in tables:
        resolve(name, ())
    return out


def _lock_entries(lock, where, problems) -> tuple[list[str] | None, dict[str, float]]:
    """(joints, explicit values) from ``lock = [joints]`` or ``lock = {joint = value}``."""
    if isinstance(lock, dict):
        names, values = list(lock), {}
        for j, val in lock.items():
            val, problem = S.numbers(val)  # "pi", "30 deg": an expression like every scalar of a scene
            if problem is not None:
                problems.add(f"{where}.{j}", problem)
                return None, {}
            if not S._type_ok("number", val) or not math.isfinite(val):
                problems.add(f"{where}.{j}", f"= {S.show(val)}: must be a finite number (rad for a revolute "
                             "joint, m for a prismatic one)")
                return None, {}
            values[j] = float(val)
    else:
        names, values = lock, {}
        bad = [x for x in lock if not isinstance(x, str)]
        if bad:
            problems.add(where, f"= {S.show(lock)}: must be a list of joint names, or a table {{joint = value}}")
            return None, {}
        dup = sorted({x for x in lock if lock.count(x) > 1})
        if dup:
            problems.add(where, f"= {S.show(lock)}: names {', '.join(dup)} more than once")
            return None, {}
    if not names:
        problems.add(where, "is empty: name at least one joint to lock")
        return None, {}
    return names, values


def check_initial(scene_configs: dict[str, ConfigurationSpec], initial: str, problems: S.Problems) -> None:
    """The run starts in the initial configuration, so nothing enters it: its locks need values."""
    spec = scene_configs.get(initial)
    if spec is not None and spec.derivation is not None and spec.derivation.at_entry:
        j = spec.derivation.at_entry[0]
        problems.add("scene.initial_configuration",
                     f"= {initial!r}: the run starts in this derived configuration, so nothing enters it and its "
                     f"locked joints ({', '.join(spec.derivation.at_entry)}) have no value at entry; give them: "
                     f"lock = {{ {j} = value }} in [configurations.{initial}]")


# ---- check and derive (command line) -------------------------------------------------------------
def _describe(spec: ConfigurationSpec, values: dict[str, float]) -> str:
    der = spec.derivation
    locks = ", ".join(f"{j} = {values[j]:.10g}" if j in values else j for j in der.lock)
    return f"'{der.base}' with {locks} locked"


def check_derived(scene: Scene, build) -> list[str]:
    """Build every derived configuration's model (``build(spec)``), as ``pcmm check`` does: with
    the values the scene gives, else those a coordinate guard into it fixes, else (values known
    only at entry) at 0 for the check of its structure.  Returns one line per derived
    configuration."""
    lines = []
    for name, spec in scene.configurations.items():
        if spec.derivation is None:
            continue
        fixed = guard_values(scene, name)
        unknown = [j for j in spec.derivation.at_entry if j not in fixed]
        model = build(concrete(spec, {**fixed, **{j: 0.0 for j in unknown}}))
        how = []
        if fixed:
            how.append(f"{', '.join(fixed)} fixed by the guards into it")
        if unknown:
            how.append(f"{', '.join(unknown)} known only when the run enters it (model checked at 0)")
        lines.append(f"configuration '{name}': {_describe(spec, {**dict(spec.derivation.values), **fixed})}, "
                     f"{model.nv} coordinates" + (f"; {'; '.join(how)}" if how else ""))
    return lines


def derived_urdfs(scene: Scene, run):
    """The URDF text of every derived configuration: those with values given in the scene
    directly; those with values at entry as the run built them (the scene is run once, only if
    needed: ``run()`` returns the run's ``stats["derived_configurations"]`` and, when it stopped
    early, its message).  Returns ``(written, unreached, note)``: ``written`` is a list of
    ``(name, index, values, text)`` (index None, or 1, 2, ... for a configuration the run
    entered at several values), ``unreached`` the derived configurations the run never entered, and ``note`` the
    run's end when it stopped early (its partial result still counts)."""
    derived = {n: s for n, s in scene.configurations.items() if s.derivation is not None}
    written, unreached, note = [], [], None
    runs: dict[str, list[dict]] = {}
    if any(s.derivation.at_entry for s in derived.values()):
        runs, note = run()
    for name, spec in derived.items():
        if not spec.derivation.at_entry:
            written.append((name, None, dict(spec.derivation.values), spec.xml))
            continue
        entries = runs.get(name, [])
        if not entries:
            unreached.append(name)
        for k, values in enumerate(entries):
            written.append((name, k + 1 if len(entries) > 1 else None, values, concrete(spec, values).xml))
    return written, unreached, note
