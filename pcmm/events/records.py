"""The event record: one dict per configuration transformation, as the summary writes it.

Its keys are declared once, by :class:`EventRecord` (a ``TypedDict``), and
filled in one place, :func:`event_dict`.  An impact's record is built from the
:class:`~pcmm.impulse.Impulse` alone (:func:`event_record`): the impulse solver
has already computed the mass matrix, the kinetic energies and the contact
kinematics, and nothing is computed twice.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import TypedDict

import math

import numpy as np

from ..model import compiled
from ..model.configuration import Configuration
from ..errors import SimulationError
from .contact import impact_kind
from .impulse import Impulse
from .momentum import CONTACT, about_point, external_impulses, momentum_record
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
    and tangential impulses, and the energy lost to each: Routh's per-phase works (J, >= 0 for
    friction; the two sum to KE- - KE+), for "stick" those of its limit mu -> infinity
    (:func:`pcmm.events.friction.stuck_at_once`).  Where that limit does not end at the impulse taken,
    ``energy_lost`` is None and ``energy_split`` says why (as for a pin, :func:`pcmm.events.pins.strike_works`)."""
    fr = imp.friction
    record = {"mu": "stick" if math.isinf(fr.mu) else fr.mu, "law": fr.law, "phases": fr.phase_text,
              "impulse": {"normal": fr.P_n, "tangential": fr.P_t},
              "slip": {"before": fr.slip_before, "after": fr.slip_after}}
    if fr.no_split is not None:
        return {**record, "energy_lost": None, "energy_split": f"none: {fr.no_split}"}
    return {**record, "energy_lost": {"normal": -fr.work_normal, "tangential": -fr.work_tangential}}


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
        common["momentum"] = momentum_record(cfg, q, imp.v_before, imp.v_after, imp.momenta, imp.point)
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


# ---- a bounce's record as its numbers ------------------------------------------------------------
def record_numbers(record) -> list:
    """Every number of ``record`` (a float or an int, not a flag), depth first in its keys' and
    items' order: the order in which a run's event log keeps them (:mod:`pcmm.results.event_log`)."""
    out: list = []

    def walk(x):
        kind = type(x)
        if kind is dict:
            for y in x.values():
                walk(y)
        elif kind is list or kind is tuple:
            for y in x:
                walk(y)
        elif kind is float or kind is int or isinstance(x, (float, np.floating)):
            out.append(x)
    walk(record)
    return out


def _filled(template, numbers: list, pos: list):
    """``template`` with its numbers replaced, in :func:`record_numbers`' order, by ``numbers``
    from ``pos[0]`` on (each number keeping its template's type: float or int)."""
    kind = type(template)
    if kind is dict:
        return {k: _filled(y, numbers, pos) for k, y in template.items()}
    if kind is list or kind is tuple:
        items = [_filled(y, numbers, pos) for y in template]
        return items if kind is list else tuple(items)
    if kind is float or kind is int or isinstance(template, (float, np.floating)):
        x = numbers[pos[0]]
        pos[0] += 1
        return int(x) if kind is int else float(x)
    return template


