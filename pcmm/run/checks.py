"""Check-time consistency of a scene's geometry (``pcmm check``), before anything is simulated.

The schema (:mod:`pcmm.scene`) validates each value on its own; this module builds the
configurations' models and checks that the values agree with each other where a guard fixes the
posture, so a scene that would fail at its first switch, after the whole pre-switch run, fails
here at once, each problem naming the file and the field:

* **the pose at a switch**: at the posture where a guard sits at its value (an open chain: the
  guard coordinate set; a loop: assembled with the guard as one more equation), every link the
  target configuration shares with the source sits where the source puts it;
* **the contact at the guard value**: the two contact points meet (gap zero along the normal and
  nothing across it); for a frictionless contact on a pair joined by one joint, the normal is the
  direction in which that joint moves the contact point (for a revolute pair, perpendicular to the
  lever from the joint axis; how far it is off, in degrees): an error between two moving links, a
  warning against a wall (:mod:`pcmm.events.contact_faults` says why); it points from a towards b,
  so the guard's direction approaches;
* **reach**: each guard value lies in the range its coordinate can reach (the URDF's joint limits;
  a loop that cannot close there), else a warning;
* **freedom at an impact**: a contact whose configuration has no free coordinate at the guard's
  posture (nv minus the rank of the loops' and drives' rows is 0: a driven slider-crank striking
  with its slider) can take no impulse, and the run would stop at the strike: a warning naming the
  drives;
* **units**: a guard on an angle (a revolute joint, a link's angle, the angle between two links)
  whose value lies outside [-2 pi, 2 pi] was most likely written in degrees: a warning that
  gives the value in radians (``"-50 deg"``);
* **redundant rows** at a switch: a target configuration whose rows (cut joints, drives; and the
  lock rows its holding forces are solved with) are dependent leaves the forces they carry
  statically indeterminate (a warning naming them), or, where no motion or posture satisfies them,
  is an error (:func:`redundant_rows`).

**Which posture.** The posture a guard is judged at is the one the run reaches: where the loops
leave one freedom, the first crossing along the path from the start, in the direction the
mechanism moves, as far as its energy carries it (:func:`path_posture`); elsewhere the solution
nearest the start (:func:`guard_posture`), of which every finding says that pcmm could not tell
whether the run reaches it. Every finding names the posture it was made at.

A message blames the normal only when the normal is at fault: rounded contact points that do not
meet are reported as points (:func:`pcmm.contact_faults.contact_findings`, also used by the run's
latch check).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..model.assembly import _distance, _near, _revolute
from ..model.configuration import Configuration
from ..model.mechanism import Mechanism
from ..errors import PcmmError
from ..scene.spec import Scene, TransitionSpec
from ..events.contact_faults import contact_findings
from ..events.entry import map_state, pose_mismatches
from ..events.pins import anchor_where_entered

NEWTON_TOL = 1e-13


@dataclass
class CheckReport:
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    postures: dict[str, np.ndarray] = field(default_factory=dict)  # transition name -> q at its guard
    reach: dict[str, str] = field(default_factory=dict)  # transition name -> which posture that is (path_posture)


# ---- the posture at a guard ---------------------------------------------------------------
def _closure(cfg: Configuration, q):
    """(phi, dPhi/dq) of the loop-closure rows only (drives are functions of time, not posture); the
    derivative in pcmm's coordinates, which for a planar joint is not the velocity Jacobian (its x, y
    columns are body-frame: :meth:`Configuration.position_jacobian`)."""
    phi, Jq = cfg.coords.loop_rows(q)
    return phi, cfg.position_jacobian(q, Jq)


def _guard_row(cfg: Configuration, tr: TransitionSpec, q):
    """(residual, gradient) of the guard at q: measure - value, or gap - value."""
    if tr.guard.type == "coordinate":
        row, offset = cfg.measure_row(tr.guard.measure)
        return float(row @ q + offset - tr.guard.value), row
    from ..events.contact import contact_state

    def gap(x):
        return contact_state(cfg, x, np.zeros(cfg.nv), tr.contact)[1]
    grad = np.zeros(cfg.nv)
    for i in range(cfg.nv):
        e = np.zeros(cfg.nv)
        e[i] = 1e-7
        grad[i] = (gap(q + e) - gap(q - e)) / 2e-7
    return gap(q) - tr.guard.value, grad


#: quarter and eighth turns added, one revolute coordinate at a time, to the start of the guard's Newton
#: solve: a start where the guard's gradient vanishes (a pendulum hanging level over a wall: the gap is
#: stationary there) makes no step, and a start far from the posture may land a turn away
START_SHIFTS = (0.25 * math.pi, -0.25 * math.pi, 0.5 * math.pi, -0.5 * math.pi, math.pi)


def _newton(cfg: Configuration, tr: TransitionSpec, q_start, iterations: int) -> tuple[np.ndarray, float]:
    """Minimum-norm Newton steps from ``q_start`` to the guard at its value with every loop closed;
    (q, largest residual), the residual ~1e-13 when reached, inf when the steps blew up."""
    q = np.array(q_start, dtype=float)
    worst = math.inf
    for _ in range(iterations):
        phi, Jq = _closure(cfg, q)
        r, g = _guard_row(cfg, tr, q)
        res = np.append(phi, r)
        worst = float(np.max(np.abs(res)))
        if worst < NEWTON_TOL:
            break
        q = q + np.linalg.lstsq(np.vstack([Jq, g]), -res, rcond=None)[0]
        if not np.all(np.isfinite(q)):
            return np.array(q_start, dtype=float), math.inf
    return q, worst


def _outside_limits(cfg: Configuration, q) -> bool:
    return any(not lo - 1e-12 <= float(q[cfg.joint_slice[n].start]) <= hi + 1e-12
               for n, j in cfg.spec.info.joints.items()
               if j.limits is not None and n in cfg.joint_slice and j.type in ("revolute", "prismatic")
               for lo, hi in [j.limits])


def guard_posture(cfg: Configuration, tr: TransitionSpec, q_start) -> tuple[np.ndarray, float]:
    """The posture nearest ``q_start`` with the guard at its value and every loop closed; returns
    (q, largest residual), the residual ~1e-13 when reached (else the smallest any start left).

    Newton (minimum-norm steps) runs from ``q_start`` and from starts with one revolute coordinate
    turned by :data:`START_SHIFTS`, as the assembly tries several (:func:`pcmm.model.assembly._candidates`);
    of the postures reached, each revolute angle taken within pi of the start, the nearest to the start
    within the URDF's joint limits wins (one outside them only when no other is found); of two as near,
    the lower in gravity's potential, where a mechanism released at rest goes."""
    q0 = np.array(q_start, dtype=float)
    rev = np.flatnonzero(_revolute(cfg))
    starts = [q0] + [q0 + shift * np.eye(cfg.nv)[i] for i in rev for shift in START_SHIFTS]
    reached, closest = [], (q0, math.inf)
    for k, start in enumerate(starts):
        q, residual = _newton(cfg, tr, start, 60 if k == 0 else 30)
        if residual < 1e-9:
            q = _near(cfg, q, q0)
            far = round(float(np.max(_distance(cfg, q, q0), initial=0.0)), 9)
            reached.append((_outside_limits(cfg, q), far, cfg.gravity_energy(q), q, residual))
        elif residual < closest[1]:
            closest = (q, residual)
    if not reached:
        return closest
    _, _, _, q, residual = min(reached, key=lambda c: c[:3])
    return q, residual


