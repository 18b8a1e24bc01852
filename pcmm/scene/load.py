"""Scene files: TOML data describing a metamorphic mechanism run.

A scene is data, parsed with :mod:`tomllib` and never evaluated.  Paths in a
scene resolve relative to the scene file.  :func:`load_scene` validates the
whole file and every URDF it names before anything is simulated, and reports
every problem at once (:class:`~pcmm.errors.SceneError`).

The format is documented in docs/scene_format.md, whose key tables are generated from the
``*_KEYS`` tables below.
"""
from __future__ import annotations

import math
import re
import sys
import tomllib
from pathlib import Path

from . import schema as S
from . import settings
from ..errors import ModelError, SceneError
from .spec import (ConfigurationSpec, ContactSpec, CutJointSpec, DriveSpec, ForceSpec, GuardSpec,
                   BranchSpec, LatchSpec, Measure, PinSpec, PointPair, ReleaseSpec, Scene, StopSpec, Target)
from .urdf import MOVABLE, read_urdf
from .variations import read_urdf_cached, set_values


# ---- schema tables ---------------------------------------------------------------
_DIRECTIONS = {"increasing": +1, "decreasing": -1}
FORCE_TYPES = {
    # type: (keys required, keys allowed) -- all compile to f = value - k (x - rest) - c x'
    "torque": ({"value"}, {"value"}),
    "spring": ({"k"}, {"k", "rest"}),
    "damper": ({"c"}, {"c"}),
    "spring_damper": ({"k", "c"}, {"k", "c", "rest"}),
    "linear": (set(), {"value", "k", "rest", "c"}),
    # between two points: x is their distance, f acts along their line (> 0 pushes them apart)
    "point_spring": ({"k", "rest"}, {"value", "k", "rest", "c"}),
}
TRANSITION_TYPES = ("latch", "stop", "release", "pin")
GUARD_TYPES = ("coordinate", "gap", "time", "reaction", "entry")
CUT_JOINT_TYPES = {"revolute": 2, "prismatic": 2, "weld": 3}

SCENE_KEYS = [
    S.Key("name", "str", check=S.name, doc="a short name for the scene"),
    S.Key("description", "str", required=False, default="", doc="free text describing the mechanism"),
    S.Key("gravity", "list", check=S.vector(2), doc="[gx, gy] in m/s^2, e.g. [0.0, -9.81]"),
    S.Key("t_end", "number", check=S.positive, doc="end time of the run in s"),
    S.Key("initial_configuration", "str", doc="name of a [configurations.NAME] table"),
    S.Key("momentum_point", "list|str", required=False, check=S.vector_or(2, "contact"),
          doc="[x, y]: the point the events' angular momenta are taken about, or \"contact\": each event's "
              "contact point (default: the first frame pivot)"),
]
CONFIG_KEYS = [
    S.Key("urdf", "str", required=False, doc="path of the configuration's URDF, relative to the scene file"),
    S.Key("from", "str", required=False, doc="a derived configuration: the configuration whose joints it locks"),
    S.Key("lock", "list|table", required=False,
          doc="[joints] locked at their values when the run enters, or {joint = value}"),
    S.Key("cut_joints", "list", required=False, default=[],
          doc="closed loops: the joints cut from the URDF tree, each a table (see the cut_joints entries)"),
]
CUT_JOINT_KEYS = [
    S.Key("name", "str", check=S.name, doc="the cut joint's name; its constraint force on link b is the series NAME.fx, NAME.fy "
          "(revolute; N, world axes), NAME.fn, NAME.mz (prismatic: across the axis, N, and the moment, N m) or "
          "NAME.fx, NAME.fy, NAME.mz (weld)"),
    S.Key("type", "str", check=S.one_of(*CUT_JOINT_TYPES), doc="revolute and prismatic: 2 constraint rows, weld: 3"),
    S.Key("a", "str", doc="link on one side of the cut"),
    S.Key("point_a", "list|str", check=S.point_or_entry,
          doc="[x, y] in link a's frame, or \"entry\": where b's point is when the configuration is entered"),
    S.Key("b", "str", doc="link on the other side of the cut"),
    S.Key("point_b", "list", check=S.vector(2), doc="[x, y] in link b's frame"),
    S.Key("axis", "list", required=False, check=S.nonzero_vector(2),
          doc="prismatic only: sliding direction [x, y] in link a's frame"),
    S.Key("angle", "number", required=False,
          doc="prismatic and weld: the fixed relative angle theta_b - theta_a in rad"),
    S.Key("contact", "table", required=False,
          doc="revolute: { normal = [x, y] in a's frame, friction = mu | \"stick\" }: held by compression only"),
]
PIN_CONTACT_KEYS = [
    S.Key("normal", "list", check=S.nonzero_vector(2), doc="[nx, ny] in link a's frame, from a towards b"),
    S.Key("friction", "number|str", required=False, check=S.friction_coefficient,
          doc="Coulomb's mu >= 0 the pin's impulse and force must respect, or \"stick\""),
]
INITIAL_KEYS = [
    S.Key("q", "table", doc="{joint = value, ...} for every movable joint"),
    S.Key("v", "table", doc="{joint = velocity, ...} for every movable joint"),
    S.Key("independent", "list", required=False, default=[], check=S.distinct_names,
          doc="closed loops: joints whose given q and v are kept when the loop is assembled"),
    S.Key("branch", "table", required=False,
          doc='closed loops: { between = [A, B], sign = "+" } (or joint = J, link = L): the assembly whose '
              "angle, wrapped into (-pi, pi], has that sign"),
]
MEASURE_KEYS = [
    S.Key("joint", "str", required=False, doc="a joint's coordinate (rad or m)"),
    S.Key("link", "str", required=False, doc="a link's absolute angle in rad"),
    S.Key("between", "list", required=False, check=S.names_list, doc="[A, B]: the relative angle theta_B - theta_A in rad"),
]
FORCE_KEYS = [
    S.Key("name", "str", check=S.name, doc="the element's name (its force is reported over time under it)"),
    S.Key("type", "str", check=S.one_of(*FORCE_TYPES),
          doc="f = value - k (x - rest) - c x'; each type requires and allows the keys of the table below"),
    S.Key("on", "table", required=False, doc="{joint = NAME} or {link = NAME}"),
    S.Key("a", "str", required=False, doc="point_spring: the link carrying point_a"),
    S.Key("point_a", "list", required=False, check=S.vector(2), doc="point_spring: [x, y] in link a's frame"),
    S.Key("b", "str", required=False, doc="point_spring: the link (or the frame) carrying point_b"),
    S.Key("point_b", "list", required=False, check=S.vector(2), doc="point_spring: [x, y] in link b's frame"),
    S.Key("measure", "table", required=False, doc="{joint = NAME}, {link = NAME} or {between = [A, B]}"),
    S.Key("value", "number", required=False, default=0.0, doc="constant force (N) or moment (N m)"),
    S.Key("k", "number", required=False, default=0.0, check=S.non_negative,
          doc="stiffness >= 0 (a negative spring is an energy source: model it as a torque)"),
    S.Key("rest", "number", required=False, default=0.0, doc="the measure's value (rad or m) where the spring is relaxed"),
    S.Key("c", "number", required=False, default=0.0, check=S.non_negative,
          doc="damping >= 0 (a negative damper feeds energy in)"),
    S.Key("configurations", "list", required=False, check=S.configuration_names,
          doc="the configurations it acts in, each once (default: every one)"),
]
WHEN_KEYS = [
    S.Key("measure", "table", doc="{joint = NAME}, {link = NAME} or {between = [A, B]}"),
    S.Key("above", "number", required=False, doc="the crossing counts only with the measure above this value"),
    S.Key("below", "number", required=False, doc="the crossing counts only with the measure below this value"),
]
GUARD_KEYS = [
    S.Key("type", "str", check=S.one_of(*GUARD_TYPES),
          doc="coordinate (a measure), gap (a contact's gap), time, reaction (a lock's holding force), "
              "entry (a release: the instant its configuration is entered; no other key)"),
    S.Key("when", "table", required=False,
          doc="coordinate and gap guards: { measure, above | below }: a crossing counts only on that side"),
    S.Key("measure", "table", required=False, doc="coordinate guards: the measure watched, { joint }, { link } or { between }"),
    S.Key("value", "number", required=False,
          doc="the guard fires when the measure, gap or holding force crosses this value"),
    S.Key("direction", "str", required=False, check=S.one_of(*_DIRECTIONS),
          doc="coordinate, gap and reaction guards: the sense of the crossing that fires"),
    S.Key("at", "number", required=False, check=S.non_negative, doc="time guard: the instant in s"),
    S.Key("every", "number", required=False, check=S.positive, doc="time guard: the period in s"),
    S.Key("start", "number", required=False, default=0.0, doc="time guard with every: the first instant in s"),
    S.Key("of", "str", required=False,
          doc="reaction guard: the locked joint, or the stop transition whose merge it watches"),
]
CONTACT_KEYS = [
    S.Key("a", "str", required=False, doc="point contact: the link (or the frame) carrying point_a"),
    S.Key("point_a", "list", required=False, check=S.vector(2), doc="point contact: [x, y] in link a's frame"),
    S.Key("b", "str", required=False, doc="point contact: the link whose point_b strikes"),
    S.Key("point_b", "list", required=False, check=S.vector(2), doc="point contact: [x, y] in link b's frame"),
    S.Key("normal", "list", required=False, check=S.nonzero_vector(2),
          doc="[nx, ny] in link a's frame, from a towards b"),
    S.Key("joint", "str", required=False, doc="a joint stop: the joint whose coordinate strikes the stop"),
    S.Key("arm", "number", required=False, check=S.positive,
          doc="joint stop: the lever (m) at which the impulse moment is also reported as a force"),
    S.Key("friction", "number|str", required=False, check=S.friction_coefficient,
          doc="point contacts: Coulomb's mu >= 0 along the tangent, or \"stick\" (no slip); absent: frictionless"),
    S.Key("restitution_law", "str", required=False, default="newton", check=S.one_of("newton", "poisson", "energetic"),
          doc="with friction: how the impact ends (Newton's kinematic law, Poisson's, Stronge's energetic)"),
]
POINT_CONTACT = ("a", "point_a", "b", "point_b", "normal")
TRANSITION_KEYS = [
    S.Key("name", "str", check=S.name, doc="the transition's name, as its events and holding force (NAME.hold) are named"),
    S.Key("type", "str", check=S.one_of(*TRANSITION_TYPES),
          doc="latch (locks on contact), stop (bounces with restitution), release (frees), pin (a point held where it strikes)"),
    S.Key("from", "str", doc="the configuration the guard is watched in"),
    S.Key("to", "str", required=False, doc="latch, release and pin: the configuration the run goes on in (required there)"),
    S.Key("merge_to", "str", required=False,
          doc="stop: the configuration the bodies merge into when the bounces accumulate"),
    S.Key("restitution", "number", required=False, check=S.unit_interval, doc="stop: Newton's coefficient e (required there)"),
    S.Key("cut", "list", required=False, check=S.distinct_names,
          doc="latch and stop, required there: the metamorphic joint(s) cut to solve the impulse; [] if none"),
    S.Key("guard", "table", doc="what fires the transition: { type, ... }, the keys of a guard"),
    S.Key("contact", "table", required=False,
          doc="latch, stop and pin: the two points that strike (a pin: b's point is held), or a joint stop"),
    S.Key("accumulation_speed", "number", required=False, check=S.non_negative,
          doc="stop: overrides [solver] accumulation_speed for this stop"),
    S.Key("accumulation_interval", "number", required=False, check=S.non_negative,
          doc="stop: overrides [solver] accumulation_interval for this stop"),
    S.Key("law", "str", required=False, default="impulse",
          check=S.one_of("impulse", "hunt_crossley", "lankarani_nikravesh", "flores"),
          doc="how the impact is resolved: the instantaneous impulse or a continuous contact-force law"),
    S.Key("stiffness", "number", required=False, check=S.positive, doc="continuous laws: k in N/m^n"),
    S.Key("exponent", "number", required=False, check=S.positive, doc="continuous laws: n, e.g. 1.5 (Hertz)"),
    S.Key("unmerge", "bool", required=False,
          doc="stop only: undo the merge when the holding force turns tensile (default: solver.unmerge)"),
]
DRIVE_KEYS = [
    S.Key("joint", "str", doc="the driven joint: its coordinate is prescribed, and its velocity comes from the drive"),
    S.Key("coefficients", "list", check=S.numbers_list, doc="q(t) = c0 + c1 t + c2 t^2 + ..."),
    S.Key("configurations", "list", required=False, check=S.configuration_names,
          doc="the configurations it drives in, each once (default: every one)"),
]
TOP_KEYS = [
    S.Key("scene", "table", doc="[scene]: name, gravity, t_end, the initial configuration"),
    S.Key("solver", "table", required=False, default={}, doc="[solver]: the integrator's settings"),
    S.Key("configurations", "table", doc="one [configurations.NAME] table per configuration"),
    S.Key("initial", "table", doc="[initial]: the state at t = 0"),
    S.Key("forces", "list", required=False, default=[], doc="[[forces]]: the force elements"),
    S.Key("transitions", "list", required=False, default=[], doc="[[transitions]]: guards and what they fire"),
    S.Key("drives", "list", required=False, default=[], doc="[[drives]]: prescribed coordinates"),
]


