"""The configuration-complete simulation (paper Fig. 3).

Integrate the current configuration's dynamics (Eq. 1) until a guard fires;
solve the transformation (impulse, velocity jump, configuration switch); go
on in the next configuration until ``t_end``.  With ``impact=False`` the
transformations switch without impulse (the paper's comparison runs).
"""
from __future__ import annotations

import math
import os
import threading
import time
from dataclasses import replace

import numpy as np

from .approach import closest_approach
from .audit import FlightAudit
from .dense import dense_states
from ..model.assembly import assemble
from ..model.configuration import Configuration
from ..events.contact import contact_point, contact_row, contact_state
from ..events.contact_laws import ContactPhase
from ..errors import ModelError, Repartition, SimulationError, UsageError
from ..events.guards import guard_residual, make_guard
from ..events.holding import Holds
from ..model.mechanism import Mechanism
from ..ode.integrators import EPS, INTEGRATORS, METHODS, Segment, method_for
from ..scene.settings import RunOptions, resolve
from ..signals import deferred, describe, exit_status
from ..scene.load import load_scene
from ..scene.spec import Scene
from ..results.trajectory import RunStats, SegmentRecord, Trajectory, holding_extremes, record_views
from ..events.records import EventRecord, event_dict
from ..events.transitions import POSE_TOL, TRANSITIONS, Context, unmerge


def initial_state(scene: Scene, cfg: Configuration):
    """The assembled initial ``(q, v, warnings)`` (:func:`pcmm.assembly.assemble`)."""
    try:
        return assemble(scene, cfg)
    except Repartition:  # the partition the kept joints force is ill-conditioned where the run starts
        raise SimulationError(
            f"{scene.path}: initial.independent = {list(scene.independent)}: keeping these joints makes the "
            "loop's dependent coordinates ill-conditioned at the initial posture; name other joints "
            "(or none, and pcmm picks the best-conditioned ones)") from None


#: this many configuration switches at one instant are a cycle that time does not pass in
ZERO_TIME_CYCLE = 64


def _zero_time_cycle(events: list[dict]) -> str:
    """The transitions of a cycle of switches at one instant ('' if the last ``ZERO_TIME_CYCLE``
    events are not one): with no time passing no impulse can end it, as a macro-impact's
    accumulation ends a bounce sequence, and only the event budget would stop the run."""
    tail = events[-ZERO_TIME_CYCLE:]
    if len(tail) < ZERO_TIME_CYCLE or tail[0]["t"] != tail[-1]["t"] or any(e["from"] == e["to"] for e in tail):
        return ""
    return ", ".join(dict.fromkeys(f"'{e['name']}' ({e['from']} -> {e['to']})" for e in tail))


