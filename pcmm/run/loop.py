"""The configuration-complete simulation (paper Fig. 3).

Integrate the current configuration's dynamics (Eq. 1) until a guard fires
(:func:`integrate_segment`); do what that guard's kind does (one entry of
:data:`pcmm.run.actions.GUARD_ACTIONS`: solve the transformation - impulse, velocity jump,
configuration switch - or start or end a contact phase, or repartition a loop); go on in the
next configuration until ``t_end``.  The run's state is a :class:`~pcmm.run.state.RunState`;
segments are recorded by :mod:`pcmm.run.recording` and flights audited by
:mod:`pcmm.run.audit`.  With ``impact=False`` the transformations switch without impulse
(the paper's comparison runs).
"""
from __future__ import annotations

import math
import os
import time
import weakref
from dataclasses import replace

import numpy as np

from ..errors import ModelError, Repartition, SimulationError, UsageError
from ..events.contact import contact_row, contact_state, normal_speed
from ..events.guards import guard_residual, left_at_value, make_guard
from ..events.holding import Holds
from ..events.transitions import AT_REST_SPEED, POSE_TOL, Context
from ..model.assembly import assemble
from ..model.configuration import Configuration
from ..model.mechanism import Mechanism
from ..ode.integrators import EPS, INTEGRATORS, Segment, method_for
from ..results.segment_log import SegmentLog
from ..results.store import StoreWriter
from ..results.trajectory import RunStats, Trajectory, holding_extremes, merged_extremes, record_views
from ..scene.load import load_scene
from ..scene.settings import RunOptions, resolve
from ..scene.spec import Scene
from ..signals import deferred, describe, exit_status
from .actions import GUARD_ACTIONS, action_of
from .approach import closest_approach
from .audit import FlightAudit
from .guard_cache import GuardCache
from .recording import record as _record, recorded_steps
from .stability import diagnose, fixed_step_instability, largest_velocity, unphysical_speed
from .state import RunState


def initial_state(scene: Scene, cfg: Configuration):
    """The assembled initial ``(q, v, warnings)`` (:func:`pcmm.assembly.assemble`)."""
    try:
        return assemble(scene, cfg)
    except Repartition:  # the partition the kept joints force is ill-conditioned where the run starts
        raise SimulationError(
            f"{scene.path}: initial.independent = {list(scene.independent)}: keeping these joints makes the "
            "loop's dependent coordinates ill-conditioned at the initial posture; name other joints "
            "(or none, and pcmm picks the best-conditioned ones)") from None


def simulate(scene: Scene | str | os.PathLike, options: RunOptions = RunOptions(), progress=None,
             store=None) -> Trajectory:
    """Run ``scene`` configuration after configuration (paper Fig. 3).

    Parameters
    ----------
    scene : Scene or path
        A scene from :func:`pcmm.load_scene`, or a scene file's path (loaded here).
    options : RunOptions, optional
        Overrides of the scene's ``[solver]`` values and ``t_end``; ``impact=False``
        switches configurations without impulse (the paper's comparison runs).
    progress : callable, optional
        ``progress(t)`` is called after each segment and every few steps.
    store : path or StoreWriter, optional
        A new (or empty) folder the record streams to as the run goes, in chunks
        (:mod:`pcmm.results.store`): memory no longer grows with the run's length, and a run
        killed midway leaves every chunk written so far readable (``Trajectory.load(folder)``).
        The trajectory returned reads its segments and events from the folder.

    Returns
    -------
    Trajectory
        Samples of every segment, one event record (:class:`pcmm.events.EventRecord`)
        per transformation, and the run's stats.

    Raises
    ------
    UsageError
        An option or setting out of range (every one named).
    SimulationError
        The run cannot go on honestly (a singular posture, an impossible switch, too many
        events, ...).  On it, or on Ctrl-C, the exception carries the trajectory up to that
        point (``exc.partial``, status ``"partial"``), so no result is lost.

    Examples
    --------
    Example 1 of the paper: the metamorphic joint O3 latches at t_p (mobile impact).

    >>> import pcmm
    >>> scene = pcmm.load_scene("examples/three_bar.toml")
    >>> traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=0.2))
    >>> ev = traj.events[0]
    >>> round(ev["t"], 6), ev["kind"], ev["from"], ev["to"]
    (0.167285, 'mobile', 'config1', 'config2')
    >>> ev["kinetic_energy_after"] < ev["kinetic_energy_before"]
    True
    """
    run = start(_scene_of(scene, options), options, store)
    completed = False
    try:
        while True:
            # integrate the configuration's dynamics (Eq. 1) until a guard fires (Fig. 3)
            seg, guards = integrate_segment(run, progress)
            if seg is None:  # the partition degenerated mid-step: go on in a better one
                continue
            if seg.event is None:
                break
            run.t, run.y = float(seg.t[-1]), seg.y[:, -1]
            guard = guards[seg.event]
            run.q, run.v = _at_event(run.cfg.coords, seg, guard, run.q)
            # what the guard fires (the paper's Fig. 3 boxes): one entry per kind
            switched = GUARD_ACTIONS[action_of(run, guard)](run, guard)
            if switched and run.t >= run.opts.t_end:
                break
        completed = True
    except KeyboardInterrupt as exc:
        raise _interrupted(run, exc) from None
    except (ModelError, UsageError) as exc:  # a configuration's model first built mid-run: keep what ran
        run.traj.status, run.traj.message = "partial", exc.text()
        raise SimulationError(exc.problems, partial=run.traj) from None
    except SimulationError as exc:
        raise _stopped(run, exc)
    finally:  # a partial run keeps them too (pcmm derive writes what it reached)
        _finish(run, completed)
    # the guards that did not fire: computed when read (it reads the final segments' coordinates)
    run.stats.defer("closest_approach", lambda scene=run.scene, cfg=run.cfg, traj=run.traj:
                    closest_approach(scene, cfg, traj))
    if run.store is not None:  # the last chunk and the end record (its stats read now); a signal
        with deferred():  # meanwhile waits, and is dropped: the run is complete and returned whole
            run.store.end(run.traj)
    return run.traj