class RecordPlan:
    """What every bounce at one stop of one configuration shares in its event record: the keys, the
    texts, the flags and the None (``template``: the first bounce's record, built and checked the
    general way), where the top-level values sit among the numbers, and the constants of its numbers:
    the stop's kind (``"prismatic"``, ``"revolute"``, ``"point"``), the point the momenta are taken
    about, the root joints with their (fixed) points, which contact impulse the frame applies."""

    __slots__ = ("cfg", "tr", "template", "top", "consts", "why", "stop", "about", "roots", "root_rows", "frame_contact",
                 "bounce", "bounce_why")

    def __init__(self, cfg: Configuration, tr, template: dict):
        self.cfg, self.tr, self.template, self.why = cfg, tr, template, None
        self.top: dict = {}  # top-level float: its position among the numbers
        self.consts: dict = {}  # top-level text, flag or None: itself
        at = 0
        for key, value in template.items():
            n = len(record_numbers([value]))
            if isinstance(value, float):
                self.top[key] = at
            elif n == 0 and type(value) is not dict and type(value) is not list:
                self.consts[key] = value
            at += n
        joint = tr.contact.joint
        self.stop = "point" if joint is None else cfg.spec.info.joints[joint].type == "prismatic" and "prismatic" \
            or "revolute"
        o = None if cfg.scene.momentum_point == CONTACT else about_point(cfg)  # "contact": per bounce
        self.about = None if o is None else (o[0], o[1])  # (numpy floats: momentum_record's operations on them)
        self.roots: list = []  # [(joint, [x, y])] of the joints on the frame (external_impulses')
        self.root_rows = None  # their rows in a compiled solve's joint array (ArrayImpulse.arrays)
        self.frame_contact = None  # the contact impulse on b (0) or on a (1) the frame applies, if any
        self.bounce = None  # the compiled bounce (:func:`compiled_bounce`), once checked against the Python route
        self.bounce_why = None  # why the bounces take the Python route (None: not asked yet, or compiled)
        if cfg.root == tr.contact.a and cfg.root != tr.contact.b:
            self.frame_contact = 0
        elif cfg.root == tr.contact.b and cfg.root != tr.contact.a:
            self.frame_contact = 1


class BounceRecord(Mapping):
    """A bounce's event record (:class:`EventRecord`) kept as its numbers over its plan's template:
    a read-only mapping with the record's keys and values.  A top-level key reads its number (or its
    template's constant) directly; any other builds the whole record once.  A run's event log appends
    it as its numbers (``log_row``), without the dict."""

    __slots__ = ("plan", "numbers", "_record")

    def __init__(self, plan: RecordPlan, numbers: list):
        self.plan, self.numbers, self._record = plan, numbers, None

    def log_row(self):
        """(template, numbers): the record's layout, by a record of it, and its numbers in order."""
        return self.plan.template, self.numbers

    def record(self) -> dict:
        if self._record is None:
            self._record = _filled(self.plan.template, self.numbers, [0])
        return self._record

    def __getitem__(self, key):
        plan = self.plan
        at = plan.top.get(key)
        if at is not None:
            return float(self.numbers[at])
        if key in plan.consts:
            return plan.consts[key]
        return self.record()[key]  # KeyError for a key the record lacks

    def get(self, key, default=None):
        plan = self.plan  # (__getitem__'s reads, in one call: the run asks a bounce's record several times)
        at = plan.top.get(key)
        if at is not None:
            return float(self.numbers[at])
        if key in plan.consts:
            return plan.consts[key]
        return self.record()[key] if key in plan.template else default

    def __contains__(self, key) -> bool:
        return key in self.plan.template

    def __iter__(self):
        return iter(self.plan.template)

    def __len__(self) -> int:
        return len(self.plan.template)

    def __repr__(self) -> str:
        return repr(self.record())


#: why a stop's bounces take the general record: {(configuration, transition): reason}
BOUNCE_RECORD_REFUSED: dict = {}