def simulate(scene: Scene | str | os.PathLike, options: RunOptions = RunOptions(), progress=None) -> Trajectory:
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
    if isinstance(scene, (str, os.PathLike)):
        scene = load_scene(scene)
    elif not isinstance(scene, Scene):
        raise UsageError(f"pcmm.simulate takes a Scene (pcmm.load_scene(path)) or a scene file's path, "
                         f"not {type(scene).__name__}")
    if not isinstance(options, RunOptions):
        raise UsageError(f"pcmm.simulate's options are a pcmm.RunOptions(...), not {type(options).__name__}")
    opts = resolve(scene, options)
    mech = Mechanism(scene)
    traj = Trajectory(scene=str(scene.path.resolve()), scene_name=scene.name, impact=opts.impact,
                      views=record_views(scene))
    ctx = Context(mech, opts.impact, opts.accumulation_speed, opts.accumulation_interval,
                  forced_speed=options.accumulation_speed, forced_interval=options.accumulation_interval)
    stats = {"steps": 0, "rhs_evals": 0, "wall_s": 0.0, "record_s": 0.0, "impacts": 0,
             "constraint_drift_max": 0.0, "method": opts.method, "rtol": opts.rtol, "atol": opts.atol}
    traj.stats = stats
    cfg = mech[scene.initial_configuration]
    t = 0.0
    q, v, stats["warnings"] = initial_state(scene, cfg)
    check_start(scene, cfg, t, q, v)
    offsets: dict[str, float] = {}
    fired: set[str] = set()  # the names of the events so far (a time guard at = T fires once in a run)
    holds = Holds(mech, opts.unmerge)  # joints locked by latches and stop-merges, watched while they hold
    holds.adopt(cfg, q, v)
    phase: ContactPhase | None = None  # a collision resolved by a continuous contact law
    bounced = None  # the stop that just bounced: its guard is re-armed (see guards.make_guard)
    audit = FlightAudit()
    stats["macro_impacts"] = audit.macro_impacts
    stats = traj.stats = RunStats(stats, holding=lambda: holding_extremes(traj))  # "holding": computed when read
    completed = False
    try:
        while True:
            # integrate the configuration's dynamics (Eq. 1) until a guard fires (Fig. 3)
            y0 = cfg.coords.pack(t, q, v)
            guards = _guards(scene, cfg, holds, t, phase, bounced, fired)
            # a flight between two impacts at the same contact: its energy is audited (pcmm.run.audit)
            flight = audit.in_flight and phase is None and y0.size > 0
            bounced = None
            pending = None if phase is not None else _pending(cfg, guards, t, y0)
            fun = cfg.coords.rhs
            if phase is not None:
                guards = [phase.end_guard()] + [g.on_state(y0.size) for g in guards]
                y0, fun = np.append(y0, 0.0), phase.rhs()
            elif flight:  # integrated with its work appended, as it always was: that component takes part
                # in the step-size control, and the accumulation's series were measured with it (the
                # audit itself measures the work by its own quadrature, pcmm.run.audit)
                guards = [g.on_state(y0.size) for g in guards]
                y0, fun = np.append(y0, 0.0), cfg.coords.rhs_with_power
            stepping = (fun, method_for(opts.method, cfg.coords.constrained), opts)  # for dense resampling
            if progress is not None:
                fun = _reporting(fun, progress)
            t0 = time.perf_counter()
            try:
                method = stepping[1]
                if pending is not None:  # a contact already closed at this instant (simultaneous impacts)
                    seg = Segment(np.array([t]), y0[:, None], pending, 0, 0, 1, "simultaneous")
                elif y0.size:
                    seg = method.integrate(fun, t, y0, opts.t_end, guards, opts)
                else:  # no free coordinate: the motion is a known function of time, not integrated
                    seg = _known_motion(cfg, t, y0, guards, opts)
            except Repartition as exc:  # a loop's dependent block degenerated: new partition, go on
                seg = exc.segment
                _record(traj, cfg, seg, offsets, q, holds, stepping)
                t = float(seg.t[-1])
                q, v = cfg.coords.unpack(t, seg.y[:, -1])
                continue
            except (SimulationError, KeyboardInterrupt) as exc:
                if getattr(exc, "segment", None) is not None:  # the steps the failing segment took count
                    stats["steps"] += exc.segment.nsteps
                    stats["rhs_evals"] += exc.segment.nfev
                    if exc.segment.t.size > 1:
                        _record(traj, cfg, exc.segment, offsets, q, holds, stepping)
                raise
            finally:
                stats["wall_s"] += time.perf_counter() - t0
            stats["steps"] += seg.nsteps
            stats["rhs_evals"] += seg.nfev
            if seg.status < 0:
                raise SimulationError(f"the integrator ({method.name if y0.size else 'RK4'}) failed at t = {seg.t[-1]:.9g} s in "
                                      f"configuration '{cfg.name}': {seg.message}")
            impulse_integral = 0.0
            _record(traj, cfg, seg, offsets, q, holds, stepping)
            if phase is not None:
                impulse_integral = float(seg.y[-1, -1])
                seg.y = seg.y[:-1]
            elif flight:
                audit.flight(cfg, seg.t, seg.y, stepping, q, *cfg.coords.unpack(float(seg.t[-1]), seg.y[:-1, -1]))
                seg.y = seg.y[:-1]
            if progress:
                progress(float(seg.t[-1]))
            if seg.event is None:
                break
            t = float(seg.t[-1])
            q, v = cfg.coords.unpack(t, seg.y[:, -1])
            guard = guards[seg.event]
            # what the guard fires (the paper's Fig. 3 boxes)
            if guard.action == "repartition":
                # the coordinates' own guard: the partition degenerates here, go on with a better
                # one, or stop at a singular posture of the loop itself
                cfg.coords.at_guard(guard, t, q)
                continue
            tr = guard.transition
            if guard.action == "separation":
                traj.events.append(_contact_event(phase, t, q, v, impulse_integral))
                fired.add(traj.events[-1]["name"])
                stats["impacts"] += 1
                phase = None
                continue
            if ctx.impact and tr.type == "stop" and tr.law != "impulse":
                _, _, vn, _ = contact_state(cfg, q, v, tr.contact)
                phase = ContactPhase(cfg, tr, max(-vn, 1e-12), t, q.copy(), v.copy())
                continue
            phase = None
            t0 = time.perf_counter()
            residual = None
            if guard.action == "unmerge":
                out = unmerge(ctx, cfg, guard.payload, holds.release_target(guard.payload, cfg), t, q, v)
            else:
                if tr.guard.type in ("coordinate", "gap"):
                    residual = guard_residual(cfg, tr, t, seg.y[:, -1])
                out = TRANSITIONS[tr.type](ctx, cfg, tr, t, q, v)
            stats["wall_s"] += time.perf_counter() - t0
            stats["impacts"] += int(out.event.get("impact", False))
            traj.events.append(out.event)
            fired.add(out.event["name"])
            cycle = _zero_time_cycle(traj.events)
            if cycle:
                raise SimulationError(
                    f"at t = {t:.9g} s the run switched configuration {ZERO_TIME_CYCLE} times without time "
                    f"passing: {cycle} keep firing, each one's guard already past its value when the run "
                    "enters its configuration (a release into a configuration whose forces push it straight "
                    "back into the stop that merged it, say); change a guard, or the forces acting right "
                    "after a switch")
            if len(traj.events) > opts.max_events:
                raise SimulationError(f"more than {opts.max_events} events by t = {t:.9g} s (last: "
                                      f"'{tr.name}'); raise solver.max_events or the accumulation "
                                      "tolerances if the impacts are meant to go on")
            if out.configuration != cfg.name:
                offsets = {k: offsets.get(k, 0.0) + d for k, d in out.angle_offsets.items()}
            else:
                bounced = tr
            audit.event(cfg, q, out.event, bounced is not None, residual)
            nxt = mech[out.configuration]
            nxt.continue_angles(offsets)  # measures (springs, guards) continue the series' angles
            if out.locks is not None:
                holds.lock(cfg, nxt, tr, q, merge=out.locks == "merge")
            holds.follow(nxt)
            cfg = nxt
            q, v = out.q, out.v
            if t >= opts.t_end:
                break
        completed = True
    except KeyboardInterrupt as exc:
        traj.status, traj.message = "partial", f"{scene.path}: {describe(exc)} at t = {_t_last(traj):.6g} s"
        err = SimulationError(traj.message, partial=traj)
        err.exit_code = exit_status(exc)  # 130 for Ctrl-C, 143 for SIGTERM: the shell's convention
        raise err from None
    except (ModelError, UsageError) as exc:  # a configuration's model first built mid-run: keep what ran
        traj.status, traj.message = "partial", exc.text()
        raise SimulationError(exc.problems, partial=traj) from None
    except SimulationError as exc:
        where = str(scene.path)
        exc.problems = [p if p.startswith(where) else f"{where}: {p}" for p in exc.problems]
        exc.args = (exc.text(),)
        traj.status, traj.message = "partial", exc.text()
        exc.partial = traj
        raise
    finally:  # a partial run keeps them too (pcmm derive writes what it reached)
        stats["configurations_built"] = list(mech.built)
        stats["derived_configurations"] = mech.derived
        # which evaluations each configuration ran: "compiled", or "python" and why (pcmm.compiled)
        stats["evaluations"] = {name: mech[name].coords.evaluations for name in mech.built}
        try:  # the flights' energy balances, measured now that the run needs its state no more
            audit.finish()
        except (SimulationError, Repartition):
            if completed:  # a partial run keeps what it has; its own error is the one to report
                raise
    # the guards that did not fire: computed when read (it reads the final segments' coordinates)
    stats.defer("closest_approach", lambda cfg=cfg: closest_approach(scene, cfg, traj))
    return traj


