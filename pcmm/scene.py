"""Scene files: TOML data describing a metamorphic mechanism run.

A scene is data, parsed with :mod:`tomllib` and never evaluated.  Paths in a
scene resolve relative to the scene file.  :func:`load_scene` validates the
whole file and every URDF it names before anything is simulated, and reports
every problem at once (:class:`~pcmm.errors.SceneError`).

The format is documented in the README ("Scene format").
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from . import schema as S
from .errors import ModelError, SceneError
from .urdf import MOVABLE, UrdfInfo, read_urdf


# ---- dataclasses --------------------------------------------------------------
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
class ForceSpec:
    """``f = value - k (x - rest) - c x'`` with ``x`` the measure, applied on ``on``."""

    name: str
    type: str
    on: Target
    measure: Measure | None
    value: float
    k: float
    rest: float
    c: float
    configurations: tuple[str, ...] | None


@dataclass(frozen=True)
class GuardSpec:
    type: str  # "coordinate" | "gap"
    measure: Measure | None
    value: float
    direction: int  # +1 increasing, -1 decreasing


@dataclass(frozen=True)
class ContactSpec:
    """Contact points on links a and b (link frames), normal in a's frame from a to b."""

    a: str
    point_a: tuple[float, float]
    b: str
    point_b: tuple[float, float]
    normal: tuple[float, float]


@dataclass(frozen=True)
class TransitionSpec:
    name: str
    type: str  # "latch" | "stop"
    source: str
    target: str | None  # latch: the next configuration
    merge_to: str | None  # stop: the configuration an accumulation merges into
    restitution: float  # latch: 0 (perfectly plastic in the locked direction)
    cut: tuple[str, ...]
    guard: GuardSpec
    contact: ContactSpec
    accumulation_speed: float | None
    accumulation_interval: float | None
    law: str = "impulse"  # or a continuous contact-force law (pcmm.contact_laws)
    stiffness: float | None = None  # continuous laws: k in N / m^n
    exponent: float | None = None  # continuous laws: n (1.5 for Hertz)
    unmerge: bool | None = None  # stop-merges: undo when the holding force turns tensile (None: solver.unmerge)


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


@dataclass(frozen=True)
class DriveSpec:
    """A prescribed coordinate ``q(t) = sum_k coefficients[k] t^k``."""

    joint: str
    coefficients: tuple[float, ...]
    configurations: tuple[str, ...] | None


@dataclass(frozen=True)
class ConfigurationSpec:
    name: str
    urdf: Path
    info: UrdfInfo
    cut_joints: tuple[CutJointSpec, ...] = ()


@dataclass(frozen=True)
class SolverSettings:
    method: str = "DOP853"
    rtol: float = 1e-10
    atol: float = 1e-12
    max_step: float = math.inf
    step: float = 1e-3  # fixed-step methods (RK4)
    event_tol: float = 1e-14  # s: how precisely an event time is located on the dense output
    max_steps: int = 1_000_000  # per segment: a run that needs more is too stiff for its method
    accumulation_speed: float = 1e-6
    accumulation_interval: float = 1e-9
    max_events: int = 10_000
    unmerge: bool = True


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
    solver: SolverSettings = field(default_factory=SolverSettings)

    def forces_in(self, config: str) -> tuple[ForceSpec, ...]:
        return tuple(f for f in self.forces if f.configurations is None or config in f.configurations)

    def drives_in(self, config: str) -> tuple[DriveSpec, ...]:
        return tuple(d for d in self.drives if d.configurations is None or config in d.configurations)

    def transitions_from(self, config: str) -> tuple[TransitionSpec, ...]:
        return tuple(t for t in self.transitions if t.source == config)