def _scene_of(scene, options) -> Scene:
    """The scene to run (loaded when given as a path); the options checked for their type."""
    if isinstance(scene, (str, os.PathLike)):
        scene = load_scene(scene)
    elif not isinstance(scene, Scene):
        raise UsageError(f"pcmm.simulate takes a Scene (pcmm.load_scene(path)) or a scene file's path, "
                         f"not {type(scene).__name__}")
    if not isinstance(options, RunOptions):
        raise UsageError(f"pcmm.simulate's options are a pcmm.RunOptions(...), not {type(options).__name__}")
    return scene


def start(scene: Scene, options: RunOptions, store=None) -> RunState:
    """The run's state at t = 0: the initial configuration assembled and checked, the locks it
    starts with, an empty record (streamed to ``store``, a folder, when given)."""
    opts = resolve(scene, options)
    mech = Mechanism(scene)
    traj = Trajectory(scene=str(scene.path.resolve()), scene_name=scene.name, impact=opts.impact,
                      views=record_views(scene), segments=SegmentLog())
    ctx = Context(mech, opts.impact, opts.accumulation_speed, opts.accumulation_interval,
                  forced_speed=options.accumulation_speed, forced_interval=options.accumulation_interval)
    stats = {"steps": 0, "rhs_evals": 0, "wall_s": 0.0, "record_s": 0.0, "impacts": 0,
             "constraint_drift_max": 0.0, "method": opts.method, "rtol": opts.rtol, "atol": opts.atol}
    traj.stats = stats
    cfg = mech[scene.initial_configuration]
    q, v, stats["warnings"] = initial_state(scene, cfg)
    check_start(scene, cfg, 0.0, q, v)
    holds = Holds(mech, opts.unmerge)
    holds.adopt(cfg, q, v)
    audit = FlightAudit()
    stats["macro_impacts"] = audit.macro_impacts
    traj.stats = RunStats(stats, holding=lambda: holding_extremes(traj))  # "holding": computed when read
    writer = None
    if store is not None:
        writer = store if isinstance(store, StoreWriter) else StoreWriter(store)
        writer.start(traj)  # the trajectory becomes the store's view
        # the holding extremes: each chunk's on its dense output as it is written (read back, it has none)
        writer.extremes_of = lambda segments: holding_extremes(traj, segments, merged_extremes(writer.extremes))
        traj.stats.defer("holding", lambda: merged_extremes(writer.extremes))
    return RunState(scene, opts, mech, ctx, traj, holds, audit, cfg, 0.0, q, v, store=writer)