def bounce_record(cfg: Configuration, tr: TransitionSpec, t, imp: Impulse, q):
    """The record of a bounce (``event_record(cfg, tr, t, cfg.name, False, imp, q=q)``) as its
    numbers, formed from the impulse's arrays without the record's dicts: the same numbers, to the
    bit, in the order the record holds them.  Taken where the impulse was solved compiled (its momenta
    at hand), without friction, in a configuration without planar joints or loops whose root joints
    are revolute; checked at the stop's first bounce against the general record (the plan is refused
    for good, and the general record kept, where any number differs).  Elsewhere the general record."""
    key = (cfg.name, tr.name)
    plans = cfg.impulse_models.setdefault("bounce_records", {})
    plan = plans.get(key)
    if plan is not None and plan.tr is tr and plan.cfg is cfg:
        if plan.why is None:
            check_energy(tr, t, (imp.ke_before, imp.ke_after), imp.drive_work)
            return BounceRecord(plan, _bounce_numbers(plan, cfg, tr, t, imp))
        return event_record(cfg, tr, t, cfg.name, False, imp, q=q)
    record = event_record(cfg, tr, t, cfg.name, False, imp, q=q)
    plan = plans[key] = RecordPlan(cfg, tr, record)
    plan.why = _unplanned(cfg, imp, record)
    if plan.why is None:
        model = cfg.model
        names = [model.names[jid] for jid in range(1, model.njoints) if model.parents[jid] == 0]
        plan.roots = [(name, record["external_impulses"][f"joint {name}"]["point"]) for name in names]
        solved = getattr(imp, "solved", None)  # a compiled solve's: the roots' rows in its joint array
        if solved is not None:
            plan.root_rows = tuple(solved[0].joint_names.index(name) for name in names)
        got, want = _bounce_numbers(plan, cfg, tr, t, imp), record_numbers(record)
        if len(got) != len(want) or any(_bits(a) != _bits(b) for a, b in zip(got, want)):
            plan.why = "its numbers differ from the general record's"
    if plan.why is not None:
        BOUNCE_RECORD_REFUSED[key] = plan.why
    return record


def _bits(x) -> tuple:
    return (type(x) is int, np.float64(x).tobytes())


def _unplanned(cfg: Configuration, imp: Impulse, record: dict) -> str | None:
    """Why a bounce's record cannot be formed from its impulse's arrays (None: it can)."""
    if imp.momenta is None:
        return "the impulse was not solved compiled (no momenta at hand)"
    if imp.friction is not None:
        return "a frictional contact"
    if cfg.scene.momentum_point == CONTACT:
        return 'the momenta are taken about each bounce\'s contact point (momentum_point = "contact")'
    if cfg._planar or len(cfg.joint_names) != cfg.nv:
        return "a planar joint"
    if getattr(cfg.coords, "constrained", False) and cfg.coords.closure.specs:
        return "a closed loop"
    model = cfg.model
    for jid in range(1, model.njoints):
        if model.parents[jid] == 0 and cfg.spec.info.joints[model.names[jid]].type not in ("revolute", "continuous"):
            return f"root joint '{model.names[jid]}' is not revolute (its position moves with q)"
    if set(record) - set(EventRecord.__annotations__) - {"momentum", "external_impulses", "kinetic_energy_change"}:
        return "a record with keys of its own"
    return None


