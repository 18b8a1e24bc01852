"""The scene's data model: frozen dataclasses, validated and ready to simulate.

A :class:`Scene` is what :func:`pcmm.scene.load_scene` returns; every name in
it has been checked against the URDFs.  Nothing here reads files: the TOML
loader (:mod:`pcmm.scene`) builds these, and the layers above read them.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, ClassVar

from .settings import SolverSettings, solver_settings_type
from ..errors import SceneError
from .urdf import UrdfInfo, UrdfJoint

@dataclass(frozen=True)
class Measure:
    """A scalar coordinate: a joint's coordinate, a link's absolute angle, or
    the relative angle ``theta_b - theta_a`` between two links."""

    kind: str  # "joint" | "link" | "between"
    names: tuple[str, ...]

    def __str__(self) -> str:
        return {"joint": "joint {}", "link": "angle of {}", "between": "angle {1} - {0}"}[
            self.kind].format(*self.names)


@dataclass(frozen=True)
class Target:
    """Where a generalized force acts: a joint (action/reaction between its
    bodies) or a link's absolute angle (a torque from the frame)."""

    kind: str  # "joint" | "link"
    name: str


@dataclass(frozen=True)
class PointPair:
    """Two points, each fixed on a link (link frames): the ends of a point-to-point element."""

    a: str
    point_a: tuple[float, float]
    b: str
    point_b: tuple[float, float]


@dataclass(frozen=True)
class ForceSpec:
    """``f = value - k (x - rest) - c x'`` with ``x`` the measure, applied on ``on``; for a
    ``point_spring``, ``x`` is the distance between ``points`` and ``f`` acts along their line,
    pushing them apart when positive (``on`` and ``measure`` are then None)."""

    name: str
    type: str
    on: Target | None
    measure: Measure | None
    value: float
    k: float
    rest: float
    c: float
    configurations: tuple[str, ...] | None
    points: PointPair | None = None


@dataclass(frozen=True)
class GuardSpec:
    """When a transition fires.

    * ``coordinate``: ``measure`` crosses ``value`` in ``direction``;
    * ``gap``: the contact gap crosses ``value``;
    * ``time``: t reaches ``at``, or each ``start + k every`` for repeated cycles;
    * ``reaction``: the holding force/moment of the locked joint or merged stop ``of``
      (a joint name, or the name of the stop transition that merged) crosses ``value``;
    * ``entry``: a release fires the instant its configuration is entered (a separate event at
      that instant, before anything is integrated in it).
    """

    type: str  # "coordinate" | "gap" | "time" | "reaction" | "entry"
    measure: Measure | None
    value: float
    direction: int  # +1 increasing, -1 decreasing
    at: float | None = None  # time guard: the instant
    every: float | None = None  # time guard: the period (fires at start + k every)
    start: float = 0.0
    of: str | None = None  # reaction guard: the locked joint or the stop transition it watches
    #: coordinate and gap guards armed by a region: (measure, +1 above / -1 below, bound); the guard
    #: reads max(its value, -(distance into the region)) on its unfired side (Drake's witness for a
    #: walker's heel strike): a crossing counts only inside the region
    when: tuple | None = None


@dataclass(frozen=True)
class ContactSpec:
    """Contact points on links a and b (link frames), normal in a's frame from a to b.

    A *joint stop* names a joint instead (``joint``): the stop acts on that joint's
    coordinate, at the value and in the direction of the transition's coordinate guard
    (``stop_value``, ``stop_sign``: +1 when the joint moves towards the stop with its
    coordinate increasing); a and b are then the joint's parent and child links, the impulse
    is a moment (revolute) or a force along the axis (prismatic), and ``arm`` (m, optional)
    is the lever at which the moment is also reported as a force.

    A point contact may carry Coulomb friction along its tangent t = (n_y, -n_x): ``friction``
    is mu (``math.inf`` for "stick", no slip; None: frictionless, the normal impulse alone), and
    ``restitution_law`` says how a frictional impact ends (:mod:`pcmm.events.friction`)."""

    a: str
    point_a: tuple[float, float] | None
    b: str
    point_b: tuple[float, float] | None
    normal: tuple[float, float] | None
    joint: str | None = None
    arm: float | None = None
    stop_value: float | None = None
    stop_sign: int = 1
    friction: float | None = None
    restitution_law: str = "newton"


