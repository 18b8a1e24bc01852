"""The configuration-complete simulation (paper Fig. 3).

Integrate the current configuration's dynamics (Eq. 1) until a guard fires;
solve the transformation (impulse, velocity jump, configuration switch); go
on in the next configuration until ``t_end``.  With ``impact=False`` the
transformations switch without impulse (the paper's comparison runs).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields, replace

import numpy as np

from .configuration import Configuration, Mechanism
from .errors import Repartition, SimulationError, UsageError
from .contact_laws import ContactPhase, strip
from .guards import make_guard, make_release_guard
from .impulse import contact_state
from .integrators import INTEGRATORS, Segment
from .scene import Scene, SolverSettings
from .trajectory import SegmentRecord, Trajectory
from .transitions import TRANSITIONS, Context, event_dict, handle_release


@dataclass(frozen=True)
class RunOptions:
    """Accuracy and mode knobs; ``None`` means the scene's ``[solver]`` value."""

    t_end: float | None = None
    method: str | None = None
    rtol: float | None = None
    atol: float | None = None
    max_step: float | None = None
    step: float | None = None  # fixed-step methods (RK4)
    event_tol: float | None = None
    max_steps: int | None = None
    accumulation_speed: float | None = None
    accumulation_interval: float | None = None
    max_events: int | None = None
    impact: bool = True


@dataclass(frozen=True)
class Resolved:
    """The settings a run uses: the scene's ``[solver]`` overridden by the options."""

    solver: SolverSettings
    t_end: float
    impact: bool

    def __getattr__(self, name):  # opts.rtol etc. read through to the solver settings
        return getattr(self.solver, name)


def resolve(scene: Scene, options: RunOptions) -> Resolved:
    overrides = {f.name: getattr(options, f.name) for f in fields(SolverSettings)
                 if getattr(options, f.name, None) is not None}
    r = Resolved(replace(scene.solver, **overrides),
                 scene.t_end if options.t_end is None else options.t_end, options.impact)
    problems = []
    if r.method not in INTEGRATORS:
        problems.append(f"method = {r.method!r}: must be one of {', '.join(INTEGRATORS)}")
    for name in ("t_end", "rtol", "atol", "max_step", "step", "event_tol"):
        val = getattr(r, name)
        if not (isinstance(val, (int, float)) and val > 0 and not math.isnan(val)):
            problems.append(f"{name} = {val!r}: must be a number > 0")
    for name in ("accumulation_speed", "accumulation_interval"):
        if not getattr(r, name) >= 0:
            problems.append(f"{name} = {getattr(r, name)!r}: must be >= 0")
    if problems:
        raise UsageError(problems)
    return r


def initial_state(scene: Scene, cfg: Configuration):
    q0 = cfg.vector(scene.q0)
    v0 = cfg.vector(scene.v0)
    prefer = [cfg.joint_slice[j].start for j in scene.independent]
    return cfg.coords.project(0.0, q0, v0, prefer)


