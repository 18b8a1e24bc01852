"""What is wrong with a contact where its guard fires: the points or the normal, whichever is at fault.

Used by ``pcmm check`` (:mod:`pcmm.checks`) before a run and by the merge of a transition
(:mod:`pcmm.transitions`) when an impact leaves a locked joint moving, so both name the same
culprit. A message blames the normal only when the normal is at fault: rounded contact points
that do not meet are reported as points first.

**An oblique normal on a one-coordinate pair.**  For a contact between the two links of one revolute
or prismatic joint, every motion of the contact point is along u, the direction in which that joint
moves it; a normal n at an angle alpha to u gives the normal row J_n = (n . u) and Newton's law along n
(Eq. 21) gives q'+ = -e q'- whatever alpha is: the velocities after the impact do not depend on the
normal's angle.  The normal impulse does, P_n = (1 + e) M |q'-| / |n . u|, larger by 1 / cos alpha than
one along u, the joint carrying the rest.  So:

* with friction, the normal is the surface's: it fixes the friction cone and the tangential impulse
  (Routh's process), so an oblique wall is as right as any, and nothing is reported;
* frictionless against a link no coordinate moves (a wall on the frame): the impulse is the wall's
  along its oblique normal, right for an oblique wall, 1 / cos alpha more than the joint's share if the
  contact was meant as the joint's own stop: a warning that says which;
* frictionless between two moving links joined only by that joint: the contact is that joint's own
  stop and its impulse (and a stop-merge's holding force) is read as the joint's; the angle changes
  no velocity, only that reported number, so an oblique normal there is a typo: an error.

Which of the three applies depends on the contact alone (its friction, its links), not on the
posture where the check finds the guard.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..model.configuration import Configuration
from ..model.pinocchio_helpers import frame_jacobian
from ..scene.spec import TransitionSpec

POSE_TOL = 1e-9  # m or rad: where a guard fires the bodies meet, and a switch's shared links agree, to this
NORMAL_TOL = 1e-6  # rad: a normal off by less changes the impulse by less than 1e-12 relative


@dataclass(frozen=True)
class Finding:
    field: str  # under the transition: "contact.normal", "contact.point_b", ...
    text: str
    warning: bool = False  # True: a fact the user should know (the scene is valid), not a fault


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


def _moves(cfg: Configuration, frame_id: int) -> bool:
    """Does any coordinate move the link that carries ``frame_id`` (needs :meth:`kinematics`)?"""
    return bool(np.any(frame_jacobian(cfg.model, cfg.data, frame_id) != 0.0))


def contact_findings(cfg: Configuration, tr: TransitionSpec, q, warnings: bool = False) -> list[Finding]:
    """What is wrong with the contact of ``tr`` at a posture where its guard fires (with
    ``warnings``, also what is right but worth saying: :class:`Finding` ``.warning``).

    Points first: rounded points that do not meet are the points' fault, whatever the normal.
    Then the normal, for a contact on a pair joined by one revolute or prismatic joint, against
    the direction in which that joint moves the contact point (perpendicular to the lever from
    a revolute joint's axis): see the module's note for when an oblique normal is a fault."""
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
    frictional = c.friction is not None and c.friction > 0
    if off > NORMAL_TOL and not frictional:
        wall = not (_moves(cfg, pa.frame_id) and _moves(cfg, pb.frame_id))
        out += [] if wall and not warnings else [_oblique(cfg, tr, joint, n, u, cosang, off, xb, Ra, wall)]
    if tr.guard.type == "coordinate":
        row, _ = cfg.measure_row(tr.guard.measure)
        if row[col] != 0 and tr.guard.direction * np.sign(row[col]) * cosang > 0:
            out.append(Finding("contact.normal", (
                f"normal {_fmt(c.normal)} points from '{c.b}' to '{c.a}': as the guard's {tr.guard.measure} "
                f"moves {'up' if tr.guard.direction > 0 else 'down'} to its value the contact separates along "
                "it; the normal must point from link a towards link b (flip its sign)")))
    return out


def _oblique(cfg: Configuration, tr: TransitionSpec, joint: str, n, u, cosang, off, xb, Ra, wall) -> Finding:
    """The finding of a frictionless normal at ``off`` rad from the direction u in which ``joint``
    moves the contact point: a warning against a wall, an error between two moving links."""
    c = tr.contact
    jtype = cfg.spec.info.joints[joint].type
    want = Ra.T @ (u / np.linalg.norm(u)) * (1.0 if cosang >= 0 else -1.0)
    lever = ""
    if jtype == "revolute":
        axis = cfg.data.oMi[cfg.joint_id[joint]].translation[:2]
        lever = (f" (for a revolute pair, perpendicular to the lever {_fmt(xb - axis)} from the joint axis at "
                 f"{_fmt(axis)} to the contact point)")
    more = 100 * (1 / max(abs(cosang), 1e-300) - 1)
    head = (f"normal {_fmt(c.normal)} (world {_fmt(n)}) is {math.degrees(off):.6g} deg off the direction "
            f"{_fmt(u / np.linalg.norm(u))} in which joint '{joint}' moves the contact point{lever}. The "
            "velocities after the impact do not depend on that angle (Newton's law along the normal gives "
            f"{joint}'+ = -e {joint}'-); the normal impulse does")
    if wall:
        return Finding("contact.normal", (
            f"{head}: it is the wall's along its normal, {more:.3g} % larger (1/cos) than one along that "
            f"direction, the joint '{joint}' carrying the rest. Right for a frictionless wall oblique to the "
            f"path; if the contact is meant as the joint's own stop, write normal = {_fmt(want)} (in "
            f"'{c.a}''s frame)"), warning=True)
    return Finding("contact.normal", (
        f"{head}. Between the two moving links '{c.a}' and '{c.b}', joined only by '{joint}', a frictionless "
        f"contact is that joint's own stop and its impulse is read as the joint's: it would come out "
        f"{more:.3g} % too large (1/cos); write normal = {_fmt(want)} (in '{c.a}''s frame). A surface "
        "that is really oblique changes the motion only with friction (contact.friction)"))
