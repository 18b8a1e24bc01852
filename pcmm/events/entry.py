"""Entering a configuration after a switch: the state mapped by joint name, and every constraint
of the target checked at the post-impact state (issue 22).  Every transition kind reaches its
target through :func:`enter`, so none can skip the check.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from ..errors import SimulationError
from ..model.configuration import Configuration
from .contact_faults import POSE_TOL


@dataclass
class Entry:
    """The state a switch enters its target configuration with."""

    q: np.ndarray
    v: np.ndarray
    dropped: dict[str, float]  # joints the target lacks: their velocity before the switch
    offsets: dict[str, float]  # link -> 2 pi k
    velocity_residual: float  # largest |Phi_q v + Phi_t| of the target's rows at the mapped velocity


#: a constraint holds at a velocity "to round-off" below this x max(1, |v|) x max(1, |Phi_q|)
VELOCITY_ROUNDOFF = 1e-9


def anchor_entered(src: Configuration, dst: Configuration, q_map: np.ndarray) -> None:
    """Anchor ``dst``'s cut joints anchored at entry (``point_a = "entry"``) as the run enters it at
    ``q_map``: one that ``src`` holds too (the same name, anchored) keeps ``src``'s anchor (a foot pinned
    where it struck stays there across a latch, a stop-merge or a release in its stance); any other is
    anchored where its point is now.  (Before, only a pin and a lift-off set them: a latch or a release
    into such a configuration kept the anchor of its previous entry, or the origin, and the switch's
    projection moved the whole mechanism there.)"""
    if not getattr(dst.coords, "constrained", False) or not dst.coords.closure.anchored:
        return
    keep = {}
    if getattr(src.coords, "constrained", False):
        held = src.coords.closure
        keep = {s.name: held.anchors[k] for k, s in enumerate(held.specs) if k in held.anchors}
    dst.kinematics(q_map)
    dst.coords.closure.set_anchors(dst.data, keep)


def enter(src: Configuration, dst: Configuration, t: float, q: np.ndarray, v: np.ndarray,
          known: dict | None = None, what: str = "switch", reset: bool = False, anchored: bool = False) -> Entry:
    """The one way a run enters a configuration after a switch (every transition kind ends here).

    (q, v) of ``src`` (after the impulse, if any) are mapped onto ``dst`` by joint name; joints
    ``dst`` has and ``src`` lacks take their value from ``known`` (at rest), else from the links'
    poses.  Then every constraint of ``dst`` is checked at the mapped state:

    * the links both share sit where they were (``POSE_TOL``);
    * the joints ``dst`` locks (a latch, a merged stop: a weld in ``dst``'s URDF) are at rest
      relative to each other: their velocity is dropped, so it must be zero to round-off;
    * every row of ``dst``'s loops (cut joints) and drives holds at the mapped velocity,
      ``Phi_q v + Phi_t = 0`` to round-off (the impulse solved with ``src``'s rows and the contact
      normal alone cannot satisfy a row ``dst`` adds that they do not span).

    Cut joints of ``dst`` anchored at entry are anchored first (:func:`anchor_entered`), unless the
    caller has (``anchored``: a pin, which anchors the struck point and keeps the others itself).
    Only then is the state assembled onto ``dst`` (its Newton solve moves it by round-off).  A
    violated constraint stops the run with its name, the velocity it leaves and the time: a
    switch never silently replaces the velocity the impulse gave.  ``reset=True`` is the one
    exception the scene asks for (a run without impact, the paper's comparison): the locked
    joints' velocities are dropped and the rest assembled, as its event reports.
    """
    if src is dst:  # a bounce: every joint maps onto itself (map_state's copies; the projection below makes its own)
        q_map, v_map, dropped = q, v, {}
    else:
        q_map, v_map, dropped = map_state(src, dst, q, v, known)
        if not anchored:
            anchor_entered(src, dst, q_map)
    scale = max(1.0, float(np.abs(v).max())) if len(v) else 1.0  # (the method: numpy's np.max wrappers cost more than the reduction)
    if not reset:
        moving = {n: w for n, w in dropped.items() if abs(w) > VELOCITY_ROUNDOFF * scale}
        if moving:
            raise SimulationError(
                f"t = {t:.9g} s, {what} '{src.name}' -> '{dst.name}': '{dst.name}' locks "
                + ", ".join(f"joint '{n}'" for n in moving) + " but after the switch it still moves ("
                + ", ".join(f"{n}' = {w:.6g}" for n, w in moving.items()) + "); locking it would drop that "
                "velocity silently. The impulse must stop the joint: give the transition a contact acting along "
                "its motion and list it in cut")
    q_new, v_new = dst.coords.project(t, q_map, v_map)
    offsets, problems = pose_mismatches(src, dst, q, q_new)
    if problems:
        raise SimulationError([f"t = {t:.9g} s, switching '{src.name}' -> '{dst.name}': {p}" for p in problems]
                              + ["the two URDFs must place every shared link identically at the switch "
                                 "(check the fixed joint's origin in the merged configuration)"])
    residual = 0.0
    if len(dst.coords.labels) and not reset:
        residual = _velocity_rows(src, dst, t, what, v_map, q_new, v_new, scale)
    return Entry(q_new, v_new, dropped, offsets, residual)


def _velocity_rows(src, dst, t, what, v_map, q_new, v_new, scale: float) -> float:
    """The largest residual of ``dst``'s rows at the mapped velocity ``v_map`` (``scale``: max(1, |v|));
    the run stops naming the rows it violates beyond round-off."""
    Jq, Jq_scale = _jacobian(dst, t, q_new, v_new)
    # v_new satisfies every row (the projection solved them), so Phi_q v_map + Phi_t = Phi_q (v_map - v_new)
    rows = Jq @ (v_map - v_new)
    tol = VELOCITY_ROUNDOFF * scale * Jq_scale
    residual = float(np.abs(rows).max())
    if residual > tol:
        raise SimulationError(_violated(src, dst, t, what, rows, tol, v_map, v_new))
    return residual


def enter_bounce(cfg: Configuration, t: float, q: np.ndarray, v: np.ndarray, what: str = "bounce"):
    """:func:`enter` of a bounce, ``cfg`` into itself after its impulse: ``(q, v)`` projected onto
    ``cfg``'s constraints, every row of its loops and drives checked at the post-impact velocity, and
    the links' poses where the projection moved the posture; the same checks and the same state as
    ``enter(cfg, cfg, t, q, v)`` without the parts a bounce leaves empty (no joint dropped, no angle
    offset).  Returns ``(q, v, the largest residual of the rows at the post-impact velocity)``."""
    q_new, v_new = cfg.coords.project(t, q, v)
    if q_new.tobytes() != q.tobytes():
        _, problems = pose_mismatches(cfg, cfg, q, q_new)
        if problems:
            raise SimulationError([f"t = {t:.9g} s, switching '{cfg.name}' -> '{cfg.name}': {p}" for p in problems]
                                  + ["the projection onto the configuration's constraints moved its links"])
    residual = 0.0
    if len(cfg.coords.labels):
        columns = _unit_columns(cfg.coords)
        if columns:  # drives without a loop: each row reads one coordinate's rate (Phi_q a unit row)
            for c in columns:  # |Phi_q (v - v_new)| of that row, the same number as the product gives
                residual = max(residual, abs(float(v[c]) - float(v_new[c])))
            if residual <= VELOCITY_ROUNDOFF:  # below the least tolerance (scale and |Phi_q| are >= 1)
                return q_new, v_new, residual
        residual = _velocity_rows(cfg, cfg, t, what, v, q_new, v_new, max(1.0, float(np.abs(v).max())) if len(v) else 1.0)
    return q_new, v_new, residual


def bounce_projection(cfg: Configuration) -> tuple | None:
    """:func:`enter_bounce`'s projection as plain numbers, for the compiled bounce (``BouncePlan`` of
    pcmm/model/_impulse.hpp): ``((), (), ())`` for a tree (its ``project`` hands ``(q, v)`` back as they
    are, and it has no row); for drives without a loop (``PartitionedCoordinates.project``'s prescribed
    route, whose rows are the unit rows :func:`_unit_columns` reads the residual off) the driven
    coordinates and each drive's f and f' coefficients (low order first: ``Drives.values``' Horner sums);
    None for anything else (a loop, a planar joint, a coordinate driven twice): the Python entry."""
    coords = cfg.coords
    if cfg.has_planar:
        return None
    if not getattr(coords, "constrained", False):  # a tree: no row, (q, v) as they are
        return ((), (), ()) if not len(coords.labels) else None
    drives = getattr(coords, "drives", None)
    if (drives is None or getattr(coords, "time_rows", lambda: None)() is None or getattr(coords, "D", None) is None
            or len(set(drives.index)) != drives.size):
        return None
    driven = tuple(int(i) for i in drives.index)
    if sorted(_unit_columns(coords)) != sorted(driven) or len(coords.labels) != len(driven):
        return None
    return driven, tuple(tuple(d[0]) for d in drives._derivs), tuple(tuple(d[1]) for d in drives._derivs)


#: {coordinates: the column of each row where every row of the coordinates is a unit row of time-only
#: rows (drives without a loop: q_j - f(t) = 0), else ()}
_UNIT_COLUMNS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _unit_columns(coords) -> tuple[int, ...]:
    """The columns of ``coords``' rows where each is a unit row (``Phi_q = e_j^T``) depending on time
    alone (:func:`_jacobian`'s ``time_rows``), so that ``Phi_q dv`` is ``dv[j]`` row by row to the bit
    (the product's other terms are 0 x a finite number); () otherwise.  Decided once per coordinates."""
    kept = _UNIT_COLUMNS.get(coords)
    if kept is not None:
        return kept
    out: tuple = ()
    timed = getattr(coords, "time_rows", None)
    timed = timed() if timed is not None else None
    if timed is not None and len(timed[0]):
        columns = []
        for row in np.asarray(timed[0]):
            hot = np.flatnonzero(row)
            if len(hot) != 1 or row[hot[0]] != 1.0:
                columns = []
                break
            columns.append(int(hot[0]))
        out = tuple(columns)
    _UNIT_COLUMNS[coords] = out
    return out


#: {coordinates: (Phi_q, max(1, max |Phi_q|))} of coordinates whose rows depend on time alone (``time_rows``)
_TIME_ROWS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _jacobian(dst: Configuration, t, q, v) -> tuple[np.ndarray, float]:
    """``(Phi_q, max(1, max |Phi_q|))`` of ``dst``'s rows at (q, v).  Where they depend on time alone
    (drives without a loop: ``time_rows``, the same array ``rows`` gives) they are kept for the
    coordinates (read-only): a bounce's entry neither evaluates the drives nor forms them again."""
    coords = dst.coords
    kept = _TIME_ROWS.get(coords)
    if kept is not None:
        return kept
    timed = getattr(coords, "time_rows", None)
    timed = timed() if timed is not None else None
    Jq = timed[0] if timed is not None else coords.rows(t, q, v)[0]
    out = (Jq, max(1.0, float(np.abs(Jq).max())))
    if timed is not None:
        Jq.flags.writeable = False
        _TIME_ROWS[coords] = out
    return out


def _violated(src, dst, t, what, rows, tol, v_map, v_new) -> list[str]:
    """The message of a switch whose velocity violates constraints of the target."""
    bad = [(lab, float(r)) for lab, r in zip(dst.coords.labels, rows) if abs(r) > tol]
    unit = {True: "rad/s", False: "m/s"}
    named = ", ".join(f"'{lab}' ({_constraint_kind(lab)}) by {r:.6g} {unit[lab.endswith('.drive') or lab.endswith('.m')]}"
                      for lab, r in bad)
    change = {}
    for n in dst.joint_names:
        sl = dst.joint_slice[n]
        names = [n] if sl.stop - sl.start == 1 else [f"{n}.x", f"{n}.y", f"{n}.theta"]
        for k, name in zip(range(sl.start, sl.stop), names):
            if abs(v_map[k] - v_new[k]) > tol:
                change[name] = (float(v_map[k]), float(v_new[k]))
    return [f"t = {t:.9g} s, {what} '{src.name}' -> '{dst.name}': the velocity after the switch violates the "
            f"constraints of '{dst.name}': {named}",
            "it leaves the joint velocities " + ", ".join(f"{n}' = {a:.6g}" for n, (a, _) in change.items())
            + (" where the constraints need " + ", ".join(f"{n}' = {b:.6g}" for n, (_, b) in change.items())
               + " (keeping the independent ones)" if change else ""),
            "the impulse acts only along the transition's contact normal and the rows of "
            f"'{src.name}', which do not span these; pcmm does not replace the velocity silently. Give the "
            f"transition a contact (or cut joints) whose impulse can make every constraint of '{dst.name}' hold, "
            f"or enter a configuration without them"]


def _constraint_kind(label: str) -> str:
    if label.endswith(".drive"):
        return f"the drive of joint {label[:-6]}"
    return f"cut joint {label.rsplit('.', 1)[0]}"


def map_state(src: Configuration, dst: Configuration, q, v, known: dict | None = None):
    """(q, v) of ``src`` as ``dst``'s coordinates, by joint name (not yet projected onto
    ``dst``'s constraints), and the velocities of the joints ``dst`` drops."""
    if src is dst:  # a bounce: every joint maps onto itself (the same entries, signed zeros kept)
        return q.copy(), v.copy(), {}
    q_new = dst.neutral()
    v_new = np.zeros(dst.nv)
    missing = []
    for name in dst.joint_names:
        if name in src.joint_slice:
            q_new[dst.joint_slice[name]] = q[src.joint_slice[name]]
            v_new[dst.joint_slice[name]] = v[src.joint_slice[name]]
        elif known and name in known:
            q_new[dst.joint_slice[name]] = known[name]
        else:
            missing.append(name)
    if missing:
        q_new, v_new = joints_from_poses(src, dst, q, v, q_new, v_new, missing)
    dropped = {n: float(v[src.joint_slice[n]][0]) for n in src.joint_names
               if n not in dst.joint_slice and src.joint_slice[n].stop - src.joint_slice[n].start == 1}
    return q_new, v_new, dropped


def pose_mismatches(src: Configuration, dst: Configuration, q_src, q_dst):
    """Angle offsets {link: 2 pi k} of the links both configurations share, and one text per
    shared link whose pose differs by more than ``POSE_TOL``."""
    if src is dst and np.asarray(q_src).tobytes() == np.asarray(q_dst).tobytes():
        return {link: 0.0 for link in dst.links}, []  # the same posture of the same model (a bounce): k = 0
    poses_src = src.link_poses(q_src)
    poses_dst = dst.link_poses(q_dst)
    offsets = {}
    problems = []
    for link in dst.links:
        if link not in src.link_index:
            continue
        a, b = poses_src[src.link_index[link]], poses_dst[dst.link_index[link]]
        dtheta = a[2] - b[2]
        k = np.round(dtheta / (2 * np.pi))
        dpos = np.linalg.norm(a[:2] - b[:2])
        dang = abs(dtheta - 2 * np.pi * k)
        if dpos > POSE_TOL or dang > POSE_TOL:
            problems.append(f"link '{link}' is at (x, y, theta) = ({a[0]:.9g}, {a[1]:.9g}, {a[2]:.9g}) in "
                            f"'{src.name}' ({src.spec.source}) but at ({b[0]:.9g}, {b[1]:.9g}, {b[2]:.9g}) "
                            f"in '{dst.name}' ({dst.spec.source}): position differs by {dpos:.3g} m, "
                            f"angle by {dang:.3g} rad (allowed {POSE_TOL:g})")
        offsets[link] = float(2 * np.pi * k)
    return offsets, problems


def joints_from_poses(src, dst, q, v, q_new, v_new, names):
    """Values and rates of joints that ``src`` does not have (a released lock): from the poses
    and velocities of their parent and child links in ``src``."""
    poses = src.link_poses(q)
    vel = src.link_velocities(q, v)
    for name in names:
        uj = dst.spec.info.joints[name]
        if uj.type not in ("revolute", "continuous", "prismatic") or uj.parent not in src.link_index \
                or uj.child not in src.link_index:
            raise SimulationError(f"switching '{src.name}' -> '{dst.name}': joint '{name}' ({uj.type}) appears "
                                  "and pcmm derives only a revolute or prismatic joint's value from the poses "
                                  "of its two links, which must both be in the source configuration")
        ip, ic = src.link_index[uj.parent], src.link_index[uj.child]
        if uj.type == "prismatic":
            # child origin = parent origin + R_p (xyz + R_o axis q): q = axis . R_o^T (R_p^T r - xyz)
            th = poses[ip, 2]
            Rp = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
            c, s_ = np.cos(uj.rpy[2]), np.sin(uj.rpy[2])
            Ro = np.array([[c, -s_], [s_, c]])
            axis = np.asarray(uj.axis[:2], dtype=float) / np.linalg.norm(uj.axis[:2])
            r = poses[ic, :2] - poses[ip, :2]
            q_new[dst.joint_slice[name]] = axis @ (Ro.T @ (Rp.T @ r - np.asarray(uj.xyz[:2])))
            w = vel[ip, 2]
            rel = vel[ic, :2] - vel[ip, :2] - w * np.array([-r[1], r[0]])
            v_new[dst.joint_slice[name]] = (Rp @ Ro @ axis) @ rel
        else:
            q_new[dst.joint_slice[name]] = poses[ic, 2] - poses[ip, 2] - uj.rpy[2]
            v_new[dst.joint_slice[name]] = vel[ic, 2] - vel[ip, 2]
    return q_new, v_new