def simulate(scene: Scene, options: RunOptions = RunOptions(), progress=None) -> Trajectory:
    """Run ``scene``; return the :class:`Trajectory`.

    On an error or Ctrl-C mid-run the exception carries the trajectory up to
    that point (``exc.partial``, status ``"partial"``) so no result is lost.
    ``progress(t)`` is called after each segment and every few steps if given.
    """
    opts = resolve(scene, options)
    mech = Mechanism(scene)
    traj = Trajectory(scene=str(scene.path.resolve()), scene_name=scene.name, impact=opts.impact)
    ctx = Context(mech, opts.impact, opts.accumulation_speed, opts.accumulation_interval,
                  forced_speed=options.accumulation_speed, forced_interval=options.accumulation_interval)
    method = INTEGRATORS[opts.method]
    stats = {"steps": 0, "rhs_evals": 0, "wall_s": 0.0, "record_s": 0.0, "impacts": 0,
             "constraint_drift_max": 0.0, "method": opts.method, "rtol": opts.rtol, "atol": opts.atol}
    traj.stats = stats
    cfg = mech[scene.initial_configuration]
    t = 0.0
    q, v = initial_state(scene, cfg)
    offsets: dict[str, float] = {}
    merges: list[tuple] = []  # stop-merges that a tensile holding force undoes
    phase: ContactPhase | None = None  # a collision resolved by a continuous contact law
    bounced = None  # the stop that just bounced: its guard restarts unarmed
    try:
        while True:
            y0 = cfg.coords.pack(t, q, v)
            guards = [make_guard(cfg, tr, start=(t, y0) if tr is bounced else None)
                      for tr in scene.transitions_from(cfg.name) if phase is None or tr is not phase.tr]
            bounced = None
            if merges:
                source, mtr, locked = merges[-1]
                if (scene.solver.unmerge if mtr.unmerge is None else mtr.unmerge):
                    guards.append(make_release_guard(cfg, mech[source], mtr, locked))
            if cfg.coords.constrained and cfg.coords.closure.size:
                guards.append(cfg.coords.singularity_guard())
            fun = cfg.coords.rhs
            if phase is not None:
                guards = [phase.end_guard()] + [strip(g) for g in guards]
                y0, fun = np.append(y0, 0.0), phase.rhs()
            if progress is not None:
                fun = _reporting(fun, progress)
            pending = None if phase is not None else _pending(cfg, guards, t, y0)
            t0 = time.perf_counter()
            try:
                if pending is not None:  # a contact already closed at this instant (simultaneous impacts)
                    seg = Segment(np.array([t]), y0[:, None], pending, 0, 0, 1, "simultaneous")
                elif y0.size:
                    seg = method.integrate(fun, t, y0, opts.t_end, guards, opts)
                else:  # no free coordinate: the motion is locked or fully driven; sample it, watch the guards
                    fixed = replace(opts.solver, step=min(opts.step, max(opts.t_end - t, 1e-12) / 1000))
                    seg = INTEGRATORS["RK4"].integrate(_assembled(cfg), t, y0, opts.t_end, guards, fixed)
            except Repartition as exc:  # a loop's dependent block degenerated: new partition, go on
                seg = exc.segment
                _record(traj, cfg, seg, offsets, q)
                t = float(seg.t[-1])
                q, v = cfg.coords.unpack(t, seg.y[:, -1])
                continue
            except (SimulationError, KeyboardInterrupt) as exc:
                if getattr(exc, "segment", None) is not None and exc.segment.t.size > 1:
                    _record(traj, cfg, exc.segment, offsets, q)
                raise
            finally:
                stats["wall_s"] += time.perf_counter() - t0
            stats["steps"] += seg.nsteps
            stats["rhs_evals"] += seg.nfev
            if seg.status < 0:
                raise SimulationError(f"the integrator ({opts.method}) failed at t = {seg.t[-1]:.9g} s in "
                                      f"configuration '{cfg.name}': {seg.message}")
            impulse_integral = 0.0
            if phase is not None:
                impulse_integral = float(seg.y[-1, -1])
                seg.y = seg.y[:-1]
            _record(traj, cfg, seg, offsets, q)
            if progress:
                progress(float(seg.t[-1]))
            if seg.event is None:
                break
            t = float(seg.t[-1])
            q, v = cfg.coords.unpack(t, seg.y[:, -1])
            guard = guards[seg.event]
            if getattr(guard, "singular", False):
                # the partition degenerates here: go on with a better one, or stop at a singular
                # posture of the loop itself
                cfg.coords.at_degenerate_partition(t, q)
                continue
            tr = guard.transition
            if getattr(guard, "contact_end", False):
                traj.events.append(_contact_event(phase, t, q, v, impulse_integral))
                stats["impacts"] += 1
                phase = None
                continue
            if ctx.impact and tr.type == "stop" and tr.law != "impulse":
                _, _, vn, _ = contact_state(cfg, q, v, tr.contact)
                phase = ContactPhase(cfg, tr, max(-vn, 1e-12), t, q.copy(), v.copy())
                continue
            phase = None
            t0 = time.perf_counter()
            if hasattr(guard, "release"):
                out = handle_release(ctx, cfg, tr, t, q, v, guard.release)
                merges.pop()
            else:
                out = TRANSITIONS[tr.type](ctx, cfg, tr, t, q, v)
                if out.merged_from is not None:
                    merges.append(out.merged_from)
                elif out.configuration != cfg.name:
                    merges.clear()
            stats["wall_s"] += time.perf_counter() - t0
            stats["impacts"] += int(out.event.get("impact", False))
            traj.events.append(out.event)
            if len(traj.events) > opts.max_events:
                raise SimulationError(f"more than {opts.max_events} events by t = {t:.9g} s (last: "
                                      f"'{tr.name}'); raise solver.max_events or the accumulation "
                                      "tolerances if the impacts are meant to go on")
            if out.configuration != cfg.name:
                offsets = {k: offsets.get(k, 0.0) + d for k, d in out.angle_offsets.items()}
            else:
                bounced = tr
            cfg = mech[out.configuration]
            q, v = out.q, out.v
            if t >= opts.t_end:
                break
    except KeyboardInterrupt:
        traj.status, traj.message = "partial", f"{scene.path}: interrupted by the user at t = {_t_last(traj):.6g} s"
        raise SimulationError(traj.message, partial=traj) from None
    except SimulationError as exc:
        where = str(scene.path)
        exc.problems = [p if p.startswith(where) else f"{where}: {p}" for p in exc.problems]
        exc.args = (exc.text(),)
        traj.status, traj.message = "partial", exc.text()
        exc.partial = traj
        raise
    stats["configurations_built"] = list(mech.built)
    return traj