# ---- the posture the run reaches -----------------------------------------------------------------
#: path-length step (in coordinates: rad, m) and the most steps of the path followed from the start
PATH_STEP = 0.01
PATH_STEPS = 4000
TURNS = "a turning point (its energy runs out)"


@dataclass
class PathPosture:
    """Where the guard of a transition is met along the mechanism's path from its start
    (:func:`path_posture`)."""

    q: np.ndarray | None  # the posture, None when the path does not reach the guard
    residual: float
    how: str  # which posture this is and why the run reaches it (or does not)


def _guard_value(cfg: Configuration, tr: TransitionSpec, q) -> float:
    if tr.guard.type == "coordinate":
        row, offset = cfg.measure_row(tr.guard.measure)
        return float(row @ q + offset - tr.guard.value)
    from ..events.contact import contact_state
    return float(contact_state(cfg, q, np.zeros(cfg.nv), tr.contact)[1] - tr.guard.value)


def _tangent(cfg: Configuration, q) -> np.ndarray | None:
    """The unit tangent of a one-freedom posture space at q (the null vector of the loops'
    position rows), None where it has not exactly one (a singular posture, or more freedom)."""
    _, Jq = _closure(cfg, q)
    if Jq.shape[0] == 0:
        return np.ones(1) if cfg.nv == 1 else None
    _, s, Vt = np.linalg.svd(Jq)
    s = np.concatenate([s, np.zeros(cfg.nv - s.size)])
    if s[0] == 0 or np.count_nonzero(s > 1e-8 * s[0]) != cfg.nv - 1:
        return None
    return Vt[-1]


def _loads(cfg: Configuration, q) -> np.ndarray:
    """The generalized force at rest (force elements at zero velocity, minus gravity's load):
    its work along the path is the kinetic energy the motion gains (dampers left out)."""
    import pinocchio as pin
    return cfg.forces.generalized(q, np.zeros(cfg.nv)) - pin.computeGeneralizedGravity(cfg.model, cfg.data, cfg.to_pin(q))


