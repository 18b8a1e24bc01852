"""Momenta and external impulses at an event: the impulse-momentum balance a researcher publishes.

At an impact the only external impulses on the moving bodies come from the frame: through the
joints whose parent is the frame (``joint_impulses``, moment about the joint centre), through loop
cut joints with the frame on one side (``constraint_impulses``), and through a stable contact
(the contact impulse).  Gravity and springs carry no impulse.  So, with ``L`` the linear and ``H_O``
the angular momentum about a point O,

    L+ - L- = sum F_k,      H_O+ - H_O- = sum ((r_k - O) x F_k + m_k)

over the external impulses ``[F_k, m_k]`` applied at ``r_k``.  Each event of the summary reports
``momentum`` (before/after, about ``momentum.about``: the scene's ``momentum_point``, default the
first pivot on the frame; ``"contact"``: the event's own contact point) and ``external_impulses``
so the balance can be checked from the JSON.

**Where it is conserved.**  With O the struck point of a ``pin`` whose only impulse from the frame
is the struck point's own (the mechanism floats: every joint on the frame is planar and undriven;
the target holds no other point to the frame; the released contacts take none), the sum above is
zero about O: H_O+ = H_O- (a walker's heel strike, the rocking block, the rimless wheel; for a
single body, I_cm w + m (c - O) x v_c).  :func:`check_struck_point_momentum` asserts it at each
such strike.  About any other fixed point the frame's impulse at O has a moment, so the block
shows a change there that is no conservation failure.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..errors import SimulationError
from ..model.configuration import Configuration
from ..scene.spec import TransitionSpec

CONTACT = "contact"  # [scene] momentum_point = "contact": each event's momenta about its contact point
#: |H_O+ - H_O-| allowed at a strike that must conserve it, relative to the momenta's scale
CONSERVATION_TOL = 1e-9


def frame_pivot(cfg: Configuration) -> np.ndarray:
    """The first revolute joint on the frame (model order): where it sits; the origin if none."""
    for jid in range(1, cfg.model.njoints):
        name = cfg.model.names[jid]
        if cfg.model.parents[jid] == 0 and cfg.spec.info.joints[name].type == "revolute":
            return np.asarray(cfg.model.jointPlacements[jid].translation[:2], float).copy()
    return np.zeros(2)


def about_point(cfg: Configuration, contact_point=None) -> np.ndarray:
    """The point an event's angular momentum is taken about: the scene's ``momentum_point``
    ([x, y]; ``"contact"``: the event's ``contact_point``, where its record reports the contact),
    by default the first pivot on the frame (:func:`frame_pivot`)."""
    p = cfg.scene.momentum_point
    if p == CONTACT:  # (the loader refuses any other string)
        if contact_point is None:
            raise ValueError("momentum_point = \"contact\" needs the event's contact point")
        return np.asarray(contact_point, float)[:2].copy()
    if p is not None:
        return np.asarray(p, float)
    kept = cfg.impulse_models  # the configuration's event-path constants: its frame pivot, read once
    if "frame_pivot" not in kept:
        kept["frame_pivot"] = frame_pivot(cfg)
    return kept["frame_pivot"].copy()


def momenta(cfg: Configuration, q, v, about) -> tuple[np.ndarray, float]:
    """(linear momentum [px, py] in kg m/s, angular momentum about ``about`` in kg m^2/s) of the
    moving bodies (those welded to the frame do not move)."""
    if cfg.nv == 0:
        return np.zeros(2), 0.0
    model, data = cfg.model, cfg.data
    kept = cfg.impulse_models  # the bodies' inertias, read from the model once
    inertias = kept.get("inertias")
    if inertias is None:
        inertias = kept["inertias"] = list(model.inertias)
    pin.forwardKinematics(model, data, cfg.to_pin(q), v)
    total = pin.Force.Zero()
    oMi, vel = data.oMi, data.v
    for jid in range(1, model.njoints):  # body momenta, moved to the world origin
        total += oMi[jid].act(inertias[jid] * vel[jid])
    return _about(np.asarray(total.linear[:2], float).copy(), float(total.angular[2]), about)


def _about(L: np.ndarray, H0: float, about) -> tuple[np.ndarray, float]:
    """(L, H about ``about``) from the linear momentum and the angular momentum about the origin."""
    o = np.asarray(about, float)
    return L, H0 - float(o[0] * L[1] - o[1] * L[0])


def external_impulses(cfg: Configuration, tr: TransitionSpec, imp, q) -> dict[str, dict]:
    """The frame's impulses on the moving bodies at an impact: ``{name: {"point": [x, y],
    "impulse": [fx, fy, mz]}}`` (world axes, moment about the point)."""
    out = {}
    cfg.kinematics(q)
    root = cfg.root
    for jid in range(1, cfg.model.njoints):
        if cfg.model.parents[jid] == 0:
            name = cfg.model.names[jid]
            out[f"joint {name}"] = {"point": [float(x) for x in cfg.data.oMi[jid].translation[:2]],
                                    "impulse": list(imp.joint_impulses[name])}
    if getattr(cfg.coords, "constrained", False):
        for s, fb in zip(cfg.coords.closure.specs, cfg.coords.closure.frames_b):
            if root not in (s.a, s.b):
                continue
            F = np.asarray(imp.constraint_impulses[s.name], float)  # on b, at point_b
            point = cfg.data.oMf[fb].translation[:2]
            out[f"cut joint {s.name}"] = {"point": [float(x) for x in point],
                                          "impulse": [float(x) for x in (F if s.b != root else -F)]}
    for (link, point, F, mz), (other, *_) in zip(imp.contact_impulses, imp.contact_impulses[::-1]):
        if other == root and link != root:  # the contact (or joint stop) impulse the frame applies
            out["contact"] = {"point": [float(x) for x in point], "impulse": [float(F[0]), float(F[1]), float(mz)]}
    return out


def momentum_record(cfg: Configuration, q, v_before, v_after, at_origin: tuple | None = None,
                    contact_point=None) -> dict:
    """The momenta before and after about the scene's point (:func:`about_point`; ``contact_point``:
    the event's, for ``momentum_point = "contact"``); ``at_origin``: (Lx, Ly, H0) before and after
    about the world origin, where the impulse solve computed them (:func:`momenta`'s operations),
    moved to the point here."""
    o = about_point(cfg, contact_point)
    if at_origin is None:
        Lb, Hb = momenta(cfg, q, v_before, o)
        La, Ha = momenta(cfg, q, v_after, o)
    else:
        Lb, Hb = _about(np.array(at_origin[:2]), at_origin[2], o)
        La, Ha = _about(np.array(at_origin[3:5]), at_origin[5], o)
    return {"about": [float(o[0]), float(o[1])], "linear_before": [float(x) for x in Lb],
            "linear_after": [float(x) for x in La], "angular_before": Hb, "angular_after": Ha}


def balance(event: dict) -> tuple[np.ndarray, float]:
    """Residual of the impulse-momentum balance of a summary event: (linear [2], angular)."""
    m = event["momentum"]
    o = np.asarray(m["about"])
    F = np.zeros(2)
    M = 0.0
    for ext in event["external_impulses"].values():
        f = np.asarray(ext["impulse"], float)
        r = np.asarray(ext["point"], float) - o
        F += f[:2]
        M += float(r[0] * f[1] - r[1] * f[0]) + f[2]
    dL = np.asarray(m["linear_after"]) - np.asarray(m["linear_before"])
    return dL - F, (m["angular_after"] - m["angular_before"]) - M


def struck_point_only(cfg: Configuration, dst: Configuration, struck: str) -> str | None:
    """Why the frame's impulses at a pin strike of ``cfg`` into ``dst`` (its new cut joint ``struck``)
    may have a moment about the struck point (None: the struck point takes the only one, so the
    angular momentum about it is conserved).  Decided from the structure alone: a joint on the frame
    other than a planar one (a pivot, a slider) or a planar one with a drive, or another cut joint of
    ``dst`` to the frame (a foot held through the strike), can take an impulse.  The source's contacts
    that ``dst`` drops are released by the strike with no impulse (pcmm.events.pins)."""
    model, root = cfg.model, cfg.root
    driven = {lab[:-len(".drive")] for lab in getattr(dst.coords, "labels", ()) if lab.endswith(".drive")}
    for jid in range(1, model.njoints):
        if model.parents[jid] != 0:
            continue
        name = model.names[jid]
        kind = cfg.spec.info.joints[name].type
        if kind != "planar":
            return f"the {kind} joint '{name}' holds the mechanism to the frame"
        if name in driven:
            return f"the planar joint '{name}' on the frame is driven"
    for s in dst.spec.cut_joints:
        if s.name != struck and root in (s.a, s.b):
            return f"the cut joint '{s.name}' holds a point to the frame through the strike"
    return None


def check_struck_point_momentum(cfg: Configuration, tr: TransitionSpec, t, q, v_before, v_after, point) -> tuple:
    """At a pin whose struck point takes the only impulse from the frame (:func:`struck_point_only`),
    the angular momentum about that point is conserved: returns (H_O-, H_O+), or raises where they
    differ by more than :data:`CONSERVATION_TOL` of the momenta's scale (max of |H_O-|, |H_O+| and
    |L| times the distance from O to the centre of mass), which only a wrong impulse solve gives."""
    o = np.asarray(point, float)[:2]
    Lb, Hb = momenta(cfg, q, v_before, o)
    La, Ha = momenta(cfg, q, v_after, o)
    com = pin.centerOfMass(cfg.model, cfg.data, cfg.to_pin(q))[:2]
    reach = float(np.hypot(*(com - o)))
    scale = max(abs(Hb), abs(Ha), reach * float(np.hypot(*Lb)), reach * float(np.hypot(*La)), 1e-300)
    if not abs(Ha - Hb) <= CONSERVATION_TOL * scale:
        raise SimulationError(
            f"t = {t:.9g} s, transition '{tr.name}': the angular momentum about the struck point "
            f"({o[0]:.6g}, {o[1]:.6g}) goes from {Hb:.12g} to {Ha:.12g} kg m^2/s, but the struck point takes the "
            "only impulse from the frame, so it must be conserved: the impulse solve is wrong here (a defect of "
            "pcmm: please report it with the scene)")
    return Hb, Ha
