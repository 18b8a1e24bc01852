"""Design studies: a plan of scene variations, run on this machine's cores or on a Dask
cluster, one row per run in a results table that survives interruption.

* A **plan** (:mod:`pcmm.sweep_plan`) is a list of runs, each a value per swept path
  (:mod:`pcmm.variations`): a grid over listed values or ``start:stop:count`` ranges, or
  random / Latin-hypercube samples of ``low:high`` boxes with a seed.
* Every run's scene is validated before the first run starts, with the scene
  validator's own messages.
* A **run** (:mod:`pcmm.sweep_run`) rebuilds its scene from the parsed TOML (the base
  scene and its URDFs are read once per worker process), simulates it, and reduces
  the summary to one row of quantities.  A run that fails is a row with its status
  and error message.
* The runs go to this process, a local process pool or a Dask cluster
  (:mod:`pcmm.sweep_backends`).
* The **results table** (:mod:`pcmm.sweep_table`) is a CSV appended and flushed as runs
  finish; ``resume`` reads it back and runs only the plans' runs it lacks, identified
  by their parameter values.
"""
from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Iterable

from ..errors import SceneError, UsageError
from .backends import DaskCluster, _distributed, run_dask, run_pool, run_serial
from .pool import DEFAULT_RUN_TIMEOUT
from .plan import SAMPLES, Axis, Plan, axis_from_spec, make_plan, parse_set, read_plan_file  # noqa: F401
from .job import QUANTITIES, Job, _token, check_collect, collect_value, quantities, run_one  # noqa: F401
from .table import ResultsTable, columns, write_parquet
from ..files import atomic_write
from ..scene.variations import value_text


@dataclass
class SweepResult:
    out: Path
    planned: int
    skipped: int  # already in the table (resume)
    ran: int
    status: dict = field(default_factory=dict)  # status -> count, over the whole table
    parquet: Path | None = None
    uncollected: list = field(default_factory=list)  # --collect paths no run's summary had
    dropped: list = field(default_factory=list)  # rows of the table dropped on resume, and why
    retried: int = 0  # crashed or timed-out rows run again (retry_failed)


def validate_plan(scene, plan: Plan) -> None:
    """Build every run's scene before the first run: the validator's message, with the run.

    One build per run (a sampled plan of 10,000 runs: about 7 s on this machine); only a run
    that fails is built again with each of its values alone, so that a path or value that is
    wrong on its own is named on its own (``--set PATH = VALUE: ...``)."""
    alone: dict = {}  # (path, value text) -> the problems of that value on its own ([]: none)

    def problems_alone(path, v) -> list:
        key = (path, value_text(v))
        if key not in alone:
            try:
                scene.with_values({path: v})
                alone[key] = []
            except SceneError as exc:
                alone[key] = [f"--set {path} = {value_text(v)}: {p}" for p in exc.problems]
        return alone[key]

    for i, vals in enumerate(plan.runs):
        try:
            scene.with_values(plan.values(i))
        except SceneError as exc:
            for path, v in zip(plan.paths, vals):
                own = problems_alone(path, v)
                if own:
                    raise SceneError(own) from None
            desc = ", ".join(f"{p} = {value_text(v)}" for p, v in zip(plan.paths, vals))
            raise SceneError([f"run {i} ({desc}): {p}" for p in exc.problems]) from None