def _follow(cfg: Configuration, tr: TransitionSpec, q0, sign: float, energy: float | None):
    """Follow the one-freedom path from ``q0`` with the tangent's orientation ``sign`` (predictor
    along the tangent, Newton back onto the loops) until the guard crosses its value in its
    direction; ``energy``: the kinetic energy at q0 (None: not counted), the work of the loads at
    rest added on the way, the path ending where it runs out (a turning point).  Returns
    (q near the crossing or None, the path length, why it ended, the postures near crossings
    against the guard's direction on the way, which the motion meets in its direction after
    turning back, and at a turning point that posture last)."""
    back: list[np.ndarray] = []
    t_prev = _tangent(cfg, q0)
    if t_prev is None:
        return None, 0.0, "no single path from the start", back
    t_prev = sign * t_prev
    q, r, length = np.array(q0, float), _guard_value(cfg, tr, q0), 0.0
    r0 = r
    ke, load = energy, (_loads(cfg, q0) if energy is not None else None)
    for _ in range(PATH_STEPS):
        nxt = q + PATH_STEP * t_prev
        closed = False
        for _ in range(8):  # back onto the loops, minimum-norm Newton steps (closed below 1e-10)
            phi, Jq = _closure(cfg, nxt)
            closed = phi.size == 0 or float(np.max(np.abs(phi))) < 1e-10
            if phi.size == 0 or np.max(np.abs(phi)) < 1e-12:
                break
            nxt = nxt - np.linalg.lstsq(Jq, phi, rcond=None)[0]
        t = _tangent(cfg, nxt) if closed and np.all(np.isfinite(nxt)) else None
        if t is None:
            return None, length, f"a singular posture after {length:.3g} along the path", back
        t = t if t @ t_prev >= 0 else -t
        length += float(np.linalg.norm(nxt - q))
        if ke is not None:
            new_load = _loads(cfg, nxt)
            gained = 0.5 * float((load + new_load) @ (nxt - q))
            if ke + gained < 0:  # the turning point (last in ``back``), the energy linear across the step
                back.append(q + (ke / (ke - (ke + gained))) * (nxt - q))
                return None, length, TURNS, back
            ke, load = ke + gained, new_load
        r_next = _guard_value(cfg, tr, nxt)
        near = nxt if abs(r_next) <= abs(r) else q
        if (r > 0 >= r_next and tr.guard.direction < 0) or (r < 0 <= r_next and tr.guard.direction > 0):
            return near, length, "the guard", back
        if (r > 0 >= r_next) or (r < 0 <= r_next):
            back.append(near)
        if length > 2 * PATH_STEP and float(np.max(_distance(cfg, nxt, q0), initial=0.0)) < 0.5 * PATH_STEP:
            turned = q0 + (nxt - _near(cfg, nxt, q0))  # the start, whole turns on: the same posture
            if abs(_guard_value(cfg, tr, turned) - r0) < 1e-9 * max(1.0, abs(r0)):  # (a joint's angle is not periodic)
                return None, length, "a whole turn back to the start", back
        q, r, t_prev = nxt, r_next, t
    return None, length, f"{length:.3g} along the path", back


def _describe_posture(cfg: Configuration, q) -> str:
    return ", ".join(f"{n} = {float(q[cfg.joint_slice[n].start]):.6g}" for n in cfg.joint_names
                     if cfg.joint_slice[n].stop - cfg.joint_slice[n].start == 1)


def path_posture(scene: Scene, cfg: Configuration, tr: TransitionSpec, q0, v0=None) -> PathPosture | None:
    """The posture where the run meets the guard of ``tr``, found by following the mechanism's
    path from ``q0`` (its start in ``cfg``), for a configuration whose loops leave one freedom
    (a pendulum, a slider-crank, a four-bar): the motion stays on that curve, so the posture it
    reaches is the first crossing along it, in the direction it moves, before its energy runs out.

    The direction: the initial velocity ``v0`` along the path, else (at rest) the loads' (gravity's,
    the force elements') push along it, else a drive's rate; with none known both ways are followed
    and the nearer crossing kept, said so. The energy: with ``v0`` known and no drive, the kinetic
    energy at the start plus the work of the loads at rest along the path (dampers, which only take
    energy, left out): where it runs out the motion turns back and the other way is followed (to
    its own turning point). None where the path cannot be followed (more than one freedom, a planar
    joint, a singular start): the caller then takes the nearest solution and says it could not tell."""
    if cfg.has_planar:
        return None
    t0 = _tangent(cfg, q0)
    if t0 is None:
        return None
    drives = getattr(cfg.coords, "drives", None)
    driven = drives is not None and drives.size > 0
    sign, why = 0.0, ""
    if v0 is not None and abs(float(t0 @ v0)) > 1e-12:
        sign, why = float(np.sign(t0 @ v0)), "in the direction of its initial velocity"
    elif driven:  # each driven coordinate first moves as its first non-zero term beyond the constant
        lead = [next((float(c) for c in d[0][1:] if c != 0), 0.0) for d in drives._derivs]
        along = [(x, t0[i]) for i, x in zip(drives.index, lead) if abs(t0[i]) > 1e-9]
        if along and all(x == 0 for x, _ in along):
            if v0 is None:
                return None  # entered at a time not known here: the drive's law then decides
            return PathPosture(None, math.inf, (
                f"its drives ({', '.join(drives.joints)}) are constant and hold the configuration's one "
                "freedom still from the start: the guard cannot fire while they do"))
        push = float(sum(np.sign(x) * ti for x, ti in along))
        if v0 is not None and abs(push) > 1e-12:
            sign, why = float(np.sign(push)), "in the direction its drive moves it"
    elif v0 is not None:
        push = float(t0 @ _loads(cfg, q0))
        if abs(push) > 1e-12 * max(1.0, float(np.max(np.abs(_loads(cfg, q0))))):
            sign, why = float(np.sign(push)), "released at rest, in the direction its loads push it"
    energy = None if v0 is None or driven else cfg.kinetic_energy(q0, v0)
    where = f"from the initial posture ({_describe_posture(cfg, q0)})" if v0 is not None else \
        f"from where '{cfg.name}' is entered ({_describe_posture(cfg, q0)})"
    if sign:
        q, length, end, back = _follow(cfg, tr, q0, sign, energy)
        if q is not None:
            return _settle(cfg, tr, q, f"reached along the path {where}, {why}, after {length:.3g} of path")
        if end != TURNS:
            return None  # a singular posture, or a whole turn or the longest path without the guard
        turn = back.pop()
        if back:  # met against its direction on the way out, so in it on the way back: the last one first
            return _settle(cfg, tr, back[-1], f"reached along the path {where}, {why}, as the motion turns back "
                                              f"{length:.3g} of path out")
        q, length, end, other = _follow(cfg, tr, q0, -sign, energy)
        if q is not None:
            return _settle(cfg, tr, q, f"reached along the path {where} after the motion turns back, "
                                       f"{length:.3g} of path the other way")
        if end != TURNS:
            return None
        turn_back = other.pop()
        if other:  # met against its direction on the way to the second turning point: in it coming back
            return _settle(cfg, tr, other[-1], f"reached along the path {where} after the motion turns back twice")
        return PathPosture(None, math.inf, (
            f"the path {where} swings between two turning points where its energy runs out (dampers left out), "
            f"{_describe_posture(cfg, turn)} and {_describe_posture(cfg, turn_back)}, "
            "and the guard's value is not met in its direction between them: the guard cannot fire unless a "
            "force adds energy or another transition changes the motion first"))
    found = []
    for d in (1.0, -1.0):
        q, length, _, _ = _follow(cfg, tr, q0, d, None)
        if q is not None:
            found.append((length, q))
    if not found:
        return None
    length, q = min(found, key=lambda f: f[0])
    return _settle(cfg, tr, q, f"the nearer of the crossings along the path {where} (either way, "
                               f"{length:.3g} of path: the direction it moves is not known at check time)")


