"""The mechanism as an engineer draws it: one drawing model for the replay page and the 2D sketch.

:func:`symbols` reads a recorded run (its URDF texts, cut joints, locks and transitions, as
:func:`pcmm.results.trajectory.record_views` recorded them) and returns the kinematic symbols of
the mechanism, each riding on one link (its position and angle in that link's frame) and shown
in some configurations only:

``ground``      the hatched frame under a fixed pivot (on the root link)
``pivot``       a grounded pin: a revolute joint between the frame and a link
``revolute``    a revolute joint, an open circle on its child link
``slider``      a prismatic joint's block on its child link; ``guide`` its line on the parent
``locked``      a locked revolute joint or a merged (locked) slider, a filled symbol, present
                exactly in the configurations that lock it
``cut``         a cut joint (the loop closure), a circle crossed by a slash
``stop``        a stop where it is: a contact stop's block on link a, a joint stop's pin line
                on the joint's parent link at the stop's angle

:func:`event_marks` adds what happens at the events: each event's plate ("impact, mobile,
e = 0.8", "latch: impact + merge", "release (tensile hold)"), riding on the body it belongs to
and fading out over :data:`PLATE_S`, a macro-impact's plates grouped into one with its count, and
each joint-stop impulse as an arc about the joint with its moment in N·m·s.

:func:`world` places the symbols at an instant (for the 2D sketch and the video,
:mod:`pcmm.viz.draw2d`); the replay page hangs them on the links' nodes and gives them visibility
tracks (:mod:`pcmm.viz.replay`).  Nothing here reads a scene or a model.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np

from .marks import RecordedRun, event_kind

#: How long an event's plate stays (it fades out over this time), s.
PLATE_S = 0.5
#: How long a joint stop's moment arc stays, s.
ARC_S = 0.1
MOVABLE = ("revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class Symbol:
    kind: str  # ground | pivot | revolute | slider | guide | locked | cut | stop | plate | arc
    link: str  # the link it rides on
    xy: tuple[float, float]  # in that link's frame
    angle: float = 0.0  # in that link's frame
    name: str = ""  # the joint, transition or event it draws
    configurations: frozenset | None = None  # shown in these configurations only (None: always)
    window: tuple[float, float] | None = None  # shown in [t0, t1) only (events)
    text: str = ""  # a plate's text, an arc's label
    shape: str = ""  # locked: "disk" (revolute) or "square" (prismatic); arc: "+" or "-" (sense)
    extra: dict = field(default_factory=dict, compare=False)

    def shown(self, configuration: str, t: float) -> bool:
        if self.configurations is not None and configuration not in self.configurations:
            return False
        return self.window is None or self.window[0] <= t < self.window[1]

    def alpha(self, t: float) -> float:
        """A plate's opacity at ``t``: 1 at its event, falling linearly to 0 at the window's end."""
        if self.kind != "plate" or self.window is None:
            return 1.0
        t0, t1 = self.window
        return float(min(1.0, max(0.0, 1.0 - (t - t0) / (t1 - t0))))


# ---- the recorded URDF joints ---------------------------------------------------------------
def _floats(text, n, default):
    if not text:
        return default
    vals = tuple(float(x) for x in text.split())
    return vals if len(vals) == n else default


def urdf_joint_frames(urdf_text: str) -> dict[str, dict]:
    """``{joint: {type, parent, child, xy, yaw, axis}}``: each joint's origin in its parent link's
    frame (x, y and the rotation about z) and its axis (in the joint frame)."""
    out = {}
    for j in ET.fromstring(urdf_text).findall("joint"):
        o = j.find("origin")
        xyz = _floats(o.get("xyz") if o is not None else None, 3, (0.0, 0.0, 0.0))
        rpy = _floats(o.get("rpy") if o is not None else None, 3, (0.0, 0.0, 0.0))
        a = j.find("axis")
        axis = _floats(a.get("xyz") if a is not None else None, 3, (1.0, 0.0, 0.0))
        out[j.get("name")] = {"type": j.get("type"), "parent": j.find("parent").get("link"),
                              "child": j.find("child").get("link"), "xy": (xyz[0], xyz[1]), "yaw": rpy[2],
                              "axis": (axis[0], axis[1])}
    return out


def _joints(run: RecordedRun) -> dict[str, dict[str, dict]]:
    """``{configuration: {joint: frame}}`` of every recorded configuration."""
    return {c: urdf_joint_frames(v["urdf"]) for c, v in run.views.get("configurations", {}).items() if v.get("urdf")}


def root_links(run: RecordedRun) -> set[str]:
    """The links no joint moves (the frame)."""
    per = _joints(run)
    children = {j["child"] for js in per.values() for j in js.values()}
    parents = {j["parent"] for js in per.values() for j in js.values()}
    return parents - children


def locks(run: RecordedRun) -> dict[str, set[str]]:
    """``{configuration: joints it locks}``: a joint that moves in some configuration and is fixed
    (or locked by a derivation) in this one."""
    per = _joints(run)
    movable = {n for js in per.values() for n, j in js.items() if j["type"] in MOVABLE}
    out = {}
    for c, js in per.items():
        listed = set(run.views["configurations"][c].get("locked", []))
        out[c] = {n for n in movable if n in listed or (n in js and js[n]["type"] not in MOVABLE)}
    return out


# ---- the symbols --------------------------------------------------------------------------
def symbols(run: RecordedRun) -> list[Symbol]:
    """The mechanism's kinematic symbols (see the module's table), each once."""
    per = _joints(run)
    configs = list(per)
    roots = root_links(run)
    locked = locks(run)
    out: list[Symbol] = []
    seen = {}
    for c in configs:  # a joint's symbol once, from the first configuration where it moves
        for n, j in per[c].items():
            if n not in seen and j["type"] in MOVABLE:
                seen[n] = j
    for c in configs:
        for n, j in per[c].items():
            seen.setdefault(n, j)
    for n, j in seen.items():
        free = frozenset(c for c in configs if n not in locked[c] and n in per[c])
        held = frozenset(c for c in configs if n in locked[c])
        if j["type"] == "prismatic":
            axis_angle = j["yaw"] + math.atan2(j["axis"][1], j["axis"][0])
            out.append(Symbol("guide", j["parent"], j["xy"], axis_angle, n))
            out.append(Symbol("slider", j["child"], (0.0, 0.0), math.atan2(j["axis"][1], j["axis"][0]), n, free))
            if held:
                out.append(Symbol("locked", j["child"], (0.0, 0.0), 0.0, n, held, shape="square"))
            continue
        if j["type"] not in MOVABLE:
            continue  # fixed in every configuration: a weld, part of one body
        if j["parent"] in roots:
            out.append(Symbol("ground", j["parent"], j["xy"], 0.0, n))
            out.append(Symbol("pivot", j["parent"], j["xy"], 0.0, n))
        out.append(Symbol("revolute", j["child"], (0.0, 0.0), 0.0, n, free if held else None))
        if held:
            out.append(Symbol("locked", j["child"], (0.0, 0.0), 0.0, n, held, shape="disk"))
    cuts: dict[str, tuple] = {}
    for c, v in run.views.get("configurations", {}).items():
        for cj in v.get("cut_joints", []) or []:
            key = cj["name"]
            cuts.setdefault(key, (cj, set()))[1].add(c)
    for name, (cj, where) in cuts.items():
        if cj.get("anchor_at_entry"):
            continue  # drawn where each stay pinned it (pinned_symbols)
        out.append(Symbol("cut", cj["a"], tuple(cj["point_a"]), 0.0, name, frozenset(where)))
        if cj["a"] in roots:
            out.append(Symbol("ground", cj["a"], tuple(cj["point_a"]), 0.0, name))
    for tr in run.views.get("transitions", []) or []:
        ct = tr.get("contact")
        if tr["type"] != "stop" or not ct:
            continue
        if ct.get("joint"):
            j = seen.get(ct["joint"])
            if j is None or j["type"] not in ("revolute", "continuous") or ct.get("stop_value") is None:
                continue
            out.append(Symbol("stop", j["parent"], j["xy"], j["yaw"] + float(ct["stop_value"]), tr["name"],
                              shape="joint"))
        elif ct.get("point_a") is not None:
            nrm = ct.get("normal") or (1.0, 0.0)
            out.append(Symbol("stop", ct["a"], tuple(ct["point_a"]), math.atan2(nrm[1], nrm[0]), tr["name"],
                              shape="contact"))
    return _dedupe(out + pinned_symbols(run))


def pinned_symbols(run: RecordedRun) -> list[Symbol]:
    """A cut joint anchored at entry (a struck point pinned where it lands) as a grounded pin where
    b's point was when the run entered the configuration (its segment's first sample), shown for
    that stay only: ``cut`` and ``ground`` on the frame, with a window per stay."""
    views = run.views.get("configurations", {})
    roots = sorted(root_links(run))
    if not roots:
        return []
    out: list[Symbol] = []
    segs = run.segments
    for i, seg in enumerate(segs):
        t0 = float(seg.t[0])
        t1 = float(segs[i + 1].t[0]) if i + 1 < len(segs) else math.inf
        for cj in (views.get(seg.configuration, {}).get("cut_joints") or []):
            if not cj.get("anchor_at_entry"):
                continue
            pose = pose_at(run, cj["b"], t0)
            if pose is None:
                continue
            anchor = to_world(pose, cj["point_b"])
            last = out[-1] if out and out[-1].name == cj["name"] and out[-1].kind == "ground" else None
            if last is not None and last.window[1] == t0 and math.dist(last.xy, anchor) < 1e-9:
                # the same stay, split by a new partition of its coordinates: one symbol
                out[-2:] = [Symbol(k.kind, k.link, k.xy, 0.0, k.name, window=(k.window[0], t1)) for k in out[-2:]]
                continue
            out += [Symbol("cut", roots[0], anchor, 0.0, cj["name"], window=(t0, t1)),
                    Symbol("ground", roots[0], anchor, 0.0, cj["name"], window=(t0, t1))]
    return out


def _dedupe(syms: list[Symbol]) -> list[Symbol]:
    out, keys = [], set()
    for s in syms:
        key = (s.kind, s.link, round(s.xy[0], 9), round(s.xy[1], 9), round(s.angle, 9), s.configurations, s.shape,
               s.window)
        if key not in keys:
            keys.add(key)
            out.append(s)
    return out


# ---- the events ----------------------------------------------------------------------------
def macro_groups(run: RecordedRun) -> list[list[int]]:
    """The events as groups: a macro-impact (consecutive events of one stop transition, its
    impacts and the merge that ends it) is one group; every other event is a group of one."""
    groups: list[list[int]] = []
    events = list(run.events)  # each record built once (an EventLog builds one on every read)
    for i, ev in enumerate(events):
        prev = events[groups[-1][-1]] if groups else None
        if (prev is not None and ev.get("transition") == "stop" and prev.get("transition") == "stop"
                and ev.get("name") == prev.get("name") and not prev.get("merge")):
            groups[-1].append(i)
        else:
            groups.append([i])
    return groups


def plate_text(ev: dict, count: int = 1, first: dict | None = None) -> str:
    """What an event was, in words: ``impact, mobile, e = 0.8``, ``latch: impact + merge``,
    ``release (tensile hold)``; a macro-impact's ``count`` impacts (``first`` to ``ev``) as one plate."""
    kind = event_kind(ev)
    e = (first or ev).get("restitution")
    if kind == "release":
        cause = str(ev.get("cause") or "")
        why = "tensile hold" if "tensile" in cause else (cause or "guard")
        return f"release ({why})"
    if ev.get("transition") == "latch":
        return "latch: impact + merge"
    if ev.get("transition") == "pin":  # a struck point pinned where it lands (and what it released)
        freed = ", ".join(ev.get("released") or {})
        return "pin: impact, point pinned" + (f", {freed} lifts off" if freed else "")
    if count > 1:
        tail = ", merge" if ev.get("merge") else ""
        return f"macro-impact ({count} impacts), {ev.get('kind', 'impact')}, e = {e:g}{tail}" if e is not None else \
            f"macro-impact ({count} impacts){tail}"
    if kind == "merge":
        return f"stop: impact + merge ({ev.get('kind', '')})".replace(" ()", "")
    if kind == "impact":
        return f"impact, {ev.get('kind', '')}, e = {e:g}" if e is not None else f"impact, {ev.get('kind', '')}"
    return f"switch {ev.get('from')} → {ev.get('to')}"