def integrate_segment(run: RunState, progress):
    """Integrate ``run.cfg``'s dynamics from ``run.t`` until a guard fires (or ``t_end``) and
    record the segment.  Returns (segment, the guards it watched), or (None, guards) when the
    loop's partition degenerated mid-step (recorded up to there; ``run`` moved on to it)."""
    cfg, t = run.cfg, run.t
    y0 = cfg.coords.pack(t, run.q, run.v)
    # redundant rows the coordinates now solve without, holds they leave indeterminate: named once
    run.traj.stats["warnings"] += cfg.coords.take_notes() + run.holds.indeterminate_notes(cfg, t, run.q, run.v)
    guards = _guards(run.scene, cfg, run.holds, t, run.phase, run.bounced, run.fired, run.guard_cache)
    # a flight between two impacts at the same contact: its energy is audited (pcmm.run.audit)
    flight = run.bounced is not None and run.phase is None and y0.size > 0
    bounced, run.bounced = run.bounced, None
    leaving = []  # guards at their value whose contact does not approach (_pending): re-armed, not crossed
    pending = None if run.phase is not None else _pending(cfg, guards, t, y0, leaving)
    if run.phase is None:
        run.traj.stats["warnings"] += _releases_past_at_entry(cfg, guards, t, y0, run.releases_said,
                                                              bounced)
    leaving = [i for i in leaving if guards[i].transition is not bounced]  # (that one is re-armed already)
    if pending is None and leaving:
        guards = left_at_value(cfg, guards, leaving, t)
    fun = cfg.coords.rhs
    if run.phase is not None:  # the collision's impulse integrated with the state
        guards = [run.phase.end_guard()] + [g.on_state(y0.size) for g in guards]
        y0, fun = _appended(y0), run.phase.rhs()
    elif flight:  # integrated with its work appended, as it always was: that component takes part in
        # the step-size control, and the accumulation's series were measured with it (the audit
        # itself measures the work by its own quadrature, pcmm.run.audit)
        guards = _on_state(guards, y0.size, run.guard_cache)
        y0, fun = _appended(y0), cfg.coords.rhs_with_power
    stepping = run.stepping = (fun, method_for(run.opts.method, cfg.coords.constrained), run.opts)  # for dense resampling
    # a flight keeps each step's dense output as taken, for its audit (measured when it ends, then dropped)
    seg = _integrate(run, _reporting(fun, progress) if progress is not None else fun, stepping, y0, guards, pending,
                     keep_dense=flight)
    if seg is None:
        return None, guards
    _record(run.traj, cfg, seg, run.offsets, run.q, run.holds, stepping)
    run.impulse_integral = 0.0
    if run.phase is not None:
        run.impulse_integral = float(seg.y[-1, -1])
        seg.y = seg.y[:-1]
    elif flight:
        run.audit.flight(cfg, recorded_steps(run.traj, seg, run.q), stepping,
                         *cfg.coords.unpack(float(seg.t[-1]), seg.y[:-1, -1]), kept=seg.dense)
        seg.y, seg.dense = seg.y[:-1], None
    if run.store is not None and run.store.due(run.traj):
        _write_chunk(run)
    if progress:
        progress(float(seg.t[-1]))
    return seg, guards


def _write_chunk(run: RunState) -> None:
    """The chunk being filled is full: its segments and events go to the store, and the run goes
    on with empty logs (every segment's series are derived now, not when the run has ended; its
    flights were audited as each ended)."""
    with deferred() as held:  # a Ctrl-C or SIGTERM meanwhile waits until the chunk is written
        run.store.aside(lambda: run.store.flush(run.traj))  # on a thread of its own: the run's Pinocchio data left alone
    held.reraise()


#: segments that end in a new partition before their first step, at the same instant this many times
#: running, stop the run (it would repeat for ever)
_STALLED_REPARTITIONS = 16


def _at_last_step(coords, seg: Segment, q_start):
    """``(q, v)`` at the last accepted step of a segment that ended in a new partition
    (:class:`~pcmm.errors.Repartition`), started from the assembled ``q_start``: followed along the
    segment's steps from its start by a reader of it (``restored``, as its series are read), on the
    run's own assembly branch, not solved from the loop's warm starts.  The step that was abandoned
    left those anywhere along its trial stages and its guards' samples, up to across the change point
    that ended it, and the last 8 of them pushed the accepted step's own solution out: solved from the
    nearest, 1.2 rad off (a coasting parallelogram's step across its change point), Newton landed on
    another assembly (the crank 12 rad off) and the next segment started there
    (tests/test_loop_turns.py).  A segment of one step (none accepted) is its start, solved as before."""
    t = float(seg.t[-1])
    if seg.t.size == 1:
        return coords.unpack(t, seg.y[:, -1])
    with coords.restored(coords.frozen_state(), q_start, steps=(seg.t, seg.y)) as reader:
        q, v = reader.unpack(t, seg.y[:coords.ny, -1])
    # The run's own solution at that step, where it is the reader's posture (the same assembly, no
    # whole turns), is kept: near the degenerate block that ended the segment the two solves agree
    # only to their residual over the block's smallest singular value (2.5e-8 rad/s apart on
    # tests/test_planar_base.py's pinned bar, whose run then parts from the revolute pendulum's by
    # 2.5e-8 instead of 9.2e-9), and the reader is here to catch another assembly, not to move
    # the run within its own.
    try:
        q_own, v_own = coords.unpack(t, seg.y[:, -1])
    except SimulationError:
        return q, v
    return (q_own, v_own) if float(np.max(np.abs(q_own - q), initial=0.0)) <= SAME_ASSEMBLY else (q, v)