def _settle(cfg: Configuration, tr: TransitionSpec, q, how: str) -> PathPosture | None:
    """The crossing near ``q`` to round-off (Newton with the guard and the loops); None when it
    does not converge near q."""
    exact, residual = _newton(cfg, tr, q, 30)
    if residual > 1e-9 or float(np.max(_distance(cfg, exact, q), initial=0.0)) > 10 * PATH_STEP:
        return None
    return PathPosture(exact, residual, f"{how}: {_describe_posture(cfg, exact)}")


# ---- freedom at an impact ----------------------------------------------------------------------
def no_free_coordinate(scene: Scene, cfg: Configuration, q) -> str | None:
    """The warning for an impact at ``q`` in a configuration whose rows (loops and drives) leave no
    free coordinate: nv minus the rank of the velocity rows is 0, so no impulse can change a
    velocity and the run stops at the strike; None when a coordinate is free."""
    drives = getattr(cfg.coords, "drives", None)
    joints = tuple(drives.joints) if drives is not None else ()
    _, Jq = cfg.coords.loop_rows(q)
    Jd = np.zeros((len(joints), cfg.nv))
    Jd[np.arange(len(joints)), [cfg.joint_slice[j].start for j in joints]] = 1.0
    rows = np.vstack([Jq, Jd])
    if cfg.nv - (np.linalg.matrix_rank(rows) if rows.shape[0] else 0) > 0:
        return None
    loops = cfg.nv - (np.linalg.matrix_rank(Jq) if Jq.shape[0] else 0)
    named = ", ".join(f"drives[{i}] ('{d.joint}')" for i, d in enumerate(scene.drives) if d.joint in joints)
    why = (f"its loops leave {loops} and {named} prescribe{'s' if len(joints) == 1 else ''} "
           f"{'it' if loops == 1 else 'them'}" if loops and joints else "its loops fix them all")
    return (f"at the guard's posture configuration '{cfg.name}' has no free coordinate ({cfg.nv} coordinates; "
            f"{why}): the impact cannot change a velocity and the run will stop at the strike. A driven joint "
            "takes the freedom an impact needs: give the struck part a freedom of its own (e.g. on a spring), "
            "or drive it by a motor torque (a `torque` force) instead of a drive")


# ---- redundant rows --------------------------------------------------------------------------
#: a singular value of a configuration's rows below this (relative to the largest) is a redundancy
RANK_TOL = 1e-9