@dataclass(frozen=True)
class TransitionSpec:
    """What every transition has: the guard that fires it, the contact that strikes, and the
    metamorphic joints cut to solve the impulse.  Each kind adds its own fields
    (:class:`LatchSpec`, :class:`StopSpec`); ``type`` names the kind (the handler registry's key)."""

    type: ClassVar[str]
    name: str
    source: str
    cut: tuple[str, ...]
    guard: GuardSpec
    contact: ContactSpec | None  # None for a release (no impulse: paper section 2.2)


@dataclass(frozen=True)
class LatchSpec(TransitionSpec):
    """The metamorphic joint locks on contact and the run continues in ``target``."""

    type: ClassVar[str] = "latch"
    restitution: ClassVar[float] = 0.0  # perfectly plastic in the locked direction
    target: str  # the next configuration


@dataclass(frozen=True)
class ReleaseSpec(TransitionSpec):
    """A transformation that frees joints: no impulse (paper section 2.2); the run continues in
    ``target``, the configuration with more freedom (no contact, no cut)."""

    type: ClassVar[str] = "release"
    restitution: ClassVar[float] = 0.0
    target: str


@dataclass(frozen=True)
class StopSpec(TransitionSpec):
    """A unilateral stop with Newton's restitution; accumulated bounces merge into ``merge_to``."""

    type: ClassVar[str] = "stop"
    restitution: float
    merge_to: str | None  # the configuration an accumulation merges into
    accumulation_speed: float | None = None  # None: the scene's [solver] value
    accumulation_interval: float | None = None
    law: str = "impulse"  # or a continuous contact-force law (pcmm.contact_laws)
    stiffness: float | None = None  # continuous laws: k in N / m^n
    exponent: float | None = None  # continuous laws: n (1.5 for Hertz)
    unmerge: bool | None = None  # undo the merge when the holding force turns tensile (None: solver.unmerge)


@dataclass(frozen=True)
class PinSpec(TransitionSpec):
    """A point of b strikes a and is pinned where it lands (issue 24): the run continues in
    ``target``, whose cut joint anchored at entry holds b's point; the impulse is solved with every
    constraint of ``target`` at once and the closed unilateral contacts of the source
    (:mod:`pcmm.events.pins`).  Plastic (e = 0) and without slip, or within the contact's friction."""

    type: ClassVar[str] = "pin"
    restitution: ClassVar[float] = 0.0
    target: str


@dataclass(frozen=True)
class CutJointSpec:
    """A joint that closes a loop; the URDF holds the spanning tree."""

    name: str
    type: str  # "revolute" | "prismatic" | "weld"
    a: str
    point_a: tuple[float, float]
    b: str
    point_b: tuple[float, float]
    axis: tuple[float, float] | None  # prismatic: sliding direction in a's frame
    angle: float | None  # prismatic, weld: the fixed relative angle theta_b - theta_a
    #: ``point_a = "entry"`` (a revolute cut joint to the frame): a's point is where b's point is when
    #: the run enters the configuration (a struck point pinned where it lands); point_a is then (0, 0)
    #: and the anchor a per-instance offset (:class:`pcmm.model.constraints.ClosureRows`)
    anchor_at_entry: bool = False
    #: a contact held by compression only: the normal (in a's frame, from a towards b) along which
    #: the cut joint may only push, and Coulomb's mu it must respect ("stick": math.inf; None: any)
    normal: tuple[float, float] | None = None
    friction: float | None = None


@dataclass(frozen=True)
class BranchSpec:
    """The assembly of a closed loop: the sign (+1 or -1) of a measure wrapped into (-pi, pi]."""

    measure: Measure
    sign: int


@dataclass(frozen=True)
class DriveSpec:
    """A prescribed coordinate ``q(t) = sum_k coefficients[k] t^k``."""

    joint: str
    coefficients: tuple[float, ...]
    configurations: tuple[str, ...] | None


@dataclass(frozen=True)
class Derivation:
    """A configuration derived by locking joints of another (``from``, ``lock``): its model is the
    root URDF with each locked joint made ``fixed`` at its value (:mod:`pcmm.derive`).  Chains are
    flattened: ``lock`` holds every joint locked from the root URDF on, ``joints`` their original
    (movable) URDF joints, and ``values`` the values known so far: given in the scene
    (``lock = {J = value}``), or, in a built model, taken when the run entered it."""

    base: str  # the configuration named by `from`
    lock: tuple[str, ...]
    joints: dict[str, UrdfJoint]
    values: tuple[tuple[str, float], ...] = ()

    @property
    def at_entry(self) -> tuple[str, ...]:
        """Locked joints whose values are those they have when the run enters the configuration."""
        known = dict(self.values)
        return tuple(j for j in self.lock if j not in known)