# ---- schema tables ---------------------------------------------------------------
_DIRECTIONS = {"increasing": +1, "decreasing": -1}
FORCE_TYPES = {
    # type: (keys required, keys allowed) -- all compile to f = value - k (x - rest) - c x'
    "torque": ({"value"}, {"value"}),
    "spring": ({"k"}, {"k", "rest"}),
    "damper": ({"c"}, {"c"}),
    "spring_damper": ({"k", "c"}, {"k", "c", "rest"}),
    "linear": (set(), {"value", "k", "rest", "c"}),
}
TRANSITION_TYPES = ("latch", "stop")
GUARD_TYPES = ("coordinate", "gap")
CUT_JOINT_TYPES = {"revolute": 2, "prismatic": 2, "weld": 3}

SCENE_KEYS = [
    S.Key("name", "str", doc="a short name for the scene"),
    S.Key("description", "str", required=False, default=""),
    S.Key("gravity", "list", check=S.vector(2), doc="[gx, gy] in m/s^2, e.g. [0.0, -9.81]"),
    S.Key("t_end", "number", check=S.positive, doc="end time of the run in s"),
    S.Key("initial_configuration", "str", doc="name of a [configurations.NAME] table"),
]
SOLVER_KEYS = [
    S.Key("method", "str", required=False, default=SolverSettings.method),
    S.Key("rtol", "number", required=False, default=SolverSettings.rtol, check=S.positive),
    S.Key("atol", "number", required=False, default=SolverSettings.atol, check=S.positive),
    S.Key("max_step", "number", required=False, default=SolverSettings.max_step, check=S.positive),
    S.Key("step", "number", required=False, default=SolverSettings.step, check=S.positive,
          doc="step of fixed-step methods (RK4) in s"),
    S.Key("event_tol", "number", required=False, default=SolverSettings.event_tol, check=S.positive,
          doc="event-location tolerance in s"),
    S.Key("max_steps", "int", required=False, default=SolverSettings.max_steps, check=S.positive),
    S.Key("accumulation_speed", "number", required=False, default=SolverSettings.accumulation_speed,
          check=S.non_negative),
    S.Key("accumulation_interval", "number", required=False,
          default=SolverSettings.accumulation_interval, check=S.non_negative),
    S.Key("max_events", "int", required=False, default=SolverSettings.max_events, check=S.positive),
    S.Key("unmerge", "bool", required=False, default=SolverSettings.unmerge),
]
CONFIG_KEYS = [
    S.Key("urdf", "str", doc="path of the configuration's URDF, relative to the scene file"),
    S.Key("cut_joints", "list", required=False, default=[]),
]
CUT_JOINT_KEYS = [
    S.Key("name", "str"),
    S.Key("type", "str", check=S.one_of(*CUT_JOINT_TYPES)),
    S.Key("a", "str", doc="link on one side of the cut"),
    S.Key("point_a", "list", check=S.vector(2), doc="[x, y] in link a's frame"),
    S.Key("b", "str", doc="link on the other side of the cut"),
    S.Key("point_b", "list", check=S.vector(2), doc="[x, y] in link b's frame"),
    S.Key("axis", "list", required=False, check=S.nonzero_vector(2),
          doc="prismatic only: sliding direction [x, y] in link a's frame"),
    S.Key("angle", "number", required=False,
          doc="prismatic and weld: the fixed relative angle theta_b - theta_a in rad"),
]
INITIAL_KEYS = [
    S.Key("q", "table", doc="{joint = value, ...} for every movable joint"),
    S.Key("v", "table", doc="{joint = velocity, ...} for every movable joint"),
    S.Key("independent", "list", required=False, default=[], check=S.names_list,
          doc="closed loops: joints whose given q and v are kept when the loop is assembled"),
]
MEASURE_KEYS = [
    S.Key("joint", "str", required=False),
    S.Key("link", "str", required=False),
    S.Key("between", "list", required=False, check=S.names_list),
]
FORCE_KEYS = [
    S.Key("name", "str"),
    S.Key("type", "str", check=S.one_of(*FORCE_TYPES)),
    S.Key("on", "table", doc="{joint = NAME} or {link = NAME}"),
    S.Key("measure", "table", required=False, doc="{joint = NAME}, {link = NAME} or {between = [A, B]}"),
    S.Key("value", "number", required=False, default=0.0),
    S.Key("k", "number", required=False, default=0.0, check=S.non_negative,
          doc="stiffness >= 0 (a negative spring is an energy source: model it as a torque)"),
    S.Key("rest", "number", required=False, default=0.0),
    S.Key("c", "number", required=False, default=0.0, check=S.non_negative,
          doc="damping >= 0 (a negative damper feeds energy in)"),
    S.Key("configurations", "list", required=False, check=S.names_list),
]
GUARD_KEYS = [
    S.Key("type", "str", check=S.one_of(*GUARD_TYPES)),
    S.Key("measure", "table", required=False),
    S.Key("value", "number", doc="the guard fires when the measure (or gap) crosses this value"),
    S.Key("direction", "str", check=S.one_of(*_DIRECTIONS)),
]
CONTACT_KEYS = [
    S.Key("a", "str"), S.Key("point_a", "list", check=S.vector(2)),
    S.Key("b", "str"), S.Key("point_b", "list", check=S.vector(2)),
    S.Key("normal", "list", check=S.nonzero_vector(2), doc="[nx, ny] in link a's frame, from a towards b"),
]
TRANSITION_KEYS = [
    S.Key("name", "str"),
    S.Key("type", "str", check=S.one_of(*TRANSITION_TYPES)),
    S.Key("from", "str"),
    S.Key("to", "str", required=False),
    S.Key("merge_to", "str", required=False),
    S.Key("restitution", "number", required=False, check=S.unit_interval),
    S.Key("cut", "list", check=S.names_list, doc="metamorphic joint(s) cut to solve the impulse; [] if none"),
    S.Key("guard", "table"),
    S.Key("contact", "table"),
    S.Key("accumulation_speed", "number", required=False, check=S.non_negative),
    S.Key("accumulation_interval", "number", required=False, check=S.non_negative),
    S.Key("law", "str", required=False, default="impulse",
          check=S.one_of("impulse", "hunt_crossley", "lankarani_nikravesh", "flores"),
          doc="how the impact is resolved: the instantaneous impulse or a continuous contact-force law"),
    S.Key("stiffness", "number", required=False, check=S.positive, doc="continuous laws: k in N/m^n"),
    S.Key("exponent", "number", required=False, check=S.positive, doc="continuous laws: n, e.g. 1.5 (Hertz)"),
    S.Key("unmerge", "bool", required=False,
          doc="stop only: undo the merge when the holding force turns tensile (default: solver.unmerge)"),
]
DRIVE_KEYS = [
    S.Key("joint", "str"),
    S.Key("coefficients", "list", check=lambda v: None if v and all(
        S._type_ok("number", x) and math.isfinite(x) for x in v) else "must be a non-empty list of numbers",
        doc="q(t) = c0 + c1 t + c2 t^2 + ..."),
    S.Key("configurations", "list", required=False, check=S.names_list),
]
TOP_KEYS = [
    S.Key("scene", "table"), S.Key("solver", "table", required=False, default={}),
    S.Key("configurations", "table"), S.Key("initial", "table"),
    S.Key("forces", "list", required=False, default=[]),
    S.Key("transitions", "list", required=False, default=[]),
    S.Key("drives", "list", required=False, default=[]),
]