#: how far the run's own solution at a segment's last step may be from its reader's and still be
#: the same posture (the solves' disagreement near a degenerate block is about 1e-8)
SAME_ASSEMBLY = 1e-6


def _at_event(coords, seg: Segment, guard, q_start):
    """``(q, v)`` where a segment ended at its guard: the run's own solution there; where the guard is
    a loop's singularity guard (its partition degenerates, the next segment starts a new one), the
    posture its reader follows along the segment (:func:`_at_last_step`) wherever the run's own lies on
    another assembly.  The event was located by solves warm-started from the step's samples, up to
    across the change point: at 0.613 rad (benchmarks/change_point_survey.py, "auto") they put the
    event on the anti-parallelogram, (3.213, -3.177, 3.106) for (3.106, -3.106, 3.106), and the next
    segment went on there (tests/test_loop_turns.py).  A reader that cannot follow the segment (a
    singular posture on the way) leaves the run's own: the new partition decides there."""
    if guard.action != "repartition" or getattr(guard, "payload", None) is not None or seg.t.size < 2:
        return coords.unpack(float(seg.t[-1]), seg.y[:, -1])
    try:
        return _at_last_step(coords, seg, q_start)
    except SimulationError:
        return coords.unpack(float(seg.t[-1]), seg.y[:, -1])


def _integrate(run: RunState, fun, stepping, y0, guards, pending, keep_dense=False) -> Segment | None:
    """One segment from ``run.t``: simultaneous (a contact already closed), integrated, or a known
    motion (no free coordinate).  Its steps and time count in the stats, also when it fails.
    ``keep_dense``: the segment keeps its steps' dense outputs (:attr:`Segment.dense`)."""
    cfg, t, opts, stats = run.cfg, run.t, run.opts, run.stats
    method = stepping[1]
    t0 = time.perf_counter()
    try:
        if pending is not None:  # a contact already closed at this instant (simultaneous impacts)
            seg = Segment(np.array([t]), y0[:, None], pending, 0, 0, 1, "simultaneous")
        elif y0.size:
            unstable = method.fixed_step and fixed_step_instability(cfg, stepping[0], t, y0, opts.step, method.name)
            if unstable:  # the step alone would make the motion grow: say so, before any symptom
                raise SimulationError(unstable)
            seg = method.integrate(fun, t, y0, opts.t_end, guards, opts, keep_dense=keep_dense)
        else:  # no free coordinate: the motion is a known function of time, not integrated
            seg = _known_motion(cfg, t, y0, guards, opts)
    except Repartition as exc:  # a loop's dependent block degenerated: new partition, go on
        seg = exc.segment
        held = t  # the instant, whatever partition each attempt chose
        last = getattr(run, "_repartitioned", None)
        repeats = last[1] + 1 if seg.t.size == 1 and last is not None and last[0] == held else 0
        if repeats >= _STALLED_REPARTITIONS:  # new partitions again and again at one instant: for ever
            raise SimulationError(
                f"configuration '{cfg.name}': at t = {t:.9g} s the loop's partition of its coordinates "
                f"degenerates within the integrator's first trial step (at t = {exc.args[0] if exc.args else t:.9g} s), "
                f"{_STALLED_REPARTITIONS} times running, whatever partition is chosen at t: the posture is next to a change point or dead centre, "
                "where no partition holds across the step; a smaller solver.max_step lets the integrator "
                "approach it (pcmm then stops at the singular posture, or passes it where the motion is determined)") from None
        run._repartitioned = (held, repeats) if seg.t.size == 1 else None
        _record(run.traj, cfg, seg, run.offsets, run.q, run.holds, stepping)
        run.t = float(seg.t[-1])
        run.q, run.v = _at_last_step(cfg.coords, seg, run.q)
        return None
    except (SimulationError, KeyboardInterrupt) as exc:
        if getattr(exc, "segment", None) is not None:  # the steps the failing segment took count
            stats["steps"] += exc.segment.nsteps
            stats["rhs_evals"] += exc.segment.nfev
            if exc.segment.t.size > 1:
                _record(run.traj, cfg, exc.segment, run.offsets, run.q, run.holds, stepping)
            at, stop = getattr(exc, "at", None), float(exc.segment.t[-1])
            if isinstance(exc, SimulationError) and at is not None and at != stop:
                exc.problems[-1] += (f"; the run stopped at t = {stop:.9g} s, its last accepted step "
                                     f"(t = {at:.9g} s was a trial instant of the next one)")
        raise
    finally:
        stats["wall_s"] += time.perf_counter() - t0
    stats["steps"] += seg.nsteps
    stats["rhs_evals"] += seg.nfev
    if seg.status < 0:
        raise SimulationError(f"the integrator ({method.name if y0.size else 'RK4'}) failed at t = {seg.t[-1]:.9g} s in "
                              f"configuration '{cfg.name}': {seg.message}")
    return seg


