"""Holding forces: what keeps each locked joint and each merged stop locked.

A latch or a stop-merge locks joints: the run goes on in a configuration whose URDF fixes
them.  Their holding forces are the multipliers of the locks seen from a *reference*
configuration in which those joints are free (a scene configuration whose movable joints
include the current configuration's and every locked one): the current state is mapped onto
it (locked joints at their values, at rest relative to each other) and its dynamics are
solved with one extra row per lock, ``M a + h = Q + J^T lam`` (the loops' and drives' rows
too).  A latch-locked joint's row is its own coordinate's (``lam`` is the moment, or the axial
force, the lock applies to the child); a merged stop's row is the stop's contact normal
(``lam`` is the normal contact force, > 0 compressive).

A merge held by compression only (``unmerge``) is undone when its force would turn tensile,
in whatever configuration the run is then: that needs the configuration with the stop's
joints free again, found among the scene's configurations by its set of movable joints.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from ..model import compiled
from ..model.configuration import Configuration
from ..model.constraints import constrained_accelerations, determinate, indeterminate, left_null
from ..errors import PcmmError, SimulationError
from ..model.forces import compile_forces
from .contact import contact_row
from ..model.mechanism import Mechanism
from ..scene.spec import TransitionSpec
from .entry import joints_from_poses
from ..ode.witness import Guard


@dataclass
class Hold:
    """Joints locked by one transition and still locked."""

    label: str  # the locked joint (latch) or the stop transition's name (merge)
    transition: TransitionSpec
    joints: dict[str, np.ndarray]  # locked joint -> its value when it locked
    merge: bool  # a stop-merge: held by the stop's contact force
    unilateral: bool  # undone when the contact force would turn tensile
    carries: str = ""  # the configuration whose force elements on the held joints the lock carries
    # (where those joints are free: the one the lock was made from, or for a lock the run starts
    # with, the one that frees it); "" is the transition's source

    @property
    def free_in(self) -> str:
        return self.carries or self.transition.source


@dataclass(frozen=True)
class Applied:
    """What a segment's holding forces are solved with, kept as values when it is recorded
    (:meth:`Holds.applied`), so that reading them after the run went on gives what they were."""

    reference: Configuration  # the reference configuration's model (a derived one: the one built then)
    frozen: dict  # its coordinates' frozen state (partition, cut-joint anchors): Coordinates.frozen_state
    forces: object  # its own force elements, compiled at its angle offsets of then
    acting: object  # the elements acting while the configuration holds (Holds._forces_on), or None
    springs: object  # the held joints' own springs (Holds._held_springs), or None


class Holds:
    """The locks in force during a run, their holding forces and their releases."""

    def __init__(self, mechanism: Mechanism, unmerge: bool | None = None):
        self.mechanism = mechanism
        self.scene = mechanism.scene
        # the run's solver setting (RunOptions, --unmerge) or the scene's; a stop's own wins
        self.unmerge = self.scene.solver.unmerge if unmerge is None else unmerge
        self.items: list[Hold] = []
        self._maps: dict = {}  # (reference, configuration, holds) -> the forces acting while it holds
        self._refs: dict = {}  # (configuration, holds) -> its reference configuration
        self._sets: dict | None = None  # {configuration: its URDF's movable joints}, read on first use
        self._evaluator: tuple | None = None  # (what it was built from, by identity; the evaluator): evaluator
        self._applied: tuple | None = None  # (what it was made from; the Applied): applied
        # {configuration: "compiled", or "python: why"}: how its holding forces were evaluated, as
        # each segment's evaluator was built (the run's stats["holding_evaluations"])
        self.evaluations: dict[str, str] = {}
        self._noted: set = set()  # (configuration, holds) whose indeterminate holds were named (indeterminate_notes)

    # -- book-keeping
    def lock(self, src: Configuration, dst: Configuration, tr: TransitionSpec, q: np.ndarray, merge: bool) -> None:
        """``tr`` switched ``src`` -> ``dst`` by locking the joints ``dst`` lacks."""
        locked = {n: q[src.joint_slice[n]].copy() for n in src.joint_names if n not in dst.joint_slice}
        if not locked:
            return
        if merge:
            unilateral = self.unmerge if tr.unmerge is None else tr.unmerge
            self.items.append(Hold(tr.name, tr, locked, True, bool(unilateral)))
        else:
            self.items += [Hold(n, tr, {n: val}, False, False) for n, val in locked.items()]

    def adopt(self, cfg: Configuration, q: np.ndarray, v: np.ndarray) -> None:
        """Locks the run starts with: a joint that a reaction guard watches and the initial
        configuration lacks is held from the start, at the value its links give it."""
        watched = {tr.guard.of for tr in self.scene.transitions if tr.guard.type == "reaction"}
        joints = self._joint_sets()
        for of in sorted(watched):
            if of in cfg.joint_slice or of not in set().union(*joints.values()) or self.holds(of, cfg):
                continue
            source = next(name for name, js in joints.items() if of in js and set(cfg.joint_names) <= js)
            src = self.mechanism[source]
            q_s, v_s = joints_from_poses(cfg, src, q, v, src.neutral(), np.zeros(src.nv), [of])
            tr = next(t for t in self.scene.transitions if t.guard.type == "reaction" and t.guard.of == of)
            # the lock carries the elements acting on the joint where it is free (source), not those
            # of the release's source (the locked configuration, where the scene does not list them)
            self.items.append(Hold(of, tr, {of: q_s[src.joint_slice[of]].copy()}, False, False, carries=source))

    def indeterminate_notes(self, cfg: Configuration, t: float, q: np.ndarray, v: np.ndarray) -> list[str]:
        """For the run's warnings, once per configuration and set of holds: the holds in force at
        (t, q, v) of ``cfg`` that their rows leave statically indeterminate (NaN in :meth:`forces`:
        the reference's rows and the lock rows are dependent), whose series are NaN."""
        key = (cfg.name, tuple(h.label for h in self.items))
        if not self.items or key in self._noted:
            return []
        self._noted.add(key)
        if self.reference(cfg) is None:  # recorded as NaN (pcmm.run.recording.holding_forces); a guard stops
            labels = [f"{h.label}.hold" for h in self.items]
            return [f"t = {t:.9g} s, configuration '{cfg.name}': the holding force{'s' if len(labels) > 1 else ''} "
                    f"{', '.join(labels)} cannot be solved here: {self._no_reference(cfg, '')}: NaN in the series, "
                    "left out of stats.holding; add such a configuration to have them"]
        try:
            _, _, _, R, _, m, owners, _, _ = self._rows(cfg, t, q, v)
        except PcmmError:  # a hold that cannot be solved here says so where it is read
            return []
        loose = [f"{label}.hold" for label, bad in zip(owners, indeterminate(left_null(R))[m:]) if bad]
        if not loose:
            return []
        return [f"t = {t:.9g} s, configuration '{cfg.name}': the holding force{'s' if len(loose) > 1 else ''} "
                f"{', '.join(loose)} {'are' if len(loose) > 1 else 'is'} statically indeterminate (solved with the "
                "rows of the configuration with the held joints free and the lock rows, which are dependent: any "
                "split of the load balances it): NaN in the series, left out of stats.holding; no guard may read it"]

    def snapshot(self) -> "Holds":
        """The locks in force now, kept as they are (a recorded segment computes its holding
        forces later, when they are read, while the run's own locks change)."""
        out = copy.copy(self)
        out.items = list(self.items)
        return out

    def follow(self, cfg: Configuration) -> None:
        """Drop the holds whose joints ``cfg`` has free (a release undid them)."""
        self.items = [h for h in self.items if not any(j in cfg.joint_slice for j in h.joints)]

    def holds(self, of: str, cfg: Configuration) -> bool:
        return any(h.label == of or of in h.joints for h in self.items)

    def label(self, of: str) -> str:
        for h in self.items:
            if h.label == of or of in h.joints:
                return h.label
        raise KeyError(of)

    def labels(self) -> list[str]:
        return [f"{h.label}.hold" for h in self.items]

    # -- the reference configuration and the state mapped onto it
    def _joint_sets(self):
        sets = self._sets
        if sets is None:  # the scene's configurations do not change: read their URDF joints once
            sets = self._sets = {name: set(spec.info.movable_joints) for name, spec in self.scene.configurations.items()}
        return sets

    def reference(self, cfg: Configuration) -> str | None:
        """The configuration the holding forces are solved in: one whose movable joints are
        ``cfg``'s and every held one, with ``cfg``'s drives and cut joints; of those one a hold was
        locked from.  Only its model (its joints, loops and drives) is used: the
        forces are always ``cfg``'s own (:meth:`forces`), whatever the reference applies."""
        key = (cfg.name, tuple(h.label for h in self.items))  # asked at every sample and guard value
        if key not in self._refs:
            need = set(cfg.joint_names).union(*(h.joints for h in self.items))
            drives = {(d.joint, d.coefficients) for d in self.scene.drives_in(cfg.name)}
            sources = {h.free_in for h in self.items}
            # exactly these joints free (a joint that ``cfg`` locks and no hold holds, free in the
            # reference, would be solved as free: the walker's swing knee, locked, read as free), the
            # same drives and the same cut joints (:meth:`_same_cut_joints`)
            fits = [(name not in sources, name) for name, js in self._joint_sets().items()
                    if need == js and {(d.joint, d.coefficients) for d in self.scene.drives_in(name)} == drives
                    and self._same_cut_joints(name, cfg)]
            self._refs[key] = min(fits)[1] if fits else None
        return self._refs[key]

    def _forces_on(self, ref: Configuration, cfg: Configuration):
        """The force elements acting while ``cfg`` holds, on ``ref``'s coordinates (None when
        ``ref`` applies the same ones): ``cfg``'s own, plus each held joint's own elements (a
        spring or motor on the joint, which the scene lists only where the joint is free) as the
        configuration the hold was locked from has them.  A locked joint's element is internal to
        the welded links, so it does not move them, but the lock holds it: the pin of a joint whose
        spring pushes it into the pin carries that moment.  A configuration with the held joints
        free may drive, spring or damp otherwise (a motor on only while a stop holds), and the hold
        balances what acts in ``cfg``, not there."""
        # ref's measures as they are now (its angle offsets: pcmm.configuration.Configuration.continue_angles)
        key = (ref.name, cfg.name, tuple(h.label for h in self.items), ref.angle_offsets)
        if key not in self._maps:
            mine = list(self.scene.forces_in(cfg.name)) + self._carried(cfg)
            theirs = self.scene.forces_in(ref.name)
            if len(mine) == len(theirs) and all(f in theirs for f in mine):
                self._maps[key] = None
            elif any(f.points is not None for f in mine + list(theirs)):
                raise SimulationError(
                    f"configuration '{cfg.name}': its holding forces are solved in '{ref.name}' (the "
                    "configuration with the held joints free), whose force elements differ, and one of "
                    "them is a point_spring, which pcmm cannot carry over; give both configurations the "
                    "same point springs")
            else:
                self._maps[key] = compile_forces(tuple(mine), ref.measure_row, ref.target_column, ref.nv)
        return self._maps[key]

    def _carried(self, cfg: Configuration) -> list:
        """The held joints' own force elements (a spring or motor on a held joint, or measuring
        it), as the configuration each hold was locked from has them, that ``cfg`` lacks."""
        own = self.scene.forces_in(cfg.name)
        out = []
        for h in self.items:
            for f in self.scene.forces_in(h.free_in):
                on_joint = f.on is not None and f.on.kind == "joint" and f.on.name in h.joints
                measures = f.measure is not None and f.measure.kind == "joint" and f.measure.names[0] in h.joints
                if (on_joint or measures) and f not in own and f not in out:
                    out.append(f)
        return out

    def _no_reference(self, cfg: Configuration, held: str) -> str:
        """Why :meth:`reference` finds none for ``cfg`` (``held``: the words before the held joints)."""
        joints = ", ".join(sorted(set().union(*(h.joints for h in self.items))))
        cuts = ", ".join(s.name for s in cfg.spec.cut_joints) or "none"
        return (f"no configuration of the scene has its joints plus {held}{joints} free, its drives and its "
                f"cut joints ({cuts})")

    def _same_cut_joints(self, name: str, cfg: Configuration) -> bool:
        """Configuration ``name`` has ``cfg``'s cut joints: the same loops and pinned points (another cut
        joint, a foot pinned elsewhere or none, is another mechanism, whose multipliers are not this one's)."""
        return set(self.scene.configurations[name].cut_joints) == set(cfg.spec.cut_joints)

    def release_target(self, hold: Hold, cfg: Configuration) -> str:
        need = set(cfg.joint_names) | set(hold.joints)
        for name, js in self._joint_sets().items():  # (a walker's stance foot, not the other)
            if js == need and self._same_cut_joints(name, cfg):
                return name
        raise SimulationError(
            f"configuration '{cfg.name}': the merge of '{hold.label}' is held by compression only "
            f"(unmerge), so pcmm must be able to release it here, into a configuration with the joints "
            f"of '{cfg.name}' plus {', '.join(sorted(hold.joints))} free and its cut joints "
            f"({', '.join(s.name for s in cfg.spec.cut_joints) or 'none'}); the scene has none. Add it "
            f"(a URDF, or a configuration derived by locking joints) or set unmerge = false on "
            f"'{hold.label}'")

    def applied(self, cfg: Configuration) -> Applied | None:
        """What the holding forces of ``cfg`` are solved with now, as values (:class:`Applied`): the
        reference configuration's model, its coordinates' frozen state, its own force elements,
        those acting while ``cfg`` holds and the held joints' springs.  A recorded segment keeps
        them: its holding forces are read later, when the run may have entered the reference again
        (a derived one is then another model, built for other locked values), compiled its forces
        at other angle offsets or anchored its cut joints elsewhere.  None without holds or
        reference."""
        ref_name = self.reference(cfg) if self.items else None
        if ref_name is None:
            return None
        ref = self.mechanism[ref_name]
        frozen, offsets, items = ref.coords.frozen_state(), ref.angle_offsets, self.items
        # the one made last where everything it is made from is the same: the configuration, the
        # reference's model and force elements (the same objects), its angle offsets (which key the
        # maps of _forces_on and _held_springs), the holds (the same Hold objects) and its frozen
        # state (the same bytes): a run recording segment after segment in one stay (a bouncing run)
        # gets one Applied, which its recording then compares by identity (pcmm.run.recording)
        last = self._applied
        if (last is not None and last[0] is cfg and last[1] is ref and last[2] is ref.forces and last[3] == offsets
                and len(last[4]) == len(items) and all(a is b for a, b in zip(last[4], items))
                and _same_bytes(last[5].frozen, frozen)):
            return last[5]
        out = Applied(ref, frozen, ref.forces, self._forces_on(ref, cfg), self._held_springs(ref, cfg))
        self._applied = (cfg, ref, ref.forces, offsets, tuple(items), out)
        return out

    def _on_reference(self, cfg: Configuration, q: np.ndarray, v: np.ndarray, ref: Configuration | None = None):
        """(ref, qs, vs): the state of ``cfg`` mapped onto its reference configuration ``ref`` (by
        default the mechanism's model of :meth:`reference` now), the held joints at their locked
        values and at rest."""
        if ref is None:
            ref_name = self.reference(cfg)
            if ref_name is None:
                raise SimulationError(
                    f"configuration '{cfg.name}': {self._no_reference(cfg, 'the locked ')}, so the holding forces "
                    f"cannot be computed; add one (e.g. derived from the same URDF, locking only the joints "
                    f"'{cfg.name}' locks that are not held)")
            ref = self.mechanism[ref_name]
        qs, vs = np.zeros(ref.nv), np.zeros(ref.nv)
        for name in ref.joint_names:
            sl = ref.joint_slice[name]
            if name in cfg.joint_slice:
                qs[sl], vs[sl] = q[cfg.joint_slice[name]], v[cfg.joint_slice[name]]
        for h in self.items:
            for name, val in h.joints.items():
                qs[ref.joint_slice[name]] = val
        return ref, qs, vs

    def held_energy(self, cfg: Configuration, q: np.ndarray, applied: Applied | None = None) -> float:
        """The energy stored in the held joints' own springs (J) at ``q`` of ``cfg``: constant
        while the lock holds them (0 without a hold or a spring).  The configuration's own
        potential energy leaves them out (``cfg`` has no such joint); the recorded potential
        energy adds it, so it does not jump where a joint locks or is released.  ``applied``: as
        for :meth:`forces`."""
        if not self.items:
            return 0.0
        if (applied.springs is None) if applied is not None else not any(f.k for f in self._carried(cfg)):
            return 0.0
        ref, qs, _ = self._on_reference(cfg, q, np.zeros(cfg.nv), applied and applied.reference)
        springs = applied.springs if applied is not None else self._held_springs(ref, cfg)
        return springs.potential_energy(qs)

    def _held_springs(self, ref: Configuration, cfg: Configuration):
        """The held joints' own elements (:meth:`_carried`) on ``ref``'s coordinates, at its angle
        offsets of now; None when none of them is a spring."""
        carried = self._carried(cfg)
        if not any(f.k for f in carried):
            return None
        key = ("energy", ref.name, cfg.name, tuple(h.label for h in self.items), ref.angle_offsets)
        if key not in self._maps:
            self._maps[key] = compile_forces(tuple(carried), ref.measure_row, ref.target_column, ref.nv)
        return self._maps[key]

    def forces(self, cfg: Configuration, t: float, q: np.ndarray, v: np.ndarray, applied: Applied | None = None) -> dict[str, float]:
        """{label: holding force or moment} of every hold at (t, q, v) of ``cfg``: the multipliers
        of the lock rows in ``M a + h = Q + J^T lam`` of the reference configuration (its loops'
        and drives' rows too).  ``applied`` (:meth:`applied`, a recorded segment's) is what they are
        solved with, as the segment had it: the reference model, its anchors and force elements;
        by default those of now."""
        if not self.items:
            return {}
        ref, qs, vs, R, bias, m, owners, extra, ref_forces = self._rows(cfg, t, q, v, applied)
        _, lam = constrained_accelerations(ref, qs, vs, R, bias, extra, forces=ref_forces)
        lam = determinate(R, lam)  # a hold the rows leave statically indeterminate: NaN, never one arbitrary split
        return {label: float(x) for label, x in zip(owners, lam[m:])}

    def _rows(self, cfg: Configuration, t: float, q: np.ndarray, v: np.ndarray, applied: Applied | None = None):
        """What :meth:`forces` solves: ``(ref, qs, vs, R, bias, m, owners, extra, ref_forces)``, the
        reference configuration and the state on it, its rows (its own ``m`` first, then one per
        hold, labelled ``owners``) with their bias, and the force elements acting."""
        ref, qs, vs = self._on_reference(cfg, q, v, applied and applied.reference)
        if applied is None:
            Jc, bc = ref.coords.rows(t, qs, vs)
            ref_forces, own = ref.forces, self._forces_on(ref, cfg)
        else:
            with ref.coords.restored(applied.frozen, qs) as reader:  # the segment's anchors, not today's
                Jc, bc = reader.rows(t, qs, vs)
            ref_forces, own = applied.forces, applied.acting
        rows, bias, owners = [Jc], [bc], []
        for h in self.items:
            if h.merge:
                Jn, bn = contact_row(ref, qs, vs, h.transition.contact)
                rows.append(Jn[None, :])
                bias.append([bn])
            else:
                (name,) = h.joints
                e = np.zeros(ref.nv)
                e[ref.joint_slice[name].start] = 1.0
                rows.append(e[None, :])
                bias.append([0.0])
            owners.append(h.label)
        extra = None if own is None else own.generalized(qs, vs) - ref_forces.generalized(qs, vs)
        return ref, qs, vs, np.vstack(rows), np.concatenate(bias), Jc.shape[0], owners, extra, ref_forces

    def evaluator(self, cfg: Configuration):
        """``(t, q, v) -> {label: holding force}``: :meth:`forces` of the holds in force now, to the
        bit, for a guard that asks at every step of a segment of ``cfg``.  Where the reference's
        rows depend on time alone (drives without a loop, or a tree) and every merge is a joint
        stop's (a constant row), what :meth:`forces` rebuilds at each call is built once here: the
        map of ``cfg``'s coordinates onto the reference, the lock rows stacked under the
        reference's, the force elements; each call then maps the state, forms the bias and solves
        the same system (:func:`constrained_accelerations`) with the same arrays.  Otherwise
        :meth:`forces` itself.  Valid while the holds and the reference's force elements stay as
        they are: the segment being integrated, and the next ones while the configuration, its
        reference, the reference's coordinates and force elements and the holds are the same
        objects (a bounce's re-arm in a sequence of impacts), which get the one built last."""
        if not self.items:
            return lambda t, q, v: {}
        ref_name = self.reference(cfg)
        if ref_name is not None:  # the one built last, where nothing it was built from has changed since
            ref = self.mechanism[ref_name]
            key = (cfg, ref, ref.coords, ref.forces, self._forces_on(ref, cfg), *self.items)  # by identity
            last = self._evaluator
            if last is not None and len(last[0]) == len(key) and all(a is b for a, b in zip(last[0], key)):
                return last[1]
        timed = None if ref_name is None else self.mechanism[ref_name].coords.time_rows()
        if timed is None or any(h.merge and h.transition.contact.joint is None for h in self.items):
            self.evaluations[cfg.name] = ("python: not compiled: " + ("no reference configuration" if ref_name is None else
                                          "the reference's rows depend on the posture (a loop)" if timed is None else
                                          "a merge at a point contact (its row depends on the posture)"))
            return lambda t, q, v: self.forces(cfg, t, q, v)
        ref = self.mechanism[ref_name]
        Jc, bias_of = timed
        rows, labels = [Jc], []
        for h in self.items:
            if h.merge:
                Jn, _ = contact_row(ref, None, None, h.transition.contact)  # a joint stop's: constant
                rows.append(Jn[None, :])
            else:
                (name,) = h.joints
                e = np.zeros(ref.nv)
                e[ref.joint_slice[name].start] = 1.0
                rows.append(e[None, :])
            labels.append(h.label)
        J, m = np.vstack(rows), Jc.shape[0]
        if left_null(J).shape[1]:  # redundant rows: forces() says which holds are indeterminate (NaN)
            self.evaluations[cfg.name] = "python: not compiled: redundant rows"
            return lambda t, q, v: self.forces(cfg, t, q, v)
        lock_bias = np.zeros(len(labels))  # joint rows: no bias (as forces() gives them)
        mine, theirs = [], []  # cfg's coordinates and where they sit in the reference's
        for name in ref.joint_names:
            if name in cfg.joint_slice:
                theirs += range(ref.joint_slice[name].start, ref.joint_slice[name].stop)
                mine += range(cfg.joint_slice[name].start, cfg.joint_slice[name].stop)
        held = np.zeros(ref.nv)  # the held joints at their locked values
        for h in self.items:
            for name, val in h.joints.items():
                held[ref.joint_slice[name]] = val
        mine, theirs = np.array(mine, dtype=int), np.array(theirs, dtype=int)
        ref_forces, own = ref.forces, self._forces_on(ref, cfg)

        def forces(t, q, v):
            qs, vs = held.copy(), np.zeros(ref.nv)
            qs[theirs], vs[theirs] = q[mine], v[mine]
            extra = None if own is None else own.generalized(qs, vs) - ref_forces.generalized(qs, vs)
            bias = np.concatenate((bias_of(t), lock_bias))
            _, lam = constrained_accelerations(ref, qs, vs, J, bias, extra, forces=ref_forces)
            return dict(zip(labels, lam[m:].tolist()))
        forces.pure = True  # the same solve at each call: a function of (t, q, v) alone (_LastState)
        fast, why = _compiled_evaluator(cfg, ref, J, m, labels, mine, theirs, held, ref_forces, own, forces)
        self.evaluations[cfg.name] = "compiled" if fast is not None else f"python: {why}"
        chosen = fast or forces
        self._evaluator = (key, chosen)  # a bounce re-arms with the same holds: built once for its sequence
        return chosen

    # -- guards
    def unmerge_guards(self, cfg: Configuration) -> list[Guard]:
        """One guard per merge held by compression only: fires when its force would turn tensile.
        The guards share one evaluator; where it reads ``cfg``'s state through ``unpack`` (no compiled
        state map) and that is a function of ``(t, y)`` alone (:class:`_LastState`), they share its
        answer at the state asked last (the second guard at a step asks where the first just did)."""
        out = []
        forces = None
        for h in self.items:
            if not (h.merge and h.unilateral):
                continue
            self.release_target(h, cfg)  # a merge that could not be released here is an error now
            if forces is None:
                forces = self.evaluator(cfg)
                if getattr(forces, "at_state", None) is None and getattr(forces, "pure", False) \
                        and _state_map(cfg) is not None:
                    forces = _LastState(forces, cfg.coords.unpack)
            value = guard_value(cfg, forces, h.label)
            out.append(Guard(f"the merge of '{h.label}': its holding force turns tensile", value, -1,
                             "unmerge", h.transition, payload=h, holding=getattr(value, "holding", None)))
        return out


def decidable(cfg: Configuration, t: float, label: str, force: float) -> float:
    """``force``, the holding force ``label`` a guard reads; a SimulationError where it is NaN: the
    rows leave it statically indeterminate (:func:`pcmm.model.rows.determinate`), so whether it turns
    tensile depends on the parts' compliance, which pcmm does not model: no guard can read it."""
    if force == force:
        return force
    raise SimulationError(
        f"t = {t:.9g} s, configuration '{cfg.name}': a guard reads the holding force of '{label}', which the "
        "constraint rows leave statically indeterminate (redundant rows: any split of the load between them "
        "balances it; the run's warnings and `pcmm check` name them): whether it turns tensile cannot be "
        "decided without the parts' compliance. Remove the redundant row (a drive limited to the "
        "configurations where its joint is free, one cut joint fewer, or a joint fewer locked), or hold the "
        "merge for good (unmerge = false) and release it by a time or coordinate guard")


def guard_value(cfg: Configuration, forces, label: str, offset: float = 0.0):
    """``(t, y) -> forces(t, q, v)[label] - offset`` at ``cfg``'s integrator state: the value of a
    guard on a holding force (``forces``: a :meth:`Holds.evaluator`).  Where the evaluator is compiled
    with ``cfg``'s state map (``forces.at_state``) it reads the state itself, and carries ``holding``
    = (the compiled evaluator, the label's index, ``offset``): a compiled segment loop evaluates the
    very same call at each step's end (pcmm/model/_segment_loop.hpp); a state it cannot solve (the
    KKT solve fails) goes to the Python evaluator, as every call of a compiled evaluator does."""
    unpack = cfg.coords.unpack
    fast = getattr(forces, "at_state", None)
    if fast is None:
        if type(forces) is _LastState:  # the evaluator at the state, shared (unmerge_guards)
            def value(t, y):
                return forces.at(t, y)[label] - offset
            value.pure = True  # a function of (t, y) alone: pcmm.ode.integrators._pure_value
            return value

        def value(t, y):
            q, v = unpack(t, y)
            return decidable(cfg, t, label, forces(t, q, v)[label]) - offset
        return value
    i = forces.labels.index(label)
    at_state, python = fast.at_state, forces.python

    def value(t, y):
        lam = at_state(t, y)
        if lam is None:
            q, v = unpack(t, y)
            return decidable(cfg, t, label, python(t, q, v)[label]) - offset
        return float(lam[i]) - offset
    value.holding = (fast, i, float(offset))
    return value


def _same_bytes(a, b) -> bool:
    """A frozen state (:meth:`Coordinates.frozen_state`: a dict of arrays, numbers and dicts of arrays)
    equal to another one to the byte: the same keys, arrays of one dtype and shape with the same bytes
    (-0.0 and 0.0 differ here: such a state is made again, which is always right)."""
    if a is b:
        return True
    if type(a) is not type(b):
        return False
    if type(a) is dict:
        if a.keys() != b.keys():
            return False
        for k, x in a.items():
            if not _same_bytes(x, b[k]):
                return False
        return True
    if type(a) is np.ndarray:
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if type(a) in (int, float, str, bool):
        return a == b
    return False


class _LastState:
    """``forces(t, *unpack(t, y))`` of a holding-force evaluator (:meth:`Holds.evaluator`) at a
    configuration's integrator state, its answer at the last state kept.  Made where that is a function
    of ``(t, y)`` alone: the configuration's coordinates read without a Newton solve (:func:`_state_map`:
    a tree, or drives without a loop: no warm start) and an evaluator that solves the same system at each
    call (``pure``: not :meth:`Holds.forces` through a loop's rows).  The guards on one evaluator ask at the
    same state one after the other (a fully driven configuration's merges, two guards at every sample:
    pcmm.run.loop._known_motion, where the evaluator is not compiled with the state map), and the second
    gets the first's answer, the same dict, instead of a
    second unpack and solve (the same bits: the same call at the same arguments)."""

    __slots__ = ("forces", "unpack", "t", "y", "out")

    def __init__(self, forces, unpack):
        self.forces, self.unpack = forces, unpack
        self.t, self.y, self.out = None, None, None

    def at(self, t, y) -> dict:
        if t == self.t and self.y is not None and y.tobytes() == self.y:
            return self.out
        q, v = self.unpack(t, y)
        out = self.forces(t, q, v)
        self.t, self.y, self.out = t, y.tobytes(), out
        return out

    def __call__(self, t, q, v) -> dict:
        return self.forces(t, q, v)


def _state_map(cfg: Configuration):
    """``(free, driven, laws)``: ``cfg``'s integrator state is ``y = [q[free], q'[free]]`` with the
    coordinates ``driven`` prescribed by ``laws`` ((f, f') coefficients, low order first, as
    :class:`pcmm.model.rows.Drives` sums them): a tree, or drives without a loop (whose partition
    never changes); None otherwise (a loop's coordinates are solved, a planar joint's v is not q')."""
    coords = cfg.coords
    if cfg.has_planar:
        return None
    if not coords.constrained:
        return list(range(cfg.nv)), [], []
    closure, drives = getattr(coords, "closure", None), getattr(coords, "drives", None)
    if closure is None or drives is None or closure.size or len(set(drives.index)) != drives.size \
            or getattr(coords, "I", None) is None:
        return None
    return ([int(i) for i in coords.I], [int(i) for i in coords._driven],
            [(d[0], d[1]) for d in drives._derivs])


def _compiled_evaluator(cfg, ref, J, m, labels, mine, theirs, held, ref_forces, own, python):
    """(the compiled evaluator of :meth:`Holds.evaluator`, None) where it is ``python``'s to round-off
    at probe states (:data:`pcmm.model.compiled.AGREEMENT`), else (None, why).  It is ``python`` with
    the same solve in C++ (pcmm/model/_holding.hpp), and where ``cfg``'s state map is known
    (:func:`_state_map`) also reads ``cfg``'s integrator state (``at_state``), checked against
    ``python`` at ``cfg.coords.unpack`` of probe states; every call it cannot solve goes to ``python``."""
    if not compiled.enabled():
        return None, compiled.why_not() or "not compiled"
    if ref_forces.points is not None or (own is not None and own.points is not None):
        return None, "not compiled: point springs"
    drives = getattr(ref.coords, "drives", None)
    f2 = [] if drives is None or not drives.size else [d[2] for d in drives._derivs]
    if len(f2) != m:
        return None, "not compiled: the reference's rows are not its drives' alone"
    built = compiled.holding_forces(ref.model, ref_forces.Q0, ref_forces.KD, J, m, f2, mine, theirs, held, cfg.nv,
                                    None if own is None else (own.Q0, own.KD))
    if built is None:
        return None, compiled.why_not() or "not compiled"
    fast, checked = built
    key = ("holding", np.asarray(J).tobytes(), m, tuple(map(tuple, f2)), tuple(mine.tolist()), tuple(theirs.tolist()),
           held.tobytes(), cfg.nv, None if own is None else (own.Q0.tobytes(), own.KD.tobytes()))
    nv = cfg.nv
    probes = [(0.37 * (j + 1), y[:nv], y[nv:]) for j, y in enumerate(compiled._probe_states(nv))]
    try:
        same = compiled.agrees(checked, fast.forces, lambda t, q, v: np.array(list(python(t, q, v).values())), probes,
                               "holding forces", key=key + ("forces",))
    except (np.linalg.LinAlgError, SimulationError, ArithmeticError) as exc:  # the Python solve fails at a probe
        return None, f"not compiled: the Python holding forces could not be solved at a probe state ({exc})"
    if not same:
        return None, compiled.why_not() or "it disagrees with the Python holding forces"

    def forces(t, q, v):
        lam = fast.forces(t, q, v)
        if lam is None:  # the KKT solve failed: the Python evaluator decides, as it does
            return python(t, q, v)
        return dict(zip(labels, lam.tolist()))
    forces.labels, forces.python, forces.at_state = list(labels), python, None
    forces.pure = getattr(python, "pure", False)  # (its fallback's too)
    state = _state_map(cfg)
    if state is not None:
        free, driven, laws = state
        fast.set_state(free, driven, laws)
        k = len(free)
        unpack = cfg.coords.unpack
        # (every coordinate driven, k = 0: the state is empty, the probes are instants; at_state then
        # prescribes every coordinate by the Horner sums unpack does, the same bits: a fully driven
        # configuration's merges read their guards in one compiled call, pcmm.run.loop._known_motion)
        states = [(0.37 * (j + 1), y if k else y[:0]) for j, y in enumerate(compiled._probe_states(max(k, 1)))]
        try:
            if compiled.agrees(checked, fast.at_state,
                                     lambda t, y: np.array(list(python(t, *unpack(t, y)).values())), states,
                                     "holding forces at the state", key=key + ("state", tuple(free), tuple(driven))):
                forces.at_state = fast
        except (np.linalg.LinAlgError, SimulationError, ArithmeticError):
            pass  # the guards read (t, q, v) then: compiled, not scanned by the loop
    return forces, None