def _assembled(cfg: Configuration):
    """The derivative of an empty state (a locked or fully driven configuration): nothing to
    compute, but the loop is assembled at every step so a posture it cannot reach stops the run."""
    def f(t, y):
        cfg.coords.unpack(t, y)
        return y
    return f


def _pending(cfg: Configuration, guards, t, y0):
    """Index of a guard that is already at or past its crossing at the start of a segment
    while its contact still approaches: a contact that closed at the same instant as the
    impact just resolved.  It is resolved now, before any integration (sequential impacts
    in scene order); a step would never see it change sign."""
    q, v = cfg.coords.unpack(t, y0)
    for i, g in enumerate(guards):
        if getattr(g, "singular", False):
            continue
        tr = getattr(g, "transition", None)
        if tr is None or hasattr(g, "release") or tr.guard.direction * g(t, y0) < 0:
            continue
        _, _, vn, _ = contact_state(cfg, q, v, tr.contact)
        if vn < -1e-12:
            return i
    return None


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


def _contact_event(phase: ContactPhase, t, q, v, impulse_integral) -> dict:
    """The event of a collision resolved by a continuous law (from first contact to separation)."""
    cfg, tr = phase.cfg, phase.tr
    n, _, vn, _ = contact_state(cfg, q, v, tr.contact)
    M0, M1 = cfg.mass_matrix(phase.q_start), cfg.mass_matrix(q)
    return event_dict(
        cfg, tr, phase.t_start, transition="stop", to=cfg.name, restitution=tr.restitution, merge=False,
        impact=True, P=impulse_integral, normal=n,
        point=cfg.point_position(cfg.point(tr.contact.b, tr.contact.point_b)),
        vn=(-phase.v_impact, vn), v=(phase.v_start, v),
        ke=(0.5 * phase.v_start @ M0 @ phase.v_start, 0.5 * v @ M1 @ v),
        t_end=float(t), duration=float(t - phase.t_start), law=tr.law)


def _t_last(traj: Trajectory) -> float:
    return float(traj.segments[-1].t[-1]) if traj.segments else 0.0


def _record(traj: Trajectory, cfg: Configuration, seg, offsets, q_start) -> None:
    t0 = time.perf_counter()
    cfg.coords.seed(q_start)
    cfg.coords.checking = False  # the segment was accepted; recording it must not stop the run
    try:
        _record_samples(traj, cfg, seg, offsets)
    finally:
        cfg.coords.checking = True
        traj.stats["record_s"] += time.perf_counter() - t0


def _record_samples(traj: Trajectory, cfg: Configuration, seg, offsets) -> None:
    n = len(seg.t)
    nv, nl = cfg.nv, len(cfg.links)
    Q, V = np.empty((n, nv)), np.empty((n, nv))
    xy = np.empty((n, nl, 2))
    ke, pe = np.empty(n), np.empty(n)
    ff = np.empty((n, len(cfg.forces.names)))
    m = len(cfg.coords.labels)
    lam = np.empty((n, m))
    drift = 0.0
    for i in range(n):
        q, v = cfg.coords.unpack(seg.t[i], seg.y[:, i])
        Q[i], V[i] = q, v
        xy[i] = cfg.link_poses(q)[:, :2]
        ke[i] = cfg.kinetic_energy(q, v)
        pe[i] = cfg.potential_energy(q)
        ff[i] = cfg.forces.element_values(q, v)
        if m:
            lam[i] = cfg.coords.accelerations(seg.t[i], q, v)[1]
            drift = max(drift, cfg.coords.residual(seg.t[i], q))
    off = np.array([offsets.get(link, 0.0) for link in cfg.links])
    coord_names = []
    for name in cfg.joint_names:
        sl = cfg.joint_slice[name]
        coord_names += [name] if sl.stop - sl.start == 1 else [f"{name}.x", f"{name}.y", f"{name}.theta"]
    traj.segments.append(SegmentRecord(
        configuration=cfg.name, coordinates=coord_names, links=list(cfg.links),
        force_names=list(cfg.forces.names), constraint_labels=list(cfg.coords.labels),
        t=np.asarray(seg.t, float).copy(), q=Q, v=V, theta=Q @ cfg.A.T + cfg.b + off, omega=V @ cfg.A.T,
        xy=xy, kinetic=ke, potential=pe, forces=ff, constraint_forces=lam))
    traj.stats["constraint_drift_max"] = max(traj.stats["constraint_drift_max"], drift)
