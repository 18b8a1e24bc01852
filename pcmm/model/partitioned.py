"""Loops and drives by generalized coordinate partitioning.

The state is the independent coordinates and their rates ``y = [q_I, q'_I]``; the dependent ones
are solved from the constraints (:mod:`pcmm.model.rows`) at every evaluation (Newton, warm-started),
so loops stay closed to the Newton tolerance instead of drifting.  The partition is chosen by QR
with column pivoting at the start of every segment, and a guard on its dependent block's
determinant asks for a new one where it degenerates.  Satisfies
:class:`~pcmm.model.coordinates.Coordinates`.
"""
from __future__ import annotations

import contextlib
import copy
import dataclasses
import math
import threading

import numpy as np
import pinocchio as pin

from . import compiled
from .configuration import Configuration
from .rows import (ClosureRows, Drives, _det, _max_abs, constrained_accelerations, determinate, independent_rows,
                   indeterminate, left_null, pivots, solve)
from ..errors import Repartition, SimulationError
from ..ode.witness import Guard

NEWTON_TOL = 1e-13
TWO_PI = 2 * math.pi
SINGULAR_COND = 1e9
#: the largest change (rad or m) the warm start of a loop's Newton solve is extrapolated by
PREDICT_MAX = 0.05
# the whole constraint Jacobian has lost its rank where its smallest singular value is at most this
# fraction of its largest: a change point or a dead centre (at_degenerate_partition, _refuse_singular_read)
RANK_LOST = 1e-6
#: whether the compiled segment loop (pcmm/model/_segment_loop.hpp) steps a configuration with closed loops
#: over its compiled loop: "auto"'s DOP853 (pcmm.ode.integrators.AUTO_DOP853, scipy's tableau and step-size
#: control in C++) and DOP853F; off: pcmm's DOP853 (or the Fortran DOP853F) steps it in Python over the
#: same compiled right-hand side, the reference the tests compare with.  The method "DOP853" named in a
#: scene is always the Python stepping
STEP_LOOPS_COMPILED = True
_thread_id = threading.get_ident
_ASK = object()  # an argument not given: the callee finds it itself


def _conditioned(JD: np.ndarray) -> bool:
    """``cond_2(JD) <= SINGULAR_COND`` shown without an SVD: ``||JD||_F ||JD^-1||_F`` bounds the
    2-norm condition number from above, and the inverse of a loop's small block is one LAPACK call
    where numpy's ``cond`` wraps an SVD (a partition at every segment's start and every switch).
    False: not shown (singular, not finite, or the bound too loose); the SVD then decides and its
    number goes into the message."""
    n = JD.shape[0]
    if n == 0 or JD.shape[1] != n:
        return False
    try:
        inv = solve(JD, np.eye(n))
    except np.linalg.LinAlgError:
        return False
    flat, iflat = JD.ravel(), inv.ravel()
    bound = math.sqrt(float(flat @ flat)) * math.sqrt(float(iflat @ iflat))
    return math.isfinite(bound) and bound <= SINGULAR_COND


def _nearest_turns(q, start, turns) -> None:
    """Moves ``q``'s angles ``turns`` (revolute dependent coordinates, not driven) by whole turns to
    within pi of the warm start ``start``, in place.  The closure constraints Phi(q) = 0 (the cut
    joints' rows, pcmm.model.rows: p_b - p_a, and the angle row through atan2) see a revolute angle
    only through its cosine and sine, so q and q + 2 pi k are one posture; but a Newton step near a
    singular dependent block (a change point, where det Phi_q[:, D] -> 0) can be huge, and without
    this it converged 2 pi k away from the warm start (a parallelogram's rocker angle minus its
    crank's 1.2e5 rad: the recorded series jumped, tests/test_loop_turns.py).  Applied to every
    iterate, it changes no posture the solve reaches and no iterate that stays within pi of the
    start (to the last bit).  A prismatic coordinate is not periodic, nor a driven angle (its row
    q_j - f(t)): they are never moved.  A solution on another assembly branch is not a whole turn
    away; this does not hide it.  The compiled loop does the same (pcmm/model/_loops.hpp, nearest_turns)."""
    for j in turns:
        d = q[j] - start[j]
        if d > math.pi or d < -math.pi:
            q[j] -= TWO_PI * round(d / TWO_PI)