# ---- loading ----------------------------------------------------------------------
#: The largest initial angle accepted (rad).  A double's spacing grows with the angle: 1e-10 rad
#: at 1e6, 16 rad at 1e17, where every angle of the mechanism would freeze.
MAX_ANGLE = 1e6


def _too_large_angle(val) -> str:
    return (f"= {S.show(val)}: an angle beyond +-{MAX_ANGLE:g} rad loses its precision (at this size "
            f"neighbouring floating-point values are {math.ulp(float(val)):.3g} rad apart); "
            "give the angle modulo 2 pi")


def _inline_table_hint(text: str, exc: Exception) -> str:
    """A hint when the error comes inside an inline table `{ ...` left open at the end of a line:
    TOML 1.0 (what tomllib reads) keeps an inline table on one line, and its message does not say so."""
    import re
    m = re.search(r"at line (\d+)", str(exc))
    if not m:
        return ""
    lines = text.splitlines()
    depth = 0
    for line in lines[:int(m.group(1))]:  # up to the error line itself
        code = re.sub(r'"[^"]*"|\'[^\']*\'', "", line).split("#")[0]
        depth = max(depth + code.count("{") - code.count("}"), 0)
    return (" (an inline table { ... } runs past the end of its line: in TOML 1.0 an inline table must"
            " stay on one line; break lines inside a list [ ... ] instead)") if depth > 0 else ""


def _repeated_key_hint(text: str, exc: Exception) -> str:
    """Where a key or a table is given twice: tomllib says "Cannot overwrite a value (at end of
    document)" or "Cannot mutate immutable namespace ('contact',)", naming neither the key nor the
    line (a second `contact = { ... }` pasted into a cut joint's inline table read so)."""
    import re
    if not re.search(r"Cannot overwrite a value|Cannot mutate immutable namespace|Duplicate inline table key"
                     r"|Cannot declare", str(exc)):
        return ""
    tables: dict[str, int] = {}  # [header] -> its line
    seen: dict[tuple[str, str], int] = {}  # (header, key) -> its line, in the current table
    header = shown = ""
    for number, line in enumerate(text.splitlines(), 1):
        code = re.sub(r'"(?:[^"\\]|\\.)*"|\'[^\']*\'', '""', line).split("#")[0]
        m = re.match(r"\s*(\[\[?)\s*([^\]]+?)\s*\]\]?\s*$", code)
        if m:
            header = m.group(2)
            shown = f"{m.group(1)}{header}{']' * len(m.group(1))}"
            if m.group(1) == "[" and header in tables:
                return (f" (the table [{header}] is declared twice, on lines {tables[header]} and {number}; "
                        "TOML allows a table once: put its keys together)")
            tables.setdefault(header, number)
            seen = {k: v for k, v in seen.items() if k[0] != header}  # [[header]]: a new element
            continue
        m = re.match(r"\s*([A-Za-z0-9_.\-]+)\s*=", code)
        if m:
            key = (header, m.group(1))
            if key in seen:
                where = f"in {shown}" if header else "at the top level"
                return (f" (the key '{m.group(1)}' is given twice {where}, on lines {seen[key]} and {number}; "
                        "TOML allows a key once per table)")
            seen[key] = number
        stack: list[set] = []  # the keys of each inline table open on this line
        for k, ch in enumerate(code):
            if ch == "{":
                stack.append(set())
            elif ch == "}" and stack:
                stack.pop()
            elif stack and (k == 0 or not re.match(r"[A-Za-z0-9_\-]", code[k - 1])):
                km = re.match(r"([A-Za-z0-9_\-]+)\s*=(?!=)", code[k:])
                if km and (k == 0 or code[k - 1] in " {,\t"):
                    if km.group(1) in stack[-1]:
                        return (f" (the key '{km.group(1)}' is given twice in one inline table {{ ... }} on line "
                                f"{number}; TOML allows a key once per table)")
                    stack[-1].add(km.group(1))
    return ""


def _momentum_point(value) -> tuple[float, float] | str | None:
    """``[scene] momentum_point`` as the scene keeps it: (x, y), "contact", or None (the default)."""
    if isinstance(value, str):
        return value
    return tuple(value) if value else None


def _same_link(link: str) -> str:
    return (f"= {link!r}: a and b are the same link, so the cut joint closes no loop (it joins two different "
            "links, or a link and the frame)")


