"""Command line: ``pcmm run | sweep | replay | plot | check | derive | new``.

Every user error ends in one message naming the file, field or value at fault
and a non-zero exit status; no traceback.  Output files are written
atomically and never overwritten without ``--force``; a run stopped by an
error or Ctrl-C saves what it computed, marked partial.
"""
from __future__ import annotations

from . import signals as _signals

# a signal while this module's imports run (argparse, pathlib, ... take a good part of a second
# on a loaded machine) is held and answered by main() like one that comes later; the handlers are
# put back at the end of the module, so importing pcmm.cli as a library changes none
_AT_IMPORT = _signals.hold()

import argparse
import contextlib
import dataclasses
import math
import os
import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path

from .errors import OutputError, PcmmError, SimulationError, UsageError
from .files import terminal_text


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


#: A replay's limits: frames per second, and frames in all (each frame is a pose of every link
#: in the page or the meshcat animation; 200,000 frames of a three-bar are about 100 MB of HTML).
MAX_FPS = 1000.0
MAX_FRAMES = 200_000


def _fps(text):
    val = _positive("fps")(text)
    if val > MAX_FPS:
        raise argparse.ArgumentTypeError(f"fps = {text!r}: at most {MAX_FPS:g} frames per second")
    return val


def _check_frames(traj, fps: float, flag: str) -> None:
    """Refuse a replay that would hold more than :data:`MAX_FRAMES` frames (it would run for
    minutes and fill memory), saying which --fps fits."""
    if not traj.segments:
        return
    duration = float(traj.segments[-1].t[-1] - traj.segments[0].t[0])
    frames = duration * fps
    if frames > MAX_FRAMES:
        raise UsageError(f"{flag}: {duration:.6g} s at {fps:g} fps is {frames:.3g} frames, more than "
                         f"{MAX_FRAMES}; give --fps {MAX_FRAMES / duration:.3g} or less")


def _count(text):
    try:
        val = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: must be a whole number") from None
    if val < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: must be >= 1")
    return val