class PartitionedCoordinates:
    """Loops and/or drives: independent coordinates and their rates ``y = [q_I, q'_I]``
    (satisfies :class:`~pcmm.coordinates.Coordinates`).  ``q'`` is ``v`` but for a planar joint's
    (x', y'), which are world-frame where its ``v`` is body-frame (:meth:`Configuration.qdot`): the
    dependent positions and rates then solve one block, ``dPhi/dq`` at the posture."""

    constrained = True
    position_noise = 4 * np.finfo(float).eps  # dependent coordinates: Newton plus one polishing step

    def __init__(self, cfg: Configuration, closure: ClosureRows, drives: Drives):
        # the loops' right-hand side compiled whole (pcmm/model/_loops.hpp: the Newton solve with its
        # warm starts, the dependent rates, the KKT solve), where it runs (_compiled_loop)
        self._loop = None
        self._loop_held = None  # (thread, force elements) the loop's tree is checked for
        self._loop_refused = "not decided yet"  # why the loop is not compiled (None: it may be): below
        self._seed_q, self._seed_t = None, 0.0  # the last seed and the time of the last partition
        self._projected = None  # (t, bytes of q) project() assembled after its partition (partition)
        self._reader = False  # a segment reader (restored): its rows and accelerations compiled too
        self.cfg = cfg
        self.closure = closure
        self.drives = drives
        self.nv = cfg.nv
        self.m = closure.size + drives.size
        self.labels = closure.labels() + [f"{j}.drive" for j in drives.joints]
        # redundant but consistent rows (partition): the rows kept (indices into labels: a maximal
        # independent set, the drives' always among them), the loop rows among them, the rows dropped
        # (checked at every solve: _check_dropped), and the redundancies already reported (take_notes)
        self._kept, self._nloop, self._dropped, self._dropped_at = None, closure.size, np.zeros(0, int), 0.0
        self._noted: set = set()
        self._notes: list[str] = []
        self.I = None
        self.D = None
        self.ny = 0  # 2 len(I), set with the partition (pack, project)
        self._qD = None
        self._recent: list[tuple[float, np.ndarray]] = []
        # a re-read segment's accepted steps (t, y) and the solutions reached along them, by step
        # (restored, _follow); None while integrating
        self._trail = None
        self._reached: dict[int, tuple | None] = {}
        self._zeros = np.zeros(self.nv)
        self.checking = True  # conditioning checks (off while recording an accepted segment)
        self._cache = None  # the last unpack: guards and the right-hand side ask for the same point
        self._max_residual = 0.0  # largest loop residual a Newton solve accepted in Python (max_residual)
        self._segment_forces = None  # a reader's own force elements (restored); None: the configuration's
        self._driven = np.array(drives.index, dtype=int)
        self._distinct_drives = len(set(drives.index)) == drives.size  # no coordinate driven twice (project)
        # the coordinates the closure rows see only through cos and sin (_nearest_turns): revolute joints,
        # not driven (a drive's row q_j - f(t) is not periodic)
        self._turns = np.zeros(self.nv, bool)
        for name in cfg.joint_names:
            if cfg.spec.info.joints[name].type == "revolute":
                self._turns[cfg.joint_slice[name].start] = True
        self._turns[self._driven] = False
        self._drive_rows = np.zeros((drives.size, self.nv))
        self._drive_rows[np.arange(drives.size), self._driven] = 1.0
        self._no_rows, self._no_jacobian = np.zeros(0), np.zeros((0, self.nv))  # no loop rows
        self._time_jacobian = None  # Phi_q of drives without a loop, formed once (time_rows)
        self._drive_columns_of: dict = {}  # {id(model): (model, the driven joints' columns)} (equality)
        # revolute cut joints' rows in one compiled call where that is the same function (pcmm.compiled)
        if not closure.specs:
            fast, why = None, "not compiled: drives only"
        elif cfg.has_planar or not closure.revolute_only or closure.anchored:
            fast, why = None, "not compiled: " + ("a planar joint" if cfg.has_planar else "a cut joint anchored at entry"
                                                  if closure.anchored else "prismatic or weld cut joints")
        else:
            fast = compiled.closure_kinematics(cfg.model, closure.frames_a, closure.frames_b,
                                               self._python_point_rows, self._python_point_rows_and_bias)
            why = compiled.why_not() or "not compiled"
        self._point_rows = fast.point_rows if fast else self._python_point_rows
        self._point_rows_and_bias_at = fast.point_rows_and_bias if fast else self._python_point_rows_and_bias
        self.evaluations = "compiled" if fast else f"python: {why}"
        # drives without loops: the right-hand side compiled whole (the prescribed coordinates and the
        # KKT solve of the drive rows in C++, pcmm.model.compiled.drive_tree), with a compiled segment
        # loop; _drives_refused says why not where it cannot be (then the Python evaluation runs)
        self._drives_refused = self._why_drives_not_compiled()
        self._compiled = None  # (thread, force elements, compiled tree) last used
        if self._drives_refused is not None and not self.closure.size:
            self.evaluations = f"python: not compiled: {self._drives_refused}"
        if self._drives_refused is None:
            self.D = self._best_dependent(None)  # the driven coordinates, whatever the posture (partition)
            self.I = np.array([i for i in range(self.nv) if i not in self.D], dtype=int)
            self.ny = 2 * len(self.I)
            self.evaluations = "compiled" if self._compiled_drives() is not None else (
                f"python: {compiled.why_not() or 'not compiled'}")
        # loops: the whole right-hand side compiled where the rows are and nothing else stands in the
        # way; checked against the Python evaluation at the first partition (_compiled_loop)
        self._loop_refused = self._why_loop_not_compiled(fast)
        if fast is not None and self._loop_refused is not None:
            self.evaluations = f"python: not compiled: {self._loop_refused}"

    def _why_loop_not_compiled(self, rows) -> str | None:
        """Why the right-hand side of these loops is not compiled whole (None: it may be): it needs
        the compiled rows of revolute cut joints (``rows``), no planar joint and no coordinate
        driven twice."""
        if not self.closure.size:
            return "no loop"
        if rows is None:
            return self.evaluations.removeprefix("python: ").removeprefix("not compiled: ")
        if len(set(self.drives.index)) != self.drives.size:
            return "a coordinate driven twice"
        return None

    @property
    def max_residual(self) -> float:
        """The largest loop residual a Newton solve accepted (the recorded drift's bound), the
        compiled loop's solves included."""
        loop = self._loop
        return self._max_residual if loop is None else max(self._max_residual, loop.max_residual())

    @max_residual.setter
    def max_residual(self, value: float) -> None:
        self._max_residual = value

    @property
    def checking(self) -> bool:
        """Whether the conditioning of the partition is checked (off while recording an accepted segment)."""
        return self._checking

    @checking.setter
    def checking(self, on: bool) -> None:
        self._checking = on
        if self._loop is not None:
            self._loop.set_checking(on)

    def _compiled_loop(self):
        """The compiled right-hand side of the loops (a :func:`pcmm.model.compiled.loop`) on the
        calling thread's compiled tree of :attr:`forces`, checked against the Python evaluation at
        probe states near the seed in this partition; or None: the Python evaluation runs (and
        :attr:`evaluations` says why where it is refused)."""
        held = self._loop_held
        if held is not None and held[0] == threading.get_ident() and held[1] is self.forces:
            return self._loop
        if self._loop_refused is not None or self._seed_q is None or self.D is None or len(self.D) != self.m:
            return None  # refused, not seeded yet, or redundant rows (the Python evaluation says so)
        forces = self.forces
        built = compiled.loop_tree(self.cfg.model, self.closure.frames_a, self.closure.frames_b, forces.Q0, forces.KD,
                                   forces.points)
        if built is None:
            self._refuse_loop(compiled.why_not() or "not compiled")
            return None
        (tree, checked), springs = built
        if self._loop is None:
            self._loop = compiled.loop(tree, self.drives.index, self.drives._derivs, springs)
            self._loop.set_turns(self.turns)
            self._loop.seed(self._seed_q, self.I, self.D)
            self._loop.set_checking(self._checking)
        else:
            self._loop.set_tree(tree, springs)
        why = self._loop_disagrees(tree, checked, springs)
        if why is not None:
            self._refuse_loop(why)
            return None
        self._loop_held = (threading.get_ident(), forces)
        compiled._register_segment_loop(PartitionedCoordinates, _segment_loop)
        return self._loop

    def _refuse_loop(self, why: str) -> None:
        """The loops run in Python from now on, and :attr:`evaluations` says ``why``."""
        self._loop_refused = why
        self._loop, self._loop_held = None, None
        self.evaluations = f"python: {why}"

    def _loop_disagrees(self, tree, checked, springs) -> str | None:
        """Why the compiled loop on ``tree`` is not the Python evaluation (None: it is): both from
        the seed, at probe states near it (independent coordinates 1e-3 off, rates of order one,
        times 1e-3 s on), the right-hand side and the one with power; once per tree, partition and
        drives.  The tree's key holds its cut joints, force elements, point springs, gravity and
        armature (compiled.loop_tree); the drives are the compiled loop's own, and configurations
        on one URDF (one model, so one tree) may drive it differently: they are in the key here."""
        what = f"loop right-hand side, dependent {tuple(int(i) for i in self.D)}"
        key = (what, compiled.drives_key(self.drives.index, self.drives._derivs))
        if key in checked and (key, "with power") in checked:  # both: the one with power may have failed
            return None
        k = len(self.I)
        base = self._seed_q[self.I]
        probes = [(self._seed_t + 1e-3 * (j + 1), np.concatenate([base + 1e-3 * p[:k] / np.pi, p[k:2 * k]]))
                  for j, p in enumerate(compiled._probe_states(max(k, 1)))]
        reference = copy.copy(self)
        reference._loop, reference._loop_held, reference._loop_refused = None, None, "the reference"
        reference._trail, reference._max_residual = None, 0.0
        reference.checking = False
        reference.seed(self._seed_q)
        scratch = compiled.loop(tree, self.drives.index, self.drives._derivs, springs)
        scratch.set_turns(self.turns)
        scratch.seed(self._seed_q, self.I, self.D)
        scratch.set_checking(False)

        def declined(out, n):
            return np.full(n, np.nan) if out is None else out
        try:
            same = (compiled.agrees(checked, lambda t, y: declined(scratch.rhs(t, y), 2 * k), reference._python_rhs,
                                    probes, what, key)
                    and compiled.agrees(checked, lambda t, y: declined(scratch.rhs_with_power(t, y), 2 * k + 1),
                                        reference._python_rhs_with_power,
                                        [(t, np.append(y, 0.0)) for t, y in probes], what + " with power",
                                        (key, "with power")))
        except (SimulationError, np.linalg.LinAlgError) as exc:
            return f"the Python evaluation fails at a probe state near the seed ({exc})"
        return None if same else (compiled.why_not() or "it disagrees with the Python evaluation")

    def _why_drives_not_compiled(self) -> str | None:
        """Why the right-hand side of drives without loops is not compiled (None: it may be).  Every
        drive law a scene can give (a polynomial in t, pcmm.scene.spec.DriveSpec) is compiled; what
        is not: loops (their Newton solve), a planar joint (its q' is not v), point springs (their
        forces are not the linear Q0 - KD y), a coordinate driven twice (no partition of drives alone),
        every coordinate driven (nothing to integrate)."""
        if self.closure.size or not self.drives.size:
            return "loops" if self.closure.size else "no drive"
        if self.cfg.has_planar:
            return "a planar joint"
        if self.cfg.forces.points is not None:
            return "point springs"
        if len(set(self.drives.index)) != self.drives.size:
            return "a coordinate driven twice"
        if self.drives.size >= self.nv:
            return "every coordinate driven"
        return None

    def _compiled_drives(self):
        """The calling thread's compiled tree for these drives and :attr:`forces` (a reader's own
        force elements included), or None: the Python evaluation runs."""
        if self._drives_refused is not None:
            return None
        forces, me = self.forces, threading.get_ident()
        held = self._compiled
        if held is not None and held[0] == me and held[1] is forces:
            return held[2]
        if forces.points is not None:
            return None
        tree = compiled.drive_tree(self.cfg.model, forces.Q0, forces.KD, self.drives.index, self.drives._derivs,
                                   self._python_rhs, self._python_rhs_with_power)
        self._compiled = (me, forces, tree)
        if tree is not None:
            compiled._register_segment_loop(PartitionedCoordinates, _segment_loop)
        return tree

    def forces_changed(self):
        """Nothing to rebuild: every evaluation reads :attr:`forces`."""

    @property
    def forces(self):
        """The force elements every evaluation applies: a segment reader's own (:meth:`restored`,
        a value: the run may compile the configuration's again meanwhile), else ``cfg.forces``."""
        return self.cfg.forces if self._segment_forces is None else self._segment_forces

    # -- re-reading an accepted segment (a trajectory's lazy series)
    def frozen_state(self) -> dict:
        """The partition a segment is integrated in and the anchors of its cut joints anchored at
        entry (a configuration entered again later holds its point elsewhere): values, which
        :meth:`restored` reads."""
        out = {"I": self.I, "D": self.D, "ny": self.ny}
        if self._kept is not None:
            out["kept"] = (self._kept, self._nloop, self._dropped, self._dropped_at)
        if self.closure.anchors:
            out["anchors"] = {k: np.array(a, float) for k, a in self.closure.anchors.items()}
        return out

    @contextlib.contextmanager
    def restored(self, frozen: dict, q_start, steps=None, forces=None):
        """A reader of an accepted segment: a copy of these coordinates in the segment's partition
        and anchors (``frozen``), warm-started at its start ``q_start``, without conditioning checks
        (the segment was accepted).  This object, which a run may be integrating meanwhile (in
        another thread), is left alone.  ``steps = (t, y)`` are the segment's accepted steps: the
        reader's Newton solves start from the step at or before the instant asked for
        (:meth:`_follow`), however far it lies from the last one solved.  ``forces`` are the
        segment's force elements (a value, compiled at its angle offsets), which the reader's
        evaluations apply instead of the configuration's current ones."""
        reader = copy.copy(self)
        reader._loop, reader._loop_held = None, None  # its own compiled loop (its own warm starts)
        reader._reader = True
        if forces is not None:
            reader._segment_forces = forces
        reader.I, reader.D, reader.ny = frozen["I"], frozen["D"], frozen["ny"]
        reader._kept, reader._nloop, reader._dropped, reader._dropped_at = frozen.get(
            "kept", (None, self.closure.size, np.zeros(0, int), 0.0))
        reader._notes = []
        reader.closure = dataclasses.replace(self.closure, anchors=dict(frozen.get("anchors", {})))
        if getattr(self._point_rows, "__self__", None) is self:  # the Python rows read the closure
            reader._point_rows = reader._python_point_rows
            reader._point_rows_and_bias_at = reader._python_point_rows_and_bias
        reader.checking = False
        reader.seed(q_start)
        if steps is not None:
            reader._trail = (np.asarray(steps[0], float), np.asarray(steps[1], float)[:reader.ny])
            reader._reached = {0: None}  # the start: seed's q_start
        yield reader

    def fresh_rhs(self):
        """The right-hand side (a method: it reads the calling thread's data at every call)."""
        return self.rhs

    # -- constraint evaluation on the tree
    def _kinematics(self, qp, v=None) -> None:
        """One kinematics pass on the configuration's data through the Python binding: frame
        placements and joint Jacobians at ``qp``, and with ``v`` also the velocities and the
        accelerations at a = 0 (what the bias terms read), the Jacobians taken from them."""
        cfg = self.cfg
        if v is None:
            pin.computeJointJacobians(cfg.model, cfg.data, qp)  # computes the placements itself
        else:
            pin.forwardKinematics(cfg.model, cfg.data, qp, v, self._zeros)
            pin.computeJointJacobians(cfg.model, cfg.data)
        pin.updateFramePlacements(cfg.model, cfg.data)

    def _python_point_rows(self, qp):
        """(Phi, Phi_q) of revolute cut joints at Pinocchio's ``qp``, through the Python binding."""
        self._kinematics(qp)
        return self.closure.point_rows(self.cfg.model, self.cfg.data)

    def _python_point_rows_and_bias(self, qp, v):
        """(Phi_q, bias) of revolute cut joints at (``qp``, v) in one kinematics pass."""
        self._kinematics(qp, v)
        cfg = self.cfg
        _, Jq = self.closure.point_rows(cfg.model, cfg.data)
        return Jq, self.closure.point_bias(cfg.model, cfg.data)

    def _phi(self, t, q, need_bias=False, v=None):
        """(Phi, Phi_q, bias) of the rows the motion is solved with: every row, or where the rows are
        redundant the independent ones kept (:meth:`partition`)."""
        phi, Jq, bias = self._phi_all(t, q, need_bias, v)
        kept = self._kept
        if kept is None:
            return phi, Jq, bias
        return phi[kept], Jq[kept], (bias[kept] if bias is not None else None)

    def _phi_all(self, t, q, need_bias=False, v=None):
        """(Phi, Phi_q, bias) of every row (the cut joints', the drives'), whether or not they are independent."""
        cfg = self.cfg
        if not self.closure.size:  # drives alone: no kinematics pass, their rows need none
            phi, Jq, bias = self._no_rows, self._no_jacobian, (self._no_rows if need_bias else None)
        elif self.closure.revolute_only and not need_bias:
            qp = cfg.to_pin(q)
            phi, Jq = self._point_rows(qp)
            bias = None
        else:
            self._kinematics(cfg.to_pin(q), v if need_bias else None)
            phi, Jq, bias = self.closure.evaluate(cfg.model, cfg.data, need_bias)
        if self.drives.size:  # the rheonomic rows q_j - f_j(t): their Jacobian rows are constant
            f, _, f2 = self.drives.values(t)
            phi = np.concatenate((phi, q[self._driven] - f))
            Jq = np.concatenate((Jq, self._drive_rows))
            if need_bias:
                bias = np.concatenate((bias, -f2))
        return phi, Jq, bias

    def _point_rows_and_bias(self, t, q, v):
        """(Phi_q, bias) of revolute cut joints and drives at an assembled (q, v) in one kinematics
        pass (placements, velocities and accelerations at a = 0, then the Jacobians from them).
        The rows are taken at the returned q itself, not reused from the Newton solve's last
        iterate: near a change point the last correction is large enough to matter."""
        if not self.closure.size:  # drives alone: their rows and bias need no kinematics pass
            Jq, bias = self._no_jacobian, self._no_rows
        else:
            Jq, bias = self._point_rows_and_bias_at(self.cfg.to_pin(q), v)
        if self.drives.size:
            Jq = np.concatenate((Jq, self._drive_rows))
            bias = np.concatenate((bias, -self.drives.values(t)[2]))
        if self._kept is not None:
            return Jq[self._kept], bias[self._kept]
        return Jq, bias

    def _phi_t(self, t):
        """``dPhi/dt``: zero for the loops, minus each drive's rate."""
        out = np.zeros(self.m)
        out[self.closure.size:] = self.drives.values(t)[1]
        np.negative(out, out=out)
        return out if self._kept is None else out[self._kept]

    def equality(self, t, model, data):
        """Velocity rows of all constraints on ``model`` (the tree or its cut system);
        kinematics must be computed on ``data``."""
        Jq = self.closure.evaluate(model, data, False)[1] if self.closure.size else np.zeros((0, model.nv))
        if self.drives.size:
            Jd = np.zeros((self.drives.size, model.nv))
            Jd[np.arange(self.drives.size), self._drive_columns(model)] = 1.0
            Jq = np.vstack([Jq, Jd])
        return Jq

    def _drive_columns(self, model):
        """The driven joints' velocity columns in ``model`` (the tree or one of its cut systems,
        which keep the joints' names), found once per model."""
        known = self._drive_columns_of
        held = known.get(id(model))
        if held is None or held[0] is not model:  # the model is held: its id stays its own
            held = known[id(model)] = (model, [model.joints[model.getJointId(name)].idx_v for name in self.drives.joints])
        return held[1]

    def _position_rows(self, t, q):
        """``dPhi/dq`` at ``q``: the derivative in pcmm's coordinates that a Newton solve of the
        positions, the partition and its conditioning need (not the velocity Jacobian, whose
        planar-joint columns are in the body frame: :meth:`Configuration.position_jacobian`)."""
        return self.cfg.position_jacobian(q, self._phi(t, q)[1])

    def residual(self, t, q) -> float:
        phi, _, _ = self._phi_all(t, q)
        return float(np.max(np.abs(phi))) if phi.size else 0.0

    # -- partition
    def partition(self, t, q, prefer_independent=()):
        """Choose dependent coordinates: driven joints, then the best-conditioned
        columns of the loop rows (QR with column pivoting).  Coordinates in
        ``prefer_independent`` are kept independent when the rest allows it."""
        if not self.closure.size and len(set(self.drives.index)) == self.drives.size:
            # drives alone: the driven coordinates, an identity block (condition number 1)
            self.D = self._best_dependent(None)
            self.I = np.array([i for i in range(self.nv) if i not in self.D], dtype=int)
            self.ny = 2 * len(self.I)
            return
        projected, self._projected = self._projected, None
        if projected is not None and not prefer_independent and projected[0] == t and projected[1] == q.tobytes():
            return  # the posture project() just assembled, partitioned there: the same choice (see project)
        self._seed_t = t
        self._kept, self._nloop, self._dropped = None, self.closure.size, np.zeros(0, int)
        Jq = self._position_rows(t, q)
        kept = self._independent(Jq) if self._distinct_drives else None
        if kept is not None and not self._persists(t, q, Jq, kept):
            kept = None  # a singular posture (a change point, a dead centre): the conditioning check's to judge
        if kept is not None:  # redundant rows: the motion is solved with a maximal independent set
            self._keep_rows(t, kept, Jq)
            Jq = Jq[kept]
        self.D = self._best_dependent(Jq, keep=prefer_independent)
        dependent = set(self.D.tolist())
        self.I = np.array([i for i in range(self.nv) if i not in dependent], dtype=int)
        self.ny = 2 * len(self.I)
        JD = Jq[:, self.D]
        if _conditioned(JD):
            return
        cond = np.linalg.cond(JD) if JD.size else 1.0
        if not np.isfinite(cond) or cond > SINGULAR_COND:
            raise SimulationError(
                f"configuration '{self.cfg.name}': the constraints are singular at t = {t:.6g} s "
                f"(condition number {cond:.3g}): the loop is at or near a singular posture "
                "(e.g. a slider-crank at dead centre) or the cut joints are redundant")

    def _independent(self, Jq):
        """The rows to keep where ``Jq`` (every row) is rank deficient to round-off
        (:func:`pcmm.model.rows.independent_rows`): every drive row (unit rows on distinct
        coordinates), and of the loop rows a maximal set independent of them; None where all are
        independent (a posture merely near a singular one is the conditioning check's to judge)."""
        nc = self.closure.size
        order = np.concatenate([np.arange(nc, self.m), np.arange(nc)]).astype(int)
        sel = independent_rows(Jq[order], first=self.m - nc)
        return None if sel is None else np.sort(order[sel])

    #: how far (relative to the coordinates' size) :meth:`_persists` moves the posture along its freedoms
    PERSIST_STEP = 1e-6

    def _persists(self, t, q, Jq, kept) -> bool:
        """Whether the dependence of the rows ``Jq`` at ``q`` persists where the rows ``kept`` let the
        posture move (a step of PERSIST_STEP along each direction of their null space): redundant rows
        (a cut joint given twice, a drive on a joint a lock and the loop fix, an over-constrained linkage
        on its motion) stay dependent there to second order in the step, while at a singular posture (a
        change point, a dead centre) the rank comes back to first order (the parallelogram with its
        links collinear), which is a singular posture, not a redundancy.  With no freedom left the
        dependence is the rows' own (more rows than coordinates the drives leave): it persists."""
        _, sv, Vt = np.linalg.svd(Jq[kept])
        rank = int(np.sum(sv > 1e-9 * max(float(sv[0]), 1e-300))) if sv.size else 0
        step = self.PERSIST_STEP * max(1.0, _max_abs(q))
        nc = self.closure.size
        order = np.concatenate([np.arange(nc, self.m), np.arange(nc)]).astype(int)
        for n in Vt[rank:]:
            moved = q + step * n
            if independent_rows(self._position_rows(t, moved)[order], first=self.m - nc) is None:
                return False
        return True

    def _keep_rows(self, t, kept, Jq) -> None:
        """Solve the motion with the rows ``kept`` from now on (redundant rows found at ``t``; ``Jq``
        every row there), the others checked at every solve (:meth:`_check_dropped`), and note it
        once for the run's warnings (:meth:`take_notes`): the rows, the rank, the rows dropped and the
        forces left statically indeterminate, which are NaN in the series (:meth:`accelerations`)."""
        self._kept = np.asarray(kept, int)
        self._nloop = int(np.count_nonzero(self._kept < self.closure.size))
        self._dropped = np.array([i for i in range(self.m) if i not in set(self._kept.tolist())], int)
        self._dropped_at = t
        loose = [lab for lab, bad in zip(self.labels, indeterminate(left_null(Jq))) if bad]
        key = (tuple(self._dropped.tolist()), tuple(loose))
        if key in self._noted:
            return
        self._noted.add(key)
        dropped = ", ".join(self.labels[i] for i in self._dropped)
        free = self.nv - len(self._kept)
        self._notes.append(
            f"t = {t:.9g} s, configuration '{self.cfg.name}': its {self.m} constraint rows ({', '.join(self.labels)}) "
            f"are of rank {len(self._kept)} on {self.nv} coordinates: redundant but consistent, so the motion is "
            f"still determined ({free} free coordinate{'s' if free != 1 else ''}). It is solved with "
            f"{', '.join(self.labels[i] for i in self._kept)}; the dropped {dropped} "
            f"{'is' if len(self._dropped) == 1 else 'are'} checked at every solve (the run stops if "
            f"{'it is' if len(self._dropped) == 1 else 'they are'} violated). The "
            f"forces of {', '.join(loose)} are statically indeterminate (any split of the load between them "
            "balances it): their constraint_forces series are NaN, not one arbitrary split")

    @property
    def redundant(self) -> bool:
        """Whether the motion is solved with a subset of the rows (:meth:`_keep_rows`): an impulse's
        solve then keeps an independent set of them too (pcmm.events.impulse)."""
        return self._kept is not None

    def take_notes(self) -> list[str]:
        """The redundancies found since last asked (:meth:`_keep_rows`), each once: for the run's warnings."""
        out, self._notes = self._notes, []
        return out

    def _check_dropped(self, t, q, rates) -> None:
        """The rows dropped as redundant (:meth:`_keep_rows`) at the solved posture ``q`` and its rates:
        their residual at position and at velocity level stays at round-off while the rows are
        consistent; where it does not (a drive's rate or position the others forbid, a constant-rank
        assumption broken at a singular posture) the run stops naming them."""
        d = self._dropped
        phi, Jq, _ = self._phi_all(t, q)
        Jp = self.cfg.position_jacobian(q, Jq)
        phi_t = np.zeros(self.m)
        phi_t[self.closure.size:] = -self.drives.values(t)[1]
        pos, vel = phi[d], Jp[d] @ rates + phi_t[d]
        scale = max(1.0, _max_abs(rates))
        if _max_abs(pos) <= 1e-9 and _max_abs(vel) <= 1e-9 * scale:
            return
        named = ", ".join(f"{self.labels[i]} (residual {p:.3g}, rate {w:.3g})" for i, p, w in zip(d, pos, vel))
        if t == self._dropped_at:  # where the rows were found dependent: never consistent
            err = SimulationError(
                f"configuration '{self.cfg.name}': at t = {t:.9g} s its {self.m} constraint rows "
                f"({', '.join(self.labels)}) are of rank {len(self._kept)} and no posture and motion satisfies "
                f"them all: solved with {', '.join(self.labels[i] for i in self._kept)}, the others are violated: "
                f"{named}. A lock or a drive holds a joint where the loop puts it elsewhere: check the locked "
                "values and the drives' values there")
            err.at = t
            raise err
        err = SimulationError(
            f"configuration '{self.cfg.name}': at t = {t:.9g} s its redundant rows, dropped at t = "
            f"{self._dropped_at:.9g} s where they were consistent with the others, are violated: {named}: the "
            "drives now ask a motion (or posture) the loops and locks forbid, or the rows' dependence was a "
            "singular posture's. Drive the joint only where it is free (the drive's configurations), or "
            "release the lock first")
        err.at = t
        raise err

    def _solve_dependent(self, t, qI, guess):
        """Dependent coordinates closing the loop at ``qI`` (Newton from ``guess``) and the
        constraint Jacobians there: ``(q, Phi_q per unit velocity, dPhi/dq)``.  Newton steps with
        ``dPhi/dq`` (the two differ in a planar joint's columns, which are body-frame in the
        first).

        Once the residual is below NEWTON_TOL one more correction is taken with the Jacobian
        already at hand: Newton converges quadratically, so that step leaves an error of
        order NEWTON_TOL squared, i.e. round-off.  Without it the dependent coordinates carry
        up to 1e-13 of solver noise that depends on the warm start, so the same state gives
        guard values that differ by 1e-13 m from one call to the next; a bounce of 1e-6 m/s
        rises only 5e-14 m, so that noise decided whether a tiny flight was seen at all."""
        q = guess.copy()
        q[self.I] = qI
        position = self.cfg.position_jacobian
        turns = [int(j) for j in self.D if self._turns[j]]
        for _ in range(30):
            phi, Jq, _ = self._phi(t, q)
            Jp = position(q, Jq)
            res = _max_abs(phi)
            if res < NEWTON_TOL:
                self.max_residual = max(self.max_residual, res)
                self._check_conditioning(t, Jp)
                if phi.size:  # one more correction with this Jacobian: exact to round-off, whatever the start
                    try:
                        q[self.D] -= solve(Jp[:, self.D], phi)
                    except np.linalg.LinAlgError:
                        pass  # the posture check above has already judged the block
                return q, Jq, Jp
            try:
                q[self.D] -= solve(Jp[:, self.D], phi)
            except np.linalg.LinAlgError:
                break
            if turns:
                _nearest_turns(q, guess, turns)
        phi, Jq, _ = self._phi(t, q)
        Jp = position(q, Jq)
        if np.max(np.abs(phi)) < 1e-9:
            self.max_residual = max(self.max_residual, float(np.max(np.abs(phi))))
            return q, Jq, Jp
        if len(self.I) == 0 and self.drives.size:
            err = SimulationError(
                f"configuration '{self.cfg.name}': the loop cannot be closed at t = {t:.9g} s "
                f"(residual {np.max(np.abs(phi)):.3g}): it has no free coordinate, and its drives "
                f"({', '.join(self.drives.joints)}) prescribe a motion its locked joints cannot follow "
                "(the lock jams the driven loop). A lock that must give way is a release: a stop-merge "
                "with unmerge = true, or a transition of type 'release' before this instant")
        else:
            start = position(guess, self._phi(t, guess)[1])  # near the last posture solved
            cond = self._cond(start)
            err = SimulationError(
                f"configuration '{self.cfg.name}': the loop cannot be closed at t = {t:.9g} s "
                f"(residual {np.max(np.abs(phi)):.3g} after 30 Newton steps; the constraint Jacobian's "
                f"condition number is {cond:.3g} at the warm start, {self._cond(Jp):.3g} at the last "
                "iterate): " + (
                    "the mechanism is at or beyond a singular posture, or the initial state is far from "
                    "an assembled one" if not math.isfinite(cond) or cond > SINGULAR_COND else
                    "the constraints are well conditioned where the solve started, so it started too far "
                    "from the assembly (a pcmm defect: please report it with the scene)"))
        err.at = t  # the instant of the failing solve (a trial instant of a step, for the run loop)
        raise err

    @property
    def turns(self) -> list[int]:
        """The coordinates whose Newton iterates are kept within pi of the warm start by whole turns
        (:func:`_nearest_turns`): revolute joints, not driven."""
        return [int(j) for j in np.flatnonzero(self._turns)]

    @staticmethod
    def _cond(J) -> float:
        """The condition number of a constraint Jacobian (1 without rows)."""
        return float(np.linalg.cond(J)) if J.size else 1.0

    def _best_dependent(self, Jq, keep=()):
        """Dependent columns for ``Jq``: driven joints, then the best-conditioned columns of the
        loop rows (QR with column pivoting), never one of ``keep``."""
        driven = list(self.drives.index)
        rest = [i for i in range(self.nv) if i not in driven and i not in keep]
        dep = list(driven)
        if self._nloop:
            piv = pivots(Jq[:self._nloop][:, rest])
            dep += [rest[i] for i in piv[:self._nloop]]
        return np.array(sorted(dep), dtype=int)

    def _scaled_det(self, Jq):
        """det(J_D) / (||J||_F / sqrt(m))^m: signed, continuous, at most 1 in magnitude for any
        number m of rows (Hadamard's bound and the mean of the squared row norms), and small when
        the dependent block degenerates or when the whole Jacobian loses rank (a row scaled by
        its own norm would hide a row that vanishes, as at a change point).  Without the sqrt(m)
        the measure fell as m^(-m/2) with the number of loops: three well-conditioned loops
        already read as singular at t = 0."""
        JD = Jq[:, self.D]
        m = JD.shape[0]
        if JD.shape[0] != JD.shape[1]:
            raise SimulationError(
                f"configuration '{self.cfg.name}': its {m} constraint rows cannot be solved for "
                f"{JD.shape[1]} dependent coordinates: more coordinates are kept independent ([initial] "
                "independent) than the loops leave free, or the cut joints are redundant (a cut joint given "
                "twice, or more loops than the tree has joints to close them), or a drive prescribes a joint "
                "that the loops and the locked joints already fix; the forces of these rows "
                f"({', '.join(self.labels)}) would be statically indeterminate (`pcmm check` says whether they "
                "are consistent where a guard fixes the posture of the switch into the configuration)")
        flat = Jq.ravel()
        return float(_det(JD) / max((math.sqrt(flat @ flat) / math.sqrt(max(m, 1))) ** m, 1e-300))

    def _check_conditioning(self, t, Jq):
        """A dependent block drifting towards singularity asks for a new partition; when the
        current one is already the best, the loop itself is at a singular posture."""
        if not self.checking:
            return
        ratio = abs(self._scaled_det(Jq))
        if ratio > 1e-4:
            return
        if not np.array_equal(self._best_dependent(Jq), self.D):
            raise Repartition(t)
        raise SimulationError(
            f"configuration '{self.cfg.name}': the loop reaches a singular posture at t = {t:.9g} s "
            f"(its best constraint block has a scaled determinant of {ratio:.2g}): at a dead centre or "
            "change point the motion is not determined by the constraints and drives; pcmm stops "
            "rather than pick a branch")

    def seed(self, q):
        """Start the Newton solve of the dependent coordinates from ``q``."""
        self._qD = q.copy()
        self._recent = []
        self._cache = None
        self._seed_q = self._qD
        self._loop_held = None  # checked again (a new partition is checked once)
        if self._loop is not None:
            if len(self.D) == self.m:
                self._loop.seed(q, self.I, self.D)
            else:  # redundant rows: the Python evaluation says so (_scaled_det)
                self._refuse_loop(f"{self.m} constraint rows for {len(self.D)} dependent coordinates")

    def _guess(self, t):
        """The warm start for a solve at ``t``: the recent solution nearest in time, carried to
        ``t`` along its own velocity (a first-order prediction: the start is off by O(dt^2)
        rather than O(dt), which saves a Newton iteration in most solves).  Nearest in time
        because an event search goes back and forth within a step; starting from the step's far
        end near a branch point could land on the mirrored assembly and make a guard's value
        depend on the order of the calls."""
        if self._trail is not None:
            near = self._follow(t)
            if near is not None and (not self._recent or abs(near[0] - t) < min(abs(r[0] - t) for r in self._recent)):
                tr, q, qd = near
                step = (t - tr) * qd
                return q + step if _max_abs(step) <= PREDICT_MAX else q
        if not self._recent:
            return self._qD
        tr, q, qd = min(self._recent, key=lambda r: abs(r[0] - t))
        step = (t - tr) * qd
        # a long extrapolation is no better a start than the solution itself (and could carry the
        # start past a branch point): beyond PREDICT_MAX the nearest solution is the start
        return q + step if _max_abs(step) <= PREDICT_MAX else q

    def _off_branch(self, t, qI, q, near=_ASK):
        """In a re-read segment, where the solution ``q`` at ``t`` (independent coordinates ``qI``)
        was solved across a long step (carrying the step before ``t`` to ``t`` along its rates
        would move a coordinate by more than PREDICT_MAX, so the Newton solve started from the step
        itself; or the segment's first step, solved from the segment's start, moved a coordinate by
        more than PREDICT_MAX): the warm start continued from that step along the way (:meth:`_continued`) when
        ``q`` lies farther than PREDICT_MAX from it — ``q`` is then on another assembly branch, or
        an angle 2 pi away, not the run's — else None (``q`` stands, to the last bit)."""
        near = self._long_step(t, q, near)
        if near is None:
            return None
        start = self._continued(t, qI, near)
        return start if _max_abs(q - start) > PREDICT_MAX else None

    def _long_step(self, t, q=None, near=_ASK):
        """In a re-read segment, the solution ``(t_r, q_r, q'_r)`` a read at ``t`` is continued from
        (:meth:`_continued`) when the read lies across a long step from it: the step before ``t``
        carried to ``t`` along its rates would move a coordinate by more than PREDICT_MAX; or ``t``
        is in the segment's first step, solved from its start, and its solution ``q`` (None: not
        solved) lies more than PREDICT_MAX from that start.  None otherwise."""
        if self._trail is None or not self.closure.size:
            return None
        if near is _ASK:  # (else: the caller's _follow(t), asked just before)
            near = self._follow(t)
        if near is None:  # the segment's first step: from its start, the seed
            t0 = self._trail[0][0]
            if not t > t0 or (q is not None and _max_abs(q - self._seed_q) <= PREDICT_MAX):
                return None
            return t0, self._seed_q, None
        return None if _max_abs((t - near[0]) * near[2]) <= PREDICT_MAX else near

    def _continued(self, t, qI, near):
        """Continuation of the dependent coordinates from a solution ``near = (t_r, q_r, q'_r)`` to
        the time ``t`` and independent coordinates ``qI``, along the straight path
        ``s -> (t_r + s (t - t_r), q_I,r + s (qI - q_I,r))``, s in [0, 1]: each piece is predicted
        along the path's tangent (``dq_D/ds`` from ``Phi_q dq/ds + Phi_t dt/ds = 0``) by at most
        PREDICT_MAX and corrected by Newton; a piece whose correction is not small against its
        prediction is halved (it left the branch it started on).  Returns the coordinates at ``t``
        on the branch of ``near``, the determinant's sign checked all the way (it once stopped
        PREDICT_MAX short of ``t`` and carried the rest along the tangent: a parallelogram read
        3.4e-3 past its change point came back on the anti-parallelogram, its rates off by 1 and
        3, tests/test_loop_branch.py).  Where the pieces shrink to nothing
        (at or next to a singular posture, where the branches meet) it raises: the reader cannot
        tell which branch the run was on; so it does where the dependent block's determinant changes
        sign along the way (the path crosses a singular posture: a change point, where the branches
        cross, which no accepted segment does: its partition's guard stops the run first)."""
        tr, q, _ = near
        loop = self._loop_name()
        sign = None
        dt = t - tr
        dI = np.asarray(qI, float) - q[self.I]
        position = self.cfg.position_jacobian
        s, qc, h = 0.0, q.copy(), 1.0
        while True:
            tc = tr + s * dt
            phi, Jq, _ = self._phi(tc, qc)
            Jp = position(qc, Jq)
            det = self._scaled_det(Jp)
            if sign is not None and det * sign < 0:
                raise SimulationError(
                    f"configuration '{self.cfg.name}': re-reading a recorded segment at t = {t:.9g} s, {loop} "
                    f"passes a singular posture between t = {tr:.9g} s (a recorded step) and t = {tc:.9g} s "
                    "(its dependent block's determinant changes sign): beyond it the assembly branch "
                    "is not determined; pcmm will not guess it")
            sign = det if det != 0 else sign
            if s == 1.0:  # at the read, its determinant's sign checked
                return qc
            tangent = np.zeros(self.nv)
            tangent[self.I] = dI
            try:
                tangent[self.D] = solve(Jp[:, self.D], -(Jp[:, self.I] @ dI + self._phi_t(tc) * dt))
            except np.linalg.LinAlgError:
                tangent = None
            size = _max_abs(tangent) if tangent is not None else math.inf
            h = min(h * 2.0, 1.0 - s, PREDICT_MAX / size if math.isfinite(size) else 0.0)
            if 1.0 - s - h < 1e-6 * h:  # what would be left: the rest of the way
                h = 1.0 - s
            while True:
                if not (h * size >= 1e-9 and math.isfinite(size)):
                    raise SimulationError(
                        f"configuration '{self.cfg.name}': re-reading a recorded segment at t = {t:.9g} s, "
                        f"the dependent coordinates of {loop} cannot be followed from the recorded step at "
                        f"t = {tr:.9g} s (the continuation stalls at t = {tc:.9g} s): the loop is at or next "
                        "to a singular posture, where its assembly branches meet; pcmm will not guess the branch")
                guess = qc + h * tangent
                try:
                    q1, _, _ = self._solve_dependent(tr + (s + h) * dt, q[self.I] + (s + h) * dI, guess)
                except SimulationError:
                    q1 = None
                if q1 is not None and _max_abs(q1 - guess) <= 0.2 * h * size + 1e-12:
                    break
                h *= 0.5
            s, qc = (1.0 if h == 1.0 - s else s + h), q1

    def _loop_name(self) -> str:
        """The loop named by its cut joints, for a message: "the loop of cut joint 'C'"."""
        return "the loop of cut joint" + ("s " if len(self.closure.specs) > 1 else " ") + ", ".join(
            f"'{c.name}'" for c in self.closure.specs)

    def _refuse_singular_read(self, t, Jp):
        """A segment reader (:meth:`restored`) must not return a solution at a singular posture of the
        loop, where the whole constraint Jacobian ``Jp`` has lost its rank (:data:`RANK_LOST`, the run's
        own test in :meth:`at_degenerate_partition`): a change point or a dead centre, where the
        assembly branches meet.  There the dependent rates are not determined and the Newton solve of
        the positions stalls short of the meeting point (a parallelogram read at its change point,
        theta = pi to the last bit: 5.4e-7 off, its rates (2, -1.5, 0.5) for the run's (2, -2, 2));
        an accepted segment never holds such a posture (the run stops there), so a read that lands on
        one is asked for an instant the run did not reach on this branch.  Raises, naming the time and
        the cut joints.  The SVD runs only where the dependent block's scaled determinant allows a lost
        rank: it is at most m^(m/2) times the Jacobian's smallest-to-largest singular value ratio."""
        m = Jp.shape[0]
        if not m or abs(self._scaled_det(Jp)) > m ** (m / 2) * RANK_LOST:
            return
        s = np.linalg.svd(Jp, compute_uv=False)
        if s[-1] > RANK_LOST * s[0]:
            return
        raise SimulationError(
            f"configuration '{self.cfg.name}': re-reading a recorded segment at t = {t:.9g} s, {self._loop_name()} "
            f"is at a singular posture (constraint Jacobian singular values {s[0]:.3g} ... {s[-1]:.3g}): at a "
            "change point or dead centre its assembly branches meet and its rates are not determined; pcmm "
            "will not guess them")

    def _follow(self, t):
        """While a segment is re-read (:meth:`restored` with its steps): the solution at the
        accepted step at or before ``t`` (``(t_k, q, q')``), the steps before it solved one after
        the other from the last one reached.  A dense-output instant, a resampled time or a
        saved series may ask for any instant of the segment; a Newton solve started from the
        last instant solved, which may lie several turns of a crank back, lands on another
        assembly or on none (a four-bar's crank 30 rad on: residual 0.45), where one started
        from the neighbouring step converges as it did in the run.  None at the segment's first
        step (its start is the seed) or when ``t`` is the step being solved."""
        ts, ys = self._trail
        # the last step strictly before t: where t is a step (the one being solved), the one before it,
        # also where the segment repeats that instant (a stopped run's last step, recorded twice)
        k = int(ts.searchsorted(t, "left")) - 1
        k = min(k, len(ts) - 1)
        if k <= 0:
            return None
        if k not in self._reached:
            start = max(j for j in self._reached if j < k)
            for j in range(start + 1, k + 1):
                if j not in self._reached:
                    self.unpack(ts[j], ys[:, j])  # registers step j (unpack)
        return self._reached.get(k)

    def pack(self, t, q, v):
        """State vector at an assembled (q, v); the partition is re-chosen here,
        at the start of every segment, so it follows the posture.

        Drives without a loop keep theirs: the dependent coordinates are the driven ones whatever
        the posture (:meth:`partition`), so once chosen it is not chosen again (the same values,
        as :meth:`project` does; at every segment's start)."""
        if self.D is None or self.closure.size or len(set(self.drives.index)) != self.drives.size:
            self.partition(t, q)
        self.seed(q)
        return np.concatenate([q[self.I], self.cfg.qdot(q, v)[self.I]])

    def at_degenerate_partition(self, t, q):
        """Where the singularity guard fired: if the whole constraint Jacobian keeps its rank a
        new partition goes on (the next segment picks it); if it loses rank the loop itself is
        at a singular posture (a dead centre, a change point) and the run stops."""
        Jq = self._position_rows(t, q)
        s = np.linalg.svd(Jq, compute_uv=False)
        if s[-1] <= RANK_LOST * s[0] or np.array_equal(self._best_dependent(Jq), self.D):
            # rank lost, or no partition does better than the one that degenerated
            raise SimulationError(
                f"configuration '{self.cfg.name}': the loop reaches a singular posture at t = {t:.9g} s "
                f"(constraint Jacobian singular values {s[0]:.3g} ... {s[-1]:.3g}): at a dead centre or "
                "change point the motion is not determined by the constraints and drives; pcmm stops "
                "rather than pick a branch")

    def guards(self) -> list:
        """The singularity guard when there are loops (drives alone never degenerate), and the
        guards of the cut joints held by compression only (:meth:`contact_guards`)."""
        return ([self.singularity_guard()] + self.contact_guards()) if self.closure.size else []

    def at_guard(self, guard, t, q):
        """The singularity guard fired: a new partition goes on, or the loop is singular (raises);
        a contact guard fired: the pinned point would lift off or slip (raises, with the cause)."""
        if guard.payload is not None:
            raise SimulationError(f"t = {t:.9g} s, configuration '{self.cfg.name}': {guard.payload}")
        self.at_degenerate_partition(t, q)

    def contact_forces(self, t, q, v) -> dict[str, tuple[float, float]]:
        """{cut joint held by compression only: (F_n, F_t)}: its force on b along its contact
        normal n (> 0 pushing) and along the tangent t = (n_y, -n_x), from its multipliers."""
        specs = [(k, s) for k, s in enumerate(self.closure.specs) if s.normal is not None]
        if not specs:
            return {}
        _, lam = self.accelerations(t, q, v)
        out = {}
        for k, s in specs:
            i = self.labels.index(f"{s.name}.fx")
            n = self.cfg.data.oMf[self.closure.links_a[k]].rotation[:2, :2] @ np.asarray(s.normal, float)
            n = n / np.linalg.norm(n)
            F = lam[i:i + 2]
            if not np.isfinite(F).all():  # redundant rows leave it indeterminate (accelerations: NaN)
                raise SimulationError(
                    f"t = {t:.9g} s, configuration '{self.cfg.name}': the point held by cut joint '{s.name}' is held "
                    "by compression (and friction) only, but its force is statically indeterminate: the rows "
                    f"({', '.join(self.labels)}) are redundant, so any split of the load between them balances it "
                    "(the run's warnings name them), and whether the point lifts off or slips cannot be decided "
                    "without the parts' compliance. Remove the redundant row (a cut joint fewer, a joint fewer "
                    "locked, a drive limited to the configurations where its joint is free)")
            out[s.name] = (float(n @ F), float(n[1] * F[0] - n[0] * F[1]))
        return out

    def contact_guards(self) -> list:
        """For each cut joint held by compression only (a ``contact`` normal): a guard where its
        normal force turns tensile, unless a transition of the scene watches it (a release with a
        reaction guard): it lifts off by itself into the scene's configuration without it
        (:meth:`pcmm.scene.spec.Scene.lift_off_target`), or where there is none the run stops.
        With a finite ``friction``, a guard where its force leaves the friction cone
        (mu F_n - |F_t| = 0): the run stops, a pinned point that slips is not modelled."""
        cfg = self.cfg
        watched = {tr.guard.of for tr in cfg.scene.transitions_from(cfg.name) if tr.guard.type == "reaction"}
        out = []
        for s in self.closure.specs:
            if s.normal is None:
                continue
            if s.name not in watched:
                def tensile(t, y, name=s.name):
                    return self.contact_forces(t, *self.unpack(t, y))[name][0]
                target = cfg.scene.lift_off_target(cfg.name, s.name)
                if target is not None:  # it lifts off by itself (pcmm.run.actions.lift_off)
                    out.append(Guard(f"cut joint '{s.name}': its normal force turns tensile (lift-off into "
                                     f"'{target}')", tensile, -1, "lift-off", payload=(s.name, target)))
                else:
                    out.append(Guard(f"cut joint '{s.name}': its normal force turns tensile", tensile, -1, "repartition",
                                     payload=f"the point held by cut joint '{s.name}' would lift off (its normal force "
                                     "turns tensile) and the scene gives it nowhere to go: add a configuration with "
                                     f"the same URDF and drives and the cut joints of '{cfg.name}' but '{s.name}' "
                                     "(pcmm releases the point into it by itself), or a release from this "
                                     f"configuration with guard = {{ type = \"reaction\", of = \"{s.name}\", "
                                     "value = 0.0, direction = \"decreasing\" } to a configuration without it"))
            if s.friction is not None and math.isfinite(s.friction):
                def cone(t, y, name=s.name, mu=s.friction):
                    Fn, Ft = self.contact_forces(t, *self.unpack(t, y))[name]
                    return mu * Fn - abs(Ft)
                out.append(Guard(f"cut joint '{s.name}': its force leaves the friction cone", cone, -1, "repartition",
                                 payload=f"the point held by cut joint '{s.name}' would slip: its force leaves the "
                                 f"friction cone (|F_t| = mu F_n, mu = {s.friction:g}); pcmm models no sliding "
                                 "contact: give a larger friction or \"stick\""))
        return out

    @contextlib.contextmanager
    def recording(self):
        """No conditioning checks while an accepted segment is re-read for the trajectory."""
        self.checking = False
        try:
            yield
        finally:
            self.checking = True

    def cut_joint_frames(self) -> tuple:
        """(spec, frame of point a, frame of point b) of every loop cut joint."""
        return tuple(zip(self.closure.specs, self.closure.frames_a, self.closure.frames_b))

    def loop_rows(self, q) -> tuple[np.ndarray, np.ndarray]:
        """``(Phi, Phi_q)`` of the loop-closure rows alone at the posture ``q`` (drives are
        functions of time, not of the posture)."""
        cfg = self.cfg
        if not self.closure.size:
            return np.zeros(0), np.zeros((0, cfg.nv))
        pin.computeJointJacobians(cfg.model, cfg.data, cfg.to_pin(q))
        pin.updateFramePlacements(cfg.model, cfg.data)
        phi, Jq, _ = self.closure.evaluate(cfg.model, cfg.data, False)
        return phi, Jq

    def singularity_guard(self):
        """A guard on the determinant of the dependent block (scaled by its rows' norms): it
        changes sign where the current partition degenerates, which a step can jump over."""
        def g(t, y):
            self.unpack(t, y)
            return self._scaled_det(self._last_Jp)

        def rate(t, y, f):
            """Its time derivative from the state alone: a central difference along q' (two
            Jacobians, no Newton solve and no right-hand side)."""
            q, v = self.unpack(t, y)
            qd = self.cfg.qdot(q, v)
            loop = self._compiled_loop() if self._loop_refused is None else None
            if loop is not None:  # the same differences, the rows and determinants in C++
                return loop.det_rate(t, q, qd)
            eps = 1e-7 / max(1.0, float(np.max(np.abs(qd))))
            ahead, behind = (self._scaled_det(self._position_rows(t, q + s * eps * qd)) for s in (1.0, -1.0))
            return (ahead - behind) / (2 * eps)
        return Guard(f"configuration '{self.cfg.name}': the loop's partition of its coordinates degenerates",
                     g, 0, "repartition", rate=rate, rate_from_state=True,
                     loop_scan=("singularity",) if self.closure.size else None)

    def solving_loop(self):
        """The compiled Loop whose unpack :meth:`unpack` calls now (ready on this thread for these force
        elements, no segment re-read), or None: what a compiled guard evaluator solves the loop with
        (pcmm.events.guards: a loop's joint-coordinate guard located in C++ on the same solves).  Not a
        segment reader's (its solves check the posture they read: _refuse_singular_read)."""
        return None if self._reader else self._held_loop()

    def _held_loop(self):
        """The compiled loop where it is ready on this thread for these force elements and no
        segment is re-read (the common case, asked at every evaluation), else None."""
        held = self._loop_held
        if held is not None and self._trail is None and held[0] == _thread_id() and held[1] is self.forces:
            return self._loop
        return None

    def unpack(self, t, y):
        held = self._loop_held  # (_held_loop, inline: asked at every guard value, node and state of a run)
        if held is not None and self._trail is None and held[0] == _thread_id() and held[1] is self.forces:
            got = self._loop.unpack(t, y)
            if got[0] == 0 and not self._reader:  # solved by the compiled loop: _compiled_unpack's common case
                self._last_Jp = got[3]
                return got[1], got[2]
            return self._compiled_unpack(self._loop, t, y, got)
        loop = self._compiled_loop() if self._loop_refused is None else None
        if loop is not None:
            return self._compiled_unpack(loop, t, y)
        cache = self._cache
        # the same bytes are the same state (the common hit: a guard's value, then its rate);
        # otherwise numpy decides (-0.0 and 0.0 are one value)
        if cache is not None and cache[0] == t and (cache[1].tobytes() == y.tobytes() or np.array_equal(cache[1], y)):
            return cache[2]
        out = self._unpack(t, y)
        self._cache = (t, y.copy(), out)
        if self._trail is not None:  # a re-read segment: keep the solutions at its accepted steps
            ts, ys = self._trail
            k = int(ts.searchsorted(t, "left"))
            if k < len(ts) and ts[k] == t and k not in self._reached and np.array_equal(ys[:, k], y):
                self._reached[k] = self._recent[-1]
        return out

    def _compiled_unpack(self, loop, t, y, got=None):
        """:meth:`unpack` by the compiled loop (its warm starts, its cache); where it declines, the
        conditioning check decides (a new partition, or a singular posture), or the Python solve
        from the compiled loop's warm start (its error, or a solution the loop then keeps).  ``got``:
        what ``loop.unpack(t, y)`` returned, where :meth:`unpack` asked it already (no segment re-read)."""
        trail = self._trail
        if trail is not None and loop.holds(t, y):  # the last one solved: nothing to keep
            trail = None
        # a re-read segment: its steps' solutions are warm starts too (_guess, _follow)
        near = self._follow(t) if trail is not None and got is None else None
        status, q, v, Jp = got if got is not None else (
            loop.unpack(t, y) if trail is None else loop.unpack(t, y, near))
        if status == 0:
            self._last_Jp = Jp
        else:
            if status == 1:
                self._check_conditioning(t, Jp)  # raises (the compiled check fired: a round-off apart otherwise)
            q, v = self._unpack(t, y, guess=q)
            loop.remember(t, y, q, self._recent[-1][2], self._last_Jp)
        # (the step before t, as _follow found it above: solving at t registers no step before it)
        branch = self._off_branch(t, y[:len(self.I)], q, near) if trail is not None else None
        if branch is not None:  # a re-read segment's long step: the run's branch (as the Python path)
            q, v = self._unpack(t, y, guess=branch)
            loop.remember(t, y, q, self._recent[-1][2], self._last_Jp)
        elif status == 0 and self._reader:  # the Python solves above check their own
            self._refuse_singular_read(t, self._last_Jp)
        if trail is not None:  # keep the solution at an accepted step of the segment (unpack)
            ts, ys = trail
            k = int(ts.searchsorted(t, "left"))
            if k < len(ts) and ts[k] == t and k not in self._reached and np.array_equal(ys[:, k], y):
                self._reached[k] = loop.last()
        return q, v

    def _unpack(self, t, y, guess=None):
        if not self.closure.size:
            return self._prescribed(t, y)
        k = len(self.I)
        try:
            q, Jq, Jp = self._solve_dependent(t, y[:k], self._guess(t) if guess is None else guess)
        except SimulationError:
            # a re-read across a long step whose Newton solve fails from its warm start: the
            # continuation from the step before finds the run's branch, or says why there is none
            # (a singular posture on the way), naming the instant and the cut joints
            near = self._long_step(t)
            if near is None:
                raise
            q, Jq, Jp = self._solve_dependent(t, y[:k], self._continued(t, y[:k], near))
        if guess is None:  # a re-read segment's long step: the run's branch, not the one Newton found
            branch = self._off_branch(t, y[:k], q)
            if branch is not None:
                q, Jq, Jp = self._solve_dependent(t, y[:k], branch)
        if self._reader:
            self._refuse_singular_read(t, Jp)
        self._qD = q
        self._last_Jp = Jp
        # the state's second half is the independent coordinates' rates q'_I (a planar joint's
        # world-frame x', y', not its body-frame velocity): the dependent rates then solve the
        # same block as the positions, dPhi/dq q' = -Phi_t, and v follows from q'
        rates = np.empty(self.nv)
        rates[self.I] = y[k:]
        rhs = -(Jp[:, self.I] @ y[k:] + self._phi_t(t))
        rates[self.D] = solve(Jp[:, self.D], rhs)
        if self._kept is not None:
            self._check_dropped(t, q, rates)
        v = self.cfg.velocity(q, rates)
        self._recent.append((t, q, rates))
        if len(self._recent) > 8:
            del self._recent[0]
        return q, v

    def _prescribed(self, t, y):
        """Drives alone (no loop): the dependent coordinates are the driven ones, prescribed
        outright, ``q_D = f(t)`` and ``q'_D = f'(t)`` (the drive rows ``q_j - f_j(t) = 0`` are
        linear with unit Jacobian rows).  No Newton solve: the one a loop needs converges here
        in one step, and its polishing step lands on ``f(t)`` to the last bit, so the state is
        the same, only its residual is now exactly zero."""
        k = len(self.I)
        q = np.empty(self.nv)
        rates = np.empty(self.nv)
        q[self.I] = y[:k]
        rates[self.I] = y[k:]
        return self._driven_state(t, q, rates)

    def _driven_state(self, t, q, rates):
        """:meth:`_prescribed` of a posture ``q`` and its rates whose independent entries are set:
        the driven ones are written (in place) as ``f(t)`` and ``f'(t)``; returns ``(q, v)``."""
        f, f1, _ = self.drives.values(t)
        q[self._driven] = f
        rates[self._driven] = f1
        self._qD = q
        v = self.cfg.velocity(q, rates)
        self._recent.append((t, q, rates))  # what a re-read segment keeps at its steps (unpack)
        if len(self._recent) > 8:
            del self._recent[0]
        return q, v

    def state_entry(self, j: int) -> tuple[int, int] | None:
        """Where coordinate ``j`` and its rate sit in the state, ``(p, r)`` with ``q_j = y[p]`` and
        ``q'_j = y[r]``, for drives without a loop (the independent coordinates are the undriven
        ones, in order, whatever the posture: :meth:`partition`) and without a planar joint
        (its rates are not its v); None otherwise, or for a driven joint."""
        if self.closure.size or self.cfg.has_planar or len(set(self.drives.index)) != self.drives.size:
            return None
        free = [i for i in range(self.nv) if i not in self.drives.index]
        if j not in free:
            return None
        p = free.index(j)
        return p, len(free) + p

    def unpack_many(self, ts, ys):
        """``(q, v)`` at many times at once (one column each) where no Newton solve is involved:
        drives without a loop and without a planar joint (:meth:`_prescribed`, column by column
        the same bits); None otherwise.  Leaves the warm starts alone (prescribed coordinates
        need none)."""
        if self.closure.size or self.cfg.has_planar:
            return None
        k = len(self.I)
        Q = np.empty((self.nv, len(ts)))
        V = np.empty_like(Q)
        Q[self.I], V[self.I] = ys[:k], ys[k:2 * k]
        Q[self._driven], V[self._driven] = self.drives.values_many(np.asarray(ts, float))
        return Q, V

    def project(self, t, q, v, prefer_independent=()):
        """Assemble (q, v) onto the constraints keeping the independent coordinates
        (a new partition is chosen at q, preferring ``prefer_independent``).

        Drives without a loop need neither a new partition nor a solve: the dependent coordinates
        are the driven ones whatever the posture (:meth:`partition`), and the projection is
        :meth:`_prescribed` of ``[q_I, q'_I]`` itself (``q_D = f(t)``, ``q'_D = f'(t)``), the same
        bits :meth:`unpack` gives, without its dispatch and cache (a bounce's entry, at every impact)."""
        if self.D is not None and not self.closure.size and self._distinct_drives:
            self.seed(q)
            # q and its rates with the driven entries written over (the independent ones are the rest,
            # :meth:`partition`): the bits of _prescribed([q_I, q'_I]) without gathering and scattering them
            return self._driven_state(t, q.copy(), self.cfg.qdot(q, v).copy())
        self.partition(t, q, prefer_independent)
        self.seed(q)
        q_new, v_new = self.unpack(t, np.concatenate([q[self.I], self.cfg.qdot(q, v)[self.I]]))
        if not prefer_independent:
            # the next segment's pack() at this instant and this assembled posture keeps the partition just
            # chosen at q instead of choosing it again: q_new is q moved onto the rows by the Newton solve
            # (round-off), and the choice is the same there (a switch's entry then costs one partition, not two)
            self._projected = (t, q_new.tobytes())
        return q_new, v_new

    def rows(self, t, q, v):
        """(Phi_q, bias) of every constraint at (q, v): ``Phi_q a + bias = 0`` (a segment reader's
        compiled loop builds them without its KKT solve: the flight audit's power solves for the
        multipliers itself, :func:`pcmm.run.audit.power`)."""
        loop = self._reader_loop()
        if loop is not None:
            return loop.rows(t, q, v)
        _, Jq, bias = self._phi_all(t, q, need_bias=True, v=v)
        return Jq, bias

    def _reader_loop(self):
        """A segment reader's compiled loop (:meth:`restored`: the audit's powers, the lazy series, a
        hold's rows); None otherwise.  The run's own coordinates keep the Python evaluation of their
        rows and accelerations: its callers (a reaction guard, the contact forces) read the frame
        placements it leaves on the configuration's data."""
        if not self._reader or self._loop_refused is not None:
            return None
        return self._compiled_loop()

    def _reader_kkt(self, t, q, v):
        """``(a, lam, Phi_q, bias)`` at an assembled (q, v) by a segment reader's compiled loop
        (:meth:`_reader_loop`); None otherwise, or where its KKT solve hands back to Python."""
        loop = self._reader_loop()
        return None if loop is None else loop.kkt(t, q, v)

    def time_rows(self):
        """``(Phi_q, bias_of)`` where the rows depend on time alone (drives without a loop):
        ``rows(t, q, v) == (Phi_q, bias_of(t))`` to the bit, the same arrays built once; None with
        a loop (its rows depend on the posture)."""
        if self.closure.size:
            return None
        Jq = self._time_jacobian
        if Jq is None:  # formed once per coordinates (a reader's copy shares it): read-only
            Jq = np.concatenate((self._no_jacobian, self._drive_rows)) if self.drives.size else self._no_jacobian
            Jq.flags.writeable = False
            self._time_jacobian = Jq
        return Jq, (self._drive_bias if self.drives.size else self._no_bias)

    def _drive_bias(self, t):
        """The drive rows' bias at ``t``, ``-f''(t)`` (the rows of drives without a loop: :meth:`time_rows`;
        the values :meth:`rows` gives, a new array)."""
        return -self.drives.values(t)[2]

    def _no_bias(self, t):
        """No rows, no bias (:meth:`time_rows` of coordinates without drives or loops)."""
        return self._no_rows

    def accelerations(self, t, q, v, extra=None):
        """(a, lam): ``M a + h = Q + extra + Phi_q^T lam`` with ``Phi_q a + bias = 0``."""
        if self._kept is not None:  # redundant rows: the KKT solve on the kept ones, the indeterminate forces NaN
            _, Jk, bias = self._phi(t, q, need_bias=True, v=v)
            a, lam_kept = constrained_accelerations(self.cfg, q, v, Jk, bias, extra, forces=self.forces)
            lam = np.zeros(self.m)
            lam[self._kept] = lam_kept
            return a, determinate(self.rows(t, q, v)[0], lam)
        if extra is None:
            got = self._reader_kkt(t, q, v)
            if got is not None:
                return got[0], got[1]
        Jq, bias = self.rows(t, q, v)
        return constrained_accelerations(self.cfg, q, v, Jq, bias, extra, forces=self.forces)

    def derivative(self, t, q, v, extra):
        """State derivative at an assembled (q, v) with an extra generalized force (contact laws)."""
        a, _ = self.accelerations(t, q, v, extra)
        return np.concatenate([self.cfg.qdot(q, v)[self.I], self.cfg.qddot(q, v, a)[self.I]])

    def _solved_accelerations(self, t, q, v):
        """(a, lam) at an assembled (q, v): with revolute cut joints the rows and bias come from
        one kinematics pass (:meth:`_point_rows_and_bias`); otherwise :meth:`accelerations`.  Where
        the rows are redundant, ``lam`` is that of the rows kept (:meth:`solving_rows`): one split,
        for the power of the drives (the same for every split), never reported."""
        if self.closure.revolute_only:
            return constrained_accelerations(self.cfg, q, v, *self._point_rows_and_bias(t, q, v), forces=self.forces)
        if self._kept is not None:
            return constrained_accelerations(self.cfg, q, v, *self.solving_rows(t, q, v), forces=self.forces)
        return self.accelerations(t, q, v)

    def solving_rows(self, t, q, v):
        """(Phi_q, bias) of the rows the motion is solved with (:meth:`rows` but for the rows dropped
        as redundant: :meth:`partition`), whose multipliers are one split of the load: the power of
        the constraint forces, ``lam . Phi_q v``, is the same for every split of consistent rows."""
        _, Jq, bias = self._phi(t, q, need_bias=True, v=v)
        return Jq, bias

    def rhs(self, t, y):
        """``[q'_I, q''_I]`` at ``(t, y)``: compiled where the drives are (:meth:`_compiled_drives`)
        or the loops (:meth:`_compiled_loop`; a call it declines is Python's)."""
        loop = self._held_loop()
        if loop is not None:
            out = loop.rhs(t, y)
            return self._python_rhs(t, y) if out is None else out
        fast = self._compiled_drives()
        if fast is not None:
            return fast.rhs(t, y)
        loop = self._compiled_loop() if self._loop_refused is None else None
        if loop is not None:
            if self._trail is not None:  # a re-read segment: its own warm starts, and what it keeps
                self._compiled_unpack(loop, t, y)
            out = loop.rhs(t, y)
            if out is not None:
                return out
        return self._python_rhs(t, y)

    def _python_rhs(self, t, y):
        q, v = self.unpack(t, y)
        a, _ = self._solved_accelerations(t, q, v)
        qd = self.cfg.qdot(q, v)
        return np.concatenate((qd[self.I], self.cfg.qddot(q, v, a)[self.I]))

    def rhs_with_power(self, t, y):
        """``y`` is the state with the work so far appended; the state derivative with one more component: the power of the force elements and
        of the drives.  A constraint's generalized force ``Phi_q^T lam`` has the power
        ``lam . Phi_q v = -lam . Phi_t``: zero for the loops (scleronomic), the motor's
        ``mu f'(t)`` for a drive.  Compiled where the drives are (:meth:`_compiled_drives`) or the
        loops (:meth:`_compiled_loop`)."""
        loop = self._held_loop()
        if loop is not None:
            out = loop.rhs_with_power(t, y)
            return self._python_rhs_with_power(t, y) if out is None else out
        fast = self._compiled_drives()
        if fast is not None:
            return fast.rhs_with_power(t, y)
        loop = self._compiled_loop() if self._loop_refused is None else None
        if loop is not None:
            if self._trail is not None:  # a re-read segment: its own warm starts, and what it keeps
                self._compiled_unpack(loop, t, y[:-1])
            out = loop.rhs_with_power(t, y)
            if out is not None:
                return out
        return self._python_rhs_with_power(t, y)

    def _python_rhs_with_power(self, t, y):
        q, v = self.unpack(t, y[:-1])
        a, lam = self._solved_accelerations(t, q, v)
        power = float(self.forces.generalized(q, v) @ v - lam @ self._phi_t(t))
        qd = self.cfg.qdot(q, v)
        return np.concatenate([qd[self.I], self.cfg.qddot(q, v, a)[self.I], [power]])