def _transition(run: RecordedRun, name: str) -> dict | None:
    return next((tr for tr in run.views.get("transitions", []) or [] if tr["name"] == name), None)


def event_body(run: RecordedRun, ev: dict) -> str | None:
    """The body an event's plate rides on: its contact's body b (a joint stop's child link)."""
    tr = _transition(run, ev.get("name", ""))
    ct = (tr or {}).get("contact") or {}
    if ct.get("joint"):
        for js in _joints(run).values():
            if ct["joint"] in js:
                return js[ct["joint"]]["child"]
    return ct.get("b")


def pose_at(run: RecordedRun, link: str, t: float) -> tuple[float, float, float] | None:
    """``(x, y, theta)`` of ``link`` at ``t`` (the segment active at ``t``, linear between samples)."""
    segs = run.segments
    k = 0
    for i, s in enumerate(segs):
        if float(s.t[0]) <= t:
            k = i
    for s in [segs[k]] + segs[:k][::-1] + segs[k + 1:]:
        if link in s.links:
            j = s.links.index(link)
            tt = min(max(t, float(s.t[0])), float(s.t[-1]))
            return (float(np.interp(tt, s.t, s.xy[:, j, 0])), float(np.interp(tt, s.t, s.xy[:, j, 1])),
                    float(np.interp(tt, s.t, s.theta[:, j])))
    return None