def build_parser() -> argparse.ArgumentParser:
    from .scene import settings
    p = argparse.ArgumentParser(prog="pcmm", description="Impact dynamics of planar constrained "
                                "metamorphic mechanisms (Song et al., Shock and Vibration 2020).")
    sub = p.add_subparsers(dest="command", required=True)
    add_parser = sub.add_parser

    def described(name, **kwargs):  # 'pcmm NAME -h' says what NAME does, as 'pcmm -h' lists it
        kwargs.setdefault("description", kwargs.get("help"))
        return add_parser(name, **kwargs)
    sub.add_parser = described
    r = sub.add_parser("run", help="simulate a scene (TOML)")
    r.add_argument("scene", type=Path)
    r.add_argument("--t-end", type=_positive("t-end"), help="end time in s (default: the scene's)")
    settings.add_arguments(r)  # one flag per solver setting (pcmm.settings)
    r.add_argument("--no-impact", action="store_true",
                   help="switch configurations without impulse (the paper's comparison runs)")
    r.add_argument("--out", type=Path, help="save the trajectory (.npz)")
    r.add_argument("--summary", type=Path, help="save the summary (.json)")
    r.add_argument("--store", type=Path, help="stream the trajectory to this new folder as the run goes, in chunks "
                   "(memory bounded however long the run; a killed run keeps every chunk written): "
                   "read it with Trajectory.load(DIR)")
    r.add_argument("--csv", type=Path, help="export the trajectory as CSV")
    r.add_argument("--html", type=Path, help="write a self-contained offline replay page")
    r.add_argument("--replay", action="store_true", help="replay the run in meshcat (browser)")
    r.add_argument("--plots", type=Path, help="write the paper's figures (PNG) into this folder")
    r.add_argument("--no-comparison", action="store_true",
                   help="with --plots: the figures show only this run; no second run without/with impact")
    r.add_argument("--dt", type=_positive("dt"), help="write the CSV and the figures at times 0, dt, 2 dt, ... "
                   "(and at every event) on the integrator's dense output, s (default: at its steps)")
    r.add_argument("--force", action="store_true", help="overwrite existing output files")
    r.add_argument("--quiet", action="store_true", help="no progress bar, no event table (warnings still print, a guard that never fired among them)")
    sw = sub.add_parser("sweep", help="run a design study: variations of a scene, one results row per run",
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    _list_columns_in_help(sw)
    sw.add_argument("scene", type=Path)
    sw.add_argument("--set", dest="sets", action="append", default=[], metavar="PATH=VALUES",
                    help="a value path and its values: 0.2,0.5,0.8 or start:stop:count (a grid over every "
                         "--set), or low:high with --sample random|lhs")
    sw.add_argument("--plan", type=Path, help="a sweep file (TOML): [set] PATH = values, sample, runs, seed, "
                    "collect, t_end")
    sw.add_argument("--sample", choices=("grid", "random", "lhs"), help="grid (default), random or lhs "
                    "(Latin hypercube) samples of the --set boxes")
    sw.add_argument("--runs", type=_count, help="number of random or lhs samples")
    sw.add_argument("--seed", type=int, help="seed of the random or lhs samples")
    sw.add_argument("--collect", action="append", default=[], metavar="PATH",
                    help="a summary value to add as a column, e.g. final.theta.link3 or events[0].t")
    sw.add_argument("--out", type=Path, required=True, help="the results table (.csv; .parquet too with pyarrow)")
    sw.add_argument("--t-end", type=_positive("t-end"), help="end time of every run in s (default: the scene's)")
    sw.add_argument("--workers", type=_count, help="processes (default: the cores this process may use; 1: in this process)")
    sw.add_argument("--scheduler", metavar="ADDRESS", help="a Dask distributed scheduler (tcp://host:8786), or "
                    "'local' to start a LocalCluster of --workers processes")
    sw.add_argument("--resume", action="store_true", help="run only the runs missing from --out")
    sw.add_argument("--run-timeout", type=_non_negative("run-timeout"), default=600.0, metavar="SECONDS",
                    help="stop a run that takes longer than this and record it as 'timeout' (default: 600 s; "
                         "0: no limit; not with --workers 1, which runs in this process)")
    sw.add_argument("--retry-failed", action="store_true", help="with --resume: run again the runs whose row "
                    "says crashed or timeout")
    sw.add_argument("--force", action="store_true", help="start over, replacing --out")
    sw.add_argument("--plots", type=Path, help="write each quantity against each swept value (PNG) into this folder")
    sw.add_argument("--plot", dest="plot_quantities", action="append", metavar="QUANTITY",
                    help="with --plots: only this quantity (or collected path); repeatable")
    sw.add_argument("--quiet", action="store_true", help="no progress bar")
    op = sub.add_parser("optimize", help="minimise an output of the runs over boxes of scene values "
                        "(every run a row of a sweep table)")
    op.add_argument("scene", type=Path)
    op.add_argument("--vary", action="append", default=[], metavar="PATH=LOW:HIGH", required=True,
                    help="a value path and the box the optimiser searches; repeatable")
    op.add_argument("--minimize", required=True, metavar="OUTPUT",
                    help="the output to minimise: a table quantity (peak_impulse, first_impact_t, ...) or a "
                         "summary path (events[0].impulse.normal)")
    op.add_argument("--subject-to", action="append", default=[], metavar="OUTPUT<=VALUE",
                    help="a bound on another output (<= or >=); repeatable")
    op.add_argument("--method", choices=("cobyqa", "powell", "de"), help="cobyqa (default where scipy has it, "
                    "else powell): derivative-free, bounded, one run at a time; de: differential evolution, "
                    "each generation a batch of runs in parallel")
    op.add_argument("--max-evals", type=_count, default=100, help="the most runs to ask for (default 100)")
    op.add_argument("--tol", type=_positive("tol"), default=1e-6, help="the optimiser's tolerance in the box "
                    "scaled to [0, 1] (de: relative spread of the population) (default 1e-6)")
    op.add_argument("--popsize", type=_count, default=8, help="de: population per varied value (default 8)")
    op.add_argument("--seed", type=int, default=0, help="de: the seed of its population (default 0)")
    op.add_argument("--out", type=Path, required=True, help="the results table (.csv), one row per run")
    op.add_argument("--t-end", type=_positive("t-end"), help="end time of every run in s (default: the scene's)")
    op.add_argument("--workers", type=_count, help="processes (default: 1 for cobyqa and powell, the usable "
                    "cores for de)")
    op.add_argument("--scheduler", metavar="ADDRESS", help="a Dask distributed scheduler, or 'local'")
    op.add_argument("--run-timeout", type=_non_negative("run-timeout"), default=600.0, metavar="SECONDS",
                    help="stop a run that takes longer (default: 600 s; 0: no limit; on the pool and Dask)")
    op.add_argument("--resume", action="store_true", help="replay the table's runs and go on from there")
    op.add_argument("--force", action="store_true", help="start over, replacing --out")
    rp = sub.add_parser("replay", help="replay saved trajectories in meshcat (several: overlaid, one colour each)")
    rp.add_argument("trajectory", type=Path, nargs="+")
    rp.add_argument("--html", type=Path, help="write a self-contained offline page instead of serving")
    rp.add_argument("--fps", type=_fps, default=60.0,
                    help=f"frames per second (default 60, at most {MAX_FPS:g})")
    rp.add_argument("--layout", choices=("overlay", "side"), default="overlay",
                    help="several runs: overlaid, the second a faint ghost (default), or side by side")
    rp.add_argument("--view", choices=("run", "follow", "configuration"), default="run",
                    help="the page's view: fitted to the whole run (default), to each configuration's stay, or "
                         "following the mechanism, with the swept envelope traced faintly")
    rp.add_argument("--video", type=Path, help="write a video (.mp4 through ffmpeg, or .gif) of the 2D drawing instead "
                    "of serving")
    rp.add_argument("--speed", type=_positive("speed"), default=1.0,
                    help="video: simulated seconds per second of video (default 1)")
    rp.add_argument("--slow", type=_positive("slow"), default=0.1,
                    help="video: the speed's factor within --slow-window of every event (default 0.1)")
    rp.add_argument("--slow-window", type=_non_negative("slow-window"), default=0.02,
                    help="video: slow motion this long before and after each event, s (default 0.02)")
    rp.add_argument("--force", action="store_true")
    pl = sub.add_parser("plot", help="write the paper's figures for a saved trajectory")
    pl.add_argument("trajectory", type=Path)
    pl.add_argument("--compare", type=Path, help="a second trajectory (e.g. without impact) to overlay")
    pl.add_argument("--out", type=Path, required=True, help="folder for the PNG files")
    pl.add_argument("--force", action="store_true", help="overwrite existing figures")
    pl.add_argument("--impulse-sign", choices=["body_b", "paper"], default="body_b",
                    help="impulse sign: on body b along the contact normal (default) or the paper's (Fig. 12)")
    gr = sub.add_parser("graph", help="draw a scene's configurations and transitions (the paper's Fig. 3)")
    gr.add_argument("scene", type=Path)
    gr.add_argument("--run", type=Path, help="a saved run of the scene: each edge says how many times and when it fired")
    gr.add_argument("--out", type=Path, help="the figure (.png, .svg or .pdf; default: <scene>_graph.png)")
    gr.add_argument("--force", action="store_true", help="overwrite an existing figure")
    ck = sub.add_parser("check", help="validate a scene and its URDFs without simulating")
    ck.add_argument("scene", type=Path)
    dv = sub.add_parser("derive", help="write every configuration derived by locking joints as a URDF file")
    dv.add_argument("scene", type=Path)
    dv.add_argument("--out", type=Path, required=True, help="folder for the URDF files (created if missing)")
    dv.add_argument("--force", action="store_true", help="overwrite existing URDF files")
    nw = sub.add_parser("new", help="write a template scene and its URDFs that run as they are")
    nw.add_argument("name", help="names the files: NAME.toml, NAME_open.urdf, NAME_latched.urdf")
    nw.add_argument("--links", type=_count, default=3, help="bars of the open chain (default 3)")
    nw.add_argument("--closed", action="store_true", help="a four-bar (closed loop) instead of an open chain")
    nw.add_argument("--dir", type=Path, default=Path("."), help="folder to write into (default: here)")
    nw.add_argument("--force", action="store_true", help="overwrite existing files")
    return p


def main(argv=None) -> int:
    """Run one command.  SIGTERM and SIGHUP stop it like Ctrl-C (a partial run is saved, the
    meshcat server is shut down); a closed standard output (``pcmm run ... | head``) only
    silences what is printed; a write beyond a file-size limit is an error, not a kill."""
    from .signals import as_interrupts, deferred, exit_status
    with contextlib.suppress(AttributeError, ValueError, OSError):
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a file-size limit: EFBIG, reported, not a kill
    try:
        with as_interrupts():
            with deferred() as held:  # a signal while the arguments are read waits until the command
                held.received[:0], _AT_IMPORT.received = _AT_IMPORT.received, []  # (or while pcmm.cli loaded)
                args = build_parser().parse_args(argv)  # knows its outputs (a run then keeps a partial)
            if args.command == "run":
                return cmd_run(args, held)
            held.reraise()
            return {"sweep": cmd_sweep, "optimize": cmd_optimize, "replay": cmd_replay, "plot": cmd_plot,
                    "check": cmd_check, "derive": cmd_derive, "new": cmd_new, "graph": cmd_graph}[args.command](args)
    except PcmmError as exc:
        _error(exc.text())
        return exc.exit_code
    except KeyboardInterrupt as exc:
        from .signals import describe
        _error(describe(exc), prefix="pcmm: ")
        return exit_status(exc)
    except ImportError as exc:
        # Ctrl-C while Pinocchio or scipy load (on first use, inside a command): a compiled
        # (pybind11) module initialising when the signal lands turns the KeyboardInterrupt into
        # "ImportError: initialization failed" with the interrupt as its cause
        interrupt = _interrupt_in(exc)
        if interrupt is None:
            raise
        from .signals import describe
        _error(describe(interrupt) + " while starting", prefix="pcmm: ")
        return exit_status(interrupt)


def _interrupt_in(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt in an exception's chain of causes, if any."""
    while exc is not None and not isinstance(exc, KeyboardInterrupt):
        exc = exc.__cause__ or exc.__context__
    return exc


def say(text: str = "", file=None) -> None:
    """Print, unless the reader has gone: a closed pipe (``| head``) silences the rest of the
    output and nothing else (the results are written before anything is printed)."""
    stream = file or sys.stdout
    try:
        print(terminal_text(text), file=stream, flush=True)
    except (BrokenPipeError, ValueError, OSError):
        with contextlib.suppress(OSError, ValueError, AttributeError):
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, stream.fileno())  # so the interpreter's own flush at exit is silent too
            os.close(devnull)


def _error(text: str, prefix: str = "pcmm: error: ") -> None:
    say(prefix + text, file=sys.stderr)


def _resolved(p: Path) -> Path:
    try:
        return p.resolve()
    except (OSError, RuntimeError, ValueError):
        return p.absolute()


def _list_columns_in_help(parser) -> None:
    """`pcmm sweep -h` ends with the table's columns and what each holds (which impulse, which
    energy), read from :data:`pcmm.studies.job.QUANTITIES` when the help is shown: a plain run
    does not import the studies."""
    plain = parser.format_help

    def format_help():
        import textwrap
        from .studies.job import QUANTITIES
        lines = ["the table's columns: run, one per swept path, status, error, then:"]
        for name, text in QUANTITIES.items():
            lines += textwrap.wrap(f"{name}: {text}", 96, initial_indent="  ", subsequent_indent="      ")
        lines.append("then one per --collect PATH, and check (the row's CRC-32); docs/studies.md says more")
        parser.epilog = "\n".join(lines)
        return plain()
    parser.format_help = format_help


#: the file formats of `pcmm run`'s outputs, by suffix: a file named for one written in another
#: would be read wrongly by every tool that trusts its name (a spreadsheet opening an NPZ)
_RUN_FORMATS = {".npz": ("--out", "the trajectory (NPZ)"), ".csv": ("--csv", "the samples as CSV"),
                ".json": ("--summary", "the summary (JSON)"), ".html": ("--html", "the replay page (HTML)")}


def _suffix_problems(paths) -> list[str]:
    """`pcmm run --out x.csv` (it wrote an NPZ named .csv, silently) and the like: an output whose
    suffix names another output's format.  Other suffixes are the user's choice."""
    problems = []
    for flag, p in paths:
        if p is None:
            continue
        meant = _RUN_FORMATS.get(Path(p).suffix.lower())
        if meant is not None and meant[0] != flag:
            own = next(s for s, (f, _) in _RUN_FORMATS.items() if f == flag)
            problems.append(f"{flag} {p}: {flag} writes {_RUN_FORMATS[own][1]}, not a {Path(p).suffix} file; "
                            f"for {meant[1]} give {meant[0]} {p}, or name this output *{own}")
    return problems


def _check_outputs(paths, force, folders=(), formats=False):
    """Refuse, before anything runs: an output that exists (without --force), is a folder, lies
    in a missing folder, or is named twice (one would silently replace the other); with
    ``formats``, one named for another output's format (:func:`_suffix_problems`)."""
    problems = _suffix_problems(paths) if formats else []
    seen: dict[Path, str] = {}
    for flag, p in paths:
        if p is None:
            continue
        if "\0" in str(p):
            problems.append(f"{flag} {str(p)!r}: a file name cannot contain a NUL character")
            continue
        key = _resolved(p)
        if key in seen:
            problems.append(f"{flag} {p}: is also the {seen[key]} output; give each output its own file")
        seen[key] = flag
        if p.is_dir():
            problems.append(f"{p}: is a folder; give a file name")
        elif p.exists() and not force:
            problems.append(f"{p}: exists; pass --force to overwrite it")
        if not p.parent.exists():
            problems.append(f"{p}: folder {p.parent} does not exist")
    for flag, d in folders:
        if d is None:
            continue
        if "\0" in str(d):
            problems.append(f"{flag} {str(d)!r}: a folder name cannot contain a NUL character")
        elif d.exists() and not d.is_dir():
            problems.append(f"{flag} {d}: is a file; give a folder for the figures")
        elif _resolved(d) in seen:
            problems.append(f"{flag} {d}: is also the {seen[_resolved(d)]} output")
        elif d.is_dir() and not force:
            figures = sorted(p.name for p in d.glob("*.png"))
            if figures:
                problems.append(f"{flag} {d}: already holds figures ({', '.join(figures[:4])}"
                                f"{', ...' if len(figures) > 4 else ''}); pass --force to overwrite them")
    if problems:
        raise UsageError(problems)


def _run_warnings(traj) -> list[str]:
    """The warnings the run itself found on its way, each ``t = ... s, configuration ...`` (redundant
    rows, a hold no configuration can solve, a release already past its value where it is entered):
    printed, since only the summary and ``traj.stats`` kept them (a kneed walker's trailing knee stayed
    locked and the terminal said nothing).  The assembly's, which ``pcmm check`` printed before the
    run, do not start so.  Read only where the stats are already settled or settle cleanly."""
    try:
        said = traj.stats.get("warnings") or []
    except PcmmError:
        return []
    return [w for w in said if w.startswith("t = ")]


def _check_geometry(scene):
    """The check-time consistency of the geometry (pcmm.checks): problems stop before any
    simulation, warnings are printed (also under --quiet, which silences progress and tables,
    not what the user must know)."""
    from .run.checks import check_scene
    from .errors import SceneError
    report = check_scene(scene)
    for w in report.warnings + _pin_frictions(scene):
        print(f"pcmm: warning: {w}", file=sys.stderr)
    if report.problems:
        raise SceneError(report.problems)
    return report


def _pin_frictions(scene) -> list[str]:
    """A pin whose strike and stance judge one contact with two friction coefficients: the
    transition's ``contact.friction`` bounds the strike's impulse, the target's cut joint's
    ``contact.friction`` the stance's force (a leg's foot struck with mu = 0.6 and held with 0.3 stopped
    at once "right after the strike ... would slip", from a scene whose strike said 0.6)."""
    def mu(x):
        return "none (frictionless)" if x is None else '"stick"' if math.isinf(x) else f"{x:g}"
    out = []
    for i, t in enumerate(scene.transitions):
        if t.type != "pin" or t.target not in scene.configurations or t.contact is None:
            continue
        for cj in scene.configurations[t.target].cut_joints:
            held = cj.anchor_at_entry and cj.b == t.contact.b and tuple(cj.point_b) == tuple(t.contact.point_b)
            if held and cj.normal is not None and cj.friction != t.contact.friction:
                out.append(f"{scene.path}: transitions[{i}] ({t.name}).contact.friction: = {mu(t.contact.friction)}, "
                           f"but the cut joint '{cj.name}' of '{t.target}' that holds the point after the strike has "
                           f"friction = {mu(cj.friction)}: the strike's impulse is judged with "
                           f"{mu(t.contact.friction)}, the stance's force with {mu(cj.friction)}; give both the same "
                           "mu if they are one surface")
    return out


def cmd_check(args) -> int:
    """Validate the scene and its URDFs, then build every configuration's Pinocchio model, so a
    URDF that Pinocchio rejects fails here and not when a run reaches that configuration."""
    from .scene.derive import check_derived
    from .model.mechanism import Mechanism
    from .scene.load import load_scene
    scene = load_scene(args.scene)
    mech = Mechanism(scene)
    problems = []
    for name, spec in scene.configurations.items():
        if spec.derivation is not None:
            continue  # built below, with the values its guards fix
        try:
            mech[name]
        except PcmmError as exc:
            problems += [f"configuration '{name}': {p}" for p in exc.problems]
    if problems:
        raise UsageError([f"{args.scene}: {p}" for p in problems])
    derived = check_derived(scene, mech.build)
    report = _check_geometry(scene)  # the geometry where the guards fix the posture
    def count(n: int, word: str) -> str:
        return f"{n} {word}" if n == 1 else f"{n} {word}s"
    say(f"{args.scene}: valid ({count(len(scene.configurations), 'configuration')}, all models built, "
        f"{count(len(scene.transitions), 'transition')}, {count(len(scene.forces), 'force element')}; "
        f"poses and contacts consistent at {count(len(report.postures), 'guard value')})")
    for line in derived:
        say(f"  {line}")
    for source, cut_joint, target in scene.lift_offs():  # releases pcmm adds by itself
        say(f"  '{source}': the point held by '{cut_joint}' lifts off into '{target}' where its normal force turns tensile")
    for line in _undrawn(scene):
        say(f"  {line}")
    return 0


def _undrawn(scene) -> list[str]:
    """A note per URDF with links the drawing cannot show (no box or sphere ``<visual>``),
    each with a visual to paste: the run itself does not need them."""
    from .scene.urdf import undrawn_links
    out = []
    for path in dict.fromkeys(spec.urdf for spec in scene.configurations.values()):
        links = undrawn_links(path)
        if links:
            names = ", ".join(f"'{n}'" for n, _ in links)
            out.append(f"{path.name}: link{'s' if len(links) > 1 else ''} {names} "
                       f"{'have' if len(links) > 1 else 'has'} no <box> or <sphere> <visual>: the drawing and the "
                       f"video show only {'their' if len(links) > 1 else 'its'} joints (and so does the replay page, "
                       f"unless a <cylinder> draws {'them' if len(links) > 1 else 'it'}); "
                       f"for example, " + "; ".join(f"in <link name=\"{n}\">: {v}" for n, v in links))
    return out


def _derive_run(scene, progress):
    """The run ``pcmm derive`` needs for values at entry: (the models it built, its end note)."""
    from .run.loop import RunOptions, simulate
    try:
        traj, note = simulate(scene, RunOptions(), progress=progress), None
    except SimulationError as exc:
        if exc.partial is None:
            raise
        traj, note = exc.partial, exc.text()
    return traj.stats.get("derived_configurations", {}), note


def cmd_derive(args) -> int:
    from .scene.derive import derived_urdfs
    from .scene.load import load_scene
    from .results.trajectory import atomic_write
    scene = load_scene(args.scene)
    if not any(s.derivation is not None for s in scene.configurations.values()):
        raise UsageError(f"{args.scene}: has no derived configuration (from = NAME, lock = [...]); "
                         "nothing to write")
    if args.out.exists() and not args.out.is_dir():
        raise UsageError(f"{args.out}: is a file; --out takes a folder")
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"{args.out}: cannot create the output folder: {exc.strerror}") from None
    # before a possibly long run: the files it will surely write
    _check_outputs([(f"configuration {n}", args.out / f"{n}.urdf") for n, s in scene.configurations.items()
                    if s.derivation is not None], args.force)
    update, close = _progress(False, scene.t_end)
    try:
        written, unreached, note = derived_urdfs(scene, lambda: _derive_run(scene, update))
    finally:
        close()
    files = [(args.out / (f"{name}.urdf" if k is None else f"{name}-{k}.urdf"), values, text)
             for name, k, values, text in written]
    renamed = sorted({name for name, k, _, _ in written if k is not None})
    _check_outputs([(f"derived URDF {p.name}", p) for p, _, _ in files], args.force)
    for path, values, text in files:
        atomic_write(path, lambda f, text=text: f.write(text), force=True)
        locks = ", ".join(f"{j} = {v:.10g}" for j, v in values.items())
        print(f"wrote {path} ({locks})")
    if renamed:
        print(f"entered at several values, one URDF each: {', '.join(renamed)}")
    for name in unreached:
        print(f"configuration '{name}': never reached by the run (t = 0 .. {scene.t_end:g} s); not written")
    if note:
        print(f"pcmm: error: the run stopped early, so only what it reached is written: {note}", file=sys.stderr)
        return SimulationError.exit_code
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


