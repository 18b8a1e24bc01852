"""The event record: one dict per configuration transformation, as the summary writes it.

Its keys are declared once, by :class:`EventRecord` (a ``TypedDict``), and
filled in one place, :func:`event_dict`.  An impact's record is built from the
:class:`~pcmm.impulse.Impulse` alone (:func:`event_record`): the impulse solver
has already computed the mass matrix, the kinetic energies and the contact
kinematics, and nothing is computed twice.
"""
from __future__ import annotations

from typing import TypedDict

import math

from ..model.configuration import Configuration
from ..errors import SimulationError
from .contact import impact_kind
from .impulse import Impulse
from .momentum import external_impulses, momentum_record
from ..scene.spec import TransitionSpec


class ImpulseValues(TypedDict, total=False):
    normal: float  # N s, on b along the normal (a revolute joint stop with an arm: the force at the arm)
    vector: list  # world [Px, Py] (None for a revolute joint stop without an arm)
    joint: str  # joint stops: the joint
    moment: float  # revolute joint stops: N m s on the child
    arm: float  # revolute joint stops: the lever, m
    tangential: float  # frictional point contacts: N s, on b along the tangent t = (n_y, -n_x)


class BeforeAfter(TypedDict):
    before: float
    after: float


_EventCore = TypedDict("_EventCore", {
    "t": float,  # s
    "name": str,  # the transition's name
    "kind": str,  # "stable" (with the frame), "mobile" (between components) or "release"
    "transition": str,  # "latch", "stop", "pin" or "release"
    "from": str,  # configuration before
    "to": str,  # configuration after
    "restitution": "float | None",  # None: no impact
    "merge": bool,  # the bodies merged (a latch, or an accumulated stop)
    "impact": bool,  # an impulse acted (False in the runs without impact and at a release)
    "impulse": ImpulseValues,
    "normal": list,  # world unit normal, from a towards b
    "contact_point": list,  # world (x, y) of b's contact point
    "normal_velocity": BeforeAfter,  # m/s, n . (v_b - v_a); < 0 approaching
    "omega_before": dict,  # {link: rad/s}
    "omega_after": dict,
    "v_before": dict,  # {joint: velocity} (a planar joint: [vx, vy, w])
    "v_after": dict,
    "joint_impulses": dict,  # {joint: [fx, fy, mz]} on the child, world axes
    "kinetic_energy_before": float,  # J
    "kinetic_energy_after": float,
})


class EventRecord(_EventCore, total=False):
    """One event of ``Trajectory.events`` and of the summary's ``events``.

    Every event has the keys of the core; an impact solved by an impulse adds
    the cut joints' and constraints' impulses and the energy balance; a merge
    adds the velocities the locked joints drop; a collision resolved by a
    continuous contact law adds its end, duration and law.
    """

    cut_impulses: dict  # {metamorphic joint: [fx, fy, mz]} on the child, world axes
    constraint_impulses: dict  # {row label: impulse}: loop cut joints, drives ("J.drive")
    drive_work: float  # J, the drives' impulsive work
    energy_dissipated: float  # J, KE- + drive_work - KE+ >= 0
    dropped_velocities: dict  # {locked joint: velocity before the merge}
    changed_velocities: dict  # without impact: {kept joint: [rate before, rate after]} the target's constraints changed
    t_end: float  # contact laws: the instant the bodies separate
    duration: float
    law: str
    cause: str  # releases: what fired the release ("guard", ...)
    freed: dict  # releases: {freed joint: its value}
    velocity_jump_max: float  # releases: the largest change of a shared body's velocity (round-off)
    tangent: list  # frictional point contacts: world unit tangent t = (n_y, -n_x)
    friction: dict  # frictional point contacts: mu, law, phases, slip, impulse and energy lost to each part


def friction_record(imp: Impulse) -> dict:
    """The frictional part of an impact (:mod:`pcmm.events.friction`): Coulomb's mu ("stick" for no
    slip), the restitution law, Routh's phases, the slip (m/s along t) before and after, the normal
    and tangential impulses, and the energy lost to each (J, >= 0 for friction; the two sum to
    KE- - KE+)."""
    fr = imp.friction
    return {"mu": "stick" if math.isinf(fr.mu) else fr.mu, "law": fr.law, "phases": fr.phase_text,
            "impulse": {"normal": fr.P_n, "tangential": fr.P_t},
            "slip": {"before": fr.slip_before, "after": fr.slip_after},
            "energy_lost": {"normal": -fr.work_normal, "tangential": -fr.work_tangential}}


def by_link(cfg: Configuration, v):
    """{link: angular velocity} of ``v``."""
    return dict(zip(cfg.links, (cfg.A @ v).tolist()))


