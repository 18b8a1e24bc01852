"""Contact kinematics: the two points that strike, their gap, normal speed and normal row.

A contact (:class:`~pcmm.spec.ContactSpec`) names a point on link a and one on
link b, and a normal fixed in a's frame pointing from a towards b.  Everything
here is a pure function of a configuration and its state; guards (the gap
guard), impulses (the normal row J_n of Eqs. 21, 29), continuous contact laws
and the run loop all read the contact through this module.

* :func:`contact_state`: (n, gap, vn, J_n) at (q, v);
* :func:`gap_rate`: the gap's exact time derivative (n turns with link a);
* :func:`contact_row`: J_n and the bias of ``d/dt (J_n v)`` (a holding force);
* :func:`contact_point`: where b's point is (the event's contact point);
* :func:`joint_stop_row`: a joint stop's normal and row (the joint's own coordinate);
* :func:`impact_kind`: stable (with the frame) or mobile (paper section 3).
"""
from __future__ import annotations

import threading
import weakref

import numpy as np
import pinocchio as pin

from ..model import compiled
from ..model.configuration import Configuration
from ..model.pinocchio_helpers import LWA, frame_jacobian
from ..scene.spec import ContactSpec


def normal_row(cfg: Configuration, contact: ContactSpec):
    """(points a and b, world normal n from a to b, J_n = n^T (J_b - J_a)); kinematics must be
    computed on the configuration's data."""
    pa, pb = cfg.point(contact.a, contact.point_a), cfg.point(contact.b, contact.point_b)
    n = cfg.rotation(contact.a) @ np.asarray(contact.normal, dtype=float)
    n /= np.linalg.norm(n)
    return pa, pb, n, n @ (cfg.point_jacobian(pb) - cfg.point_jacobian(pa))


def joint_stop_row(cfg: Configuration, model, data, contact: ContactSpec):
    """(n, J_n) of a joint stop on ``model``/``data``: the tree or its cut system, whose link
    frames keep their indices; kinematics and Jacobians must be computed on ``data``.

    ``J_n v = -s q'`` (s = ``contact.stop_sign``), negative while the joint moves towards the
    stop.  Revolute: q' = w_child - w_parent, from the links' angular rows.  Prismatic:
    q' = axis . (v_child - v_parent - w_parent z x r), r from the parent's origin to the
    child's.  ``n`` is where the impulse pushes the child: against the motion of its point
    on its x axis (revolute), or along the axis (prismatic)."""
    uj = cfg.spec.info.joints[contact.joint]
    fa, fb = cfg.link_frame[contact.a], cfg.link_frame[contact.b]
    Ja, Jb = frame_jacobian(model, data, fa), frame_jacobian(model, data, fb)
    s = contact.stop_sign
    Rb = data.oMf[fb].rotation
    if uj.type != "prismatic":
        return -s * Rb[:2, 1].copy(), -s * (Jb[5] - Ja[5])
    axis = Rb @ np.asarray(uj.axis, dtype=float)
    axis = axis[:2] / np.linalg.norm(axis[:2])
    r = data.oMf[fb].translation[:2] - data.oMf[fa].translation[:2]
    rel = Jb[:2] - Ja[:2] - np.outer([-r[1], r[0]], Ja[5])
    return -s * axis, -s * (axis @ rel)


def contact_state(cfg: Configuration, q, v, contact: ContactSpec):
    """(normal, gap, vn, J_n) at (q, v): n in world from a to b, gap = n . (p_b - p_a); for a
    joint stop the gap is -s (q_j - stop value) and J_n the joint's own row, -s e_j."""
    cfg.kinematics(q, v)
    if contact.joint is not None:
        n, _ = joint_stop_row(cfg, cfg.model, cfg.data, contact)
        j = cfg.joint_slice[contact.joint].start
        Jn = np.zeros(cfg.nv)
        Jn[j] = -contact.stop_sign
        return n, float(-contact.stop_sign * (q[j] - contact.stop_value)), float(Jn @ v), Jn
    pa, pb, n, Jn = normal_row(cfg, contact)
    gap = float(n @ (cfg.point_position(pb) - cfg.point_position(pa)))
    return n, gap, float(Jn @ v), Jn


def normal_speed(cfg: Configuration, q, v, contact: ContactSpec) -> float:
    """``vn`` of :func:`contact_state` alone: for a joint stop the joint's own row times v
    (the same product, without the kinematics pass the normal needs); a tree's point contact by
    its compiled evaluation (:func:`compiled_contact`); else from the state."""
    if contact.joint is not None:
        Jn = np.zeros(cfg.nv)
        Jn[cfg.joint_slice[contact.joint].start] = -contact.stop_sign
        return float(Jn @ v)
    desc = compiled_contact(cfg, contact)
    if desc is not None:
        return compiled.normal_speed(desc, np.concatenate((q, v)))
    return contact_state(cfg, q, v, contact)[2]