def _interrupted_at_start(args, exc: BaseException) -> SimulationError:
    """A signal before the run's first step (while the scene, the models or Pinocchio load): the
    failure whose partial trajectory is empty, marked partial, so a run asked for --out or
    --summary leaves a result that says it was stopped, and when, rather than none."""
    from .results.trajectory import Trajectory
    from .signals import describe, exit_status
    traj = Trajectory(scene=str(_resolved(args.scene)), scene_name=Path(args.scene).stem, impact=not args.no_impact)
    traj.status = "partial"
    traj.message = f"{args.scene}: {describe(exc)} while starting, before the run's first step (t = 0): nothing computed"
    failure = SimulationError(traj.message, partial=traj)
    failure.exit_code = exit_status(exc)  # 130 Ctrl-C, 143 SIGTERM, as for a run stopped later
    failure.interrupted = True
    return failure


def cmd_run(args, held=None) -> int:
    scene = None
    try:  # from here on a signal leaves a partial result (an empty one before the first step)
        if held is not None:
            held.reraise()  # a signal that arrived while the arguments were read
        from .scene.load import load_scene
        from .scene.settings import options_from_arguments
        from .run.loop import simulate
        from .results.summary import event_table
        _check_outputs([("--out", args.out), ("--summary", args.summary), ("--csv", args.csv),
                        ("--html", args.html)], args.force, folders=[("--plots", args.plots)], formats=True)
        if args.no_comparison and args.plots is None:
            raise UsageError("--no-comparison: only with --plots (it leaves out the figures' comparison run)")
        scene = load_scene(args.scene)
        _check_geometry(scene)
        opts = options_from_arguments(args, t_end=args.t_end, impact=not args.no_impact)
        update, close = _progress(args.quiet, args.t_end or scene.t_end)
    except (KeyboardInterrupt, ImportError) as exc:
        interrupt = _interrupt_in(exc)  # (Pinocchio or scipy interrupted while loading: an ImportError)
        if interrupt is None:
            raise
        failure, traj, opts = _interrupted_at_start(args, interrupt), None, None
    else:
        failure = None
        try:
            stored = {"store": args.store} if args.store is not None else {}  # a folder streamed to as it goes
            traj = simulate(scene, opts, progress=update, **stored)
        except SimulationError as exc:
            failure, traj = exc, exc.partial
        except KeyboardInterrupt as exc:  # before simulate's own loop began (models, assembly)
            failure, traj = _interrupted_at_start(args, exc), None
        finally:
            close()
    if failure is not None and getattr(failure, "interrupted", False):
        traj = failure.partial
        if not traj.segments and not (args.out or args.summary):
            raise failure  # nothing computed and no output asked for: no file to litter the folder
    elif failure is not None and (traj is None or not traj.segments):
        raise failure
    from .signals import deferred
    with deferred() as held:  # a second Ctrl-C (or SIGTERM) waits until the results are kept
        written, warnings, problems = _write_results(args, scene, opts, traj, partial=failure is not None)
    if not args.quiet and failure is None:
        say(f"{scene.name}: {'with' if traj.impact else 'without'} impact, "
            f"t = 0 .. {traj.t[-1]:.6g} s, configuration {scene.initial_configuration} -> "
            f"{traj.segments[-1].configuration}, {len(traj.events)} events, "
            f"{traj.stats['steps']} steps, {traj.stats['rhs_evals']} rhs evaluations, "
            f"{traj.stats['wall_s']:.3f} s solve")
        say(event_table(traj))
    if failure is None and traj.stats.get("closest_approach"):
        _say_approach(traj.stats["closest_approach"], args.quiet)
    for w in (w for e in traj.events for w in e.get("warnings", ())):  # check printed the assembly's
        _error(w, prefix="pcmm: warning: ")
    for w in _run_warnings(traj):
        _error(w, prefix="pcmm: warning: ")
    if failure is not None:
        kept = "; ".join(f"{what} {path}" for what, path in written) or "nothing could be saved"
        _error(f"the run stopped at t = {float(traj.t[-1]) if traj.t.size else 0.0:.6g} s; {kept}", prefix="pcmm: ")
    for what, path in written if failure is None else ():
        say(f"{what}: {path}")
    for w in warnings:
        _error(w, prefix="pcmm: warning: ")
    for p in problems:
        _error(p.text())
    if failure is not None:
        raise failure
    held.reraise()
    if problems:
        return max(p.exit_code for p in problems)
    if args.replay:
        from .viz.replay import serve
        _check_frames(traj, 60.0, "--replay")
        serve(traj)
    return 0