def _bounce_numbers(plan: RecordPlan, cfg: Configuration, tr: TransitionSpec, t, imp: Impulse) -> list:
    """The numbers of :func:`event_record`'s record of a bounce, in its order, by the same operations
    (:func:`event_dict`, :func:`joint_stop_impulse`, :func:`momentum_record`,
    :func:`pcmm.events.momentum.external_impulses`)."""
    P, normal = imp.P, imp.normal
    n0, n1 = float(normal[0]), float(normal[1])
    out = [float(t), imp.restitution]
    stop = plan.stop
    if stop == "revolute":  # joint_stop_impulse
        arm = tr.contact.arm
        at_arm = P / arm if arm else None
        normal_P = float(P if at_arm is None else at_arm)
        out.append(float(P))
        if arm is not None:
            out.append(arm)
        out.append(normal_P)
        if at_arm is not None:
            out += [normal_P * n0 + 0.0, normal_P * n1 + 0.0]
    elif stop == "prismatic":
        out += [float(P), float(P * n0) + 0.0, float(P * n1) + 0.0]
    else:
        P = float(P)
        out += [P, P * n0 + 0.0, P * n1 + 0.0]
    point, A = imp.point, cfg.A
    v_before, v_after = imp.v_before, imp.v_after
    out += [n0, n1, float(point[0]), float(point[1]), float(imp.vn_before), float(imp.vn_after)]
    out += (A @ v_before).tolist()
    out += (A @ v_after).tolist()
    out += np.asarray(v_before, float).tolist()
    out += np.asarray(v_after, float).tolist()
    arrays = getattr(imp, "arrays", None)  # a compiled solve's (ArrayImpulse): its dicts' numbers, in their order
    if arrays is not None:
        rows = arrays[2].tolist()  # [fx, fy, mz] per joint
        for x in rows:
            out += x
    else:
        joints = imp.joint_impulses
        for x in joints.values():
            out += x
    ke0, ke1 = imp.ke_before, imp.ke_after
    out += [float(ke0), float(ke1), float(ke1 - ke0)]
    o0, o1 = plan.about  # momentum_record's, from the momenta about the origin
    m = imp.momenta
    out += [float(o0), float(o1), float(m[0]), float(m[1]), float(m[3]), float(m[4]),
            m[2] - float(o0 * m[1] - o1 * m[0]), m[5] - float(o0 * m[4] - o1 * m[3])]
    if arrays is not None:
        for x in arrays[0].tolist():
            out += x
    else:
        for x in imp.cut_impulses.values():
            out += x
    for x in imp.constraint_impulses.values():
        out += x
    out += [imp.drive_work, imp.energy_dissipated]
    if arrays is not None and plan.root_rows is not None:
        for (_, p), k in zip(plan.roots, plan.root_rows):  # external_impulses
            out += p
            out += rows[k]
    else:
        joints = imp.joint_impulses
        for name, p in plan.roots:  # external_impulses
            out += p
            out += joints[name]
    if plan.frame_contact is not None:
        _, p, F, mz = imp.contact_impulses[plan.frame_contact]
        out += [float(p[0]), float(p[1]), float(F[0]), float(F[1]), float(mz)]
    return out



# ---- the whole bounce in one compiled call ------------------------------------------------------------------
#: why a stop's bounces take the Python route rather than the compiled bounce: {(configuration, transition): reason}
COMPILED_BOUNCE_REFUSED: dict = {}

_STOP_KINDS = {"revolute": 0, "prismatic": 1, "point": 2}


def compiled_bounce(cfg: Configuration, tr: TransitionSpec):
    """The compiled bounce of ``tr``'s stop in ``cfg`` (``BouncePlan`` of pcmm/model/_impulse.hpp: the
    impulse, the record's numbers and the projection onto the drives in one call), once it has given the
    Python route's bits (:func:`adopt_compiled_bounce`); else None.  ``PCMM_COMPILED`` is read where it
    is adopted, once per stop and run (a configuration is a run's own: :class:`pcmm.model.mechanism.Mechanism`),
    not at every bounce (reading the environment costs more than the rest of this look-up)."""
    plan = cfg.impulse_models.get("bounce_records", _NONE).get((cfg.name, tr.name))
    if plan is None or plan.bounce is None or plan.tr is not tr or plan.cfg is not cfg:
        return None
    return plan


_NONE: dict = {}


def solve_bounce(plan: RecordPlan, t, q, v, e):
    """The compiled bounce's one call (``BouncePlan.solve``) at the located state ``(t, q, v)`` with
    restitution ``e``: ``(record numbers, q_new, v_new, v_after, (P, vn_before, vn_after, ke_before, ke_after,
    drive_work), moved, residual)``, or None where the contact takes no impulse along its normal (the
    Python solve decides and says why)."""
    return plan.bounce.solve(t, q, v, e)