@dataclass(frozen=True)
class ConfigurationSpec:
    name: str
    urdf: Path  # a derived configuration: its root URDF (links and visuals are the same)
    info: UrdfInfo
    cut_joints: tuple[CutJointSpec, ...] = ()
    derivation: Derivation | None = None
    xml: str | None = None  # a derived configuration with every value known: its URDF text

    @property
    def source(self) -> str:
        """Where the model comes from, for messages: the URDF file, or how it is derived."""
        if self.derivation is None:
            return self.urdf.name
        values = dict(self.derivation.values)
        locks = ", ".join(f"{j} = {values[j]:.9g}" if j in values else j for j in self.derivation.lock)
        return f"{self.urdf.name} with {locks} locked"


@dataclass(frozen=True)
class Scene:
    path: Path
    name: str
    description: str
    gravity: tuple[float, float]
    t_end: float
    configurations: dict[str, ConfigurationSpec]
    initial_configuration: str
    q0: dict[str, float]
    v0: dict[str, float]
    independent: tuple[str, ...]
    forces: tuple[ForceSpec, ...]
    transitions: tuple[TransitionSpec, ...]
    drives: tuple[DriveSpec, ...]
    solver: SolverSettings = field(default_factory=lambda: solver_settings_type()())
    branch: BranchSpec | None = None  # closed loops: the assembly to start on ([initial] branch)
    momentum_point: tuple[float, float] | str | None = None  # momenta about this point (None: first frame pivot; "contact": each event's contact point)
    #: the parsed TOML the scene was validated from (what :meth:`with_values` edits)
    source: dict | None = field(default=None, repr=False, compare=False)
    #: the loader that validated it, ``(scene, values) -> Scene``: it validates edited values
    #: exactly as the TOML file (:func:`pcmm.scene.load.with_values`)
    loader: Callable | None = field(default=None, repr=False, compare=False)

    def with_values(self, values) -> "Scene":
        """A new scene with the values at the given paths changed, validated exactly as
        the TOML file is, e.g. ``{"forces.tau1.value": 2.0}`` (:mod:`pcmm.scene.variations`)."""
        if self.source is None or self.loader is None:
            raise SceneError(f"{self.path}: this scene was not loaded from TOML (pcmm.load_scene), "
                             "so it has no values to vary")
        return self.loader(self, values)

    def forces_in(self, config: str) -> tuple[ForceSpec, ...]:
        return tuple(f for f in self.forces if f.configurations is None or config in f.configurations)

    def drives_in(self, config: str) -> tuple[DriveSpec, ...]:
        return tuple(d for d in self.drives if d.configurations is None or config in d.configurations)

    def transitions_from(self, config: str) -> tuple[TransitionSpec, ...]:
        return tuple(t for t in self.transitions if t.source == config)

    def lift_off_target(self, config: str, cut_joint: str) -> str | None:
        """The configuration a point held by compression only (``cut_joint`` of ``config``, a cut
        joint with a contact normal) lifts off into by itself when its normal force turns tensile:
        the first of the scene's configurations with the same URDF (and derivation), the same
        drives, and the cut joints of ``config`` except ``cut_joint``.  None: there is none (the
        scene must then watch the point with a release of its own)."""
        src = self.configurations[config]
        rest = {s for s in src.cut_joints if s.name != cut_joint}
        drives = {(d.joint, d.coefficients) for d in self.drives_in(config)}
        for name, spec in self.configurations.items():
            if (name != config and spec.urdf == src.urdf and spec.derivation == src.derivation
                    and len(spec.cut_joints) == len(rest) and set(spec.cut_joints) == rest
                    and {(d.joint, d.coefficients) for d in self.drives_in(name)} == drives):
                return name
        return None

    def lift_offs(self) -> list[tuple[str, str, str]]:
        """(configuration, cut joint, target) of every point held by compression only that lifts
        off by itself (:meth:`lift_off_target`; not one a ``release`` with a reaction guard watches)."""
        out = []
        for name, spec in self.configurations.items():
            watched = {t.guard.of for t in self.transitions_from(name) if t.guard.type == "reaction"}
            for cj in spec.cut_joints:
                if cj.normal is not None and cj.name not in watched:
                    target = self.lift_off_target(name, cj.name)
                    if target is not None:
                        out.append((name, cj.name, target))
        return out