def _say_approach(records: list[dict], quiet: bool) -> None:
    """Each guard of the final configuration that did not fire: one that never fired in the run
    (or crossed its value against its direction) is a warning on stderr, which --quiet does not
    hide; one that fired before and not again by t_end is information (stdout, not with --quiet)."""
    from .run.approach import describe as describe_approach
    for r in records:
        if r.get("last_fired") is None or r.get("crossed_against") is not None:
            _error(describe_approach([r]), prefix="pcmm: warning: ")
        elif not quiet:
            say(describe_approach([r]))


def _write_results(args, scene, opts, traj, partial: bool):
    """Write every requested output of ``traj``, each on its own: one that fails never keeps
    the others from being written, and what the operating system refuses is written to a
    fallback folder that is named.  A partial run writes its trajectory (to ``--out``, else
    ``<scene>-partial.npz``, never over another file) and the requested summary, both
    marked ``status: "partial"``.  Returns ([(what, path)], [warnings], [errors])."""
    from .files import write_new
    from .results.summary import summary
    from .results.trajectory import dumps_json_finite
    written, warnings, problems = [], [], []

    def write_summary(path, force):
        initial = scene.initial_configuration if scene is not None else None  # None: stopped while loading it
        text = dumps_json_finite(summary(traj, initial), f"summary {args.summary}")
        return atomic_write_text(path, text, force)

    comparison = []

    def compare_run():
        # --no-comparison: not asked for; a scene without a transition: nothing to compare
        if not comparison and (args.no_comparison or not scene.transitions):
            comparison.append(None)
        if not comparison:
            from .run.loop import simulate
            try:
                other = simulate(scene, dataclasses.replace(opts, impact=not opts.impact))
                comparison.append(other)
                warnings.extend(f"{'without' if opts.impact else 'with'} impact (figures' comparison run): {w}"
                                for e in other.events for w in e.get("warnings", ()))
            except SimulationError as exc:
                comparison.append(None)
                warnings.append(f"--plots: the comparison run {'without' if opts.impact else 'with'} impact "
                                f"failed, so the figures show this run alone: {exc.text()}")
        return comparison[0]

    def shown(run):  # --dt: CSV and figures resampled on the dense output
        return run.resampled(args.dt) if (run is not None and getattr(args, "dt", None)) else run

    def plotted(run):  # the figures: --dt, else the plot resolution, on the integrator's dense output
        if run is None or getattr(args, "dt", None):
            return shown(run)
        from .viz.dense import plot_times
        return dataclasses.replace(run, segments=[s.resampled(plot_times(run, s)) for s in run.segments])

    def write_plots(folder, force):
        from .viz.plots import write_figures
        other = compare_run()
        return _figures_into(folder, force, lambda d: write_figures(plotted(traj), d, compare=plotted(other)))

    def write_html(path, force):
        from .viz.replay import html_page
        _check_frames(traj, 60.0, "--html")
        return atomic_write_text(path, html_page(traj), force)

    if partial:
        stem = Path(args.scene).stem  # a file name, whatever the scene's 'name' says
        target = args.out or Path(f"{stem}-partial.npz")

        def save_partial(path, force):
            if force:
                return traj.save(path, force=True)
            return write_new(path, lambda p: traj.save(p, force=False))
        jobs = [("the partial trajectory is saved in", target, save_partial)]
        if getattr(args, "store", None) is not None and args.out is None:
            # a stored run's partial trajectory is its store (every chunk written, ended 'partial'):
            # a <scene>-partial.npz beside it would load the whole run at once, what --store avoids
            jobs = []
            written.append(("the partial trajectory is in its store", args.store))
        if args.summary:
            jobs.append(("the partial summary in", args.summary, write_summary))
        skipped = [f for f, v in (("--csv", args.csv), ("--html", args.html), ("--plots", args.plots)) if v]
        if skipped:
            warnings.append(f"{', '.join(skipped)}: not written, the run did not complete "
                            "(the partial trajectory, status 'partial', holds every step it took)")
    else:
        jobs = [(label, path, fn) for label, path, fn in (
            ("trajectory", args.out, lambda p, force: traj.save(p, force=force)),
            ("summary", args.summary, write_summary),
            ("csv", args.csv, lambda p, force: shown(traj).to_csv(p, force=force)),
            ("figures", args.plots, write_plots),
            ("replay page", args.html, write_html)) if path is not None]
    for label, path, fn in jobs:
        try:
            out = fn(path, args.force)
            written.append((label, ", ".join(str(f) for f in out) if isinstance(out, list) else out))
        except (OutputError, UsageError) as exc:
            kept = _fallback(path, fn)
            if kept is None:
                problems.append(_Kept(f"{exc.text()}; no fallback folder would take it either: "
                                      "this output is lost"))
            else:
                written.append((f"{label} (instead of {path})", kept))
                problems.append(_Kept(f"{exc.text()}; written to {kept} instead"))
        except SimulationError as exc:  # e.g. a summary with numbers that are not finite
            problems.append(exc)
    return written, warnings, problems