#: whether a tree's point contact is evaluated in C++ (pcmm/model/_guard_eval.hpp): its gap guard (which
#: the compiled segment loop then scans and the compiled locator locates, pcmm.events.guards) and its
#: normal speed; off, they run through Pinocchio's Python binding (the reference the tests compare with)
COMPILED_CONTACTS = True


class _Described(threading.local):
    """This thread's compiled descriptions (each holds a compiled tree whose Data is this thread's
    scratch space): ``{configuration: {(contact, value): description or None}}``."""

    def __init__(self):
        self.by_cfg = weakref.WeakKeyDictionary()


_DESCRIBED = _Described()


def compiled_contact(cfg: Configuration, contact: ContactSpec, value: float = 0.0):
    """The compiled description of the gap guard ``gap - value`` of ``contact`` (pcmm/model/_guard_eval.hpp,
    :func:`pcmm.model.compiled.gap_guard`) where the configuration is a tree whose state is ``[q, v]`` (no
    loop, drive or planar joint) and the contact is between two points (not a joint stop), checked against
    :func:`contact_state`, :func:`gap_rate` and the normal speed at probe states; else None (Python runs)."""
    if not COMPILED_CONTACTS or contact.joint is not None or not compiled.enabled():
        return None
    by_cfg = _DESCRIBED.by_cfg
    known = by_cfg.get(cfg)
    if known is None:
        known = by_cfg[cfg] = {}
    key = (contact, value)
    if key in known:
        return known[key]
    desc = None
    if not cfg.coords.constrained and not cfg.has_planar:
        unpack = cfg.coords.unpack

        def reference(t, y):
            q, v = unpack(t, y)
            _, gap, vn, _ = contact_state(cfg, q, v, contact)
            return gap - value, gap_rate(cfg, q, v, contact), vn
        pa, pb = cfg.point(contact.a, contact.point_a), cfg.point(contact.b, contact.point_b)
        desc = compiled.gap_guard(cfg.model, pa.frame_id, pb.frame_id, cfg.link_frame[contact.a], contact.normal,
                                  value, reference)
    known[key] = desc
    return desc


def gap_rate(cfg: Configuration, q, v, contact: ContactSpec) -> float:
    """d/dt of the gap n . (p_b - p_a) at (q, v): the points' normal relative velocity plus
    the turn of the normal with link a, n' = w_a z x n (n is fixed in a)."""
    if contact.joint is not None:
        return -contact.stop_sign * float(v[cfg.joint_slice[contact.joint].start])
    cfg.kinematics(q, v)
    pa, pb, n, Jn = normal_row(cfg, contact)
    w_a = pin.getFrameVelocity(cfg.model, cfg.data, cfg.link_frame[contact.a], LWA).angular[2]
    r = cfg.point_position(pb) - cfg.point_position(pa)
    return float(Jn @ v + w_a * (n[0] * r[1] - n[1] * r[0]))


def contact_row(cfg: Configuration, q, v, contact: ContactSpec):
    """(J_n, bias) of the contact's normal row: ``d/dt (J_n v) = J_n a + bias``."""
    if contact.joint is not None:  # the joint's own coordinate row: constant
        Jn = np.zeros(cfg.nv)
        Jn[cfg.joint_slice[contact.joint].start] = -contact.stop_sign
        return Jn, 0.0
    qp = cfg.to_pin(q)
    pin.forwardKinematics(cfg.model, cfg.data, qp, v, np.zeros(cfg.nv))
    pin.computeJointJacobians(cfg.model, cfg.data, qp)
    pin.updateFramePlacements(cfg.model, cfg.data)
    pa, pb, n, Jn = normal_row(cfg, contact)
    acc = (pin.getFrameClassicalAcceleration(cfg.model, cfg.data, pb.frame_id, LWA).linear[:2]
           - pin.getFrameClassicalAcceleration(cfg.model, cfg.data, pa.frame_id, LWA).linear[:2])
    w_a = pin.getFrameVelocity(cfg.model, cfg.data, cfg.link_frame[contact.a], LWA).angular[2]
    vrel = (pin.getFrameVelocity(cfg.model, cfg.data, pb.frame_id, LWA).linear[:2]
            - pin.getFrameVelocity(cfg.model, cfg.data, pa.frame_id, LWA).linear[:2])
    ndot = w_a * np.array([-n[1], n[0]])
    return Jn, float(n @ acc + ndot @ vrel)


def contact_point(cfg: Configuration, contact: ContactSpec) -> np.ndarray:
    """Where the contact is reported (world): point b, or for a joint stop the child's point
    at ``arm`` along its x axis (its origin without an arm); needs kinematics first."""
    if contact.joint is None:
        return cfg.point_position(cfg.point(contact.b, contact.point_b))
    M = cfg.data.oMf[cfg.link_frame[contact.b]]
    return M.translation[:2] + (contact.arm or 0.0) * M.rotation[:2, 0]


def impact_kind(cfg: Configuration, contact: ContactSpec) -> str:
    """``"stable"`` when the contact involves the frame (the URDF's root link), else ``"mobile"``."""
    return "stable" if cfg.root in (contact.a, contact.b) else "mobile"