def check_start(scene: Scene, cfg: Configuration, t, q, v) -> None:
    """The initial state must be one a run can start from honestly: finite energies (a huge
    velocity overflows them), and no body already inside a stop - a guard on its fired side
    while its contact approaches (or, for a gap guard, penetrates) would never change sign, and
    the body would fall through with no event."""
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
        _, _, vn, _ = contact_state(cfg, q, v, tr.contact)
        if tr.guard.type == "gap" or vn < 0:
            raise SimulationError(
                f"{scene.path}: transition '{tr.name}': the run starts on the far side of its guard "
                f"({'gap' if tr.guard.type == 'gap' else str(tr.guard.measure)} is {past:.3g} past the "
                f"value {tr.guard.value:g} in its direction) while the contact "
                f"{'penetrates' if tr.guard.type == 'gap' else 'approaches'}: the bodies start inside the "
                "stop, and the guard would never fire; start the bodies apart (initial.q)")


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


def _guards(scene: Scene, cfg: Configuration, holds: Holds, t: float, phase, bounced, fired=()) -> list:
    """Every guard watched in ``cfg`` from ``t``: its transitions' (the one that just bounced
    re-armed), one per merge held by compression only, and a loop's partition guard.  A time
    guard ``at = T`` is one instant of the run: once its transition has fired it is not watched
    again (re-entered at T itself it would fire again, for ever)."""
    out = []
    for tr in scene.transitions_from(cfg.name):
        if phase is not None and tr is phase.tr:
            continue
        if tr.guard.type == "time" and tr.guard.at is not None and tr.name in fired:
            continue
        g = make_guard(cfg, tr, rearm=tr is bounced, context=holds if tr.guard.type == "reaction" else t)
        if g is not None:
            out.append(g)
    out += holds.unmerge_guards(cfg)
    out += cfg.coords.guards()  # the coordinates' own: a loop's partition guard
    return out