class _Kept(OutputError):
    """An output written to a fallback place (the message says where)."""

    def __init__(self, text: str):
        PcmmError.__init__(self, text)


def _fallback(path: Path, fn):
    """Write the output ``fn`` makes to a free name in the first folder that takes it.  A free
    name another process takes meanwhile (runs started together on one ``--out``) moves on to the
    next free name in the same folder, not to the next folder."""
    from .files import fallback_folders, write_new
    for folder in fallback_folders(_resolved(path).parent):
        try:  # write_new: the first free name, path's own or stem-N, whatever others create meanwhile
            out = write_new(folder / Path(path).name, lambda target: fn(target, False))
            return ", ".join(str(f) for f in out) if isinstance(out, list) else out
        except (OutputError, UsageError):
            continue
    return None


def atomic_write_text(path, text: str, force: bool):
    from .files import atomic_write
    return atomic_write(path, lambda f: f.write(text), force=force)


def _figures_into(folder: Path, force: bool, draw) -> list[Path]:
    """Draw the figures into a fresh staging folder next to ``folder``, then move them in;
    an existing figure is refused (without --force) before any is moved."""
    from .files import publish_folder
    parent = _resolved(folder).parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".figures", dir=parent))
    except OSError as exc:
        raise OutputError(folder, exc) from None
    try:
        draw(staging)
    except BaseException as exc:
        shutil.rmtree(staging, ignore_errors=True)
        if isinstance(exc, OSError):
            raise OutputError(folder, exc) from None
        raise
    return publish_folder(staging, folder, force)


