"""Check-time consistency of a scene's geometry (``pcmm check``), before anything is simulated.

The schema (:mod:`pcmm.scene`) validates each value on its own; this module builds the
configurations' models and checks that the values agree with each other where a guard fixes the
posture, so a scene that would fail at its first switch, after the whole pre-switch run, fails
here at once, each problem naming the file and the field:

* **the pose at a switch**: at the posture where a guard sits at its value (an open chain: the
  guard coordinate set; a loop: assembled with the guard as one more equation), every link the
  target configuration shares with the source sits where the source puts it;
* **the contact at the guard value**: the two contact points meet (gap zero along the normal and
  nothing across it), and the normal is the direction in which the pair's joint moves the contact
  point: for a revolute pair, perpendicular to the lever from the joint axis to the contact point
  (how far it is off, in degrees); it points from a towards b, so the guard's direction approaches;
* **reach**: each guard value lies in the range its coordinate can reach (the URDF's joint limits;
  a loop that cannot close there), else a warning.

A message blames the normal only when the normal is at fault: rounded contact points that do not
meet are reported as points (:func:`contact_findings`, also used by the run's latch check).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from .configuration import Configuration
from .mechanism import Mechanism
from .errors import PcmmError
from .spec import Scene, TransitionSpec
from .transitions import POSE_TOL, map_state, pose_mismatches

NORMAL_TOL = 1e-6  # rad: a normal off by less changes the impulse by less than 1e-12 relative
NEWTON_TOL = 1e-13


@dataclass
class CheckReport:
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    postures: dict[str, np.ndarray] = field(default_factory=dict)  # transition name -> q at its guard


@dataclass(frozen=True)
class Finding:
    field: str  # under the transition: "contact.normal", "contact.point_b", ...
    text: str


# ---- the posture at a guard ---------------------------------------------------------------
def _closure(cfg: Configuration, q):
    """(phi, Phi_q) of the loop-closure rows only (drives are functions of time, not posture)."""
    coords = cfg.coords
    if not getattr(coords, "constrained", False) or not coords.closure.size:
        return np.zeros(0), np.zeros((0, cfg.nv))
    pin.computeJointJacobians(cfg.model, cfg.data, cfg.to_pin(q))
    pin.updateFramePlacements(cfg.model, cfg.data)
    phi, Jq, _ = coords.closure.evaluate(cfg.model, cfg.data, False)
    return phi, Jq


def _guard_row(cfg: Configuration, tr: TransitionSpec, q):
    """(residual, gradient) of the guard at q: measure - value, or gap - value."""
    if tr.guard.type == "coordinate":
        row, offset = cfg.measure_row(tr.guard.measure)
        return float(row @ q + offset - tr.guard.value), row
    from .contact import contact_state

    def gap(x):
        return contact_state(cfg, x, np.zeros(cfg.nv), tr.contact)[1]
    grad = np.zeros(cfg.nv)
    for i in range(cfg.nv):
        e = np.zeros(cfg.nv)
        e[i] = 1e-7
        grad[i] = (gap(q + e) - gap(q - e)) / 2e-7
    return gap(q) - tr.guard.value, grad


def guard_posture(cfg: Configuration, tr: TransitionSpec, q_start) -> tuple[np.ndarray, float]:
    """The posture nearest ``q_start`` (minimum-norm Newton steps) with the guard at its value
    and every loop closed; returns (q, largest residual), the residual ~1e-13 when reached."""
    q = np.array(q_start, dtype=float)
    worst = math.inf
    for _ in range(60):
        phi, Jq = _closure(cfg, q)
        r, g = _guard_row(cfg, tr, q)
        res = np.append(phi, r)
        worst = float(np.max(np.abs(res)))
        if worst < NEWTON_TOL:
            break
        step = np.linalg.lstsq(np.vstack([Jq, g]), -res, rcond=None)[0]
        q = q + step
        if not np.all(np.isfinite(q)):
            return q_start, math.inf
    return q, worst


# ---- the contact at a posture ---------------------------------------------------------------
def pair_joint(cfg: Configuration, tr: TransitionSpec) -> str | None:
    """The one-coordinate joint that joins the contact's links a and b directly, if any."""
    pair = {tr.contact.a, tr.contact.b}
    for name, j in cfg.spec.info.joints.items():
        if {j.parent, j.child} == pair and name in cfg.joint_slice and j.type in ("revolute", "prismatic"):
            return name
    return None