def _pending(cfg: Configuration, guards, t, y0):
    """Index of a guard that is already at or past its crossing at the start of a segment
    while its contact still approaches: a contact that closed at the same instant as the
    impact just resolved; or a merge whose holding force is already tensile (it never held).  It is resolved now, before any integration (sequential impacts
    in scene order); a step would never see it change sign."""
    q, v = cfg.coords.unpack(t, y0)
    for i, g in enumerate(guards):
        if g.action == "unmerge" and g(t, y0) < 0:
            return i  # the merge would have to pull from its first instant: the bodies separate now
        tr = g.transition
        if g.action != "transition" or tr.contact is None or tr.guard.type not in ("coordinate", "gap"):
            continue
        value = tr.guard.direction * g(t, y0)
        # round-off puts a state that is exactly at the guard (a joint freed by a release at its
        # latch value, re-read from the links' poses) on either side of it by an ulp or two
        at_value = 64 * EPS * max(1.0, abs(tr.guard.value))
        if value < -at_value or value > POSE_TOL:  # not at its crossing (far past it: entered from the other side)
            continue
        _, _, vn, Jn = contact_state(cfg, q, v, tr.contact)
        if vn < -1e-12:
            return i
        if abs(vn) <= 1e-12 and _pushed_closed(cfg, t, q, v, tr.contact):
            # at rest against the contact and pushed into it: it closes now (with no impulse),
            # whichever side of the guard round-off left the state on
            return i
    return None


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
    return f


def _contact_event(phase: ContactPhase, t, q, v, impulse_integral) -> EventRecord:
    """The event of a collision resolved by a continuous law (from first contact to separation)."""
    cfg, tr = phase.cfg, phase.tr
    n, _, vn, _ = contact_state(cfg, q, v, tr.contact)
    M0, M1 = cfg.mass_matrix(phase.q_start), cfg.mass_matrix(q)
    return event_dict(
        cfg, tr, phase.t_start, transition="stop", to=cfg.name, restitution=tr.restitution, merge=False,
        impact=True, P=impulse_integral, normal=n,
        point=contact_point(cfg, tr.contact),
        vn=(-phase.v_impact, vn), v=(phase.v_start, v),
        ke=(0.5 * phase.v_start @ M0 @ phase.v_start, 0.5 * v @ M1 @ v),
        t_end=float(t), duration=float(t - phase.t_start), law=tr.law)


def _t_last(traj: Trajectory) -> float:
    return float(traj.segments[-1].t[-1]) if traj.segments else 0.0


def _record(traj: Trajectory, cfg: Configuration, seg, offsets, q_start, holds: Holds, stepping) -> None:
    """Record an accepted segment (:func:`_record_samples`); a Ctrl-C or SIGTERM meanwhile waits
    until it is kept, so an interrupted run never loses the segment it was recording."""
    with deferred() as held:
        _record_samples(traj, cfg, seg, offsets, q_start, holds, stepping)
    held.reraise()