def cmd_new(args) -> int:
    from .scene.template import write_template
    files = write_template(args.name, args.dir, links=args.links, closed=args.closed, force=args.force)
    print(f"wrote {', '.join(str(f) for f in files)}; next: pcmm check {files[0]}")
    return 0


def cmd_sweep(args) -> int:
    from .scene.load import load_scene
    from .run.loop import RunOptions
    from .studies.sweep import make_plan, parse_set, read_plan_file, sweep
    if args.resume and args.force:
        raise UsageError("--resume and --force: give one (complete the table, or start it over)")
    if args.retry_failed and not args.resume:
        raise UsageError("--retry-failed runs a table's crashed and timed-out runs again: give it with --resume")
    plan_file = read_plan_file(args.plan) if args.plan else {"axes": [], "collect": []}
    axes = plan_file["axes"] + [parse_set(s) for s in args.sets]
    sample = args.sample or plan_file.get("sample") or "grid"
    runs = args.runs if args.runs is not None else plan_file.get("runs")
    seed = args.seed if args.seed is not None else plan_file.get("seed")
    plan = make_plan(axes, sample, runs, seed)
    collect = list(dict.fromkeys(plan_file["collect"] + args.collect))
    t_end = args.t_end if args.t_end is not None else plan_file.get("t_end")
    if args.plots is not None and not args.plots.parent.exists():
        raise UsageError(f"{args.plots}: folder {args.plots.parent} does not exist")
    from .studies.sweep import QUANTITIES
    for q in args.plot_quantities or ():
        if q not in QUANTITIES and q not in collect:
            raise UsageError(f"--plot {q!r}: not a quantity of the table; quantities: {', '.join(QUANTITIES)}, "
                             "or a --collect path")
    scene = load_scene(args.scene)
    try:  # SIGTERM and SIGHUP are interrupts already (main: signals.as_interrupts): rows kept, exit 128 + N
        res = sweep(scene, plan, args.out, RunOptions(t_end=t_end), collect, workers=args.workers,
                    scheduler=args.scheduler, resume=args.resume, force=args.force, progress=not args.quiet,
                    retry_failed=args.retry_failed, run_timeout=args.run_timeout or None)
    except KeyboardInterrupt as exc:
        from .signals import describe, exit_status
        _error(f"sweep {describe(exc)}; the finished runs are in {args.out}: complete it with --resume",
               prefix="pcmm: ")
        return exit_status(exc)
    _report_study(scene, res, args)
    if args.plots is not None:
        from .studies.plots import plot_sweep
        try:
            args.plots.mkdir(exist_ok=True)
            files = plot_sweep(args.out, plan.paths, args.plots, quantities=args.plot_quantities)
        except OSError as exc:
            raise OutputError(args.plots, exc) from None
        say(f"figures: {len(files)} files in {args.plots}")
    return 0


