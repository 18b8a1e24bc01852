"""Optimisation over a scene's values (``pcmm optimize``): minimise one output of the run
(a quantity of :data:`~pcmm.studies.job.QUANTITIES` or a summary path) over boxes of value
paths, optionally subject to bounds on other outputs, with :mod:`scipy.optimize`.

Every evaluation is a run, and every run is a row of the same results table as ``pcmm sweep``
(:mod:`pcmm.studies.table`): checked, locked, resumable.  The methods are deterministic, so a
resumed optimisation *replays* the table: the optimiser starts again from the same point, every
run it asks for that the table already has is read from it (the same text, so the same numbers,
so the same next point), and only the runs beyond the table are run.  No row is lost or run twice.

Methods:

* ``cobyqa`` (the default where scipy has it, else ``powell``): derivative-free, bounded, with
  the constraints as such (Ragonneau and Zhang's COBYQA); one run at a time.
* ``powell``: derivative-free, bounded; constraints by an exact penalty.
* ``de``: :func:`scipy.optimize.differential_evolution`, seeded; each generation is one batch
  of runs on the pool or the Dask cluster (``vectorized``), constraints as such.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np

from ..errors import UsageError
from ..files import atomic_write
from .job import QUANTITIES, Job, _token, check_collect
from .plan import Axis, parse_set
from .table import ResultsTable, columns, write_parquet

METHODS = ("cobyqa", "powell", "de")
#: the weight of a constraint's violation added to the objective by ``powell`` (exact penalty)
PENALTY = 1e3


@dataclass(frozen=True)
class Constraint:
    output: str
    op: str  # "<=" or ">="
    value: float

    def text(self) -> str:
        return f"{self.output}{self.op}{self.value:g}"


def parse_vary(text: str) -> Axis:
    """``PATH=LOW:HIGH``: a box of one value path."""
    axis = parse_set(text.replace("--set", "--vary"))
    if axis.low is None:
        raise UsageError(f"--vary {text!r}: give PATH=LOW:HIGH, the box the optimiser searches")
    return axis


def parse_constraint(text: str) -> Constraint:
    """``OUTPUT<=VALUE`` or ``OUTPUT>=VALUE``."""
    m = re.fullmatch(r"\s*([^<>=\s]+)\s*(<=|>=)\s*(\S+)\s*", text)
    value = None
    if m:
        try:
            value = float(m.group(3))
        except ValueError:
            value = None
    if not m or value is None or not math.isfinite(value):
        raise UsageError(f"--subject-to {text!r}: give OUTPUT<=VALUE or OUTPUT>=VALUE with a number, "
                         "e.g. 'first_impact_t<=0.5'")
    return Constraint(m.group(1), m.group(2), value)


def default_method() -> str:
    from scipy.optimize import minimize
    try:
        minimize(lambda x: float(x[0] ** 2), [0.5], method="COBYQA", bounds=[(0.0, 1.0)], options={"maxfev": 1})
        return "cobyqa"
    except ValueError:  # this scipy has no COBYQA (before 1.14)
        return "powell"


@dataclass
class OptimizeResult:
    out: Path
    method: str
    x: dict  # the best feasible run's values
    value: float | None  # its output
    run: int | None  # its row
    evaluations: int  # runs the optimiser asked for (repeats counted once)
    ran: int  # of them, run now
    replayed: int  # of them, read from the table
    message: str
    status: dict = field(default_factory=dict)
    dropped: list = field(default_factory=list)
    parquet: Path | None = None


def _number(text) -> float | None:
    try:
        x = float(text)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


class Evaluations:
    """The runs of an optimisation: each a row of the table, looked up by its values first."""

    def __init__(self, scene, axes: list[Axis], table: ResultsTable, runner, options, collect):
        self.scene, self.axes, self.table, self.runner = scene, axes, table, runner
        self.options, self.collect = options, tuple(collect)
        self.paths = [a.path for a in axes]
        self.raw, self.token = scene.source, _token(scene.source)
        self.next_run = 1 + max((int(r["run"]) for r in table.rows()), default=-1)
        self.asked: set = set()
        self.before = set(table.done)  # the runs the table had when the optimisation (re)started
        self.ran = self.replayed = 0

    def values(self, x) -> tuple:
        # in the box exactly (an optimiser may step a rounding outside it), as Python floats
        return tuple(float(min(max(float(v), a.low), a.high)) for v, a in zip(x, self.axes))

    def rows(self, points) -> list[dict]:
        """The row of each point (a batch: the missing runs run together)."""
        vals = [self.values(x) for x in points]
        keys = [self.table.key_of(v) for v in vals]
        todo, seen = [], set()
        for v, k in zip(vals, keys):
            if k not in self.asked:
                self.asked.add(k)
                self.replayed += k in self.before
            if k not in self.table.done and k not in seen:
                seen.add(k)
                todo.append(Job(self.next_run, str(self.scene.path), self.raw, self.token,
                                dict(zip(self.paths, v)), self.options, self.collect))
                self.next_run += 1
        for row in self.runner.rows(iter(todo)):
            self.table.append(row)
            self.ran += 1
        return [self.table.done[k] for k in keys]


def optimize(scene, axes: list[Axis], minimize: str, out: str | Path, options=None,
             subject_to: Iterable[Constraint] = (), method: str | None = None, max_evals: int = 100,
             workers: int | None = None, scheduler: str | None = None, resume: bool = False,
             force: bool = False, run_timeout: float | None = None, seed: int | None = 0,
             tol: float = 1e-6, popsize: int = 8, worker_init: str | None = None) -> OptimizeResult:
    """Minimise the output ``minimize`` of the runs of ``scene`` over the boxes ``axes``.

    ``max_evals`` bounds the runs (``de``: about ``max_evals`` / (``popsize`` x the number of
    boxes) generations); ``tol`` is COBYQA's final trust-region radius in the box scaled to
    [0, 1], Powell's ``xtol`` there, and DE's relative ``tol``.  ``workers`` (default: 1 for
    ``cobyqa``/``powell``, which ask one run at a time; the usable cores for ``de``) and
    ``scheduler`` as for :func:`pcmm.studies.sweep.sweep`."""
    from scipy import optimize as so
    from ..run.loop import RunOptions
    from .backends import Runner
    from .pool import DEFAULT_RUN_TIMEOUT
    from .sweep import _meta, usable_cores, validate_plan
    from .plan import Plan
    options = options or RunOptions()
    constraints = list(subject_to)
    method = (method or default_method()).lower()
    if method not in METHODS:
        raise UsageError(f"--method {method!r}: one of {', '.join(METHODS)}")
    if not axes:
        raise UsageError("nothing to vary: give at least one --vary PATH=LOW:HIGH")
    outputs = [minimize, *(c.output for c in constraints)]
    collect = [o for o in dict.fromkeys(outputs) if o not in QUANTITIES]
    check_collect(collect)
    paths = [a.path for a in axes]
    if len(set(paths)) != len(paths):
        raise UsageError("--vary: a path is given twice")
    lows, highs = np.array([a.low for a in axes]), np.array([a.high for a in axes])
    centre = tuple(float(v) for v in (lows + highs) / 2)
    validate_plan(scene, Plan(tuple(paths), (tuple(float(v) for v in lows), tuple(float(v) for v in highs), centre)))
    out = Path(out)
    if workers is None:
        workers = usable_cores() if method == "de" else 1
    run_timeout = DEFAULT_RUN_TIMEOUT if run_timeout is None else (run_timeout or None)
    study = {"minimize": minimize, "subject_to": [c.text() for c in constraints], "method": method,
             "seed": seed, "tol": tol, "popsize": popsize,
             "boxes": {a.path: [a.low, a.high] for a in axes}}
    meta = _meta(out, scene, Plan(tuple(paths), ()), options, collect, resume, study=study)
    runner = None
    table = ResultsTable(out, columns(paths, collect), len(paths), resume, force)
    try:
        atomic_write(out.with_name(out.name + ".sweep.json"), lambda f: f.write(meta), force=True)
        runner = Runner(workers, scheduler, run_timeout, worker_init)
        ev = Evaluations(scene, axes, table, runner, options, collect)
        span = highs - lows

        def unit(z):  # the optimisers work in the box scaled to [0, 1]
            return lows + np.clip(np.asarray(z, float), 0.0, 1.0) * span

        def out_of(row, output):
            return _number(row.get(output)) if row["status"] == "complete" else None

        worst = [None]

        def objective_of(row):
            f = out_of(row, minimize)
            if f is None:  # a run without the output: worse than any seen (the table says why)
                w = worst[0] if worst[0] is not None else 0.0
                return w + abs(w) + 1.0
            worst[0] = f if worst[0] is None else max(worst[0], f)
            return f

        def slack(row, c):  # >= 0 where the constraint holds
            g = out_of(row, c.output)
            if g is None:
                return -1.0
            return c.value - g if c.op == "<=" else g - c.value

        if method == "de":
            def f_batch(z):  # z: (N, S) with vectorized=True
                pts = [unit(col) for col in np.atleast_2d(z).T]
                return np.array([objective_of(r) for r in ev.rows(pts)])

            def g_batch(z):
                pts = [unit(col) for col in np.atleast_2d(z).T]
                rows = ev.rows(pts)
                return np.array([[slack(r, c) for r in rows] for c in constraints])
            cons = [so.NonlinearConstraint(g_batch, 0.0, np.inf)] if constraints else ()
            n = len(axes)
            maxiter = max(1, max_evals // (popsize * n) - 1)
            res = so.differential_evolution(f_batch, [(0.0, 1.0)] * n, popsize=popsize, maxiter=maxiter, tol=tol,
                                            rng=seed, polish=False, updating="deferred", vectorized=True,
                                            constraints=cons, init="latinhypercube")
        else:
            def f(z):
                return objective_of(ev.rows([unit(z)])[0])

            x0 = np.full(len(axes), 0.5)
            if method == "cobyqa":
                cons = [so.NonlinearConstraint(lambda z, c=c: slack(ev.rows([unit(z)])[0], c), 0.0, np.inf)
                        for c in constraints]
                res = so.minimize(f, x0, method="COBYQA", bounds=[(0.0, 1.0)] * len(axes), constraints=cons,
                                  options={"maxfev": max_evals, "final_tr_radius": tol,
                                           "initial_tr_radius": 0.25})  # a quarter of the box: 1 (its default) jumps to a corner and stalls there
            else:
                def penalised(z):
                    row = ev.rows([unit(z)])[0]
                    return objective_of(row) + PENALTY * sum(max(0.0, -slack(row, c)) for c in constraints)
                res = so.minimize(penalised if constraints else f, x0, method="Powell",
                                  bounds=[(0.0, 1.0)] * len(axes), options={"maxfev": max_evals, "xtol": tol})
        best = _best(table.rows(), paths, minimize, constraints, out_of, slack)
        result = OptimizeResult(out, method, best[0], best[1], best[2], len(ev.asked), ev.ran, ev.replayed,
                                str(res.message), dropped=table.dropped)
    finally:
        if runner is not None:
            runner.close()
        table.close()
    for r in table.rows():
        result.status[r["status"]] = result.status.get(r["status"], 0) + 1
    result.parquet = write_parquet(out)
    return result


def _best(rows, paths, minimize, constraints, out_of, slack):
    """The feasible row with the least output (its values, output and run), from the table."""
    best = (None, None, None)
    for r in rows:
        f = out_of(r, minimize)
        if f is None or any(slack(r, c) < 0 for c in constraints):
            continue
        if best[1] is None or f < best[1]:
            best = ({p: float(r[p]) for p in paths}, f, int(r["run"]))
    return best