def _record_samples(traj: Trajectory, cfg: Configuration, seg, offsets, q_start, holds: Holds, stepping) -> None:
    """Keep the segment's times and the integrator's states; everything derived from them is
    computed when first asked for (:meth:`SegmentRecord.deferred`), in the partition and from
    the warm start the segment was integrated with.  ``stepping = (fun, method, opts)`` lets
    the segment be resampled at other times on the dense output of its steps.  The holding
    forces of the locks in force at the time are among the constraint forces (labels
    ``<lock>.hold``); their extremes are ``stats["holding"]``."""
    t0 = time.perf_counter()
    coords, forces = cfg.coords, cfg.forces
    frozen = coords.frozen_state()
    y_full, offsets, q_start = np.array(seg.y, float), dict(offsets), np.array(q_start, float)
    t = np.asarray(seg.t, float).copy()
    n_state = coords.ny  # the partition's state size (the tree's: 2 nv)
    y = y_full[:n_state]  # a contact phase or a flight integrates one more component
    held, holds = holds.labels(), holds.snapshot()
    owner = threading.get_ident()

    def in_segment_state(work):
        """Run ``work`` with the coordinates as they were for this segment.  Pinocchio's data are
        scratch space shared by the runs of one thread (models are built once per process and
        thread): asked from another thread, the series are computed on data of their own."""
        data, now = cfg.data, cfg.forces
        if threading.get_ident() != owner:
            cfg.data = cfg.__dict__.setdefault("_foreign_data", {}).setdefault(
                threading.get_ident(), cfg.model.createData())
        cfg.forces = forces  # as they were (a later entry may have compiled them at other angle offsets)
        try:
            with coords.restored(frozen, q_start):  # the segment was accepted: nothing here stops anything
                return work()
        finally:
            cfg.data, cfg.forces = data, now

    def derive():
        def work():
            out = _derived_series(cfg, t, y, offsets)
            if held:
                out["constraint_forces"] = np.hstack((out["constraint_forces"], _holding_forces(cfg, holds, t, out)))
            return out
        return in_segment_state(work)

    def resample(times):
        def work():
            fun, method, opts = stepping
            if not coords.constrained and fun is coords.rhs:
                fun = coords.fresh_rhs()
            states = dense_states(t, y_full, times, (fun, method, opts))[:n_state]
            # the dense steps left the loop's warm starts at the segment's end: the series are
            # solved from its start onwards, as the recorded ones are (from the end, a loop's
            # Newton solve at the start could land on another assembly)
            coords.seed(q_start)
            out = _derived_series(cfg, times, states, offsets)
            if held:
                out["constraint_forces"] = np.hstack((out["constraint_forces"], _holding_forces(cfg, holds, times, out)))
            return out
        return in_segment_state(work)
    coord_names = []
    for name in cfg.joint_names:
        sl = cfg.joint_slice[name]
        coord_names += [name] if sl.stop - sl.start == 1 else [f"{name}.x", f"{name}.y", f"{name}.theta"]
    traj.segments.append(SegmentRecord.deferred(
        derive, t, resample=resample, configuration=cfg.name, coordinates=coord_names, links=list(cfg.links),
        force_names=list(cfg.forces.names), constraint_labels=list(coords.labels) + held))
    traj.stats["constraint_drift_max"] = max(traj.stats["constraint_drift_max"], getattr(coords, "max_residual", 0.0))
    traj.stats["record_s"] += time.perf_counter() - t0


def _holding_forces(cfg: Configuration, holds: Holds, t, series: dict) -> np.ndarray:
    """(n, holds) holding force or moment of every lock in force, at the segment's own solved
    coordinates ``series["q"], series["v"]`` (those every other series was derived from).  Never
    solved again from the integrator's state: a loop's Newton solve warm-started from wherever
    the coordinates were left (the segment's end, or a later segment's) can land on the other
    assembly, and the series would then depend on what the run did after the segment."""
    out = np.empty((len(t), len(holds.items)))
    for i in range(len(t)):
        out[i] = list(holds.forces(cfg, t[i], series["q"][i], series["v"][i]).values())
    return out


def _derived_series(cfg: Configuration, t, y, offsets) -> dict:
    """Coordinates, angles, positions, energies, force elements and constraint forces at the
    recorded states of one segment."""
    n = len(t)
    nv, nl = cfg.nv, len(cfg.links)
    Q, V = np.empty((n, nv)), np.empty((n, nv))
    xy = np.empty((n, nl, 2))
    ke, pe = np.empty(n), np.empty(n)
    ff = np.empty((n, len(cfg.forces.names)))
    m = len(cfg.coords.labels)
    lam = np.empty((n, m))
    for i in range(n):
        q, v = cfg.coords.unpack(t[i], y[:, i])
        Q[i], V[i] = q, v
        xy[i] = cfg.link_poses(q)[:, :2]
        ke[i] = cfg.kinetic_energy(q, v)
        pe[i] = cfg.potential_energy(q)
        ff[i] = cfg.forces.element_values(q, v)
        if m:
            lam[i] = cfg.coords.accelerations(t[i], q, v)[1]
    off = np.array([offsets.get(link, 0.0) for link in cfg.links])
    return dict(q=Q, v=V, theta=Q @ cfg.A.T + cfg.b + off, omega=V @ cfg.A.T, xy=xy, kinetic=ke, potential=pe,
                forces=ff, constraint_forces=lam)