def cmd_optimize(args) -> int:
    from .scene.load import load_scene
    from .run.loop import RunOptions
    from .studies.optimize import optimize, parse_constraint, parse_vary
    if args.resume and args.force:
        raise UsageError("--resume and --force: give one (go on with the table, or start it over)")
    axes = [parse_vary(v) for v in args.vary]
    constraints = [parse_constraint(c) for c in args.subject_to]
    scene = load_scene(args.scene)
    try:
        res = optimize(scene, axes, args.minimize, args.out, RunOptions(t_end=args.t_end), constraints,
                       method=args.method, max_evals=args.max_evals, workers=args.workers, scheduler=args.scheduler,
                       resume=args.resume, force=args.force, run_timeout=args.run_timeout, seed=args.seed,
                       tol=args.tol, popsize=args.popsize)
    except KeyboardInterrupt as exc:
        from .signals import describe, exit_status
        _error(f"optimize {describe(exc)}; its runs are in {args.out}: go on with --resume", prefix="pcmm: ")
        return exit_status(exc)
    for why in res.dropped:
        _error(f"{args.out}: {why}", prefix="pcmm: warning: ")
    counts = ", ".join(f"{n} {s}" for s, n in sorted(res.status.items()))
    say(f"{scene.name}: {res.method}: {res.evaluations} runs asked for, {res.replayed} read from {res.out}, "
        f"{res.ran} run; table: {counts}")
    say(f"optimiser: {res.message}")
    if res.value is None:
        say(f"no run met every --subject-to bound with a value of {args.minimize}")
        return 0
    values = ", ".join(f"{p} = {v!r}" for p, v in res.x.items())
    say(f"best: {args.minimize} = {res.value!r} at {values} (run {res.run})")
    return 0


