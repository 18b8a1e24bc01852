"""Command line: ``pcmm run | replay | plot | check``.

Every user error ends in one message naming the file, field or value at fault
and a non-zero exit status; no traceback.  Output files are written
atomically and never overwritten without ``--force``; a run stopped by an
error or Ctrl-C saves what it computed, marked partial.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from .errors import PcmmError, SimulationError, UsageError


def _number(name, strict=True):
    """argparse type: a finite number > 0 (``strict``) or >= 0, named in its error."""
    bound = "> 0" if strict else ">= 0"

    def parse(text):
        try:
            val = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} = {text!r}: must be a number") from None
        if math.isinf(val) or not (val > 0 if strict else val >= 0):
            raise argparse.ArgumentTypeError(f"{name} = {text!r}: must be a finite number {bound}")
        return val
    return parse


def _positive(name):
    return _number(name, strict=True)


def _non_negative(name):
    return _number(name, strict=False)


def _count(text):
    try:
        val = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: must be a whole number") from None
    if val < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: must be >= 1")
    return val


def build_parser() -> argparse.ArgumentParser:
    from .integrators import INTEGRATORS
    p = argparse.ArgumentParser(prog="pcmm", description="Impact dynamics of planar constrained "
                                "metamorphic mechanisms (Song et al., Shock and Vibration 2020).")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="simulate a scene (TOML)")
    r.add_argument("scene", type=Path)
    r.add_argument("--t-end", type=_positive("t-end"), help="end time in s (default: the scene's)")
    r.add_argument("--method", choices=list(INTEGRATORS), help="integrator (default: the scene's, else DOP853)")
    r.add_argument("--rtol", type=_positive("rtol"), help="relative tolerance (default: scene, else 1e-10)")
    r.add_argument("--atol", type=_positive("atol"), help="absolute tolerance (default: scene, else 1e-12)")
    r.add_argument("--max-step", type=_positive("max-step"), help="largest step in s")
    r.add_argument("--step", type=_positive("step"), help="step of fixed-step methods (RK4), s (default 1e-3)")
    r.add_argument("--accumulation-speed", type=_non_negative("accumulation-speed"),
                   help="post-impact normal speed (m/s) below which repeated stop impacts end in a merge")
    r.add_argument("--accumulation-interval", type=_non_negative("accumulation-interval"),
                   help="impact interval (s) below which repeated stop impacts end in a merge")
    r.add_argument("--max-events", type=_count, help="stop with an error after this many events")
    r.add_argument("--event-tol", type=_positive("event-tol"),
                   help="how precisely an event time is located on the dense output, s (default 1e-14)")
    r.add_argument("--max-steps", type=_count, help="stop with an error after this many steps in a segment")
    r.add_argument("--no-impact", action="store_true",
                   help="switch configurations without impulse (the paper's comparison runs)")
    r.add_argument("--out", type=Path, help="save the trajectory (.npz)")
    r.add_argument("--summary", type=Path, help="save the summary (.json)")
    r.add_argument("--csv", type=Path, help="export the trajectory as CSV")
    r.add_argument("--html", type=Path, help="write a self-contained offline replay page")
    r.add_argument("--replay", action="store_true", help="replay the run in meshcat (browser)")
    r.add_argument("--plots", type=Path, help="write the paper's figures (PNG) into this folder")
    r.add_argument("--force", action="store_true", help="overwrite existing output files")
    r.add_argument("--quiet", action="store_true", help="no progress bar, no event table")
    rp = sub.add_parser("replay", help="replay a saved trajectory in meshcat")
    rp.add_argument("trajectory", type=Path)
    rp.add_argument("--html", type=Path, help="write a self-contained offline page instead of serving")
    rp.add_argument("--fps", type=_positive("fps"), default=60.0, help="frames per second (default 60)")
    rp.add_argument("--force", action="store_true")
    pl = sub.add_parser("plot", help="write the paper's figures for a saved trajectory")
    pl.add_argument("trajectory", type=Path)
    pl.add_argument("--compare", type=Path, help="a second trajectory (e.g. without impact) to overlay")
    pl.add_argument("--out", type=Path, required=True, help="folder for the PNG files")
    ck = sub.add_parser("check", help="validate a scene and its URDFs without simulating")
    ck.add_argument("scene", type=Path)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return {"run": cmd_run, "replay": cmd_replay, "plot": cmd_plot, "check": cmd_check}[args.command](args)
    except PcmmError as exc:
        print(f"pcmm: error: {exc.text()}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("pcmm: interrupted", file=sys.stderr)
        return 130


def _check_outputs(paths, force):
    problems = []
    for p in paths:
        if p is None:
            continue
        if p.is_dir():
            problems.append(f"{p}: is a folder; give a file name")
        elif p.exists() and not force:
            problems.append(f"{p}: exists; pass --force to overwrite it")
        if not p.parent.exists():
            problems.append(f"{p}: folder {p.parent} does not exist")
    if problems:
        raise UsageError(problems)


def cmd_check(args) -> int:
    from .scene import load_scene
    scene = load_scene(args.scene)
    print(f"{args.scene}: valid ({len(scene.configurations)} configurations, "
          f"{len(scene.transitions)} transitions, {len(scene.forces)} force elements)")
    return 0


def _progress(quiet: bool, t_end: float):
    """A tqdm bar over simulated time, shown only on a terminal and after about a second."""
    if quiet or not sys.stderr.isatty():
        return None, lambda: None
    try:
        from tqdm import tqdm
    except ImportError:
        return None, lambda: None
    start = time.perf_counter()
    state = {"bar": None, "t": 0.0}

    def update(t):
        if state["bar"] is None:
            if time.perf_counter() - start < 1.0:
                return
            state["bar"] = tqdm(total=t_end, unit="s sim", file=sys.stderr, leave=False,
                                bar_format="{l_bar}{bar}| {n:.3f}/{total:.3f} s simulated [{elapsed}]")
        state["bar"].update(max(0.0, min(t, t_end) - state["t"]))
        state["t"] = min(t, t_end)

    def close():
        if state["bar"] is not None:
            state["bar"].close()
    return update, close


def cmd_run(args) -> int:
    from .scene import load_scene
    from .simulate import RunOptions, simulate
    from .summary import event_table, summary
    from .trajectory import atomic_write, dumps_json
    _check_outputs([args.out, args.summary, args.csv, args.html], args.force)
    scene = load_scene(args.scene)
    opts = RunOptions(t_end=args.t_end, method=args.method, rtol=args.rtol, atol=args.atol,
                      max_step=args.max_step, step=args.step, accumulation_speed=args.accumulation_speed,
                      accumulation_interval=args.accumulation_interval, max_events=args.max_events,
                      event_tol=args.event_tol, max_steps=args.max_steps,
                      impact=not args.no_impact)
    update, close = _progress(args.quiet, args.t_end or scene.t_end)
    try:
        traj = simulate(scene, opts, progress=update)
    except SimulationError as exc:
        close()
        if exc.partial is not None and exc.partial.segments:
            stem = Path(args.scene).stem  # a file name, whatever the scene's 'name' says
            where = args.out or Path(f"{stem}-partial.npz")
            if where.exists() and not args.force and args.out is None:
                where = Path(f"{stem}-partial-{int(time.time())}.npz")
            exc.partial.save(where, force=True)
            print(f"pcmm: the run stopped at t = {float(exc.partial.t[-1]):.6g} s; the partial trajectory "
                  f"is saved in {where} (status 'partial')", file=sys.stderr)
        raise
    close()
    if not args.quiet:
        print(f"{scene.name}: {'with' if traj.impact else 'without'} impact, "
              f"t = 0 .. {traj.t[-1]:.6g} s, configuration {scene.initial_configuration} -> "
              f"{traj.segments[-1].configuration}, {len(traj.events)} events, "
              f"{traj.stats['steps']} steps, {traj.stats['rhs_evals']} rhs evaluations, "
              f"{traj.stats['wall_s']:.3f} s solve")
        print(event_table(traj))
    if args.out:
        traj.save(args.out, force=True)
        print(f"trajectory: {args.out}")
    if args.summary:
        atomic_write(args.summary, lambda f: f.write(dumps_json(summary(traj, scene.initial_configuration))),
                     force=True)
        print(f"summary: {args.summary}")
    if args.csv:
        traj.to_csv(args.csv, force=True)
        print(f"csv: {args.csv}")
    if args.plots:
        from .plots import write_figures
        other = simulate(scene, RunOptions(**{**opts.__dict__, "impact": not opts.impact}))
        files = write_figures(traj, args.plots, compare=other)
        print(f"figures: {', '.join(str(f) for f in files)}")
    if args.html:
        from .replay import write_html
        write_html(traj, args.html)
        print(f"replay page: {args.html}")
    if args.replay:
        from .replay import serve
        serve(traj)
    return 0


def cmd_replay(args) -> int:
    from .trajectory import Trajectory
    traj = Trajectory.load(args.trajectory)
    if args.html:
        _check_outputs([args.html], args.force)
        from .replay import write_html
        write_html(traj, args.html, fps=args.fps)
        print(f"replay page: {args.html}")
        return 0
    from .replay import serve
    serve(traj, fps=args.fps)
    return 0


def cmd_plot(args) -> int:
    from .plots import write_figures
    from .trajectory import Trajectory
    traj = Trajectory.load(args.trajectory)
    other = Trajectory.load(args.compare) if args.compare else None
    args.out.mkdir(parents=True, exist_ok=True)
    files = write_figures(traj, args.out, compare=other)
    print(f"figures: {', '.join(str(f) for f in files)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