def _interrupted(run: RunState, exc: KeyboardInterrupt) -> SimulationError:
    """Ctrl-C or SIGTERM: the partial run, with the shell's exit status (130, 143)."""
    traj = run.traj
    traj.status, traj.message = "partial", f"{run.scene.path}: {describe(exc)} at t = {_t_last(traj):.6g} s"
    err = SimulationError(traj.message, partial=traj)
    err.exit_code = exit_status(exc)
    err.interrupted = True  # stopped, not failed: the CLI keeps the partial even before its first sample
    return err


def _stopped(run: RunState, exc: SimulationError) -> SimulationError:
    """A run that cannot go on: its messages name the scene file, and it carries the partial run.
    A blown-up state is blamed on the integration, not on what failed in it."""
    blown = diagnose(run.cfg, exc, run.t, run.q, run.v, run.stepping[1], run.opts.step) if run.stepping else None
    if blown:
        exc.problems = [blown]
    where = str(run.scene.path)
    exc.problems = [p if p.startswith(where) else f"{where}: {p}" for p in exc.problems]
    exc.args = (exc.text(),)
    run.traj.status, run.traj.message = "partial", exc.text()
    exc.partial = run.traj
    return exc


def _finish(run: RunState, completed: bool) -> None:
    """What every run keeps, a partial one too: the configurations built and their evaluations
    (the flights' energy balances were measured as each ended)."""
    stats, mech = run.stats, run.mech
    stats["configurations_built"] = list(mech.built)
    stats["derived_configurations"] = mech.derived
    # which evaluations each configuration ran: "compiled", or "python" and why (pcmm.compiled)
    stats["evaluations"] = {name: mech[name].coords.evaluations for name in mech.built}
    # and the holding forces of each configuration's locks: "compiled", or "python" and why (pcmm.events.holding)
    stats["holding_evaluations"] = dict(run.holds.evaluations)
    if run.store is not None and not completed:  # a stopped run's store ends here
        run.store.end(run.traj)


def check_start(scene: Scene, cfg: Configuration, t, q, v) -> None:
    """The initial state must be one a run can start from honestly: finite energies (a huge
    velocity overflows them), and no body already inside a stop - a guard on its fired side
    while its contact approaches (or, for a gap guard, penetrates) would never change sign, and
    the body would fall through with no event."""
    fast = unphysical_speed(cfg, q, v)
    if fast:
        raise SimulationError(f"{scene.path}: initial.v: {fast} at t = {t:g} s: the initial velocities are not "
                              f"physical (the largest: {largest_velocity(cfg, v)}); check initial.v and its units "
                              "(rad/s for a revolute joint, m/s for a slider)")
    ke, pe = cfg.kinetic_energy(q, v), cfg.potential_energy(q)
    if not (math.isfinite(ke) and math.isfinite(pe)):
        raise SimulationError(f"{scene.path}: the initial state's kinetic energy ({ke:.3g} J) or potential "
                              f"energy ({pe:.3g} J) is not finite: initial.q / initial.v (or a mass or inertia) "
                              "are too large for floating point")
    y0 = cfg.coords.pack(t, q, v)
    for tr in scene.transitions_from(cfg.name):
        if tr.guard.type not in ("coordinate", "gap") or tr.contact is None:
            continue
        past = tr.guard.direction * guard_residual(cfg, tr, t, y0)
        if not past > POSE_TOL * max(1.0, abs(tr.guard.value)):
            continue
        _, gap, vn, _ = contact_state(cfg, q, v, tr.contact)
        if tr.guard.type == "gap" or vn < 0:
            # along -n the gap is -gap: were the normal flipped, would the run start on the guard's near side?
            flipped = tr.guard.type == "gap" and tr.guard.direction * (-gap - tr.guard.value) <= 0
            flip = (f"; or, if they are apart already (b's point {abs(gap):.3g} m from a's along -n, on the side "
                    f"opposite the normal), the normal points from b to a: flip contact.normal to "
                    f"[{-tr.contact.normal[0] + 0.0:g}, {-tr.contact.normal[1] + 0.0:g}]" if flipped else "")
            raise SimulationError(
                f"{scene.path}: transition '{tr.name}': the run starts on the far side of its guard "
                f"({'gap' if tr.guard.type == 'gap' else str(tr.guard.measure)} is {past:.3g} past the "
                f"value {tr.guard.value:g} in its direction) while the contact "
                f"{'penetrates' if tr.guard.type == 'gap' else 'approaches'}: the bodies start inside the "
                f"stop, and the guard would never fire; start the bodies apart (initial.q){flip}")