def _fmt(x):
    return "[" + ", ".join(f"{float(c):.9g}" for c in x) + "]"


def contact_findings(cfg: Configuration, tr: TransitionSpec, q) -> list[Finding]:
    """What is wrong with the contact of ``tr`` at a posture where its guard fires.

    Points first: rounded points that do not meet are the points' fault, whatever the normal.
    Then the normal, for a contact on a pair joined by one revolute or prismatic joint: it must
    be the direction in which that joint moves the contact point (perpendicular to the lever from
    a revolute joint's axis)."""
    c = tr.contact
    if c is None or c.joint is not None:  # a release, or a joint stop: no points, no normal
        return []
    cfg.kinematics(q)
    pa, pb = cfg.point(c.a, c.point_a), cfg.point(c.b, c.point_b)
    xa, xb = cfg.point_position(pa), cfg.point_position(pb)
    Ra = cfg.rotation(c.a)
    n = Ra @ np.asarray(c.normal, float)
    n /= np.linalg.norm(n)
    d = xb - xa
    gap = float(n @ d)
    across = float(abs(n[0] * d[1] - n[1] * d[0]))
    out = []
    if tr.guard.type == "coordinate" and max(abs(gap), across) > POSE_TOL:
        out.append(Finding("contact.point_b", (
            f"the contact points do not meet where the guard fires ({tr.guard.measure} = "
            f"{tr.guard.value:.12g}): point_a {_fmt(c.point_a)} of '{c.a}' is at {_fmt(xa)}, point_b "
            f"{_fmt(c.point_b)} of '{c.b}' at {_fmt(xb)}, {np.linalg.norm(d):.3g} m apart ({gap:.3g} m along "
            f"the normal, {across:.3g} m across it; allowed {POSE_TOL:g}): the points are at fault, not the "
            "normal. A rounded coordinate? Write it as an expression, e.g. \"0.125*cos(30 deg)\"")))
    joint = pair_joint(cfg, tr)
    if joint is None or out:  # the normal is judged once the points meet
        return out
    col = cfg.joint_slice[joint].start
    u = cfg.point_jacobian(pb)[:, col] - cfg.point_jacobian(pa)[:, col]
    jtype = cfg.spec.info.joints[joint].type
    if np.linalg.norm(u) < 1e-12:
        out.append(Finding("contact.point_b", (
            f"the contact point {_fmt(xb)} lies on the axis of the {jtype} joint '{joint}' that joins "
            f"'{c.a}' and '{c.b}': an impulse there cannot stop the joint; put the contact away from the axis")))
        return out
    cosang = float(n @ u) / np.linalg.norm(u)
    off = math.acos(min(1.0, abs(cosang)))
    if off > NORMAL_TOL:
        want = Ra.T @ (u / np.linalg.norm(u)) * (1.0 if cosang >= 0 else -1.0)
        lever = ""
        if jtype == "revolute":
            axis = cfg.data.oMi[cfg.joint_id[joint]].translation[:2]
            lever = (f"; for a contact on a revolute pair the normal must be perpendicular to the lever "
                     f"{_fmt(xb - axis)} from the joint axis at {_fmt(axis)} to the contact point")
        out.append(Finding("contact.normal", (
            f"normal {_fmt(c.normal)} (world {_fmt(n)}) is {math.degrees(off):.6g} deg off the direction "
            f"{_fmt(u / np.linalg.norm(u))} in which joint '{joint}' moves the contact point{lever}. The "
            f"impulse would come out {100 * (1 / max(abs(cosang), 1e-300) - 1):.3g} % too large; in "
            f"'{c.a}''s frame the normal is {_fmt(want)}")))
    if tr.guard.type == "coordinate":
        row, _ = cfg.measure_row(tr.guard.measure)
        if row[col] != 0 and tr.guard.direction * np.sign(row[col]) * cosang > 0:
            out.append(Finding("contact.normal", (
                f"normal {_fmt(c.normal)} points from '{c.b}' to '{c.a}': as the guard's {tr.guard.measure} "
                f"moves {'up' if tr.guard.direction > 0 else 'down'} to its value the contact separates along "
                "it; the normal must point from link a towards link b (flip its sign)")))
    return out