def _drive_rows(scene: Scene, cfg: Configuration, drives_of: str) -> tuple[np.ndarray, list[str], list]:
    """(unit rows, labels, (coordinate, coefficients)) of the drives of configuration ``drives_of``
    on ``cfg``'s coordinates."""
    rows, labels, laws = [], [], []
    for d in scene.drives_in(drives_of):
        if d.joint not in cfg.joint_slice:
            continue
        e = np.zeros(cfg.nv)
        e[cfg.joint_slice[d.joint].start] = 1.0
        rows.append(e)
        labels.append(f"drives[{scene.drives.index(d)}] ('{d.joint}')")
        laws.append((cfg.joint_slice[d.joint].start, np.array(d.coefficients, dtype=float)))
    return np.array(rows).reshape(len(rows), cfg.nv), labels, laws


@dataclass
class Redundancy:
    """Constraint rows of one configuration that are not independent (:func:`redundant_rows`)."""

    configuration: str
    labels: list[str]  # every row: cut-joint rows (C.fx, ...), drives ("drives[0] ('A')"), holds
    rank: int
    nv: int
    null: np.ndarray  # left null vectors y (y^T R = 0), one per column, unit length
    consistent: bool  # some motion satisfies the rows (the drives' rates are orthogonal to every y)
    posture: bool = False  # inconsistent in posture: a constant drive holds a joint where the others do not

    @property
    def indeterminate(self) -> list[str]:
        """The rows whose force some null vector moves: statically indeterminate."""
        return [lab for lab, y in zip(self.labels, self.null) if np.max(np.abs(y)) > 1e-9]

    def message(self, also: list[str] = (), holding: bool = False) -> str:
        """The check's message; ``holding``: the rows are those the holding forces are solved with,
        not the configuration's own (which the run can integrate)."""
        m = len(self.labels)
        rows = ", ".join(self.labels)
        loose = self.indeterminate + [a for a in also if a not in self.indeterminate]
        if not self.consistent:
            what = ("a posture the others forbid: no posture satisfies {} together (a constant drive holds a "
                    "joint where the lock and the loop put it elsewhere)" if self.posture else
                    "a motion the others forbid: no motion satisfies {} together (a lock or the loop fixes what "
                    "a drive moves)").format(", ".join(self.indeterminate))
            return (f"configuration '{self.configuration}' has {m} constraint rows ({rows}) of rank {self.rank} on "
                    f"{self.nv} coordinates, and its drives ask {what}; drive the joint only where it is free (the "
                    "drive's configurations) or release the lock first")
        free = self.nv - self.rank
        return (f"configuration '{self.configuration}' has {m} constraint rows ({rows}) of rank {self.rank} on "
                f"{self.nv} coordinates: {m - self.rank} redundant but consistent, so the motion is still determined "
                f"({free} free coordinate{'s' if free != 1 else ''}) while the forces of {', '.join(loose)} are "
                "not: they are statically indeterminate (any split of the load between them balances it). "
                + ("pcmm solves the holding forces with these rows (on a configuration with the held joints free "
                   "and the same drives): any split would be one of many, so it reports those it leaves "
                   "indeterminate as NaN, and refuses a guard that reads one. " if holding else
                   "pcmm reports no arbitrary split: the run goes on with a maximal independent set of the rows "
                   "(the others checked at every solve), and these forces are NaN in its series. ")
                + "Remove the redundant row: a drive limited to the configurations where its joint is free, one "
                "cut joint fewer, or a joint fewer locked")


def redundant_rows(scene: Scene, cfg: Configuration, q, holds=(), drives_of: str | None = None) -> Redundancy | None:
    """The dependence of ``cfg``'s constraint rows at ``q`` (its cut joints', the drives of
    ``drives_of`` (default: ``cfg``'s own), plus ``holds``: ``(label, row)`` of locks whose holding
    forces are solved with them, as :meth:`pcmm.events.holding.Holds.forces` does on a configuration
    with the held joints free); None when they are independent.

    Rows ``R`` of rank r < m leave the velocities ``R v = [0; f'(t)]`` solvable only where every
    left null vector y of R (``y^T R = 0``) has ``y^T [0; f'(t)] = 0`` at every t, i.e. its drive
    components are orthogonal to the drives' rate polynomials: then the rows are *consistent*, the
    motion is still determined, but the multipliers (``R^T lam`` is the generalized force they
    apply) are determined only up to adding any such y: the force of every row on which some y is
    non-zero is statically indeterminate. Otherwise no motion satisfies the rows (inconsistent).
    A null vector whose drive components fall on constant drives alone also asks
    ``y^T [0; f - q] = 0`` (a drive being a position): a constant drive holding a joint where the
    loop and the locks put it elsewhere is inconsistent in posture. (A moving drive's position is
    the run's to judge: the guard's posture here is not solved at the drive's time.)"""
    coords = cfg.coords
    closure = getattr(coords, "closure", None)
    _, Jq = coords.loop_rows(q)
    labels = list(closure.labels()) if closure is not None and Jq.shape[0] else []
    Jd, dlabels, laws = _drive_rows(scene, cfg, drives_of or cfg.name)
    R = np.vstack([Jq, Jd] + [row[None, :] for _, row in holds])
    labels += dlabels + [label for label, _ in holds]
    m = R.shape[0]
    if m == 0:
        return None
    U, s, _ = np.linalg.svd(R)
    rank = int(np.sum(s > RANK_TOL * max(float(s[0]), 1e-300))) if s.size else 0
    if rank == m:
        return None
    Y = U[:, rank:]
    consistent = True
    if laws:  # each null vector's drive components against the drives' rates, as polynomials in t
        rates = [np.polynomial.polynomial.polyder(c) if len(c) > 1 else np.zeros(1) for _, c in laws]
        C = np.zeros((len(laws), max(len(r) for r in rates)))
        for k, r in enumerate(rates):
            C[k, :len(r)] = r
        Yd = Y[Jq.shape[0]:Jq.shape[0] + len(laws)]
        consistent = bool(np.all(np.abs(Yd.T @ C) <= 1e-9 * max(1.0, float(np.max(np.abs(C))))))
        if consistent:
            still = np.array([not np.any(c[1:]) for _, c in laws])
            rev = _revolute_joints(cfg)
            off = np.array([float(c[0]) - float(q[i]) for i, c in laws])
            off = np.where([i in rev for i, _ in laws], (off + math.pi) % (2 * math.pi) - math.pi, off)
            for y in Yd.T:
                moving = (np.abs(y) > 1e-9) & ~still
                if not moving.any() and abs(float(y @ off)) > 1e-9 * max(1.0, float(np.max(np.abs(q)))):
                    return Redundancy(cfg.name, labels, rank, cfg.nv, Y, False, posture=True)
    return Redundancy(cfg.name, labels, rank, cfg.nv, Y, consistent)