def to_local(pose, p) -> tuple[float, float]:
    x, y, th = pose
    c, s = math.cos(th), math.sin(th)
    dx, dy = p[0] - x, p[1] - y
    return (c * dx + s * dy, -s * dx + c * dy)


def to_world(pose, p) -> tuple[float, float]:
    x, y, th = pose
    c, s = math.cos(th), math.sin(th)
    return (x + c * p[0] - s * p[1], y + s * p[0] + c * p[1])


def event_marks(run: RecordedRun) -> list[Symbol]:
    """Each event group's plate, on its body at its contact point, shown for :data:`PLATE_S` from
    the group's first event (to its last event + :data:`PLATE_S` for a macro-impact), and each
    joint-stop impulse's moment arc, about the joint for :data:`ARC_S`."""
    out: list[Symbol] = []
    roots = root_links(run)
    root = next(iter(sorted(roots)), None)
    events = list(run.events)  # each record built once (an EventLog builds one on every read)
    for group in macro_groups(run):
        first, last = events[group[0]], events[group[-1]]
        t0, t1 = float(first["t"]), float(last["t"]) + PLATE_S
        body = event_body(run, first)
        p = first.get("contact_point")
        link = body if body is not None and pose_at(run, body, t0) is not None else root
        pose = pose_at(run, link, t0) if link is not None else None
        if pose is None or p is None:
            link, local = (root or ""), (0.0, 0.0)
        else:
            local = to_local(pose, p[:2])
        out.append(Symbol("plate", link, local, 0.0, first.get("name", ""), window=(t0, t1),
                          text=plate_text(last, len(group), first),
                          extra={"events": list(group), "kind": event_kind(first)}))
    for i, ev in enumerate(events):
        imp = ev.get("impulse") or {}
        if not ev.get("impact") or not imp.get("joint") or not imp.get("moment"):
            continue
        child = event_body(run, ev)
        if child is None:
            continue
        t = float(ev["t"])
        later = [float(e["t"]) for e in events[i + 1:] if float(e["t"]) > t]
        m = float(imp["moment"])
        # the sense: the moment on body b turns it back from the stop, against its rate before
        before = (ev.get("v_before") or {}).get(imp["joint"])
        sense = "-" if (before is not None and before > 0) else "+"
        out.append(Symbol("arc", child, (0.0, 0.0), 0.0, imp["joint"], window=(t, min([t + ARC_S] + later[:1])),
                          text=f"M = {abs(m):.3g} N·m·s", shape=sense, extra={"event": i, "moment": abs(m)}))
    return out


