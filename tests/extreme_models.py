"""Small URDF + scene builders for the numerical-extremes and fuzz suites.

Every builder writes its files into a folder it is given and returns the scene
path; nothing here runs a simulation.  Conventions:

* a link frame has its origin on the joint that carries it; a bar of length
  ``L`` lies along its frame's +x axis and has its centroid at ``(L/2, 0)``;
* inertias are given about the centroid; ``ixx = iyy = izz`` so the tensor is
  positive definite and satisfies the triangle inequality at every scale;
* gravity is ``(0, -g)``.
"""
from __future__ import annotations

import contextlib
import signal

import math
from pathlib import Path

import numpy as np
import pytest

G = 9.81
TRAJECTORY_ARRAYS = ("t", "q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces")


def numbers(obj):
    """Every number inside nested dicts / lists (bools and strings skipped)."""
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return
    if isinstance(obj, (int, float, np.floating, np.integer)):
        yield float(obj)
    elif isinstance(obj, dict):
        for v in obj.values():
            yield from numbers(v)
    elif isinstance(obj, (list, tuple, np.ndarray)):
        for v in obj:
            yield from numbers(v)


def assert_finite(traj):
    """No NaN or inf in any array of any segment, nor in any event record."""
    assert traj.segments, "the trajectory has no samples"
    for k, s in enumerate(traj.segments):
        for name in TRAJECTORY_ARRAYS:
            arr = np.asarray(getattr(s, name), dtype=float)
            bad = ~np.isfinite(arr)
            assert not bad.any(), (f"segment {k} ({s.configuration}): {name} has {int(bad.sum())} non-finite "
                                   f"values, first at t = {s.t[np.argwhere(bad)[0][0]]:.9g} s")
    for ev in traj.events:
        assert all(math.isfinite(x) for x in numbers(ev)), f"event at t = {ev['t']}: non-finite number"
LIMIT = '<limit lower="-1e6" upper="1e6" effort="1e6" velocity="1e6"/>'