def _revolute_joints(cfg: Configuration) -> set[int]:
    """Coordinates of revolute joints (a drive's angle is the same posture a turn away)."""
    return {cfg.joint_slice[n].start for n in cfg.joint_names if cfg.spec.info.joints[n].type == "revolute"}


def entry_redundancy(scene: Scene, src: Configuration, dst: Configuration, tr: TransitionSpec, q, q_dst
                     ) -> tuple[str | None, bool, list[str]]:
    """(message, consistent, the indeterminate labels) of the rows of configuration ``dst`` entered by ``tr`` from ``src`` at
    ``q`` (``q_dst`` there) when they are dependent (:func:`redundant_rows`), else (None, True): its
    own rows, and those its holding forces are solved with (``src``'s loops, ``dst``'s drives and one
    row per lock ``tr`` makes: the stop's normal for a merge, the joint's coordinate for a latch, as
    :class:`pcmm.events.holding.Holds` solves them), whose indeterminate holds it names too (the
    labels: the rows' ``C.fx``, ``drives[0] ('A')``, the holds' ``'stop.hold'``)."""
    own = redundant_rows(scene, dst, q_dst)
    locked = [n for n in src.joint_names if n not in dst.joint_slice]
    if not locked:
        return (None, True, []) if own is None else (own.message(), own.consistent, own.indeterminate)
    if tr.type == "stop" and tr.contact is not None:
        from ..events.contact import contact_row
        holds = [(f"'{tr.name}.hold'", contact_row(src, q, np.zeros(src.nv), tr.contact)[0])]
    else:
        holds = []
        for n in locked:
            e = np.zeros(src.nv)
            e[src.joint_slice[n]] = 1.0
            holds.append((f"'{n}.hold'", e))
    held = redundant_rows(scene, src, q, holds, drives_of=dst.name)
    holding = [lab for lab in (held.indeterminate if held is not None else []) if lab in dict(holds)]
    if own is not None:
        return own.message([f"the holding force {h}" for h in holding]), own.consistent, own.indeterminate + holding
    if held is None:
        return None, True, []
    return held.message(holding=True), held.consistent, holding


def indeterminate_readers(scene: Scene, dst: Configuration, tr: TransitionSpec, loose: list[str], here: str
                          ) -> list[str]:
    """The problems of guards that would read a force the rows leave statically indeterminate in
    ``dst`` entered by ``tr`` (``loose``: :func:`entry_redundancy`'s labels): the merge's own unmerge
    (its hold turning tensile), a reaction guard on the hold or on a cut joint of ``dst``, a cut joint
    held by compression or friction only. Whether such a force turns tensile or leaves its friction cone
    depends on the parts' compliance, which pcmm does not model: refused, as the run refuses it."""
    out = []
    why = ("which the redundant rows leave statically indeterminate (any split of the load between them "
           "balances it): whether it turns tensile cannot be decided without the parts' compliance; remove the "
           "redundant row (a drive limited to the configurations where its joint is free, one cut joint fewer, "
           "or a joint fewer locked)")
    holds = {lab.strip("'")[:-len(".hold")] for lab in loose if lab.startswith("'") and lab.endswith(".hold'")}
    rows = {lab.split(".")[0] for lab in loose if not lab.startswith("'") and not lab.startswith("drives[")}
    own = getattr(tr, "unmerge", None)  # a stop's own; a latch has none (its merge is never undone by it)
    unmerge = own if own is not None else scene.solver.unmerge
    if tr.type == "stop" and unmerge and tr.name in holds:
        out.append(f"{here}.unmerge: = true ({'the stop' if own is not None else 'solver.unmerge'}'s): the "
                   f"merge is undone where its holding force '{tr.name}.hold' turns tensile, {why}, or set "
                   "unmerge = false and release it by a time or coordinate guard")
    where = str(scene.path)
    for k, other in enumerate(scene.transitions):
        if other.source != dst.name or other.guard.type != "reaction" or other.guard.of not in holds | rows:
            continue
        what = f"the holding force '{other.guard.of}.hold'" if other.guard.of in holds else \
            f"the force of cut joint '{other.guard.of}'"
        out.append(f"{where}: transitions[{k}] ({other.name}).guard.of: = {other.guard.of!r}: in configuration "
                   f"'{dst.name}' (entered by transition '{tr.name}') it reads {what}, {why}")
    for spec in dst.spec.cut_joints:
        if spec.normal is not None and spec.name in rows:
            out.append(f"{here}: in configuration '{dst.name}' cut joint '{spec.name}' is held by compression "
                       f"{'and friction ' if spec.friction is not None else ''}only, and its force is {why}")
    return out