# ---- the whole scene ------------------------------------------------------------------------
def _limits(cfg: Configuration, q) -> list[str]:
    out = []
    for name, j in cfg.spec.info.joints.items():
        if j.limits is None or name not in cfg.joint_slice or j.type not in ("revolute", "prismatic"):
            continue
        x = float(q[cfg.joint_slice[name].start])
        lo, hi = j.limits
        if not lo - 1e-12 <= x <= hi + 1e-12:
            out.append(f"joint '{name}' is at {x:.9g} there, outside its URDF limits [{lo:g}, {hi:g}] "
                       f"({cfg.spec.urdf.name})")
    return out


def check_scene(scene: Scene, mechanism: Mechanism | None = None) -> CheckReport:
    """Every check-time problem (and warning) of ``scene``, each naming the file and the field."""
    from .assembly import assemble
    mech = mechanism or Mechanism(scene)
    report = CheckReport()
    where = str(scene.path)
    starts: dict[str, np.ndarray] = {}
    try:
        cfg0 = mech[scene.initial_configuration]
        q0, _, notes = assemble(scene, cfg0)
        starts[cfg0.name] = q0
        report.warnings += [f"{where}: initial: {w}" for w in notes]
    except PcmmError as exc:
        report.problems += [p if p.startswith(where) else f"{where}: initial: {p}" for p in exc.problems]
        return report
    todo = [scene.initial_configuration]
    entered: dict = {}
    while todo:  # configurations in the order a run reaches them, each started where it is entered
        name = todo.pop(0)
        cfg = entered.get(name) or mech[name]
        for tr in scene.transitions_from(name):
            if tr.guard.type not in ("coordinate", "gap"):  # time and reaction guards fix no posture
                continue
            i = scene.transitions.index(tr)
            here = f"{where}: transitions[{i}] ({tr.name})"
            q, residual = guard_posture(cfg, tr, starts[name])
            if residual > 1e-9:
                what = "the loop cannot close" if cfg.coords.constrained else "no posture reaches it"
                report.warnings.append(
                    f"{here}.guard.value: = {tr.guard.value:.12g}: {what} with the guard there (closest "
                    f"residual {residual:.3g}): the guard may never fire; check its value and direction")
                continue
            report.postures[tr.name] = q
            report.warnings += [f"{here}.guard.value: = {tr.guard.value:.12g}: {w}" for w in _limits(cfg, q)]
            report.problems += [f"{here}.{f.field}: {f.text}" for f in contact_findings(cfg, tr, q)]
            target = tr.merge_to if tr.type == "stop" else tr.target
            if target is None or target not in scene.configurations:
                continue
            key = "merge_to" if tr.type == "stop" else "to"
            try:
                dst = mech.enter(target, cfg, q)  # a derived target locks the values the guard gives
                entered.setdefault(target, dst)
                q_dst, _, _ = map_state(cfg, dst, q, np.zeros(cfg.nv))
                _, mismatches = pose_mismatches(cfg, dst, q, q_dst)
            except PcmmError as exc:
                report.problems += [f"{here}.{key}: {p}" for p in exc.problems]
                continue
            report.problems += [f"{here}.{key}: at the guard value ({tr.guard.measure} = {tr.guard.value:.12g}) "
                                f"{m}; the two URDFs must place every shared link identically there "
                                "(check the fixed joint's origin in the merged configuration)" for m in mismatches]
            if target not in starts:
                starts[target] = q_dst
                todo.append(target)
    return report
