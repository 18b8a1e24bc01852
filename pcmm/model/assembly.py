"""Closed-loop assembly of the initial posture, without silent surprises.

``[initial] q`` of a closed loop is a guess: the independent coordinates are kept and the
dependent ones are solved by Newton so the loop closes.  Newton may land on an angle 2 pi k away
from the guess, or on the mirrored assembly (the other branch of a four-bar), and the run then
looks right but its guards never fire.  This module

* brings every solved revolute angle to within pi of the user's value (the posture is the same;
  the angles the guards and figures see are the ones the user wrote);
* honours an explicit assembly choice, ``[initial] branch = { between = [A, B], sign = "+" }``
  (or ``joint = J`` / ``link = L``): the sign of that angle, wrapped into (-pi, pi], picks the
  branch, found among the assemblies Newton reaches from a grid of starts;
* warns when the assembled posture differs from the guess by more than ``GUESS_TOL`` or when
  another assembly lies nearer the guess (the other branch);
* names "give approximate assembly values" when the loop cannot be closed from the guess;
* says which given velocities the constraints replaced (a dependent or driven joint's velocity
  follows from the others) and which independent ones, left out of ``[initial] v``, it took as 0.
"""
from __future__ import annotations

import itertools
import math

import numpy as np

from .configuration import Configuration
from ..errors import SceneError, SimulationError
from ..scene.spec import Scene

GUESS_TOL = 0.05  # rad (m for a slider): a larger change from the guess is reported


def wrap(x):
    """Angle(s) into (-pi, pi]."""
    y = np.mod(np.asarray(x, float) + math.pi, 2 * math.pi) - math.pi
    return np.where(y == -math.pi, math.pi, y) if np.ndim(y) else (math.pi if y == -math.pi else float(y))


def _revolute(cfg: Configuration) -> np.ndarray:
    """Revolute coordinates the loop closure sees only through cos and sin (2 pi k free); a
    driven joint's value is fixed by its drive, not modulo 2 pi."""
    mask = np.zeros(cfg.nv, bool)
    for name in cfg.joint_names:
        if cfg.spec.info.joints[name].type == "revolute":
            mask[cfg.joint_slice[name].start] = True
    drives = getattr(cfg.coords, "drives", None)
    if drives is not None:
        mask[list(drives.index)] = False
    return mask


def _branch_example(cfg) -> str:
    """The ``branch`` table to write, with two links of the first loop (the angle from the first
    to the second; its sign tells the two assemblies apart where it is not 0 or pi)."""
    cuts = cfg.spec.cut_joints
    a, b = (cuts[0].a, cuts[0].b) if cuts else ("LINK_A", "LINK_B")
    return f'{{ between = ["{a}", "{b}"], sign = "+" }} (two link names; sign "+" or "-" of the angle from the first to the second)'


def _near(cfg: Configuration, q, guess):
    """``q`` with every revolute angle moved by 2 pi k to within pi of ``guess`` (same posture)."""
    rev = _revolute(cfg)
    out = q.copy()
    out[rev] = guess[rev] + wrap(q[rev] - guess[rev])
    return out


def _distance(cfg: Configuration, q, guess) -> np.ndarray:
    d = q - guess
    rev = _revolute(cfg)
    d[rev] = wrap(d[rev])
    return np.abs(d)


def _branch_value(cfg: Configuration, scene: Scene, q) -> float:
    row, offset = cfg.measure_row(scene.branch.measure)
    return wrap(float(row @ q + offset))


def _candidates(cfg: Configuration, q0, v0, prefer):
    """Distinct assemblies Newton reaches from the guess and from a grid of starts of the
    dependent revolute angles (quarter turns): the loop's branches."""
    coords = cfg.coords
    first = coords.project(0.0, q0, v0, prefer)
    dep = [i for i in coords.D if _revolute(cfg)[i]]
    found = [first]
    for shifts in itertools.product((0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi), repeat=min(len(dep), 3)):
        start = q0.copy()
        start[dep[:3]] += shifts
        try:
            q, v = coords.project(0.0, start, v0, prefer)
        except SimulationError:
            continue
        if all(np.max(_distance(cfg, q[0], f[0])) > 1e-6 for f in found):
            found.append((q, v))
    return found