# ---- units -------------------------------------------------------------------------------------
def is_angle(cfg: Configuration, tr: TransitionSpec) -> bool:
    """Does the guard measure an angle (rad): a revolute joint's coordinate, a link's angle, the
    angle between two links?"""
    m = tr.guard.measure
    if tr.guard.type != "coordinate" or m is None:
        return False
    if m.kind != "joint":
        return True
    joint = cfg.spec.info.joints.get(m.names[0])
    return joint is not None and joint.type in ("revolute", "continuous")


def angle_in_degrees(cfg: Configuration, tr: TransitionSpec) -> str | None:
    """The warning for a guard angle outside [-2 pi, 2 pi], which was likely meant in degrees."""
    value = tr.guard.value
    if not is_angle(cfg, tr) or abs(value) <= 2 * math.pi:
        return None
    return (f"= {value:.12g}: an angle ({tr.guard.measure}) of {value:.6g} rad, {value / (2 * math.pi):.3g} "
            f"turns, outside [-2 pi, 2 pi]; guard values are in radians: if {value:g} degrees is meant, write "
            f"value = \"{value:g} deg\" (= {math.radians(value):.6g} rad); a guard meant after more than a turn "
            "is right as it is")


# ---- the whole scene ------------------------------------------------------------------------
def _limits(cfg: Configuration, q) -> list[str]:
    out = []
    for name, j in cfg.spec.info.joints.items():
        if j.limits is None or name not in cfg.joint_slice or j.type not in ("revolute", "prismatic"):
            continue
        x = float(q[cfg.joint_slice[name].start])
        lo, hi = j.limits
        if not lo - 1e-12 <= x <= hi + 1e-12:
            out.append(f"joint '{name}' is at {x:.9g} there, outside its URDF limits [{lo:g}, {hi:g}] "
                       f"({cfg.spec.urdf.name})")
    return out


def check_scene(scene: Scene, mechanism: Mechanism | None = None) -> CheckReport:
    """Every check-time problem (and warning) of ``scene``, each naming the file and the field.
    What is found at a guard's posture says which posture that is and whether the run reaches it
    (:func:`path_posture`), so nothing is claimed of a posture the run never reaches."""
    from ..model.assembly import assemble
    mech = mechanism or Mechanism(scene)
    report = CheckReport()
    where = str(scene.path)
    starts: dict[str, tuple] = {}  # configuration -> (q where the run starts in it, v there or None: unknown)
    try:
        cfg0 = mech[scene.initial_configuration]
        q0, v0, notes = assemble(scene, cfg0)
        starts[cfg0.name] = (q0, v0)
        report.warnings += [f"{where}: initial: {w}" for w in notes]
    except PcmmError as exc:
        report.problems += [p if p.startswith(where) else f"{where}: initial: {p}" for p in exc.problems]
        return report
    todo = [scene.initial_configuration]
    entered: dict = {}
    while todo:  # configurations in the order a run reaches them, each started where it is entered
        name = todo.pop(0)
        cfg = entered.get(name) or mech[name]
        for tr in scene.transitions_from(name):
            here = f"{where}: transitions[{scene.transitions.index(tr)}] ({tr.name})"
            if tr.guard.type == "entry":  # fired where the run enters: its target starts at that posture
                _enter_on_entry(scene, mech, report, cfg, tr, here, starts, entered, todo)
                continue
            if tr.guard.type not in ("coordinate", "gap"):  # time and reaction guards fix no posture
                continue
            n_warnings, n_problems = len(report.warnings), len(report.problems)
            how = _check_transition(scene, mech, report, cfg, tr, here, starts, entered, todo)
            if how:  # every finding at the posture says which posture it is
                report.warnings[n_warnings:] = [f"{w} [{how}]" for w in report.warnings[n_warnings:]]
                report.problems[n_problems:] = [f"{p} [{how}]" for p in report.problems[n_problems:]]
    return report