# ---- placing the symbols -----------------------------------------------------------------
def configuration_at(run: RecordedRun, t: float) -> str:
    conf = run.segments[0].configuration
    for s in run.segments:
        if float(s.t[0]) <= t:
            conf = s.configuration
    return conf


@dataclass(frozen=True)
class Placed:
    """A symbol at an instant: its world position and angle, and its opacity."""

    symbol: Symbol
    xy: tuple[float, float]
    angle: float
    alpha: float = 1.0


def world(run: RecordedRun, syms: list[Symbol], t: float) -> list[Placed]:
    """The symbols shown at ``t``, placed in the world by their links' poses at ``t``."""
    conf = configuration_at(run, t)
    out = []
    for s in syms:
        if not s.shown(conf, t):
            continue
        pose = pose_at(run, s.link, t) or (0.0, 0.0, 0.0)
        out.append(Placed(s, to_world(pose, s.xy), pose[2] + s.angle, s.alpha(t)))
    return out


def scale(run: RecordedRun) -> float:
    """The symbols' size (m): 4 % of the largest extent the links' frames sweep (at least 1 mm)."""
    pts = np.concatenate([s.xy.reshape(-1, 2) for s in run.segments])
    span = float(np.max(pts.max(axis=0) - pts.min(axis=0))) if pts.size else 0.0
    return max(0.04 * span, 1e-3)