KNOWN_MOTION_SAMPLES = 200  # samples of a locked or fully driven stay (at most, and at least 1 / step)


def _known_motion(cfg: Configuration, t, y0, guards, opts) -> Segment:
    """A stay without a free coordinate (every joint locked or driven): the state is a known
    function of time, so nothing is integrated.  The motion is evaluated at samples only (the
    loop closed by Newton there, warm-started from the nearest recent solution), at
    most ``KNOWN_MOTION_SAMPLES`` per stay and no further apart than ``max_step``, nor closer
    than ``step``.  Between samples the guards are scanned like any step's (a sign change, or
    the cubic Hermite model of their values and rates dipping across), and a crossing is
    located on the motion itself, exact to ``event_tol``: the "dense output" of an empty state
    is the function of time.  Each sample assembles the loop, so a posture it cannot reach
    stops the run."""
    span = max(opts.t_end - t, 1e-12)
    step = min(opts.max_step, max(opts.step, span / KNOWN_MOTION_SAMPLES))

    def assemble(t, y):
        cfg.coords.unpack(t, y)
        return y
    try:
        return INTEGRATORS["RK4"].integrate(assemble, t, y0, opts.t_end, guards, replace(opts, step=step))
    except SimulationError as exc:
        seg = getattr(exc, "segment", None)
        if seg is not None and seg.t.size:
            # samples are far apart: the last instant the loop still assembles, by bisection, ends
            # the kept samples (where a lock jams a drive, or a posture becomes unreachable)
            lo, hi = float(seg.t[-1]), min(float(seg.t[-1]) + step, opts.t_end)
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                try:
                    cfg.coords.unpack(mid, y0)
                    lo = mid
                except (SimulationError, Repartition):
                    hi = mid
            if lo > seg.t[-1]:
                seg.t = np.append(seg.t, lo)
                seg.y = np.zeros((0, seg.t.size))
        raise


def _guards(scene: Scene, cfg: Configuration, holds: Holds, t: float, phase, bounced, fired=(),
            cache: GuardCache | None = None) -> list:
    """Every guard watched in ``cfg`` from ``t``: its transitions' (the one that just bounced
    re-armed), one per merge held by compression only, and a loop's partition guard.  A time
    guard ``at = T`` is one instant of the run: once its transition has fired it is not watched
    again (re-entered at T itself it would fire again, for ever).

    ``cache`` (the run's :class:`~pcmm.run.guard_cache.GuardCache`; None: everything built): outside
    a contact phase, the same configuration, bounced stop, angle offsets and holds as the last
    segment take the last segment's list (a bounce's re-arm, one look-up); else the transitions'
    guards kept for this configuration, bounced stop and offsets are taken again (where every
    transition watches a coordinate or a gap: functions of the state alone, not of ``t``, the holds
    or the events so far), else they are built; the merges' guards likewise
    (:func:`_unmerge_guards`)."""
    offsets = cfg.angle_offsets  # (a sorted tuple built per read: read once, for every look-up below)
    if cache is not None and phase is None:
        out = cache.take_last(cfg, bounced, offsets, holds.items)
        if out is not None:
            return out + cfg.coords.guards()
    kept = cache.transitions_for(cfg, bounced, offsets) if cache is not None and phase is None else None
    if kept is not None:
        out = list(kept)
    else:
        out = []
        reusable = phase is None
        for tr in scene.transitions_from(cfg.name):
            reusable = reusable and tr.guard.type in ("coordinate", "gap")
            if phase is not None and tr is phase.tr:
                continue
            if tr.guard.type == "time" and tr.guard.at is not None and tr.name in fired:
                continue
            if tr.guard.type == "entry" and phase is not None:  # fired where the collision ends (_pending)
                continue
            g = make_guard(cfg, tr, rearm=tr is bounced, context=holds if tr.guard.type == "reaction" else t)
            if g is not None:
                out.append(g)
        if cache is not None:
            cache.keep_transitions(cfg, bounced, offsets, tuple(out) if reusable else None)
    out += _unmerge_guards(cfg, holds, phase, cache, offsets)
    if cache is not None:  # the list for the next segment, where both kept sets stand for this one
        cache.keep_last(cfg, bounced, offsets, holds.items, out)
    out += cfg.coords.guards()  # the coordinates' own: a loop's partition guard
    return out