def _enter_on_entry(scene: Scene, mech: Mechanism, report: CheckReport, cfg: Configuration, tr: TransitionSpec,
                    here: str, starts: dict, entered: dict, todo: list) -> None:
    """A release fired on entry (``guard = { type = "entry" }``) leaves ``cfg`` at the posture the run
    enters it at, so its target is judged from there as any transition's is at its guard's posture
    (:func:`_check_target`: the links placed alike, the target's rows), and followed (a pinned point
    anchored where it is: where it struck)."""
    if tr.target is not None and tr.target in scene.configurations:
        _check_target(scene, mech, report, cfg, tr, starts[cfg.name][0], here, None, starts, entered, todo,
                      f"where '{cfg.name}' is entered")


def _check_transition(scene: Scene, mech: Mechanism, report: CheckReport, cfg: Configuration, tr: TransitionSpec,
                      here: str, starts: dict, entered: dict, todo: list) -> str:
    """The checks of one transition at its guard's posture (:func:`check_scene`); returns which
    posture they were made at ("" when none was)."""
    degrees = angle_in_degrees(cfg, tr)
    if degrees is not None:
        report.warnings.append(f"{here}.guard.value: {degrees}")
    q_start, v_start = starts[cfg.name]
    found = path_posture(scene, cfg, tr, q_start, v_start)
    if found is not None and found.q is None:
        report.warnings.append(f"{here}.guard.value: = {tr.guard.value:.12g}: {found.how} (its contact and pose "
                               "checks were skipped: they would judge a posture the run does not reach)")
        return ""
    if found is not None:
        q, residual, how = found.q, found.residual, f"at the guard's posture {found.how}"
    else:
        q, residual = guard_posture(cfg, tr, q_start)
        how = (f"at the guard's posture nearest the start: {_describe_posture(cfg, q)}; whether the run reaches "
               "it pcmm could not tell (the loops leave more than one freedom, or the path from the start could "
               "not be followed to the guard)")
    if residual > 1e-9:
        what = "closing the loop" if cfg.coords.constrained else "reaching it"
        tries = 1 + len(START_SHIFTS) * int(np.count_nonzero(_revolute(cfg)))
        report.warnings.append(
            f"{here}.guard.value: = {tr.guard.value:.12g}: no posture {what} with the guard there was "
            f"found from {tries} starts near the initial posture (closest residual {residual:.3g}); "
            "either none exists and the guard never fires, or the solve could not tell (its "
            "contact and pose checks were skipped); check the guard's value and direction")
        return ""
    report.postures[tr.name] = q
    report.reach[tr.name] = how
    stuck = no_free_coordinate(scene, cfg, q) if tr.contact is not None else None
    if stuck is not None:
        report.warnings.append(f"{here}.contact: {stuck}")
    report.warnings += [f"{here}.guard.value: = {tr.guard.value:.12g}: {w}" for w in _limits(cfg, q)]
    for f in contact_findings(cfg, tr, q, warnings=True):
        (report.warnings if f.warning else report.problems).append(f"{here}.{f.field}: {f.text}")
    target = tr.merge_to if tr.type == "stop" else tr.target
    if target is not None and target in scene.configurations:
        _check_target(scene, mech, report, cfg, tr, q, here, stuck, starts, entered, todo,
                      f"at the guard value ({tr.guard.measure} = {tr.guard.value:.12g})")
    return how


def _check_target(scene: Scene, mech: Mechanism, report: CheckReport, cfg: Configuration, tr: TransitionSpec,
                  q: np.ndarray, here: str, stuck, starts: dict, entered: dict, todo: list, at: str) -> None:
    """The checks of ``tr``'s target (its ``merge_to`` or ``to``) entered from ``cfg`` at the posture
    ``q`` (``at`` says which): every shared link placed alike, the target's rows at the switch
    (:func:`entry_redundancy`, not past a strike that stops the run: ``stuck``); then the target is
    followed from there."""
    target = tr.merge_to if tr.type == "stop" else tr.target
    key = "merge_to" if tr.type == "stop" else "to"
    try:
        dst = mech.enter(target, cfg, q)  # a derived target locks the values the guard gives
        entered.setdefault(target, dst)
        q_dst, _, _ = map_state(cfg, dst, q, np.zeros(cfg.nv))
        anchor_where_entered(dst, q_dst)  # a pinned point is anchored where it strikes
        _, mismatches = pose_mismatches(cfg, dst, q, q_dst)
    except PcmmError as exc:
        report.problems += [f"{here}.{key}: {p}" for p in exc.problems]
        return
    report.problems += [f"{here}.{key}: {at} {m}; the two URDFs must place every shared link identically there "
                        "(check the fixed joint's origin in the merged configuration)" for m in mismatches]
    try:  # (not past a strike that stops the run: the target is never entered)
        rows, consistent, loose = (None, True, []) if stuck else entry_redundancy(scene, cfg, dst, tr, q, q_dst)
    except PcmmError as exc:
        report.problems += [f"{here}.{key}: {p}" for p in exc.problems]
        return
    if rows is not None:
        (report.warnings if consistent else report.problems).append(f"{here}.{key}: {rows}")
        if consistent:
            report.problems += indeterminate_readers(scene, dst, tr, loose, here)
    if target not in starts:
        starts[target] = (q_dst, None)  # the velocity after the switch is not known here
        todo.append(target)