def bounce_plan_args(plan: RecordPlan, imp: Impulse, projection: tuple) -> tuple | None:
    """The arguments of the compiled bounce (``BouncePlan``) of the stop whose accepted record plan is
    ``plan``, from a bounce's compiled impulse ``imp`` and the entry's ``projection``
    (:func:`pcmm.events.entry.bounce_projection`); None where the record's numbers are not those the compiled
    bounce forms (a loop's or a prismatic drive's constraint impulses, a record plan not read from arrays)."""
    solved = getattr(imp, "solved", None)
    if solved is None or plan.why is not None or plan.root_rows is None or solved[0].loop_cuts:
        return None
    fast = solved[0]
    if not fast.checked or any(not lab.endswith(".drive") for lab in fast.row_labels):
        return None
    cfg, tr = plan.cfg, plan.tr
    arm = tr.contact.arm if plan.stop == "revolute" else None
    roots = [(float(p[0]), float(p[1]), k) for (_, p), k in zip(plan.roots, plan.root_rows)]
    driven, f, f1 = projection
    return (fast.plan, _STOP_KINDS[plan.stop], arm, cfg.A, (float(plan.about[0]), float(plan.about[1])), roots,
            -1 if plan.frame_contact is None else plan.frame_contact, driven, f, f1)


def adopt_compiled_bounce(cfg: Configuration, tr: TransitionSpec, t, q, v, imp: Impulse, record, q_new, v_new,
                          projection: tuple | None) -> None:
    """At a bounce taken by the Python route (the impulse ``imp``, its ``record``, the entry's ``(q_new,
    v_new)``), where the stop's record plan is read from arrays and its compiled bounce was never asked:
    build the compiled bounce and compare, bit by bit, everything it gives with this bounce's (the record's
    numbers, the velocity after the impulse, the state entered, the impulse's numbers the checks read).
    Adopted where all agree, for every later bounce at the stop; else refused for good, with the reason
    (:data:`COMPILED_BOUNCE_REFUSED`)."""
    plan = cfg.impulse_models.get("bounce_records", _NONE).get((cfg.name, tr.name))
    if plan is None or plan.tr is not tr or plan.cfg is not cfg or plan.bounce is not None or plan.bounce_why is not None:
        return
    why = None
    args = bounce_plan_args(plan, imp, projection) if projection is not None else None
    if projection is None:
        why = "the entry's projection is not the compiled one (a loop, a planar joint, a coordinate driven twice)"
    elif args is None:
        why = plan.why or "the record's numbers are not formed from a compiled impulse without loops"
    elif not compiled.enabled() or not hasattr(compiled._tree_dynamics, "BouncePlan"):
        why = compiled.why_not() or "this build of pcmm.model._tree_dynamics has no BouncePlan"
    if why is None:
        fast = compiled._tree_dynamics.BouncePlan(*args)
        got = fast.solve(t, q, v, imp.restitution)
        want = record.numbers if isinstance(record, BounceRecord) else record_numbers(record)
        why = _bounce_disagreement(got, want, imp, q_new, v_new)
        if why is None:
            plan.bounce = fast
    if why is not None:
        plan.bounce_why = why
        COMPILED_BOUNCE_REFUSED[(cfg.name, tr.name)] = why


def _bounce_disagreement(got, want: list, imp: Impulse, q_new, v_new) -> str | None:
    """Where the compiled bounce's ``got`` differs from the Python route's bits (None: nowhere)."""
    if got is None:
        return "the compiled bounce takes no impulse where the Python route does"
    numbers, q_c, v_c, v_after, scalars, _, _ = got
    if len(numbers) != len(want) or any(_bits(a) != _bits(b) for a, b in zip(numbers, want)):
        at = next((k for k, (a, b) in enumerate(zip(numbers, want)) if _bits(a) != _bits(b)), min(len(numbers), len(want)))
        return f"its record's numbers differ from the Python route's (number {at} of {len(want)})"
    if v_after.tobytes() != np.asarray(imp.v_after, float).tobytes():
        return "its velocity after the impulse differs from the Python route's"
    mine = (imp.P, imp.vn_before, imp.vn_after, imp.ke_before, imp.ke_after, imp.drive_work)
    if any(_bits(a) != _bits(b) for a, b in zip(scalars, mine)):
        return "its impulse's numbers differ from the Python route's"
    if q_c.tobytes() != np.asarray(q_new).tobytes() or v_c.tobytes() != np.asarray(v_new).tobytes():
        return "the state it enters differs from the Python route's"
    return None