def _segment_loop(coords: PartitionedCoordinates, *args, **options):
    """The compiled segment loop of these coordinates (registered for
    :data:`pcmm.ode.integrators.SEGMENT_LOOPS`): over the compiled loop (pcmm/model/_loops.hpp) with
    closed loops, each call it declines taken by the Python evaluation (``_python_rhs``, as :meth:`rhs`
    does), or over the compiled tree of drives without a loop; a ValueError where there is none (the
    integrator then steps in Python)."""
    if not coords.closure.size:
        return _drive_segment_loop(coords, *args, **options)
    if not STEP_LOOPS_COMPILED:
        raise ValueError("closed loops are stepped in Python (partitioned.STEP_LOOPS_COMPILED)")
    loop = coords._held_loop()
    if loop is None and coords._trail is None and coords._loop_refused is None:
        coords._compiled_loop()
        loop = coords._held_loop()
    if loop is None:
        raise ValueError(f"no compiled loop: {coords._loop_refused or compiled.why_not() or 'a segment re-read'}")
    fallback = coords._python_rhs_with_power if options.get("power") else coords._python_rhs
    return compiled.segment_loop(loop, *args, fallback=fallback, **options)


def _drive_segment_loop(coords: PartitionedCoordinates, *args, **options):
    """The compiled segment loop of a configuration with drives and no loop (registered for
    :data:`pcmm.ode.integrators.SEGMENT_LOOPS`): over the calling thread's compiled tree of its
    drives; a ValueError where there is none (the integrator then steps in Python)."""
    tree = coords._compiled_drives()
    if tree is None:
        raise ValueError(f"no compiled right-hand side: {coords._drives_refused or compiled.why_not()}")
    return compiled.segment_loop(tree, *args, **options)