def _report_study(scene, res, args) -> None:
    """What a sweep or an optimisation did to its table (names shown without control characters)."""
    for why in res.dropped:
        _error(f"{args.out}: {why}", prefix="pcmm: warning: ")
    counts = ", ".join(f"{n} {s}" for s, n in sorted(res.status.items()))
    retried = f" ({res.retried} crashed or timed-out runs again)" if res.retried else ""
    say(f"{scene.name}: {res.planned} runs planned, {res.skipped} already in {res.out}, {res.ran} run{retried}; "
        f"table: {counts}")
    say(f"results: {res.out}" + (f" and {res.parquet}" if res.parquet else " (Parquet: install pyarrow)"))
    for c in res.uncollected:
        _error(f"--collect {c!r}: no run's summary has a value there", prefix="pcmm: warning: ")


def cmd_replay(args) -> int:
    from .results.trajectory import Trajectory
    traj, *others = [Trajectory.load(p) for p in args.trajectory]
    if args.video:
        _check_outputs([("--video", args.video)], args.force)
        from .viz.video import write_video
        fps = args.fps if args.fps != 60.0 else 30.0  # the page's 60 fps default; a video's is 30
        info = write_video(traj, args.video, others=others, fps=fps, speed=args.speed, slow=args.slow,
                           window=args.slow_window)
        say(f"video: {args.video} ({info['frames']} frames at {fps:g} fps, {info['clock'].duration:.3g} s)")
        return 0
    _check_frames(traj, args.fps, "replay")
    if args.html:
        _check_outputs([("--html", args.html)], args.force)
        from .viz.replay import html_page
        atomic_write_text(args.html, html_page(traj, fps=args.fps, others=others, layout=args.layout,
                                               view=args.view), args.force)
        say(f"replay page: {args.html}")
        return 0
    from .viz.replay import serve
    serve(traj, fps=args.fps, others=others, layout=args.layout, view=args.view)
    return 0


def cmd_plot(args) -> int:
    from .viz.plots import write_figures
    from .results.trajectory import Trajectory
    _check_outputs([], args.force, folders=[("--out", args.out)])
    from .viz.dense import hermite  # a saved run: its steps, drawn C1 through their recorded rates
    traj = hermite(Trajectory.load(args.trajectory))
    other = hermite(Trajectory.load(args.compare)) if args.compare else None
    files = _figures_into(args.out, args.force,
                          lambda d: write_figures(traj, d, compare=other, impulse_sign=args.impulse_sign))
    say(f"figures: {', '.join(str(f) for f in files)}")
    return 0


def cmd_graph(args) -> int:
    from .results.trajectory import Trajectory, record_views
    from .scene.load import load_scene
    from .viz.graph import graph_figure
    out = args.out or Path(f"{args.scene.stem}_graph.png")
    if out.suffix.lower() not in (".png", ".svg", ".pdf"):
        raise UsageError(f"--out {out}: the graph is written as .png, .svg or .pdf, not '{out.suffix}'")
    _check_outputs([("--out", out)], args.force)
    scene = load_scene(args.scene)
    events = None
    if args.run:
        run = Trajectory.load(args.run)
        if run.scene_name != scene.name:
            raise UsageError(f"--run {args.run}: a run of scene '{run.scene_name}', not of {args.scene} "
                             f"('{scene.name}')")
        events = run.events
    g = graph_figure(record_views(scene), events, title=scene.name, initial=scene.initial_configuration)
    fmt = out.suffix.lower().lstrip(".")
    from .files import atomic_write
    atomic_write(out, lambda f: g.figure.savefig(f, format=fmt), force=args.force, binary=True)
    fired = f", {sum(len(e.times) for e in g.edges)} firings of {len(events)} events" if events is not None else ""
    say(f"graph: {out} ({len(g.nodes)} configurations, {len(g.edges)} transitions{fired})")
    return 0


_signals.release(_AT_IMPORT)

if __name__ == "__main__":
    sys.exit(main())