def event_dict(cfg: Configuration, tr: TransitionSpec, t, *, transition, to, restitution, merge, impact,
               P, normal, point, vn, v, ke, v_after_named=None, **extra) -> EventRecord:
    """One event of the summary (the schema lives here only): ``vn``, ``v`` and ``ke`` are
    (before, after) pairs, velocities in ``cfg``'s coordinates; ``extra`` adds keys."""
    v_before, v_after = v
    n_xy = [float(normal[0]), float(normal[1])]  # (a float's products are numpy's: the same bits)
    if tr.contact is not None and tr.contact.joint is not None:
        impulse = joint_stop_impulse(cfg, tr.contact, P, n_xy)
    elif "friction" in extra:  # a frictional point contact: P_n n + P_t t
        Pt, tangent = extra["friction"]["impulse"]["tangential"], extra["tangent"]
        impulse = {"normal": float(P), "tangential": float(Pt),
                   "vector": [float(P * c + Pt * s) + 0.0 for c, s in zip(normal[:2], tangent)]}
    else:
        P = float(P)
        impulse = {"normal": P, "vector": [P * n_xy[0] + 0.0, P * n_xy[1] + 0.0]}
    return {
        "t": float(t), "name": tr.name, "kind": impact_kind(cfg, tr.contact), "transition": transition,
        "from": cfg.name, "to": to, "restitution": restitution, "merge": merge, "impact": impact,
        "impulse": impulse,
        "normal": n_xy, "contact_point": [float(point[0]), float(point[1])],
        "normal_velocity": {"before": float(vn[0]), "after": float(vn[1])},
        "omega_before": by_link(cfg, v_before), "omega_after": by_link(cfg, v_after),
        "v_before": cfg.by_joint(v_before),
        "v_after": cfg.by_joint(v_after) if v_after_named is None else v_after_named,
        "joint_impulses": {}, "kinetic_energy_before": float(ke[0]), "kinetic_energy_after": float(ke[1]),
        "kinetic_energy_change": float(ke[1] - ke[0]),
        **extra,
    }


def joint_stop_impulse(cfg: Configuration, contact, P, normal) -> dict:
    """A joint stop's impulse: the moment (revolute, N m s) or axial force (prismatic, N s) on
    the child, and for a revolute stop with an ``arm`` the force at that lever (N s), which
    is what a point contact at the arm would report."""
    if cfg.spec.info.joints[contact.joint].type == "prismatic":
        return {"normal": float(P), "vector": [float(P * c) + 0.0 for c in normal[:2]], "joint": contact.joint}
    at_arm = P / contact.arm if contact.arm else None
    normal_P = float(P if at_arm is None else at_arm)
    return {"joint": contact.joint, "moment": float(P), "arm": contact.arm, "normal": normal_P,
            "vector": None if at_arm is None else [normal_P * float(normal[0]) + 0.0, normal_P * float(normal[1]) + 0.0]}


def event_record(cfg: Configuration, tr: TransitionSpec, t, target: str, merge: bool, imp: Impulse,
                 transition_type: str | None = None, q=None) -> EventRecord:
    """The event of a transformation, from its :class:`~pcmm.impulse.Impulse` (solved, or the
    switch without impact of :func:`~pcmm.impulse.no_impulse`) and, for the momenta about the
    scene's point and the frame's impulses (:mod:`pcmm.momentum`), the posture ``q``."""
    common = dict(transition=transition_type or tr.type, to=target, merge=merge, point=imp.point,
                  v=(imp.v_before, imp.v_after), ke=(imp.ke_before, imp.ke_after), restitution=imp.restitution,
                  impact=imp.impact, P=imp.P, normal=imp.normal, vn=(imp.vn_before, imp.vn_after))
    if q is not None:
        common["momentum"] = momentum_record(cfg, q, imp.v_before, imp.v_after, imp.momenta)
    if not imp.impact:
        record = event_dict(cfg, tr, t, **common)
        ke0, ke1 = imp.ke_before, imp.ke_after
        if ke1 - ke0 > 1e-12 * max(1.0, ke0):  # a switch without impulse can only drop velocities
            record["warnings"] = [f"t = {t:.9g} s, transition '{tr.name}' without impact raises the kinetic "
                                  f"energy by {ke1 - ke0:.3g} J ({ke0:.6g} -> {ke1:.6g} J): the velocities "
                                  f"kept do not fit '{target}', which projects them onto its constraints"]
        return record
    check_energy(tr, t, (imp.ke_before, imp.ke_after), imp.drive_work)
    extra = {} if q is None else {"external_impulses": external_impulses(cfg, tr, imp, q)}
    if imp.friction is not None:
        extra["tangent"] = [float(imp.tangent[0]), float(imp.tangent[1])]
        extra["friction"] = friction_record(imp)
    return event_dict(cfg, tr, t, **common, joint_impulses=imp.joint_impulses, cut_impulses=imp.cut_impulses,
                      constraint_impulses=imp.constraint_impulses, drive_work=imp.drive_work,
                      energy_dissipated=imp.energy_dissipated, **extra)


def check_energy(tr: TransitionSpec, t, ke, drive_work) -> None:
    """An impact never creates energy: KE- + drive work - KE+ >= 0 (to round-off).  When it
    comes out clearly negative, or not finite, the numbers of the model are beyond what
    floating point resolves (an inertia of 1e300 next to one of 1) and the result is refused."""
    dissipated = ke[0] + drive_work - ke[1]
    scale = max(abs(ke[0]), abs(ke[1]), abs(drive_work), 1e-300)
    if math.isfinite(dissipated) and dissipated >= -1e-6 * scale:
        return
    raise SimulationError(
        f"t = {t:.9g} s, transition '{tr.name}': the impact would create energy (kinetic energy "
        f"{ke[0]:.6g} -> {ke[1]:.6g} J, drive work {drive_work:.6g} J): the masses and inertias span more "
        "than floating point resolves, or are absurd; check the URDFs' <mass> and <inertia> values")
