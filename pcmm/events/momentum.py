"""Momenta and external impulses at an event: the impulse-momentum balance a researcher publishes.

At an impact the only external impulses on the moving bodies come from the frame: through the
joints whose parent is the frame (``joint_impulses``, moment about the joint centre), through loop
cut joints with the frame on one side (``constraint_impulses``), and through a stable contact
(the contact impulse).  Gravity and springs carry no impulse.  So, with ``L`` the linear and ``H_O``
the angular momentum about a point O,

    L+ - L- = sum F_k,      H_O+ - H_O- = sum ((r_k - O) x F_k + m_k)

over the external impulses ``[F_k, m_k]`` applied at ``r_k``.  Each event of the summary reports
``momentum`` (before/after, about ``momentum.about``: the scene's ``momentum_point``, default the
first pivot on the frame) and ``external_impulses`` so the balance can be checked from the JSON.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..model.configuration import Configuration
from ..scene.spec import TransitionSpec


def frame_pivot(cfg: Configuration) -> np.ndarray:
    """The first revolute joint on the frame (model order): where it sits; the origin if none."""
    for jid in range(1, cfg.model.njoints):
        name = cfg.model.names[jid]
        if cfg.model.parents[jid] == 0 and cfg.spec.info.joints[name].type == "revolute":
            return np.asarray(cfg.model.jointPlacements[jid].translation[:2], float).copy()
    return np.zeros(2)


def about_point(cfg: Configuration) -> np.ndarray:
    p = cfg.scene.momentum_point
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


def momentum_record(cfg: Configuration, q, v_before, v_after, at_origin: tuple | None = None) -> dict:
    """The momenta before and after about the scene's point; ``at_origin``: (Lx, Ly, H0) before and
    after about the world origin, where the impulse solve computed them (:func:`momenta`'s
    operations), moved to the point here."""
    o = about_point(cfg)
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