def measure_sign(force: ForceSpec, config: ConfigurationSpec) -> int | None:
    """How a force element's ``measure`` x relates to the coordinate its ``on`` acts along, in
    ``config``: +1 when x is that coordinate (plus a constant), so that ``-k (x - rest)`` is a spring
    with the potential ``k (x - rest)^2 / 2`` and ``-c x'`` a damper; -1 when x is minus it (the
    element is then a negative spring and damper: it drives x away from rest and feeds energy in);
    0 when x is another coordinate (the element does work that ``k (x - rest)^2 / 2`` does not
    account for); None where pcmm cannot tell (a point spring, a planar joint).

    A joint's coordinate is ``theta_child - theta_parent`` (revolute), a link's the absolute angle
    its ``on = { link }`` torque is conjugate to; links welded by fixed (or locked) joints are one
    body."""
    if force.points is not None or force.measure is None or force.on is None:
        return None
    info, m, on = config.info, force.measure, force.on
    locked = set(config.derivation.lock) if config.derivation is not None else set()
    parent_joint = {j.child: j for j in info.joints.values()}

    def body(link: str) -> str:  # the moving body a link is welded to (the root for the frame's)
        seen = set()
        while link in parent_joint and link not in seen:
            seen.add(link)
            j = parent_joint[link]
            if j.type != "fixed" and j.name not in locked:
                return link
            link = j.parent
        return link

    def angle_joint(link: str):  # the revolute joint whose coordinate is the link's absolute angle
        j = parent_joint.get(body(link))
        return j.name if j is not None and j.type == "revolute" and body(j.parent) == body(info.root) else None

    joints = [info.joints.get(n) for n in ([on.name] if on.kind == "joint" else []) +
              ([m.names[0]] if m.kind == "joint" else [])]
    if any(j is None or j.type == "planar" for j in joints):
        return None
    if on.kind == "joint":
        j = info.joints[on.name]
        if m.kind == "joint":
            return 1 if m.names[0] == on.name else 0
        if j.type != "revolute":
            return 0
        if m.kind == "link":
            return 1 if angle_joint(m.names[0]) == on.name else 0
        a, b = (body(n) for n in m.names)
        return 1 if (a, b) == (body(j.parent), j.child) else -1 if (a, b) == (j.child, body(j.parent)) else 0
    target = body(on.name)
    if m.kind == "link":
        return 1 if body(m.names[0]) == target else 0
    if m.kind == "joint":
        return 1 if angle_joint(on.name) == m.names[0] else 0
    a, b = (body(n) for n in m.names)
    frame = body(info.root)
    return 1 if (a, b) == (frame, target) else -1 if (a, b) == (target, frame) else 0


def load_scene(path: str | Path) -> Scene:
    """Read, validate and return the scene at ``path``.

    Parameters
    ----------
    path : str or pathlib.Path
        The scene file (TOML, never evaluated).  The URDF paths inside it resolve
        relative to the file, whatever the working directory.

    Returns
    -------
    Scene
        Frozen dataclasses (:mod:`pcmm.spec`), every name checked against the URDFs.

    Raises
    ------
    SceneError
        Every problem of the file and of its URDFs at once, each naming the file, the
        field, the bad value and what is allowed.

    Examples
    --------
    >>> import pcmm
    >>> scene = pcmm.load_scene("examples/three_bar.toml")
    >>> scene.name, scene.initial_configuration, list(scene.configurations)
    ('three_bar', 'config1', ['config1', 'config2'])
    >>> scene.transitions[0].type, scene.transitions[0].target, scene.solver.rtol
    ('latch', 'config2', 1e-10)
    """
    path = Path(path)
    try:
        if not path.is_file():
            raise SceneError(f"{path}: scene file not found")
        text = path.read_text(encoding="utf-8")
        path.resolve()
    except (OSError, ValueError, RuntimeError) as exc:  # NUL in the name, a symlink loop, no permission
        raise SceneError(f"{path!s:.200}: cannot read the scene file: {exc}") from None
    except UnicodeDecodeError as exc:
        raise SceneError(f"{path}: not UTF-8 text: {exc}") from None
    text = text.removeprefix("\ufeff")  # a byte-order mark some editors write: not part of the TOML
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML: {exc}{_inline_table_hint(text, exc)}"
                         f"{_repeated_key_hint(text, exc)}") from None
    except RecursionError:
        raise SceneError(f"{path}: not valid TOML for a scene: arrays or tables nested too deeply") from None
    except ValueError as exc:  # an integer of more than 4300 digits: Python's int limit
        raise SceneError(f"{path}: {_huge_integer(text) or f'not valid TOML for a scene: {exc}'}") from None
    S.check_plain(raw, str(path))
    return load_scene_data(raw, path)


_LONG_DIGITS = re.compile(r"(?<![\w.])[+-]?\d[\d_]{300,}")
_HEADER = re.compile(r"^\s*(\[\[?)\s*([^\]]+?)\s*\]\]?\s*(?:#.*)?$")
_KEY = re.compile(r"([A-Za-z0-9_\-]+|\"[^\"]*\"|'[^']*')\s*=")


def _huge_integer(text: str) -> str | None:
    """Where a scene holds an integer literal longer than Python's int conversion takes (tomllib
    refuses it with advice about ``sys.set_int_max_str_digits``, which is no help): 'line N:
    table.key: = an integer of 5000 digits: ...', the table and key found in the text."""
    limit = getattr(sys, "get_int_max_str_digits", lambda: 4300)() or math.inf
    m = next((m for m in _LONG_DIGITS.finditer(text) if len(m.group().lstrip("+-").replace("_", "")) > limit),
             None)
    if m is None:
        return None
    lines = text[:m.start()].split("\n")
    key, table, counts = None, "", {}
    for line in lines:
        h = _HEADER.match(line)
        if h:
            name = h.group(2).replace(" ", "")
            if h.group(1) == "[[":
                counts[name] = counts.get(name, -1) + 1
                table, key = f"{name}[{counts[name]}]", None
            else:
                table, key = name, None
            continue
        keys = _KEY.findall(line.split("#")[0])
        if keys:
            key = keys[-1].strip("\"'")  # the literal's own line: the key just before it
    field = ".".join(x for x in (table, key) if x) or "a value"
    digits = m.group().lstrip("+-").replace("_", "")
    return (f"line {len(lines)}: {field}: = an integer of {len(digits)} digits: beyond the range of a "
            "floating-point number (about 1.8e308)")  # the words of the schema's check of shorter ones


def with_values(scene: Scene, values) -> Scene:
    """Return a new :class:`~pcmm.scene.spec.Scene`: ``scene`` with each value path of ``values``
    set to its value (:mod:`pcmm.scene.variations`), validated as the TOML file is
    (:class:`SceneError`, the same messages).  What :meth:`Scene.with_values` calls."""
    raw = set_values(scene.source, values, scene.path)
    return load_scene_data(raw, scene.path, read=read_urdf_cached)


def load_scene_data(raw: dict, path: str | Path, read=read_urdf) -> Scene:
    """Validate and return the scene parsed from ``raw`` (a TOML document as a dict);
    ``path`` is the file it stands for (relative URDF paths, messages); ``read`` reads a URDF."""
    return _Builder(Path(path), raw, read).build()