def sweep(scene, plan: Plan, out: str | Path, options=None, collect: Iterable[str] = (), workers: int | None = None,
          scheduler: str | None = None, resume: bool = False, force: bool = False,
          progress: bool = False, retry_failed: bool = False, run_timeout: float | None = DEFAULT_RUN_TIMEOUT,
          worker_init: str | None = None) -> SweepResult:
    """Run every run of ``plan`` on variations of ``scene`` and write the results table ``out``.

    ``workers`` = 1 runs in this process; otherwise (default: the cores this process may use)
    a local pool of worker processes, or the Dask cluster at ``scheduler`` (``"local"``: a
    LocalCluster).  On the pool and on Dask a run that crashes its worker or runs longer than
    ``run_timeout`` seconds is a ``crashed`` or ``timeout`` row and the sweep goes on.
    Rows are written whole as runs finish, so an interrupted sweep keeps every finished run;
    ``resume`` runs only what the table lacks (and the crashed or timed-out runs with
    ``retry_failed``).  ``worker_init`` (``"module:function"``) is called in each pool worker
    as it starts.
    """
    from ..run.loop import RunOptions
    options = options or RunOptions()
    collect = tuple(collect)
    check_collect(collect)
    if scheduler:
        _distributed()
    validate_plan(scene, plan)
    out = Path(out)
    in_process = workers == 1
    workers = workers or usable_cores()
    meta = _meta(out, scene, plan, options, collect, resume)
    dask = DaskCluster(scheduler, workers) if scheduler else None
    try:
        table = ResultsTable(out, columns(plan.paths, collect), len(plan.paths), resume, force, retry_failed)
        try:
            atomic_write(out.with_name(out.name + ".sweep.json"), lambda f: f.write(meta), force=True)
            todo = [i for i in range(len(plan.runs)) if table.key_of(plan.runs[i]) not in table.done]
            result = SweepResult(out, len(plan.runs), len(plan.runs) - len(todo), 0, dropped=table.dropped,
                                 retried=table.retried)
            raw, path = scene.source, str(scene.path)
            token = _token(raw)
            jobs = (Job(i, path, raw, token, plan.values(i), options, collect) for i in todo)
            if dask is not None:
                stream = run_dask(jobs, dask, run_timeout)
            elif in_process or not todo:
                stream = run_serial(jobs)
            else:
                stream = run_pool(jobs, min(workers, len(todo)), run_timeout, worker_init)
            _consume(stream, table, result, collect, _bar(progress, len(todo)))
        finally:
            table.close()
    finally:
        if dask is not None:
            dask.close()
    rows = table.rows()
    for r in rows:
        result.status[r["status"]] = result.status.get(r["status"], 0) + 1
    found = {c for c in collect for r in rows if r.get(c) not in (None, "")}
    result.uncollected = [c for c in collect if c not in found]
    result.parquet = write_parquet(out)
    return result


def usable_cores() -> int:
    """The cores this process may run on (a container's or taskset's limit, not the machine's)."""
    try:
        return len(os.sched_getaffinity(0)) or 1
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _consume(stream, table: ResultsTable, result: SweepResult, collect, bar) -> None:
    """Append each row as its run finishes; stopping (an error, Ctrl-C) stops the runs in flight."""
    try:
        for row in stream:
            table.append(row)
            result.ran += 1
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
        stream.close()


def _bar(show: bool, total: int):
    import sys
    if not show or not sys.stderr.isatty() or total == 0:
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=total, unit="run", file=sys.stderr, smoothing=0.1)


def _meta(out: Path, scene, plan: Plan, options, collect, resume: bool, study: dict | None = None) -> str:
    """The sweep's identity, kept beside its table: resuming with another scene or other run
    options would mix results that do not belong together, and is refused."""
    meta_path = out.with_name(out.name + ".sweep.json")
    meta = {"scene": str(Path(scene.path).resolve()), "scene_data": _token(scene.source),
            "paths": list(plan.paths), "collect": list(collect),
            "options": {k: v for k, v in asdict(options).items() if v is not None}}
    if study is not None:  # an optimisation: its method and settings decide which runs it asks for
        meta["optimize"] = study
    text = json.dumps(meta, indent=2, default=str)
    if resume and out.exists() and meta_path.exists():
        try:
            old = json.loads(meta_path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise UsageError(f"{meta_path}: unreadable ({exc}); it records what {out} was made with") from None
        # the scene's data decides, not where the file lies (a moved checkout resumes)
        new = json.loads(text)
        diff = [k for k in new if k != "scene" and old.get(k) != new[k]]
        if diff:
            raise UsageError(f"{out}: was made with another {', '.join(diff)} ({meta_path}); resume "
                             "with the same scene, values and run options, or start over with --force")
    return text
