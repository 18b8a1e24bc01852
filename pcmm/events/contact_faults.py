"""What is wrong with a contact where its guard fires: the points or the normal, whichever is at fault.

Used by ``pcmm check`` (:mod:`pcmm.checks`) before a run and by the merge of a transition
(:mod:`pcmm.transitions`) when an impact leaves a locked joint moving, so both name the same
culprit. A message blames the normal only when the normal is at fault: rounded contact points
that do not meet are reported as points first.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..model.configuration import Configuration
from ..scene.spec import TransitionSpec

POSE_TOL = 1e-9  # m or rad: where a guard fires the bodies meet, and a switch's shared links agree, to this
NORMAL_TOL = 1e-6  # rad: a normal off by less changes the impulse by less than 1e-12 relative


@dataclass(frozen=True)
class Finding:
    field: str  # under the transition: "contact.normal", "contact.point_b", ...
    text: str


def pair_joint(cfg: Configuration, tr: TransitionSpec) -> str | None:
    """The one-coordinate joint that joins the contact's links a and b directly, if any."""
    pair = {tr.contact.a, tr.contact.b}
    for name, j in cfg.spec.info.joints.items():
        if {j.parent, j.child} == pair and name in cfg.joint_slice and j.type in ("revolute", "prismatic"):
            return name
    return None


def _fmt(x):
    """A vector as the scene would write it (``+ 0.0`` turns a rounded ``-0`` into ``0``)."""
    return "[" + ", ".join(f"{float(c) + 0.0:.9g}" for c in x) + "]"


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