class _Builder:
    def __init__(self, path: Path, raw: dict, read=read_urdf):
        self.read_urdf = read
        self.path = path
        self.base = path.resolve().parent
        self.raw = raw
        self.p = S.Problems(str(path))
        # configurations the file declares, valid or not: a reference to one whose own table is at
        # fault is not reported again as "no such configuration" (its own problem says it)
        self.declared: set[str] = set()
        # id(spec) -> the place of its table in the file (``transitions[3] (name)``): a table at fault
        # is not built, so a built spec's index among its kind's specs is not its place in the file
        self.places: dict[int, str] = {}

    # -- helpers
    def _placed(self, out: list, marks: list[tuple[int, str]]) -> None:
        """Note the place of each spec of ``out`` (``marks``: (len(out), place) where each table's build
        began), for the cross-checks' messages (:meth:`_place`)."""
        for (start, where), (end, _) in zip(marks, marks[1:] + [(len(out), "")]):
            for spec in out[start:end]:
                self.places[id(spec)] = where

    def _said(self, where: str) -> bool:
        """A problem of ``where`` is reported already (a check run once per configuration says it once)."""
        return any(x.startswith(f"{self.p.file}: {where}:") for x in self.p.items)

    def _place(self, spec, fallback: str) -> str:
        """Where ``spec``'s table stands in the file (``fallback`` for a spec built elsewhere)."""
        return self.places.get(id(spec), fallback)
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
            if m["between"][0] == m["between"][1]:
                self.p.add(f"{where}.between", f"= {S.show(m['between'])}: names '{m['between'][0]}' twice; a link's "
                           "angle relative to itself is 0 at all times: name two different links [A, B]")
                return None
            return Measure("between", tuple(m["between"]))
        return Measure(kind, (m[kind],))

    def _branch(self, table) -> BranchSpec | None:
        if table is None:
            return None
        sign = table.get("sign")
        if sign not in ("+", "-"):
            self.p.add("initial.branch.sign", f"= {S.show(sign)}: must be \"+\" or \"-\" (the sign of the angle "
                       "in (-pi, pi] on the assembly to start on)" if sign is not None else "missing; \"+\" or \"-\"")
        m = self._measure({k: v for k, v in table.items() if k != "sign"}, "initial.branch")
        return BranchSpec(m, 1 if sign == "+" else -1) if m is not None and sign in ("+", "-") else None

    def _target(self, table, where) -> Target | None:
        keys = [S.Key("joint", "str", required=False), S.Key("link", "str", required=False)]
        t = S.check_table(table, keys, where, self.p)
        given = [k for k in ("joint", "link") if t.get(k) is not None]
        if len(given) != 1:
            self.p.add(where, "give exactly one of joint = NAME or link = NAME")
            return None
        return Target(given[0], t[given[0]])

    def _list_of_tables(self, items, keys, where, unique: str | None = None):
        """Each table of an array of tables with its place: ``transitions[2] (O2 pin)``, the
        index and, where the table names itself, the name (as every later message about it).
        With ``unique`` (why), a name given to an earlier table of the array is refused: the run
        keys series, events and references by name, so the second would silently stand in for
        the first (or both for one)."""
        out, first = [], {}
        for i, item in enumerate(items or []):
            raw = item if isinstance(item, dict) else {}
            name = raw.get("name")
            place = f"{where}[{i}] ({name})" if isinstance(name, str) and name else f"{where}[{i}]"
            out.append((place, S.check_table(item, keys, place, self.p), raw))
            if unique is not None and isinstance(name, str) and name.strip():
                if name in first:
                    self.p.add(f"{place}.name", f"= {name!r}: already the name of {first[name]}; {unique}")
                first.setdefault(name, place)
        return out

    # -- the build
    def build(self) -> Scene:
        top = S.check_table(self.raw, TOP_KEYS, "", self.p)
        sc = S.check_table(top["scene"] or {}, SCENE_KEYS, "scene", self.p) if top["scene"] is not None else {}
        solver = S.check_table(top["solver"] if top["solver"] is not None else {}, settings.solver_keys(), "solver",
                               self.p)
        configs = self._configurations(top["configurations"] or {})
        self._joint_types_agree(configs)
        forces = self._forces(top["forces"])
        transitions = self._transitions(top["transitions"], configs)
        drives = self._drives(top["drives"])
        init = S.check_table(top["initial"] or {}, INITIAL_KEYS, "initial", self.p) if top["initial"] is not None else {}
        initial = sc.get("initial_configuration")
        if initial is not None and initial not in configs and initial not in self.declared and top["configurations"]:
            self.p.add("scene.initial_configuration", f"= {initial!r}: no such configuration; "
                       f"defined: {', '.join(configs) or '(none valid)'}")
        if initial in configs and configs[initial].derivation is not None:
            from .derive import check_initial
            check_initial(configs, initial, self.p)
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
            solver=settings.solver_settings_type()(**{k: v for k, v in solver.items() if v is not None}),
            branch=self._branch(init.get("branch")),
            momentum_point=_momentum_point(sc.get("momentum_point")),
            source=self.raw, loader=with_values,
        )
        self._cross_check(scene)
        if self.p:
            raise SceneError(self.p.items)
        return scene

    def _configurations(self, table) -> dict[str, ConfigurationSpec]:
        out, derived = {}, {}
        self.declared = set(table) if isinstance(table, dict) else set()
        if not table:
            self.p.add("configurations", "needs at least one [configurations.NAME] table")
        for name, body in table.items():
            where = f"configurations.{name}"
            c = S.check_table(body, CONFIG_KEYS, where, self.p)
            if isinstance(body, dict) and ("from" in body or "lock" in body):
                derived[name] = (c, body)  # resolved once every URDF configuration is read
                continue
            if c["urdf"] is None:
                if isinstance(body, dict) and "urdf" not in body:
                    self.p.add(f"{where}.urdf", "missing; give urdf = PATH, or from = NAME with lock = [joints] "
                               "for a configuration derived by locking joints")
                continue
            try:
                urdf = (self.base / c["urdf"]).resolve()
                info = self.read_urdf(urdf)
            except ModelError as exc:
                for prob in exc.problems:
                    self.p.add(f"{where}.urdf", prob)
                continue
            except (OSError, ValueError, RuntimeError) as exc:  # NUL in the path, a symlink loop
                self.p.add(f"{where}.urdf", f"= {S.show(c['urdf'])}: cannot read this file: {exc}")
                continue
            out[name] = ConfigurationSpec(name=name, urdf=urdf, info=info,
                                          cut_joints=self._cut_joints(c["cut_joints"], where))
            for k, cj in enumerate(out[name].cut_joints):
                if cj.anchor_at_entry and cj.a != info.root:
                    self.p.add(f"{where}.cut_joints[{k}].point_a", f"= 'entry': the anchor is fixed in the world, so "
                               f"link a must be the frame ('{info.root}', the URDF's root), not '{cj.a}'")
                elif cj.anchor_at_entry and cj.b == cj.a:
                    self.p.add(f"{where}.cut_joints[{k}].b", _same_link(cj.b))
        if derived:
            from .derive import derive_configurations
            out.update(derive_configurations(derived, out, self.p, self._cut_joints, declared=list(table)))
        return out

    def _cut_joints(self, items, where) -> tuple[CutJointSpec, ...]:
        cuts = []
        for cw, cj, _ in self._list_of_tables(
                items, CUT_JOINT_KEYS, f"{where}.cut_joints",
                unique="the cut joints of one configuration need distinct names: their constraint forces "
                       "(NAME.fx, NAME.fy, ...) and impulses are reported under them, and a transition's cut and a "
                       "reaction guard's of name them (two of one name gave NaN impulses)"):
            if None in (cj["name"], cj["type"], cj["a"], cj["point_a"], cj["b"], cj["point_b"]):
                continue
            if cj["a"] == cj["b"] and cj["point_a"] != "entry":  # an entry anchor's a: the frame (said below)
                self.p.add(f"{cw}.b", _same_link(cj["b"]))
                continue
            if cj["type"] == "prismatic" and cj["axis"] is None:
                self.p.add(f"{cw}.axis", "missing; a prismatic cut joint needs its sliding axis [x, y]")
            if cj["type"] in ("prismatic", "weld") and cj["angle"] is None:
                self.p.add(f"{cw}.angle", f"missing; a {cj['type']} cut joint needs the relative angle it holds")
            entry = cj["point_a"] == "entry"
            if entry and cj["type"] != "revolute":
                self.p.add(f"{cw}.point_a", f"= 'entry': only a revolute cut joint is anchored where it is entered "
                           f"(this one is {cj['type']!r})")
            normal = mu = None
            if cj["contact"] is not None:
                c = S.check_table(cj["contact"], PIN_CONTACT_KEYS, f"{cw}.contact", self.p)
                if cj["type"] != "revolute":
                    self.p.add(f"{cw}.contact", "only a revolute cut joint (a pinned point) is held by compression only")
                normal = tuple(c["normal"]) if c["normal"] is not None else None
                mu = None if c["friction"] is None else math.inf if c["friction"] == "stick" else float(c["friction"])
            cuts.append(CutJointSpec(cj["name"], cj["type"], cj["a"], (0.0, 0.0) if entry else tuple(cj["point_a"]),
                                     cj["b"], tuple(cj["point_b"]),
                                     tuple(cj["axis"]) if cj["axis"] else None, cj["angle"],
                                     anchor_at_entry=entry, normal=normal, friction=mu))
        return tuple(cuts)

    def _forces(self, items) -> list[ForceSpec]:
        out, marks = [], []
        for where, f, raw in self._list_of_tables(
                items, FORCE_KEYS, "forces",
                unique="each force element needs its own name: its force and energy are reported over time under "
                       "it, and a second element of that name would overwrite the first's series"):
            marks.append((len(out), where))
            if f["type"] is None or f["name"] is None:
                continue
            if "configurations" in raw and f["configurations"] is None:
                continue  # its list is at fault (said): read as None it would act in every configuration
            if f["type"] == "point_spring":
                out += self._point_spring(where, f, raw)
                continue
            for k in ("a", "point_a", "b", "point_b"):
                if k in raw:
                    self.p.add(f"{where}.{k}", f"only used by a 'point_spring' force (a {f['type']!r} force "
                               "acts on a joint or link: give on = {joint = NAME} or {link = NAME})")
            if f["on"] is None:
                if "on" not in raw:
                    self.p.add(f"{where}.on", f"missing; a {f['type']!r} force acts on {{joint = NAME}} or {{link = NAME}}")
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
        self._placed(out, marks)
        return out

    def _point_spring(self, where, f, raw) -> list[ForceSpec]:
        """A spring-damper between two points: the points and k, rest are required, on and measure
        are not used (the element measures the distance itself)."""
        required, allowed = FORCE_TYPES["point_spring"]
        for k in ("a", "point_a", "b", "point_b"):
            if k not in raw:
                self.p.add(f"{where}.{k}", "missing; a 'point_spring' force needs a, point_a, b and point_b "
                           "(the links and the points in their frames it connects)")
        for k in sorted(required - set(raw)):
            self.p.add(f"{where}.{k}", "missing; a 'point_spring' force needs k (N/m) and rest (its rest length, m)")
        for k in ("on", "measure"):
            if k in raw:
                self.p.add(f"{where}.{k}", "not used by a 'point_spring' force (it acts along the line between "
                           "its two points and measures their distance)")
        if f["rest"] is not None and f["rest"] < 0:
            self.p.add(f"{where}.rest", f"= {S.show(f['rest'])}: a rest length must be >= 0 (m)")
            return []
        if f["a"] is not None and f["a"] == f["b"]:
            self.p.add(f"{where}.b", f"= {f['b']!r}: both points are on the same link, so the distance never changes "
                       "(connect two different links, or a link and the frame)")
            return []
        if None in (f["a"], f["point_a"], f["b"], f["point_b"], f["value"], f["k"], f["rest"], f["c"]) \
                or not required <= set(raw):
            return []
        return [ForceSpec(f["name"], f["type"], None, None, float(f["value"]), float(f["k"]), float(f["rest"]),
                          float(f["c"]), tuple(f["configurations"]) if f["configurations"] else None,
                          PointPair(f["a"], tuple(float(x) for x in f["point_a"]), f["b"],
                                    tuple(float(x) for x in f["point_b"])))]

    def _transitions(self, items, configs) -> list[LatchSpec | StopSpec | ReleaseSpec]:
        out, marks = [], []
        for where, t, raw in self._list_of_tables(
                items, TRANSITION_KEYS, "transitions",
                unique="each transition needs its own name: its events, a stop's holding force (NAME.hold) and "
                       "bounce interval, and a reaction guard's of are keyed by it"):
            marks.append((len(out), where))
            if None in (t["name"], t["type"], t["from"], t["guard"]):
                continue
            kind = t["type"]
            guard = self._guard(t["guard"], f"{where}.guard", kind)
            e = t["restitution"]
            if kind in ("latch", "stop"):
                if t["contact"] is None and "contact" not in raw:  # given but bad: said by check_table
                    self.p.add(f"{where}.contact", f"missing; a {kind} needs the contact that strikes: "
                               "{ a, point_a, b, point_b, normal } or a joint stop { joint, arm }")
                if t["cut"] is None and "cut" not in raw:
                    self.p.add(f"{where}.cut", "missing; the metamorphic joint(s) cut to solve the impulse, [] if none")
            if kind == "latch":
                if t["to"] is None:
                    self.p.add(f"{where}.to", "missing; a latch names the configuration it switches to")
                elif t["to"] == t["from"]:
                    self.p.add(f"{where}.to", f"= {t['to']!r}: the configuration the latch is watched in (from), so "
                               "nothing would lock and the latch would strike again at once; name the configuration "
                               "in which the latched joint is fixed")
                for k in ("restitution", "merge_to", "unmerge"):
                    if k in raw:
                        self.p.add(f"{where}.{k}", "not used by a latch (the merge is perfectly plastic, e = 0)")
                for k in ("accumulation_speed", "accumulation_interval"):
                    if k in raw:
                        self.p.add(f"{where}.{k}", "not used by a latch (it locks at its first strike: there are "
                                   "no bounces to accumulate)")
                e = 0.0
            elif kind == "stop":
                if t["to"] is not None:
                    self.p.add(f"{where}.to", "not used by a stop (the configuration does not change); "
                               "name the merged configuration with merge_to")
                if "restitution" not in raw:
                    self.p.add(f"{where}.restitution", "missing; a stop needs Newton's coefficient e in [0, 1]")
                if t["merge_to"] is not None and t["merge_to"] == t["from"]:
                    self.p.add(f"{where}.merge_to", f"= {t['merge_to']!r}: the configuration the stop is watched in "
                               "(from), so the bodies would not merge (the last bounce made plastic, then free "
                               "again); name the configuration in which they are merged")
            elif kind == "pin":
                if t["to"] is None:
                    self.p.add(f"{where}.to", "missing; a pin names the configuration whose cut joint holds the "
                               "struck point (point_a = \"entry\")")
                if t["contact"] is None and "contact" not in raw:
                    self.p.add(f"{where}.contact", "missing; a pin needs the point contact that strikes: "
                               "{ a, point_a, b, point_b, normal }")
                for k in ("restitution", "merge_to", "unmerge", "law", "stiffness", "exponent",
                          "accumulation_speed", "accumulation_interval"):
                    if k in raw:
                        self.p.add(f"{where}.{k}", "not used by a pin (the strike is plastic and the point stays)")
                if t["cut"]:
                    self.p.add(f"{where}.cut", "a pin's impulse is solved with every constraint of its target "
                               "configuration at once; it cuts no joint (give [] or leave it out)")
                e = 0.0
            elif kind == "release":
                if t["to"] is None:
                    self.p.add(f"{where}.to", "missing; a release names the configuration with more freedom it goes to")
                for k in ("contact", "cut", "restitution", "merge_to", "unmerge", "law", "stiffness", "exponent",
                          "accumulation_speed", "accumulation_interval"):
                    if k in raw:
                        self.p.add(f"{where}.{k}", "not used by a release (a transformation that frees a joint "
                                   "carries no impulse, paper section 2.2)")
                e = 0.0
            law = t["law"]
            if law is not None and law != "impulse":
                if kind != "stop":
                    self.p.add(f"{where}.law", f"= {law!r}: a continuous contact law resolves a stop; "
                               "a latch locks on contact (law = 'impulse')")
                for k in ("stiffness", "exponent"):
                    if k not in raw:
                        self.p.add(f"{where}.{k}", f"missing; the {law!r} contact law needs stiffness and exponent")
                if law == "flores" and e is not None and e <= 0:
                    self.p.add(f"{where}.restitution", f"= {e!r}: the Flores law needs e > 0 (its damping is 8(1-e)/(5e))")
            elif kind != "release":
                for k in ("stiffness", "exponent"):
                    if k in raw:
                        self.p.add(f"{where}.{k}", "only used with a continuous contact law (law = 'hunt_crossley', "
                                   "'lankarani_nikravesh' or 'flores')")
            contact = None
            if kind != "release" and t["contact"] is not None:
                contact = self._contact(t["contact"], f"{where}.contact", guard, configs.get(t["from"]))
                if contact is None:
                    continue
            if contact is not None and contact.friction is not None and (t["law"] or "impulse") != "impulse":
                self.p.add(f"{where}.contact.friction", f"a continuous contact law ({t['law']!r}) acts along the "
                           "normal only; friction needs the impulse law (law = 'impulse')")
            if kind == "pin" and contact is not None and contact.joint is not None:
                self.p.add(f"{where}.contact.joint", "a pin needs a point contact (a, point_a, b, point_b, normal)")
                continue
            if kind == "pin" and contact is not None and guard is not None and t["to"] is not None:
                out.append(PinSpec(name=t["name"], source=t["from"], cut=(), guard=guard, contact=contact,
                                   target=t["to"]))
                continue
            if guard is None or e is None or (kind != "release" and (contact is None or t["cut"] is None)):
                continue
            common = dict(name=t["name"], source=t["from"], cut=tuple(t["cut"] or ()), guard=guard, contact=contact)
            if kind == "latch":  # a missing 'to' is reported above; the rest is still cross-checked
                out.append(LatchSpec(**common, target=t["to"]))
            elif kind == "release":
                out.append(ReleaseSpec(**common, target=t["to"]))
            else:
                out.append(StopSpec(
                    **common, restitution=float(e), merge_to=t["merge_to"],
                    accumulation_speed=t["accumulation_speed"], accumulation_interval=t["accumulation_interval"],
                    law=t["law"] or "impulse", stiffness=t["stiffness"], exponent=t["exponent"],
                    unmerge=t["unmerge"]))
        self._placed(out, marks)
        return out

    def _guard(self, table, where, kind) -> GuardSpec | None:
        g = S.check_table(table, GUARD_KEYS, where, self.p)
        # a key written but at fault (a broken expression, a wrong type) is given: its own problem
        # is reported, not a second one saying it is missing
        raw = table if isinstance(table, dict) else {}
        given = {k for k in ("measure", "value", "direction", "at", "every", "start", "of") if k in raw}
        failed = any(g.get(k) is None for k in given)
        needs = {"coordinate": {"measure", "value", "direction"}, "gap": {"value", "direction"},
                 "time": set(), "reaction": {"of", "value", "direction"}, "entry": set()}.get(g["type"])
        allowed = {"coordinate": {"measure", "value", "direction"}, "gap": {"value", "direction"},
                   "time": {"at", "every", "start"}, "reaction": {"of", "value", "direction"},
                   "entry": set()}.get(g["type"])
        if needs is None:
            return None
        ok = not failed
        for k in sorted(needs - given):
            self.p.add(f"{where}.{k}", f"missing; {'an' if g['type'][0] in 'aeiou' else 'a'} {g['type']} guard needs "
                       f"{', '.join(sorted(needs))}")
            ok = False
        for k in sorted(given - allowed):
            article = "an" if g["type"][0] in "aeiou" else "a"
            self.p.add(f"{where}.{k}", f"not used by {article} {g['type']} guard (it takes "
                       f"{', '.join(sorted(allowed)) or 'no other key: it fires the instant its configuration is entered'})")
            ok = False
        if g["type"] == "entry" and kind != "release":
            self.p.add(f"{where}.type", f"= 'entry': only a release fires the instant its configuration is entered "
                       f"(it carries no impulse); a {kind} strikes where its contact closes: use a coordinate or "
                       "gap guard")
            ok = False
        if g["type"] == "time" and (("at" in given) == ("every" in given)):
            self.p.add(where, "a time guard takes either at (one instant) or every (a period, from start)")
            ok = False
        elif g["type"] == "time" and "start" in given and "every" not in given:
            self.p.add(f"{where}.start", "only used with every (the first instant of a period); a time guard "
                       "with at fires at that instant")
            ok = False
        if g["type"] == "gap" and kind == "release":
            self.p.add(f"{where}.type", "= 'gap': a release has no contact; use a coordinate, time or reaction guard")
            ok = False
        measure = self._measure(g["measure"], f"{where}.measure") if g["type"] == "coordinate" and \
            g["measure"] is not None else None
        if g["type"] == "coordinate" and measure is None:
            ok = False
        when = None
        if g["when"] is not None:
            w = S.check_table(g["when"], WHEN_KEYS, f"{where}.when", self.p)
            if g["type"] not in ("coordinate", "gap"):
                self.p.add(f"{where}.when", f"only a coordinate or gap guard is armed by a region (this one is {g['type']!r})")
                ok = False
            elif (w["above"] is None) == (w["below"] is None):
                self.p.add(f"{where}.when", "give exactly one of above = VALUE or below = VALUE")
                ok = False
            else:
                wm = self._measure(w["measure"], f"{where}.when.measure") if w["measure"] is not None else None
                if wm is None:
                    ok = False
                else:
                    when = (wm, +1, float(w["above"])) if w["above"] is not None else (wm, -1, float(w["below"]))
        if not ok:
            return None
        return GuardSpec(g["type"], measure, float(g["value"] or 0.0),
                         _DIRECTIONS[g["direction"]] if g["direction"] else +1,
                         at=g["at"], every=g["every"], start=float(g["start"] or 0.0), of=g["of"], when=when)

    def _contact(self, table, where, guard: GuardSpec | None, source: ConfigurationSpec | None) -> ContactSpec | None:
        c = S.check_table(table, CONTACT_KEYS, where, self.p)
        points = [k for k in POINT_CONTACT if c[k] is not None]
        if c["joint"] is None:
            for k in POINT_CONTACT:
                if c[k] is None and not (isinstance(table, dict) and k in table):  # given but bad: said above
                    self.p.add(f"{where}.{k}", "missing; a contact names a, point_a, b, point_b and normal "
                               "(or is a joint stop: { joint, arm })")
            if c["arm"] is not None:
                self.p.add(f"{where}.arm", "only used by a joint stop ({ joint = NAME, arm = ... })")
            if len(points) < len(POINT_CONTACT):
                return None
            mu = c["friction"]
            return ContactSpec(c["a"], tuple(c["point_a"]), c["b"], tuple(c["point_b"]), tuple(c["normal"]),
                               friction=None if mu is None else math.inf if mu == "stick" else float(mu),
                               restitution_law=c["restitution_law"] or "newton")
        for k in ("friction", "restitution_law"):
            if isinstance(table, dict) and k in table:
                self.p.add(f"{where}.{k}", "only used by a point contact (a joint stop has no tangent)")
        for k in points:
            self.p.add(f"{where}.{k}", "not used by a joint stop (the joint's links and axis give the contact)")
        if guard is None or source is None:
            return None
        uj = source.info.joints.get(c["joint"])
        if uj is None or uj.type not in ("revolute", "prismatic", "continuous"):
            movable = [n for n, j in source.info.joints.items() if j.type in ("revolute", "prismatic", "continuous")]
            self.p.add(f"{where}.joint", f"= {c['joint']!r}: a joint stop needs a revolute or prismatic joint of "
                       f"'{source.name}' ({source.urdf.name}); its movable joints: {', '.join(movable) or '(none)'}")
            return None
        # the stop's position and approach side come from the guard, so the two cannot disagree
        m = guard.measure
        sign = None
        if guard.type == "coordinate" and m is not None:
            if m.kind == "joint" and m.names[0] == c["joint"]:
                sign, value = 1, guard.value
            elif m.kind == "between" and uj.type != "prismatic" and set(m.names) == {uj.parent, uj.child}:
                # theta_child - theta_parent = q + the joint origin's yaw
                sign = 1 if m.names == (uj.parent, uj.child) else -1
                value = sign * guard.value - uj.rpy[2]
        if sign is None:
            self.p.add(f"{where}.joint", f"= {c['joint']!r}: a joint stop takes its position from the transition's "
                       f"coordinate guard, which must measure that joint (measure = {{ joint = \"{c['joint']}\" }}) "
                       f"or the angle between its links (between = [\"{uj.parent}\", \"{uj.child}\"])")
            return None
        if uj.type == "prismatic" and c["arm"] is not None:
            self.p.add(f"{where}.arm", f"= {c['arm']!r}: a lever arm belongs to a revolute joint stop; the stop on "
                       f"prismatic joint '{c['joint']}' already reports its axial impulse (N s): remove `arm`")
            return None
        return ContactSpec(uj.parent, None, uj.child, None, None, joint=c["joint"], arm=c["arm"],
                           stop_value=float(value), stop_sign=sign * guard.direction)

    def _drives(self, items) -> list[DriveSpec]:
        out, marks = [], []
        for where, d, raw in self._list_of_tables(items, DRIVE_KEYS, "drives"):
            marks.append((len(out), where))
            if None in (d["joint"], d["coefficients"]):
                continue
            if "configurations" in raw and d["configurations"] is None:
                continue  # its list is at fault (said): read as None it would drive in every configuration
            out.append(DriveSpec(d["joint"], tuple(float(x) for x in d["coefficients"]),
                                 tuple(d["configurations"]) if d["configurations"] else None))
        self._placed(out, marks)
        return out

    def _joint_values(self, table, where, config: ConfigurationSpec | None) -> dict[str, float]:
        out = {}
        if table is None or config is None:
            return out
        movable = config.info.movable_joints
        for name, val in table.items():
            val, bad = S.numbers(val)
            if bad:
                self.p.add(f"{where}.{name}", bad)
                continue
            if name not in config.info.joints:
                self._unknown(f"{where}.{name}", "joint", name, movable, config)
            elif name not in movable:
                self.p.add(f"{where}.{name}", f"joint '{name}' is fixed in configuration '{config.name}'")
            elif isinstance(val, list) and config.info.joints[name].type == "planar":
                if S.vector(3)(val):
                    self.p.add(f"{where}.{name}", f"= {S.show(val)}: a planar joint takes [x, y, theta]")
                elif where == "initial.q" and abs(val[2]) > MAX_ANGLE:
                    self.p.add(f"{where}.{name}[2]", _too_large_angle(val[2]))
                else:
                    out[name] = tuple(float(x) for x in val)
            elif not S._type_ok("number", val) or not math.isfinite(val):
                self.p.add(f"{where}.{name}", f"= {S.show(val)}: must be a finite number")
            elif where == "initial.q" and config.info.joints[name].type == "revolute" and abs(val) > MAX_ANGLE:
                self.p.add(f"{where}.{name}", _too_large_angle(val))
            else:
                out[name] = float(val)
        # in a closed loop the dependent velocities follow from the independent ones: they may be left out
        # (pcmm.assembly says which given or missing velocity it replaced or took as zero)
        optional = where == "initial.v" and bool(config.cut_joints)
        for name in movable:
            if name not in table and not optional:
                self.p.add(where, f"joint '{name}' of configuration '{config.name}' has no value; "
                           f"give every movable joint: {', '.join(movable)}")
        return out

    def _joint_types_agree(self, configs: dict) -> None:
        """A joint keeps its name only with its type: states map from one configuration to the
        next by joint name, and a planar joint's (x, y, theta) cannot become one angle."""
        first: dict[str, tuple[str, str]] = {}
        for cname, spec in configs.items():
            for jname, j in spec.info.joints.items():
                if j.type not in MOVABLE:
                    continue
                seen = first.setdefault(jname, (j.type, cname))
                if seen[0] != j.type:
                    self.p.add(f"configurations.{cname}.urdf",
                               f"joint '{jname}' is {j.type} in '{cname}' ({spec.urdf.name}) but {seen[0]} in "
                               f"'{seen[1]}' ({configs[seen[1]].urdf.name}); the state passes between "
                               "configurations by joint name, so give the two joints different names")

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

    def _loops_keep_a_coordinate_per_row(self, scene: Scene, cfg: ConfigurationSpec) -> None:
        """The initial assembly solves the loops' constraint rows for the coordinates they involve that
        are neither kept (``[initial] independent``) nor driven: fewer of those than rows, where the drives
        alone leave enough, is a kept list that over-determines the loop (the assembly would otherwise fail
        as a Newton solve that diverged, or as a singular posture).  Where the drives and locks alone leave
        fewer coordinates than rows, the rows are dependent whatever is kept, and dependent rows may be
        consistent (a crank driven where a locked slide and the loop hold it): the assembly judges them by
        their rank (pcmm.model.partitioned), so nothing is refused here.  A cut joint's rows involve the
        joints on the tree paths of its two links that the paths do not share (a shared joint moves both
        links rigidly)."""
        rows = {cj.name: CUT_JOINT_TYPES[cj.type] for cj in cfg.cut_joints}
        if not rows or len(rows) < len(cfg.cut_joints):  # no loop, or a cut joint's name given twice (said)
            return
        locked = set(cfg.derivation.lock) if cfg.derivation is not None else set()
        by_child = {j.child: j for j in cfg.info.joints.values()}

        def path(link: str) -> set[str]:
            out = set()
            while link in by_child and len(out) <= len(by_child):
                out.add(by_child[link].name)
                link = by_child[link].parent
            return out
        involved: set[str] = set()
        for cj in cfg.cut_joints:
            involved |= path(cj.a) ^ path(cj.b)
        joints = {n: j for n, j in cfg.info.joints.items()
                  if n in involved and j.type in MOVABLE and n not in locked}
        total = sum(3 if j.type == "planar" else 1 for j in joints.values())
        kept: dict[str, str] = {}  # coordinate -> why it is kept
        for name in scene.independent:
            joint, _, part = name.rpartition(".")
            if name in joints:
                kept[f"{name}.x" if joints[name].type == "planar" else name] = "independent"
            elif joint in joints and part in ("x", "y", "theta"):
                kept[name] = "independent"
        for d in scene.drives:
            if d.joint in joints and (d.configurations is None or cfg.name in d.configurations):
                kept.setdefault(d.joint, f"driven by {self._place(d, f'drives[{scene.drives.index(d)}]')}")
        free = total - len(kept)
        if sum(rows.values()) <= free:
            return
        driven = sum(1 for why in kept.values() if why.startswith("driven"))
        if sum(rows.values()) > total - driven:
            # more rows than the drives leave coordinates: the rows are dependent whatever is kept, and
            # dependent rows may be consistent (a crank driven where the loop and a locked slide hold it,
            # a cut joint given twice): the assembly judges them by their rank, and names any it cannot
            # satisfy (pcmm.model.partitioned); counting here would refuse a posture that exists
            return
        where = "initial.independent" if scene.independent else "drives"
        value = f"= {list(scene.independent)}: " if scene.independent else ""
        self.p.add(where, f"{value}the loops of configuration '{cfg.name}' involve {total} coordinates "
                   f"({', '.join(joints)}), {len(kept)} of them kept at t = 0 "
                   f"({', '.join(f'{k}: {why}' for k, why in kept.items())}), which leaves {free} for the "
                   f"{sum(rows.values())} constraint rows of its cut joints "
                   f"({', '.join(f'{n}: {r}' for n, r in rows.items())}): no posture satisfies them all; keep "
                   f"fewer coordinates (a driven joint is kept by its drive: leave it out of independent)")

    def _one_coordinate(self, where, name, config, advice) -> None:
        """A force's ``on`` joint or a drive's joint is one coordinate: a planar joint's three
        (x, y, theta) were read as its x alone, silently."""
        j = config.info.joints.get(name)
        if j is not None and j.type == "planar" and not self._said(where):
            self.p.add(where, f"= {name!r}: a planar joint has three coordinates (x, y, theta) in configuration "
                       f"'{config.name}', and this acts along one (it was read as {name}.x alone); {advice}")

    def _check_coordinate(self, where, name, config):
        """A joint, or one coordinate of a planar joint ("P.x", "P.y", "P.theta")."""
        joint, _, part = name.rpartition(".")
        if name in config.info.joints or not joint or joint not in config.info.joints:
            self._check_joint(where, name, config)
        elif config.info.joints[joint].type != "planar" or part not in ("x", "y", "theta"):
            self.p.add(where, f"= {name!r}: only a planar joint's coordinates are named by a part, and its parts "
                       f"are .x, .y, .theta ('{joint}' is {config.info.joints[joint].type} in configuration "
                       f"'{config.name}')")

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
            elif n not in self.declared:
                self.p.add(where, f"= {n!r}: no such configuration; defined: {', '.join(scene.configurations)}")
        return out

    @staticmethod
    def _negative_element(f: ForceSpec, cfg: ConfigurationSpec) -> str:
        """Why an element whose measure is minus the coordinate it acts along is refused."""
        a, b = f.measure.names
        if f.on.kind == "joint":
            j = cfg.info.joints[f.on.name]
            along = f"joint '{j.name}' ({j.parent} -> {j.child}), whose coordinate is theta_{j.child} - theta_{j.parent}"
        else:
            along = f"the angle of '{f.on.name}'"
        parts = [w for w, x in (("stiffness", f.k), ("damping", f.c)) if x > 0]
        verb = "drive" if len(parts) > 1 else "drives"
        rest = f", with rest = {-f.rest:g} (a value of the measure)" if f.rest else ""
        return (f"= between {list(f.measure.names)} is theta_{b} - theta_{a}, minus the coordinate the element acts "
                f"along (on = {{ {f.on.kind} = '{f.on.name}' }}: {along}), so its {' and '.join(parts)} {verb} that "
                f"coordinate away from rest and feed{'s' if verb == 'drives' else ''} energy in, as k < 0 or c < 0 "
                f"would; write between = {[b, a]!r}{rest}")

    def _entry_guards(self, scene: Scene) -> None:
        """Releases fired on entry (``guard = { type = "entry" }``): one per configuration (a second
        would never fire: the first leaves at the entry instant), and no cycle of them (entering one
        configuration of it would switch round it for ever without time passing)."""
        entry = {}  # configuration -> (index, transition) of the release that leaves it on entry
        for i, t in enumerate(scene.transitions):
            if t.guard.type != "entry":
                continue
            if t.source in entry:
                j, first = entry[t.source]
                self.p.add(f"{self._place(t, f'transitions[{i}] ({t.name})')}.guard.type",
                           f"= 'entry': {self._place(first, f'transitions[{j}] ({first.name})')} already leaves '{t.source}' the instant it is "
                           "entered, so this release would never fire; give one of them another guard")
                continue
            entry[t.source] = (i, t)
        reported = set()
        for start in entry:
            path, at = [], start
            while at in entry and at not in path:
                path.append(at)
                at = entry[at][1].target
            if at not in path or at in reported:
                continue
            loop = path[path.index(at):]
            reported.update(loop)
            i, t = entry[at]
            names = " -> ".join(f"'{c}' ({entry[c][1].name})" for c in loop) + f" -> '{at}'"
            self.p.add(f"{self._place(t, f'transitions[{i}] ({t.name})')}.guard.type",
                       f"= 'entry': the releases fired on entry form a cycle, {names}: entering any of them the run "
                       "would switch round it for ever at one instant; give one of them another guard")

    def _cross_check(self, scene: Scene) -> None:
        names = scene.configurations
        self._entry_guards(scene)
        for i, f in enumerate(scene.forces):
            where = self._place(f, f"forces[{i}] ({f.name})")
            for cfg in self._configs_for(f"{where}.configurations", f.configurations, scene):
                tail = "" if f.configurations else " (the force applies in every configuration unless it lists configurations)"
                n0 = len(self.p.items)
                if f.points is not None:
                    self._check_link(f"{where}.a", f.points.a, cfg)
                    self._check_link(f"{where}.b", f.points.b, cfg)
                elif f.on.kind == "joint":
                    self._check_joint(f"{where}.on.joint", f.on.name, cfg)
                    self._one_coordinate(f"{where}.on.joint", f.on.name, cfg,
                                         "act on its link instead (on = { link = NAME }: a torque), or join the "
                                         "body to the frame by one revolute or prismatic joint per coordinate")
                else:
                    self._check_link(f"{where}.on.link", f.on.name, cfg)
                    if f.on.name == cfg.info.root and not self._said(f"{where}.on.link"):
                        self.p.add(f"{where}.on.link", f"= {f.on.name!r}: the frame (the root of "
                                   f"{cfg.info.path.name}) does not move, so a torque on it does nothing; name the "
                                   "link it turns (on = { link = NAME }) or the joint it acts across "
                                   "(on = { joint = NAME })")
                if f.measure is not None:
                    self._check_measure(f"{where}.measure", f.measure, cfg)
                if tail and len(self.p.items) > n0:
                    self.p.items[-1] += tail
                elif len(self.p.items) == n0 and (f.k > 0 or f.c > 0) and measure_sign(f, cfg) == -1 \
                        and not self._said(f"{where}.measure"):
                    self.p.add(f"{where}.measure", self._negative_element(f, cfg))
        for i, t in enumerate(scene.transitions):
            where = self._place(t, f"transitions[{i}] ({t.name})")
            for key, ref in (("from", t.source), ("to", getattr(t, "target", None)),
                             ("merge_to", getattr(t, "merge_to", None))):
                if ref is not None and ref not in names and ref not in self.declared:
                    self.p.add(f"{where}.{key}", f"= {ref!r}: no such configuration; defined: {', '.join(names)}")
            if t.source not in names:
                continue
            cfg = names[t.source]
            if t.type == "stop" and t.merge_to in names:
                locks = [j for j in cfg.info.movable_joints if j not in names[t.merge_to].info.movable_joints]
                owner = next((c for c in names.values() if t.name in c.info.joints), None)
                if owner is not None and t.name not in locks:
                    self.p.add(f"{where}.name", f"= {t.name!r}: also a joint of {owner.info.path.name}, which this "
                               f"stop's merge does not lock (it locks {', '.join(locks) or 'none'}): its holding "
                               f"force '{t.name}.hold' and a reaction guard's of = {t.name!r} would name both; "
                               "rename the stop")
            for j in t.cut:
                if any(c.name == j for c in cfg.cut_joints):
                    continue  # a loop's cut joint is already cut: its rows' impulse is what it carries
                self._check_joint(f"{where}.cut", j, cfg)
            if t.guard.measure is not None:
                self._check_measure(f"{where}.guard.measure", t.guard.measure, cfg)
            if t.guard.when is not None:
                self._check_measure(f"{where}.guard.when.measure", t.guard.when[0], cfg)
            if t.guard.type == "reaction":
                stops = {s.name for s in scene.transitions if s.type == "stop"}
                joints = set().union(*(c.info.joints for c in names.values()))
                own_cuts = {c.name: c for c in cfg.cut_joints}
                if t.guard.of in own_cuts and t.guard.of in stops:
                    self.p.add(f"{where}.guard.of", f"= {t.guard.of!r}: names both a cut joint of '{t.source}' and a "
                               "stop transition, whose forces differ; give the two different names")
                elif t.guard.of in own_cuts:  # a cut joint's holding force: along its contact normal
                    if own_cuts[t.guard.of].normal is None:
                        self.p.add(f"{where}.guard.of", f"= {t.guard.of!r}: a reaction guard on a cut joint watches "
                                   "its normal force, so the cut joint needs contact = { normal = [x, y] }")
                elif t.guard.of not in stops and t.guard.of not in joints:
                    self.p.add(f"{where}.guard.of", f"= {t.guard.of!r}: names neither a joint of the scene's URDFs "
                               f"nor a stop transition ({', '.join(sorted(stops)) or 'none'})")
                elif t.guard.of in stops and t.guard.of not in joints and all(
                        s.merge_to is None for s in scene.transitions if s.type == "stop" and s.name == t.guard.of):
                    self.p.add(f"{where}.guard.of", f"= {t.guard.of!r}: a stop without merge_to never merges, so it "
                               "holds nothing and this guard would never fire; give the stop a merge_to")
                elif t.guard.of in cfg.info.movable_joints:
                    locked = [j for j in sorted(joints) if any(j in c.info.movable_joints for c in names.values())
                              and j not in cfg.info.movable_joints]
                    self.p.add(f"{where}.guard.of", f"= {t.guard.of!r}: moves freely in '{t.source}', where this "
                               "guard is watched, so nothing holds it and its holding force is never defined; "
                               "a reaction guard watches a joint that configuration locks "
                               f"({', '.join(locked) or 'it locks none'}) or a stop that merged into it")
            if t.type == "release" and t.target in names:
                gained = set(names[t.target].info.movable_joints) - set(cfg.info.movable_joints)
                cuts_src, cuts_dst = {c.name for c in cfg.cut_joints}, {c.name for c in names[t.target].cut_joints}
                freed_cuts = cuts_src - cuts_dst  # a cut joint is a joint: releasing it frees its rows
                if not gained and not (freed_cuts and cuts_dst <= cuts_src):
                    self.p.add(f"{where}.to", f"= {t.target!r}: a release goes to a configuration with more "
                               f"freedom, but '{t.target}' has no movable joint that '{t.source}' lacks and "
                               f"drops none of its cut joints")
            if t.type == "pin" and t.target in names:
                held = [cj for cj in names[t.target].cut_joints if cj.anchor_at_entry and cj.b == t.contact.b
                        and tuple(cj.point_b) == tuple(t.contact.point_b)]
                if not held:
                    self.p.add(f"{where}.to", f"= {t.target!r}: a pin's target holds the struck point by a revolute "
                               f"cut joint with a = the frame, point_a = \"entry\", b = {t.contact.b!r} and point_b = "
                               f"{list(t.contact.point_b)} (the contact's point_b); '{t.target}' has none")
                src_joints, dst_joints = list(cfg.info.movable_joints), list(names[t.target].info.movable_joints)
                if src_joints != dst_joints:  # the strike's impulse is solved on one tree (pins.pin_strike)
                    self.p.add(f"{where}.to", f"= {t.target!r}: a pin keeps the tree and only adds the cut joint "
                               f"that holds the struck point, but '{t.target}' has the movable joints {dst_joints} "
                               f"and '{t.source}' {src_joints}: pin into a configuration with the same joints "
                               f"(the same URDF, or the same locks), and free or lock joints after the strike with "
                               f"a `release` or a `latch` from there")
                if t.contact.a != cfg.info.root:
                    self.p.add(f"{where}.contact.a", f"= {t.contact.a!r}: a pin anchors b's point on the frame "
                               f"('{cfg.info.root}'); a point pinned to a moving link is not modelled yet")
            if t.contact is None:
                continue
            self._check_link(f"{where}.contact.a", t.contact.a, cfg)
            self._check_link(f"{where}.contact.b", t.contact.b, cfg)
            if t.contact.a == t.contact.b:
                self.p.add(f"{where}.contact", f"a and b are the same link {t.contact.a!r}")
        init_cfg = names.get(scene.initial_configuration)
        for j in scene.independent:
            if init_cfg is not None:
                self._check_coordinate("initial.independent", j, init_cfg)
        if init_cfg is not None:
            self._loops_keep_a_coordinate_per_row(scene, init_cfg)
        if scene.branch is not None and init_cfg is not None:
            self._check_measure("initial.branch", scene.branch.measure, init_cfg)
            declared = ((self.raw.get("configurations") or {}).get(init_cfg.name) or {}).get("cut_joints")
            if not init_cfg.cut_joints and not declared:  # (one declared but at fault is said on its own)
                self.p.add("initial.branch", f"configuration '{init_cfg.name}' has no loop (no cut_joints), so it has "
                           "one assembly, the posture [initial] q gives, and branch would be ignored; remove it, or "
                           "give q the sign wanted")
        driven: dict[tuple[str, str], str] = {}  # (configuration, joint) -> the drive that prescribes it
        for i, d in enumerate(scene.drives):
            dw = self._place(d, f"drives[{i}]")
            for cfg in self._configs_for(f"{dw}.configurations", d.configurations, scene):
                self._check_joint(f"{dw}.joint", d.joint, cfg)
                self._one_coordinate(f"{dw}.joint", d.joint, cfg,
                                     "a drive prescribes one coordinate: give the body one revolute or prismatic "
                                     "joint per coordinate to drive")
                first = driven.setdefault((cfg.name, d.joint), dw)
                if first != dw:
                    self.p.add(f"{dw}.joint", f"= {d.joint!r}: already driven by {first} in "
                               f"configuration '{cfg.name}'; a coordinate follows one prescribed motion (two drives "
                               "of one joint are two constraints on one coordinate); give each drive the "
                               "configurations it acts in")
                    break
        for cfg in names.values():
            base = names.get(cfg.derivation.base) if cfg.derivation is not None else None
            if base is not None and cfg.cut_joints == base.cut_joints:
                continue  # inherited with the base's links: reported once, at the base
            for k, cj in enumerate(cfg.cut_joints):
                where = f"configurations.{cfg.name}.cut_joints[{k}]"
                self._check_link(f"{where}.a", cj.a, cfg)
                self._check_link(f"{where}.b", cj.b, cfg)
                if cj.name in cfg.info.joints:
                    self.p.add(f"{where} ({cj.name}).name", f"= {cj.name!r}: also a joint of {cfg.info.path.name}; "
                               "a transition's cut and a reaction guard's of name either, so the two need "
                               "different names")