def _unmerge_guards(cfg: Configuration, holds: Holds, phase, cache: GuardCache | None, offsets=None) -> list:
    """The guards of the merges held by compression only (:meth:`Holds.unmerge_guards`).  ``cache``:
    outside a contact phase, the last segment's are taken again where it was in the same configuration
    (the same object), with the same angle offsets and holds (the same ``Hold`` objects): the run has
    stayed in ``cfg`` since (a bounce does not switch), so nothing their holding-force evaluator was
    built from has changed (the reference configuration changes only when the run enters it, the holds
    only by a lock, a release or a switch), and a sequence of bounces builds them once.  ``offsets``:
    ``cfg.angle_offsets`` where the caller has read them."""
    if cache is None:
        return holds.unmerge_guards(cfg)
    items = holds.items
    if offsets is None:
        offsets = cfg.angle_offsets
    if phase is None:
        kept = cache.merges_for(cfg, offsets, items)
        if kept is not None:
            return list(kept)
    out = holds.unmerge_guards(cfg)
    cache.keep_merges(cfg, offsets, items, tuple(out) if phase is None else None)
    return out


def _appended(y0: np.ndarray) -> np.ndarray:
    """``y0`` with a 0.0 appended (``np.append(y0, 0.0)``'s values, without its ravel and dispatch)."""
    y = np.empty(y0.size + 1)
    y[:-1] = y0
    y[-1] = 0.0
    return y


def _on_state(guards: list, n: int, cache: GuardCache) -> list:
    """Each guard read on the first ``n`` components of the state (:meth:`Guard.on_state`): where the
    guards are the very objects of the last flight (a sequence of bounces re-arming with the kept
    guards, :func:`_guards`), the copies ``cache`` kept of them are taken again."""
    kept = cache.on_state_for(guards, n)
    if kept is not None:
        return list(kept)
    out = [g.on_state(n) for g in guards]
    cache.keep_on_state(guards, n, out)
    return out


def _releases_past_at_entry(cfg: Configuration, guards, t, y0, said: set, bounced=None) -> list[str]:
    """Warnings, once per configuration and release: a scene's release whose reaction guard (on a
    lock's holding force) is already past its value where a segment of ``cfg`` starts: where the run
    enters ``cfg``, or after a bounce in it (``bounced``, the stop: its impulse changes the velocities,
    and so the holding force, at once, which is no crossing).  A guard fires on a crossing in its
    direction only, so such a release waits for the force to come back and cross again, and may never
    fire; the run's closest approach describes the final configuration only (a kneed walker's
    trailing knee, tensile from the heel strike on, stayed locked for the whole step and nothing said
    so)."""
    out = []
    for g in guards:
        tr = g.transition
        if (g.action != "transition" or tr is None or tr.type != "release" or tr.guard.type != "reaction"
                or any(s.name == tr.guard.of for s in cfg.spec.cut_joints)):
            continue
        if (cfg.name, tr.name) in said:  # (``said``: the run's pairs said so far, added to here)
            continue
        past = tr.guard.direction * g(t, y0)
        if past > 0:
            said.add((cfg.name, tr.name))
            key = f"configuration '{cfg.name}': the release '{tr.name}' watches"
            way = "increasing" if tr.guard.direction > 0 else "decreasing"
            where = (f"it is already {past:.6g} past that value where the configuration is entered" if bounced is None
                     else f"the bounce at '{bounced.name}' left it {past:.6g} past that value (an impulse changes "
                     "it at once, which is no crossing)")
            advice = ("; a release meant at the instant the configuration is entered takes "
                      "guard = { type = \"entry\" }" if bounced is None else "")
            out.append(f"t = {t:.9g} s, {key} the holding force of '{tr.guard.of}' cross {tr.guard.value:.9g} "
                       f"{way}, but {where}: a guard fires on a crossing in its direction only, so the release "
                       f"waits for the force to come back and cross again (it may never fire){advice}")
    return out