def assemble(scene: Scene, cfg: Configuration):
    """(q, v, warnings): the initial state of ``cfg`` from ``[initial]``, assembled onto its loops."""
    q0, v0 = cfg.vector(scene.q0), cfg.vector(scene.v0)
    prefer = [cfg.coordinate_index(j) for j in scene.independent]
    coords = cfg.coords
    if not getattr(coords, "constrained", False) or not coords.closure.size:
        q, v = coords.project(0.0, q0, v0, prefer)
        return q, v, _velocity_notes(scene, cfg, v0, v)
    if coords.closure.anchored:  # a point pinned where it is at the start (point_a = "entry")
        cfg.kinematics(q0)
        coords.closure.set_anchors(cfg.data)
    try:
        options = _candidates(cfg, q0, v0, prefer) if scene.branch is not None else \
            [coords.project(0.0, q0, v0, prefer)]
    except SimulationError as exc:
        raise SimulationError([f"{p}; give approximate assembly values in [initial] q (each within a few "
                               "degrees of a posture where the loop closes), or name the kept joints in "
                               "[initial] independent" for p in exc.problems]) from None
    notes = []
    if scene.branch is not None:
        want = scene.branch.sign
        on = [o for o in options if np.sign(_branch_value(cfg, scene, o[0])) == want]
        if not on:
            values = ", ".join(f"{_branch_value(cfg, scene, o[0]):.6g}" for o in options)
            raise SceneError(f"{scene.path}: initial.branch: no assembly has {scene.branch.measure} "
                             f"{'> 0' if want > 0 else '< 0'} (wrapped into (-pi, pi]; the assemblies found "
                             f"have {values}); change the sign or the guess")
        q, v = min(on, key=lambda o: float(np.max(_distance(cfg, o[0], q0))))
    else:
        q, v = options[0]
    q = _near(cfg, q, q0)
    coords.seed(q)
    q, v = coords.project(0.0, q, v, prefer)
    q = _near(cfg, q, q0)
    diff = _distance(cfg, q, q0)
    moved = [(n, float(q0[cfg.joint_slice[n].start]), float(q[cfg.joint_slice[n].start]))
             for n in cfg.joint_names if diff[cfg.joint_slice[n].start] > GUESS_TOL]
    drives = driven_joints(scene, cfg)
    if any(n in drives for n, _, _ in moved):
        notes.append(_driven_replaced("positions", cfg, drives, moved, "",
                                      "give the drive's values in [initial] q, or change the drive's coefficients"))
        moved = [m for m in moved if m[0] not in drives]
    if moved:
        notes.append("the loop was assembled away from the given values: "
                     + ", ".join(f"{n} given {g:.6g}, assembled {a:.6g}" for n, g, a in moved)
                     + f" (more than {GUESS_TOL:g} apart); check that this is the posture you meant, "
                       + ("and the given values: each angle is assembled within pi of its given value, so a "
                          "guess off by more than pi lands a whole turn away (2 pi), where a guard on that "
                          "angle may never be reached" if scene.branch is not None else
                          f"or fix the branch with [initial] branch = {_branch_example(cfg)}"))
    if scene.branch is None and len(moved):
        try:
            others = _candidates(cfg, q0, v0, prefer)
        except SimulationError:
            others = []
        best = min(others, key=lambda o: float(np.max(_distance(cfg, o[0], q0))), default=None)
        if best is not None and np.max(_distance(cfg, best[0], q0)) < np.max(diff) - 1e-9:
            shown = _near(cfg, best[0], q0)  # Newton's starts may land whole turns away: the guess's turn
            notes.append("another assembly of the loop (the other branch) lies nearer the given values: "
                         + ", ".join(f"{n} = {shown[cfg.joint_slice[n].start]:.6g}" for n in cfg.joint_names)
                         + "; choose it with [initial] branch")
    return q, v, notes + _velocity_notes(scene, cfg, v0, v)


def _driven_replaced(what: str, cfg: Configuration, drives: dict, replaced, per: str, advice: str) -> str:
    """The note for given initial ``what`` (positions, velocities) of driven joints that their drives
    replaced: each joint named with its drive, the drive's value at t = 0 and the given one."""
    return (f"the drives fix some initial {what}, and these given ones were replaced: "
            + ", ".join(f"{n} is driven ({drives[n]}): its drive gives {a:.6g} {_unit(cfg, n)}{per} at t = 0, "
                        f"given {g:.6g}" for n, g, a in replaced if n in drives)
            + f"; {advice}")


VELOCITY_TOL = 1e-9  # rad/s or m/s, relative to the largest given velocity beyond 1


def _velocity_notes(scene: Scene, cfg: Configuration, v_given: np.ndarray, v: np.ndarray) -> list[str]:
    """What the constraints did to ``[initial] v``: the dependent (and driven) joints' velocities
    follow from the independent ones, so a given value that differs is replaced, and an
    independent joint left out of ``[initial] v`` starts at rest."""
    if not getattr(cfg.coords, "constrained", False):
        return []
    single = [n for n in cfg.joint_names if cfg.joint_slice[n].stop - cfg.joint_slice[n].start == 1]
    tol = VELOCITY_TOL * max(1.0, float(np.max(np.abs(v_given), initial=0.0)))
    replaced = [(n, float(v_given[cfg.joint_slice[n].start]), float(v[cfg.joint_slice[n].start])) for n in single
                if n in scene.v0 and abs(v[cfg.joint_slice[n].start] - v_given[cfg.joint_slice[n].start]) > tol]
    drives = driven_joints(scene, cfg)
    kept = set(np.asarray(cfg.coords.I if cfg.coords.I is not None else (), dtype=int).tolist())
    independent = {n for n in single if cfg.joint_slice[n].start in kept and n not in drives}
    at_rest = [n for n in single if n not in scene.v0 and n in independent]
    notes = []
    if any(n in drives for n, _, _ in replaced):
        notes.append(_driven_replaced("velocities", cfg, drives, replaced, "/s",
                                      "leave the driven joints out of [initial] v, or give the drive's rates"))
        replaced = [r for r in replaced if r[0] not in drives]
    if replaced:
        notes.append("the constraints fix some initial velocities, and these given ones were replaced: "
                     + ", ".join(f"{n} given {g:.6g}, now {a:.6g}" for n, g, a in replaced)
                     + f" (the velocities kept as given: {', '.join(sorted(independent)) or 'none'}); give only "
                       "those, or consistent values")
    if at_rest:
        notes.append(f"initial.v has no value for {', '.join(at_rest)}, kept as an independent coordinate: "
                     f"{'it starts' if len(at_rest) == 1 else 'they start'} at rest (v = 0)")
    return notes


def driven_joints(scene: Scene, cfg: Configuration) -> dict[str, str]:
    """{joint: "drives[i]"} of the scene's drives acting in ``cfg`` (i indexes ``[[drives]]``)."""
    return {d.joint: f"drives[{i}]" for i, d in enumerate(scene.drives)
            if d.configurations is None or cfg.name in d.configurations}


def _unit(cfg: Configuration, joint: str) -> str:
    """"rad" for a revolute joint's coordinate, "m" for a prismatic one's."""
    return "rad" if cfg.spec.info.joints[joint].type in ("revolute", "continuous") else "m"