# ---- TOML writer (inline tables only: valid TOML 1.0, any nesting) ---------------------------
def toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(float(v))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{toml_key(k)} = {toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(type(v))


def toml_key(k: str) -> str:
    return k if k and all(c.isalnum() or c in "_-" for c in k) else toml_value(str(k))


def dump_toml(doc: dict) -> str:
    """A whole document as top-level ``key = inline value`` lines."""
    return "".join(f"{toml_key(k)} = {toml_value(v)}\n" for k, v in doc.items())


# ---- URDF pieces ---------------------------------------------------------------------------------
def link(name: str, mass: float | None = None, izz: float | None = None, com=(0.0, 0.0)) -> str:
    if mass is None:
        return f'<link name="{name}"/>'
    izz = float(izz)
    return (f'<link name="{name}"><inertial><origin xyz="{com[0]!r} {com[1]!r} 0"/>'
            f'<mass value="{float(mass)!r}"/><inertia ixx="{izz!r}" ixy="0" ixz="0" iyy="{izz!r}" '
            f'iyz="0" izz="{izz!r}"/></inertial></link>')


def bar(name: str, L: float, m: float) -> str:
    return link(name, m, m * L * L / 12, com=(L / 2, 0.0))


def joint(name: str, jtype: str, parent: str, child: str, xyz=(0.0, 0.0), yaw=0.0, axis=(0, 0, 1)) -> str:
    ax = f'<axis xyz="{axis[0]} {axis[1]} {axis[2]}"/>' if jtype != "fixed" else ""
    lim = LIMIT if jtype in ("revolute", "prismatic") else ""
    return (f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{float(xyz[0])!r} {float(xyz[1])!r} 0" rpy="0 0 {float(yaw)!r}"/>{ax}{lim}</joint>')


def robot(name: str, *parts: str) -> str:
    return f'<?xml version="1.0"?>\n<robot name="{name}">' + "".join(parts) + "</robot>\n"


def write_scene(folder: Path, doc: dict, urdfs: dict[str, str], name: str = "scene.toml") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for fname, text in urdfs.items():
        (folder / fname).write_text(text)
    path = folder / name
    path.write_text(dump_toml(doc))
    return path


def stop(name, source, e, guard, contact, merge_to=None, cut=(), **extra) -> dict:
    tr = {"name": name, "type": "stop", "from": source, "restitution": e, "cut": list(cut),
          "guard": guard, "contact": contact, **extra}
    if merge_to is not None:
        tr["merge_to"] = merge_to
    return tr


def base_doc(name, initial, configs: dict, q, v, g=G, t_end=1.0, solver=None, **more) -> dict:
    doc = {"scene": {"name": name, "gravity": [0.0, -g], "t_end": t_end, "initial_configuration": initial},
           "configurations": {k: ({"urdf": u} if isinstance(u, str) else u) for k, u in configs.items()},
           "initial": {"q": q, "v": v}}
    if solver:
        doc["solver"] = solver
    doc.update(more)
    return doc


# ---- scenes ---------------------------------------------------------------------------------------
def ball(folder: Path, e: float, h: float = 1.0, g: float = G, mass: float = 1.0, v0: float = 0.0,
         t_end: float = 1.0, merge: bool = True, solver=None, **law) -> Path:
    """A point mass on a vertical prismatic joint Y (q = height) above the floor y = 0;
    a stop with restitution e (gap guard) that merges into 'rest' (Y fixed at 0).  ``law``
    (``law``, ``stiffness``, ``exponent``) makes the stop a continuous contact law."""
    ball_link = link("ball", mass, 1e-3 * mass)
    free = robot("ball", link("frame"), joint("Y", "prismatic", "frame", "ball", axis=(0, 1, 0)), ball_link)
    rest = robot("ball_rest", link("frame"), joint("Y", "fixed", "frame", "ball"), ball_link)
    tr = stop("floor", "free", e, {"type": "gap", "value": 0.0, "direction": "decreasing"},
              {"a": "frame", "point_a": [0.0, 0.0], "b": "ball", "point_b": [0.0, 0.0], "normal": [0.0, 1.0]},
              merge_to="rest" if merge else None, **law)
    doc = base_doc("ball", "free", {"free": "free.urdf", "rest": "rest.urdf"}, {"Y": h}, {"Y": v0}, g=g,
                   t_end=t_end, solver=solver, transitions=[tr])
    return write_scene(folder, doc, {"free.urdf": free, "rest.urdf": rest})


def pendulum(folder: Path, e: float, L: float = 0.6, m: float = 1.5, qs: float = -math.pi / 2,
             q0: float = 0.0, w0: float = 0.0, g: float = G, t_end: float = 1.0, d: float | None = None,
             direction: str = "decreasing", k: float | None = None, rest_angle: float = 0.0,
             solver=None, merge: bool = True) -> Path:
    """A uniform bar (m, L) on revolute J1 at the origin (q = angle from +x) and a stop on
    the frame where the bar's point at distance d from the pivot arrives at q = qs.
    Moving towards the stop means q decreasing (direction 'decreasing') or increasing."""
    d = L if d is None else d
    s = 1.0 if direction == "decreasing" else -1.0
    normal = [-s * math.sin(qs), s * math.cos(qs)]  # frame -> bar, along the bar's approach
    urdfs = {"p.urdf": robot("pend", link("frame"), joint("J1", "revolute", "frame", "link1"), bar("link1", L, m)),
             "rest.urdf": robot("pend_rest", link("frame"), joint("J1", "fixed", "frame", "link1", yaw=qs),
                                bar("link1", L, m))}
    tr = stop("stop", "c1", e, {"type": "coordinate", "measure": {"joint": "J1"}, "value": qs,
                                "direction": direction},
              {"a": "frame", "point_a": [d * math.cos(qs), d * math.sin(qs)], "b": "link1",
               "point_b": [d, 0.0], "normal": normal}, merge_to="rest" if merge else None)
    forces = []
    if k is not None:
        forces.append({"name": "spring", "type": "spring", "on": {"joint": "J1"}, "measure": {"joint": "J1"},
                       "k": k, "rest": rest_angle})
    doc = base_doc("pendulum", "c1", {"c1": "p.urdf", "rest": "rest.urdf"}, {"J1": q0}, {"J1": w0}, g=g,
                   t_end=t_end, solver=solver, transitions=[tr] if e is not None else [], forces=forces)
    return write_scene(folder, doc, urdfs)


def spring_pendulum(folder: Path, k: float, I_c: float, m: float = 1.0, q0: float = 0.1,
                    t_end: float = 1.0, solver=None) -> Path:
    """A body (mass m, centroid on the pivot, inertia I_c) on revolute J1 with a torsion
    spring k, no gravity: q(t) = q0 cos(sqrt(k / I_c) t)."""
    urdf = robot("sp", link("frame"), joint("J1", "revolute", "frame", "body"), link("body", m, I_c))
    doc = base_doc("spring_pendulum", "c1", {"c1": "sp.urdf"}, {"J1": q0}, {"J1": 0.0}, g=0.0, t_end=t_end,
                   solver=solver, forces=[{"name": "spring", "type": "spring", "on": {"joint": "J1"},
                                           "measure": {"joint": "J1"}, "k": k}])
    return write_scene(folder, doc, {"sp.urdf": urdf})


def two_link(folder: Path, e: float, m1: float, m2: float, L1: float = 0.5, L2: float = 0.5,
             I1: float | None = None, I2: float | None = None, w1: float = 0.0, w2: float = -3.0,
             q2_0: float = 0.0, q2_stop: float = -0.3, t_end: float = 1.0, solver=None) -> Path:
    """Two bars on J1 (frame) and J2 (tip of link1), no gravity.  Link 2 swings about J2
    (q2 decreasing) until it strikes a stop on link 1 at q2 = q2_stop: a mobile impact
    between the links; its contact is link 2's tip against link 1's point where that tip is."""
    I1 = m1 * L1 * L1 / 12 if I1 is None else I1
    I2 = m2 * L2 * L2 / 12 if I2 is None else I2
    urdf = robot("two", link("frame"), joint("J1", "revolute", "frame", "link1"), link("link1", m1, I1, (L1 / 2, 0)),
                 joint("J2", "revolute", "link1", "link2", xyz=(L1, 0.0)), link("link2", m2, I2, (L2 / 2, 0)))
    tip = [L1 + L2 * math.cos(q2_stop), L2 * math.sin(q2_stop)]  # in link1's frame
    normal = [-math.sin(q2_stop), math.cos(q2_stop)]  # link1 -> link2, against link 2's approach
    tr = stop("hit", "c1", e, {"type": "coordinate", "measure": {"joint": "J2"}, "value": q2_stop,
                               "direction": "decreasing"},
              {"a": "link1", "point_a": tip, "b": "link2", "point_b": [L2, 0.0], "normal": normal})
    doc = base_doc("two_link", "c1", {"c1": "two.urdf"}, {"J1": 0.0, "J2": q2_0}, {"J1": w1, "J2": w2},
                   g=0.0, t_end=t_end, solver=solver, transitions=[tr])
    return write_scene(folder, doc, {"two.urdf": urdf})


def two_free_bodies(folder: Path, e: float, m1: float, m2: float, I1: float, I2: float,
                    gap: float = 0.1, v1=(1.0, 0.0), v2=(-1.0, 0.0), w1: float = 0.0, w2: float = 0.0,
                    offset: float = 0.05, t_end: float = 0.2, solver=None) -> Path:
    """Two bodies on URDF planar joints A and B, no gravity.  Body a's contact point (0.1, 0)
    on its local +x face meets body b's point (-0.1, offset) (normal +x of a): a mobile
    impact between free bodies (linear and angular momentum are conserved)."""
    urdf = robot("two_free", link("frame"), joint("A", "planar", "frame", "a"), link("a", m1, I1),
                 joint("B", "planar", "frame", "b"), link("b", m2, I2))
    tr = stop("bump", "c1", e, {"type": "gap", "value": 0.0, "direction": "decreasing"},
              {"a": "a", "point_a": [0.1, 0.0], "b": "b", "point_b": [-0.1, offset], "normal": [1.0, 0.0]})
    doc = base_doc("two_free", "c1", {"c1": "free.urdf"}, {"A": [0.0, 0.0, 0.0], "B": [0.2 + gap, -offset, 0.0]},
                   {"A": [v1[0], v1[1], w1], "B": [v2[0], v2[1], w2]}, g=0.0, t_end=t_end, solver=solver,
                   transitions=[tr])
    return write_scene(folder, doc, {"free.urdf": urdf})


def two_balls(folder: Path, e1: float, e2: float, h: float = 0.5, t_end: float = 0.5) -> Path:
    """Two independent point masses on vertical prismatic joints Y1, Y2 (at x = 0 and x = 1)
    dropped from the same height: both floor contacts close at the same instant."""
    urdf = robot("balls", link("frame"), joint("Y1", "prismatic", "frame", "b1", axis=(0, 1, 0)),
                 link("b1", 1.0, 1e-3), joint("Y2", "prismatic", "frame", "b2", xyz=(1.0, 0.0), axis=(0, 1, 0)),
                 link("b2", 2.0, 1e-3))
    trs = [stop(f"floor{i}", "c1", e, {"type": "gap", "value": 0.0, "direction": "decreasing"},
                {"a": "frame", "point_a": [x, 0.0], "b": f"b{i}", "point_b": [0.0, 0.0], "normal": [0.0, 1.0]})
           for i, (e, x) in enumerate([(e1, 0.0), (e2, 1.0)], start=1)]
    doc = base_doc("two_balls", "c1", {"c1": "balls.urdf"}, {"Y1": h, "Y2": h}, {"Y1": 0.0, "Y2": 0.0},
                   t_end=t_end, transitions=trs)
    return write_scene(folder, doc, {"balls.urdf": urdf})


def flat_bar(folder: Path, e: float, L: float = 1.0, m: float = 1.0, h: float = 0.2, t_end: float = 0.5,
             solver=None) -> Path:
    """A uniform bar on a URDF planar joint, centroid at the joint, horizontal, dropped from
    height h onto two stops under its ends (x = -L/2 and +L/2): two contacts close at once."""
    urdf = robot("flat", link("frame"), joint("P", "planar", "frame", "bar"), link("bar", m, m * L * L / 12))
    trs = [stop(name, "c1", e, {"type": "gap", "value": 0.0, "direction": "decreasing"},
                {"a": "frame", "point_a": [x, 0.0], "b": "bar", "point_b": [x, 0.0], "normal": [0.0, 1.0]})
           for name, x in (("left", -L / 2), ("right", L / 2))]
    doc = base_doc("flat_bar", "c1", {"c1": "flat.urdf"}, {"P": [0.0, h, 0.0]}, {"P": [0.0, 0.0, 0.0]},
                   t_end=t_end, solver=solver, transitions=trs)
    return write_scene(folder, doc, {"flat.urdf": urdf})


def slider_crank_slider_driven(folder: Path, coefficients, a=0.1, b=0.3, theta0=0.5, t_end=1.0) -> Path:
    """Slider-crank (crank a on A, rod b on B at the crank tip, slider on prismatic P along x,
    cut joint C closes rod tip to slider) with the slider DRIVEN: x(t) = poly(coefficients).
    The crank is at dead centre (crank and rod collinear) when x = a + b."""
    urdf = robot("sc", link("frame"), joint("A", "revolute", "frame", "crank"), bar("crank", a, 0.5),
                 joint("B", "revolute", "crank", "rod", xyz=(a, 0.0)), bar("rod", b, 0.8),
                 joint("P", "prismatic", "frame", "slider", axis=(1, 0, 0)), link("slider", 2.0, 1e-3))
    phi = math.asin(-a * math.sin(theta0) / b)
    x0 = a * math.cos(theta0) + b * math.cos(phi)
    cfg = {"urdf": "sc.urdf", "cut_joints": [{"name": "C", "type": "revolute", "a": "rod", "point_a": [b, 0.0],
                                                "b": "slider", "point_b": [0.0, 0.0]}]}
    doc = base_doc("slider_crank", "c", {"c": cfg}, {"A": theta0, "B": phi - theta0, "P": x0},
                   {"A": 0.0, "B": 0.0, "P": 0.0}, g=0.0, t_end=t_end,
                   drives=[{"joint": "P", "coefficients": list(coefficients)}])
    return write_scene(folder, doc, {"sc.urdf": urdf})


def parallelogram(folder: Path, theta0: float, omega: float, a=0.1, b=0.3, t_end=1.0, solver=None) -> Path:
    """Parallelogram four-bar (crank a on A at the origin, coupler b on B, rocker a on D at
    (b, 0), cut joint C), no gravity.  On the parallelogram branch the rocker stays parallel
    to the crank and the coupler horizontal; every half turn (theta = 0, pi) all links are
    collinear: the loop Jacobian loses rank (a bifurcation into the anti-parallelogram)."""
    urdf = robot("pg", link("frame"), joint("A", "revolute", "frame", "crank"), bar("crank", a, 1.0),
                 joint("B", "revolute", "crank", "coupler", xyz=(a, 0.0)), bar("coupler", b, 1.0),
                 joint("D", "revolute", "frame", "rocker", xyz=(b, 0.0)), bar("rocker", a, 1.0))
    cfg = {"urdf": "pg.urdf", "cut_joints": [{"name": "C", "type": "revolute", "a": "coupler",
                                                "point_a": [b, 0.0], "b": "rocker", "point_b": [a, 0.0]}]}
    doc = base_doc("parallelogram", "c", {"c": cfg}, {"A": theta0, "B": -theta0, "D": theta0},
                   {"A": omega, "B": -omega, "D": omega}, g=0.0, t_end=t_end, solver=solver)
    doc["initial"]["independent"] = ["A"]
    return write_scene(folder, doc, {"pg.urdf": urdf})


@contextlib.contextmanager
def deadline(seconds, what):
    """Fail (instead of hanging the suite) if the block runs longer than ``seconds``."""
    class _Deadline(BaseException):
        pass

    def handler(signum, frame):
        raise _Deadline()
    old = signal.signal(signal.SIGALRM, handler)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    except _Deadline:
        pytest.fail(f"{what}: still running after {seconds} s (a hang)")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