# ---- loading ----------------------------------------------------------------------
def load_scene(path: str | Path) -> Scene:
    """Read, validate and return the scene at ``path``."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: scene file not found")
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise SceneError(f"{path}: not UTF-8 text: {exc}") from None
    return _Builder(path, raw).build()


class _Builder:
    def __init__(self, path: Path, raw: dict):
        self.path = path
        self.base = path.resolve().parent
        self.raw = raw
        self.p = S.Problems(str(path))

    # -- helpers
    def _measure(self, table, where) -> Measure | None:
        m = S.check_table(table, MEASURE_KEYS, where, self.p)
        given = [k for k in ("joint", "link", "between") if m.get(k) is not None]
        if len(given) != 1:
            if not any(k in table for k in ("joint", "link", "between")) or len(given) > 1:
                self.p.add(where, "give exactly one of joint = NAME, link = NAME, between = [A, B]")
            return None
        kind = given[0]
        if kind == "between":
            if len(m["between"]) != 2:
                self.p.add(f"{where}.between", f"= {S.show(m['between'])}: must name two links [A, B]")
                return None
            return Measure("between", tuple(m["between"]))
        return Measure(kind, (m[kind],))

    def _target(self, table, where) -> Target | None:
        keys = [S.Key("joint", "str", required=False), S.Key("link", "str", required=False)]
        t = S.check_table(table, keys, where, self.p)
        given = [k for k in ("joint", "link") if t.get(k) is not None]
        if len(given) != 1:
            self.p.add(where, "give exactly one of joint = NAME or link = NAME")
            return None
        return Target(given[0], t[given[0]])

    def _list_of_tables(self, items, keys, where):
        out = []
        for i, item in enumerate(items or []):
            raw = item if isinstance(item, dict) else {}
            out.append((f"{where}[{i}]", S.check_table(item, keys, f"{where}[{i}]", self.p), raw))
        return out

    # -- the build
    def build(self) -> Scene:
        top = S.check_table(self.raw, TOP_KEYS, "", self.p)
        sc = S.check_table(top["scene"] or {}, SCENE_KEYS, "scene", self.p) if top["scene"] is not None else {}
        solver = S.check_table(top["solver"] if top["solver"] is not None else {}, SOLVER_KEYS, "solver", self.p)
        configs = self._configurations(top["configurations"] or {})
        forces = self._forces(top["forces"])
        transitions = self._transitions(top["transitions"])
        drives = self._drives(top["drives"])
        init = S.check_table(top["initial"] or {}, INITIAL_KEYS, "initial", self.p) if top["initial"] is not None else {}
        from .integrators import INTEGRATORS  # registry of methods; imported late to keep scene light
        if solver.get("method") is not None and solver["method"] not in INTEGRATORS:
            self.p.add("solver.method", f"= {solver['method']!r}: must be one of {', '.join(INTEGRATORS)}")
        initial = sc.get("initial_configuration")
        if initial is not None and initial not in configs and top["configurations"]:
            self.p.add("scene.initial_configuration", f"= {initial!r}: no such configuration; "
                       f"defined: {', '.join(configs) or '(none valid)'}")
        q0 = self._joint_values(init.get("q"), "initial.q", configs.get(initial))
        v0 = self._joint_values(init.get("v"), "initial.v", configs.get(initial))
        # Built even when problems were found, so the cross-checks of every valid part
        # run too and the user sees all that is wrong at once; never returned then.
        scene = Scene(
            path=self.path, name=sc.get("name") or "", description=sc.get("description") or "",
            gravity=tuple(float(x) for x in (sc.get("gravity") or (0.0, 0.0))), t_end=float(sc.get("t_end") or 0.0),
            configurations=configs, initial_configuration=initial or "", q0=q0, v0=v0,
            independent=tuple(init.get("independent") or ()),
            forces=tuple(forces), transitions=tuple(transitions), drives=tuple(drives),
            solver=SolverSettings(**{k: v for k, v in solver.items() if v is not None}),
        )
        self._cross_check(scene)
        if self.p:
            raise SceneError(self.p.items)
        return scene

    def _configurations(self, table) -> dict[str, ConfigurationSpec]:
        out = {}
        if not table:
            self.p.add("configurations", "needs at least one [configurations.NAME] table")
        for name, body in table.items():
            where = f"configurations.{name}"
            c = S.check_table(body, CONFIG_KEYS, where, self.p)
            if c["urdf"] is None:
                continue
            urdf = (self.base / c["urdf"]).resolve()
            try:
                info = read_urdf(urdf)
            except ModelError as exc:
                for prob in exc.problems:
                    self.p.add(f"{where}.urdf", prob)
                continue
            cuts = []
            for cw, cj, _ in self._list_of_tables(c["cut_joints"], CUT_JOINT_KEYS, f"{where}.cut_joints"):
                if None in (cj["name"], cj["type"], cj["a"], cj["point_a"], cj["b"], cj["point_b"]):
                    continue
                if cj["type"] == "prismatic" and cj["axis"] is None:
                    self.p.add(f"{cw}.axis", "missing; a prismatic cut joint needs its sliding axis [x, y]")
                if cj["type"] in ("prismatic", "weld") and cj["angle"] is None:
                    self.p.add(f"{cw}.angle", f"missing; a {cj['type']} cut joint needs the relative angle it holds")
                cuts.append(CutJointSpec(cj["name"], cj["type"], cj["a"], tuple(cj["point_a"]),
                                         cj["b"], tuple(cj["point_b"]),
                                         tuple(cj["axis"]) if cj["axis"] else None, cj["angle"]))
            out[name] = ConfigurationSpec(name=name, urdf=urdf, info=info, cut_joints=tuple(cuts))
        return out

    def _forces(self, items) -> list[ForceSpec]:
        out = []
        for where, f, raw in self._list_of_tables(items, FORCE_KEYS, "forces"):
            if f["type"] is None or f["on"] is None or f["name"] is None:
                continue
            required, allowed = FORCE_TYPES[f["type"]]
            given = {k for k in ("value", "k", "rest", "c") if k in raw}
            for k in sorted(required - given):
                self.p.add(f"{where}.{k}", f"missing; a {f['type']!r} force needs {', '.join(sorted(required))}")
            for k in sorted(given - allowed):
                self.p.add(f"{where}.{k}", f"not used by a {f['type']!r} force (allowed: {', '.join(sorted(allowed))})")
            on = self._target(f["on"], f"{where}.on")
            needs_measure = bool(given & {"k", "c"})
            measure = self._measure(f["measure"], f"{where}.measure") if f["measure"] is not None else None
            if needs_measure and f["measure"] is None:
                self.p.add(f"{where}.measure", "missing; a spring or damper needs the coordinate it measures")
            if on is None or None in (f["value"], f["k"], f["rest"], f["c"]) or (needs_measure and measure is None):
                continue
            out.append(ForceSpec(f["name"], f["type"], on, measure, float(f["value"]), float(f["k"]),
                                 float(f["rest"]), float(f["c"]),
                                 tuple(f["configurations"]) if f["configurations"] else None))
        return out

    def _transitions(self, items) -> list[TransitionSpec]:
        out = []
        for where, t, raw in self._list_of_tables(items, TRANSITION_KEYS, "transitions"):
            if None in (t["name"], t["type"], t["from"], t["cut"], t["guard"], t["contact"]):
                continue
            g = S.check_table(t["guard"], GUARD_KEYS, f"{where}.guard", self.p)
            measure = None
            if g["type"] == "coordinate":
                if g["measure"] is None:
                    self.p.add(f"{where}.guard.measure", "missing; a coordinate guard needs the measure it watches")
                else:
                    measure = self._measure(g["measure"], f"{where}.guard.measure")
            elif g["type"] == "gap" and g["measure"] is not None:
                self.p.add(f"{where}.guard.measure", "not used by a gap guard (it watches the contact gap)")
            c = S.check_table(t["contact"], CONTACT_KEYS, f"{where}.contact", self.p)
            e = t["restitution"]
            if t["type"] == "latch":
                if t["to"] is None:
                    self.p.add(f"{where}.to", "missing; a latch names the configuration it switches to")
                for k in ("restitution", "merge_to", "unmerge"):
                    if k in raw:
                        self.p.add(f"{where}.{k}", "not used by a latch (the merge is perfectly plastic, e = 0)")
                e = 0.0
            elif t["type"] == "stop":
                if t["to"] is not None:
                    self.p.add(f"{where}.to", "not used by a stop (the configuration does not change); "
                               "name the merged configuration with merge_to")
                if "restitution" not in raw:
                    self.p.add(f"{where}.restitution", "missing; a stop needs Newton's coefficient e in [0, 1]")
            law = t["law"]
            if law is not None and law != "impulse":
                if t["type"] != "stop":
                    self.p.add(f"{where}.law", f"= {law!r}: a continuous contact law resolves a stop; "
                               "a latch locks on contact (law = 'impulse')")
                for k in ("stiffness", "exponent"):
                    if k not in raw:
                        self.p.add(f"{where}.{k}", f"missing; the {law!r} contact law needs stiffness and exponent")
                if law == "flores" and e is not None and e <= 0:
                    self.p.add(f"{where}.restitution", f"= {e!r}: the Flores law needs e > 0 (its damping is 8(1-e)/(5e))")
            else:
                for k in ("stiffness", "exponent"):
                    if k in raw:
                        self.p.add(f"{where}.{k}", "only used with a continuous contact law (law = 'hunt_crossley', "
                                   "'lankarani_nikravesh' or 'flores')")
            if g["type"] == "coordinate" and measure is None:
                continue
            if None in (c["a"], c["point_a"], c["b"], c["point_b"], c["normal"], g["value"], g["direction"], e):
                continue
            out.append(TransitionSpec(
                name=t["name"], type=t["type"], source=t["from"], target=t["to"], merge_to=t["merge_to"],
                restitution=float(e), cut=tuple(t["cut"]),
                guard=GuardSpec(g["type"], measure, float(g["value"]), _DIRECTIONS[g["direction"]]),
                contact=ContactSpec(c["a"], tuple(c["point_a"]), c["b"], tuple(c["point_b"]), tuple(c["normal"])),
                accumulation_speed=t["accumulation_speed"], accumulation_interval=t["accumulation_interval"],
                law=t["law"] or "impulse", stiffness=t["stiffness"], exponent=t["exponent"],
                unmerge=t["unmerge"]))
        return out

    def _drives(self, items) -> list[DriveSpec]:
        out = []
        for where, d, _ in self._list_of_tables(items, DRIVE_KEYS, "drives"):
            if None in (d["joint"], d["coefficients"]):
                continue
            out.append(DriveSpec(d["joint"], tuple(float(x) for x in d["coefficients"]),
                                 tuple(d["configurations"]) if d["configurations"] else None))
        return out

    def _joint_values(self, table, where, config: ConfigurationSpec | None) -> dict[str, float]:
        out = {}
        if table is None or config is None:
            return out
        movable = config.info.movable_joints
        for name, val in table.items():
            if name not in config.info.joints:
                self._unknown(f"{where}.{name}", "joint", name, movable, config)
            elif name not in movable:
                self.p.add(f"{where}.{name}", f"joint '{name}' is fixed in configuration '{config.name}'")
            elif isinstance(val, list) and config.info.joints[name].type == "planar":
                if S.vector(3)(val):
                    self.p.add(f"{where}.{name}", f"= {S.show(val)}: a planar joint takes [x, y, theta]")
                else:
                    out[name] = tuple(float(x) for x in val)
            elif not S._type_ok("number", val) or not math.isfinite(val):
                self.p.add(f"{where}.{name}", f"= {S.show(val)}: must be a finite number")
            else:
                out[name] = float(val)
        for name in movable:
            if name not in table:
                self.p.add(where, f"joint '{name}' of configuration '{config.name}' has no value; "
                           f"give every movable joint: {', '.join(movable)}")
        return out

    def _unknown(self, where, what, name, known, config):
        import difflib
        close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.5)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        self.p.add(where, f"= {name!r}: no {what} of that name in configuration '{config.name}' "
                   f"({config.info.path.name}){hint}")

    # -- names against URDFs
    def _check_link(self, where, name, config):
        if name not in config.info.links:
            self._unknown(where, "link", name, config.info.links, config)

    def _check_joint(self, where, name, config, movable=True):
        if name not in config.info.joints:
            self._unknown(where, "joint", name, config.info.joints, config)
        elif movable and config.info.joints[name].type not in MOVABLE:
            self.p.add(where, f"= {name!r}: joint is fixed in configuration '{config.name}'")

    def _check_measure(self, where, m: Measure, config):
        if m.kind == "joint":
            self._check_joint(where, m.names[0], config)
            if m.names[0] in config.info.joints and config.info.joints[m.names[0]].type == "planar":
                self.p.add(where, f"= {m.names[0]!r}: a planar joint has three coordinates; measure a link instead")
        else:
            for n in m.names:
                self._check_link(where, n, config)

    def _configs_for(self, where, names, scene) -> list[ConfigurationSpec]:
        if names is None:
            return list(scene.configurations.values())
        out = []
        for n in names:
            if n in scene.configurations:
                out.append(scene.configurations[n])
            else:
                self.p.add(where, f"= {n!r}: no such configuration; defined: {', '.join(scene.configurations)}")
        return out

    def _cross_check(self, scene: Scene) -> None:
        names = scene.configurations
        for i, f in enumerate(scene.forces):
            where = f"forces[{i}] ({f.name})"
            for cfg in self._configs_for(f"{where}.configurations", f.configurations, scene):
                tail = "" if f.configurations else " (the force applies in every configuration unless it lists configurations)"
                n0 = len(self.p.items)
                if f.on.kind == "joint":
                    self._check_joint(f"{where}.on.joint", f.on.name, cfg)
                else:
                    self._check_link(f"{where}.on.link", f.on.name, cfg)
                if f.measure is not None:
                    self._check_measure(f"{where}.measure", f.measure, cfg)
                if tail and len(self.p.items) > n0:
                    self.p.items[-1] += tail
        for i, t in enumerate(scene.transitions):
            where = f"transitions[{i}] ({t.name})"
            for key, ref in (("from", t.source), ("to", t.target), ("merge_to", t.merge_to)):
                if ref is not None and ref not in names:
                    self.p.add(f"{where}.{key}", f"= {ref!r}: no such configuration; defined: {', '.join(names)}")
            if t.source not in names:
                continue
            cfg = names[t.source]
            for j in t.cut:
                self._check_joint(f"{where}.cut", j, cfg)
            if t.guard.measure is not None:
                self._check_measure(f"{where}.guard.measure", t.guard.measure, cfg)
            self._check_link(f"{where}.contact.a", t.contact.a, cfg)
            self._check_link(f"{where}.contact.b", t.contact.b, cfg)
            if t.contact.a == t.contact.b:
                self.p.add(f"{where}.contact", f"a and b are the same link {t.contact.a!r}")
        init_cfg = names.get(scene.initial_configuration)
        for j in scene.independent:
            if init_cfg is not None:
                self._check_joint("initial.independent", j, init_cfg)
        for i, d in enumerate(scene.drives):
            for cfg in self._configs_for(f"drives[{i}].configurations", d.configurations, scene):
                self._check_joint(f"drives[{i}].joint", d.joint, cfg)
        for cfg in names.values():
            for k, cj in enumerate(cfg.cut_joints):
                where = f"configurations.{cfg.name}.cut_joints[{k}]"
                self._check_link(f"{where}.a", cj.a, cfg)
                self._check_link(f"{where}.b", cj.b, cfg)