def _pending(cfg: Configuration, guards, t, y0, leaving=None):
    """Index of a guard that is already at or past its crossing at the start of a segment
    while its contact still approaches: a contact that closed at the same instant as the
    impact just resolved; or a merge (or a pinned point) whose holding force is already tensile (it never held).  It is resolved now, before any integration (sequential impacts
    in scene order); a step would never see it change sign.  The state is unpacked to ``(q, v)``
    only where a contact's normal speed needs it (a joint stop whose rate is an entry of the state
    reads it there: :func:`_stop_speed`).  ``leaving`` (a list, where given): the indices of the
    guards read at their crossing whose contact separates or rests pulled apart, before the first
    pending one (the segment watches them re-armed: :func:`pcmm.events.guards.left_at_value`).  A
    guard with no contact (a release's coordinate or gap guard) at its value is pending where its own
    rate approaches its fired side, else listed leaving (:func:`_guard_approaches`).  A release fired on
    entry (``guard = { type = "entry" }``) is pending at the first segment of its configuration: its
    event is kept at the entry instant, after the event that entered, and nothing is integrated in the
    configuration (the loader refuses a cycle of them, :meth:`pcmm.scene.load._Builder._entry_guards`)."""
    state = None  # (q, v), when first needed
    for i, g in enumerate(guards):
        if g.action in ("unmerge", "lift-off") and g(t, y0) < 0:
            return i  # the merge or pin would have to pull from its first instant: the bodies separate now
        tr = g.transition
        if g.action == "transition" and tr.guard.type == "entry":
            return i
        if g.action != "transition" or tr.guard.type not in ("coordinate", "gap"):
            continue
        value = tr.guard.direction * g(t, y0)
        # round-off puts a state that is exactly at the guard (a joint freed by a release at its
        # latch value, re-read from the links' poses) on either side of it by an ulp or two
        at_value = 64 * EPS * max(1.0, abs(tr.guard.value))
        if value < -at_value or value > POSE_TOL:  # not at its crossing (far past it: entered from the other side)
            continue
        if tr.contact is None:  # a release's own guard: no contact, its own rate says where the state goes
            if g.rate is None:  # (no rate to re-arm it with: read plain)
                continue
            if _guard_approaches(cfg, g, t, y0):
                return i
            if leaving is not None:
                leaving.append(i)
            continue
        vn = _stop_speed(cfg.coords, cfg, y0, tr.contact)
        if vn is None:
            if state is None:
                state = cfg.coords.unpack(t, y0)
            vn = normal_speed(cfg, *state, tr.contact)
        if vn < -AT_REST_SPEED:
            return i
        if abs(vn) <= AT_REST_SPEED:
            if state is None:
                state = cfg.coords.unpack(t, y0)
            if _pushed_closed(cfg, t, *state, tr.contact):
                # at rest against the contact and pushed into it: it closes now (with no impulse),
                # whichever side of the guard round-off left the state on
                return i
        if leaving is not None:  # separating, or at rest pulled apart: at its value, not at a crossing
            leaving.append(i)
    return None


def _guard_approaches(cfg: Configuration, g, t, y0) -> bool:
    """Does the state move ``g``'s value towards its fired side beyond round-off (its rate along the
    flow, read as a re-armed guard reads it: :func:`pcmm.events.guards.make_guard`)?  For a guard with
    no contact (a release's) sitting at its value: it fires now where it does, else the segment watches
    it re-armed, so a state at rest there fires it at the first instant the loads carry it over and
    never where they carry it away (round-off put the start on either side of the value: on the fired
    side the crossing was missed, exactly at it the guard fired, tests/test_release_latch.py)."""
    rate = g.rate(t, y0, None if g.rate_from_state else cfg.coords.rhs(t, y0))
    return g.direction * rate > AT_REST_SPEED


#: {coordinates: {joint coordinate: where its rate sits in the state, or None}} (``state_entry``)
_RATE_ENTRIES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _stop_speed(coords, cfg: Configuration, y0, contact):
    """A joint stop's normal speed ``-s v_j`` (:func:`normal_speed`'s ``J_n v``, the same number) read
    off the state where the joint's rate is an entry of it (``coords.state_entry``: a tree's, or a free
    coordinate beside drives without a loop; its rate is then its velocity); None otherwise."""
    if contact.joint is None:
        return None
    j = cfg.joint_slice[contact.joint].start
    entries = _RATE_ENTRIES.get(coords)
    if entries is None:
        entries = _RATE_ENTRIES[coords] = {}
    if j not in entries:
        at = coords.state_entry(j)
        entries[j] = None if at is None or cfg.joint_slice[contact.joint].stop - j != 1 else at[1]
    r = entries[j]
    return None if r is None else float(-contact.stop_sign * y0[r])


def _pushed_closed(cfg: Configuration, t, q, v, contact) -> bool:
    """Is the contact's normal velocity, at rest, driven negative (closing) by the configuration's
    dynamics, beyond round-off?  (Where a compression-only merge was just undone its holding force
    was zero, and so is this acceleration, to 1e-15: that is no push either way.)"""
    a, _ = cfg.coords.accelerations(t, q, v)
    Jn, bias = contact_row(cfg, q, v, contact)
    a_n = float(Jn @ a + bias)
    return a_n < -1e-9 * max(1.0, float(np.max(np.abs(a), initial=0.0)))


def _reporting(fun, progress, every: int = 256):
    """Wrap a right-hand side so ``progress(t)`` is called every ``every`` evaluations
    (a long segment without events still moves the progress bar)."""
    count = [0]

    def f(t, y):
        count[0] += 1
        if count[0] % every == 0:
            progress(float(t))
        return fun(t, y)
    f.__wrapped__, f.progress = fun, progress  # a compiled segment loop steps fun itself and reports progress
    return f


def _t_last(traj: Trajectory) -> float:
    return float(traj.segments[-1].t[-1]) if traj.segments else 0.0
