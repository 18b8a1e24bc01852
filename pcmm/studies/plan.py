"""The plan of a design study: which values each run gives the swept value paths.

A grid over listed values or ``start:stop:count`` ranges (the first path varies
slowest), or random / Latin-hypercube (``scipy.stats.qmc``) samples of ``low:high``
boxes with a seed, so that the plan, and a resumed sweep, is reproducible.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import UsageError
from ..scene.variations import parse_scalar, plain, value_text

SAMPLES = ("grid", "random", "lhs")


@dataclass(frozen=True)
class Axis:
    """One swept value path: listed values (grid) or a box ``[low, high]`` (random, lhs)."""

    path: str
    values: tuple | None = None
    low: float | None = None
    high: float | None = None


def parse_set(text: str) -> Axis:
    """``PATH=0.2,0.5,0.8``, ``PATH=start:stop:count`` or ``PATH=low:high`` (samples)."""
    path, sep, spec = text.partition("=")
    path = path.strip()
    if not sep or not path or not spec.strip():
        raise UsageError(f"--set {text!r}: give PATH=VALUES, e.g. 'forces.tau1.value=1.5,2.0' or "
                         "'forces.tau1.value=1.5:2.5:5' (start:stop:count)")
    where = f"--set {path}"
    spec = spec.strip()
    if ":" in spec and not spec.startswith(('"', "'")):
        parts = [parse_scalar(p) for p in spec.split(":")]
        if not all(_is_number(p) for p in parts):
            raise UsageError(f"{where}={spec}: a range is start:stop:count or low:high, with numbers")
        if len(parts) == 3:
            return axis_from_spec(path, {"start": parts[0], "stop": parts[1], "count": parts[2]}, where)
        if len(parts) == 2:
            return axis_from_spec(path, {"low": parts[0], "high": parts[1]}, where)
        raise UsageError(f"{where}={spec}: a range is start:stop:count (grid) or low:high (samples)")
    return axis_from_spec(path, [parse_scalar(p) for p in spec.split(",")], where)


def axis_from_spec(path: str, spec, where: str) -> Axis:
    """An axis from a list of values, ``{start, stop, count}`` or ``{low, high}``."""
    if isinstance(spec, list):
        if not spec:
            raise UsageError(f"{where}: no values")
        texts = [value_text(v) for v in spec]
        dup = sorted({t for t in texts if texts.count(t) > 1})
        if dup:
            raise UsageError(f"{where}: value {dup[0]} is given twice (a run is identified by its values)")
        return Axis(path, values=tuple(plain(v) for v in spec))
    if isinstance(spec, dict) and set(spec) == {"start", "stop", "count"}:
        start, stop, count = spec["start"], spec["stop"], spec["count"]
        if not (_is_number(start) and _is_number(stop) and isinstance(count, int) and count >= 1):
            raise UsageError(f"{where}: start:stop:count needs numbers and a whole count >= 1 "
                             f"(got {start!r}:{stop!r}:{count!r})")
        if count > 1 and start == stop:
            raise UsageError(f"{where}: start = stop gives {count} equal values; give count = 1")
        # to 15 significant digits: 0.15:0.35:9 gives 0.2, not linspace's 0.19999999999999998
        vals = [float(f"{v:.15g}") for v in np.linspace(start, stop, count)]
        if all(isinstance(x, int) for x in (start, stop)) and all(float(v).is_integer() for v in vals):
            vals = [int(v) for v in vals]  # an integer setting (max_events) stays an integer
        return Axis(path, values=tuple(vals))
    if isinstance(spec, dict) and set(spec) == {"low", "high"}:
        low, high = spec["low"], spec["high"]
        if not (_is_number(low) and _is_number(high) and low < high):
            raise UsageError(f"{where}: low:high needs two numbers with low < high (got {low!r}:{high!r})")
        return Axis(path, low=float(low), high=float(high))
    raise UsageError(f"{where} = {spec!r}: give a list of values, {{start, stop, count}} or {{low, high}}")


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


@dataclass(frozen=True)
class Plan:
    """The runs of a sweep: one tuple of values (in ``paths`` order) per run."""

    paths: tuple[str, ...]
    runs: tuple[tuple, ...]

    def values(self, i: int) -> dict[str, Any]:
        return dict(zip(self.paths, self.runs[i]))

    def key(self, i: int) -> tuple[str, ...]:
        return tuple(value_text(v) for v in self.runs[i])


def make_plan(axes: list[Axis], sample: str = "grid", runs: int | None = None,
              seed: int | None = None) -> Plan:
    """A grid over every axis's values (the first axis varies slowest), or ``runs``
    random or Latin-hypercube (``scipy.stats.qmc``) points of the axes' boxes."""
    if not axes:
        raise UsageError("nothing to sweep: give at least one --set PATH=VALUES (or a plan file's [set])")
    paths = [a.path for a in axes]
    dup = sorted({p for p in paths if paths.count(p) > 1})
    if dup:
        raise UsageError(f"--set {dup[0]}: the path is swept twice")
    if sample not in SAMPLES:
        raise UsageError(f"sample = {sample!r}: must be one of {', '.join(SAMPLES)}")
    if sample == "grid":
        ranged = [a.path for a in axes if a.values is None]
        if ranged:
            raise UsageError(f"--set {ranged[0]}: low:high is a box for random or lhs samples; a grid "
                             "takes listed values or start:stop:count")
        if runs is not None:
            raise UsageError("--runs is the number of random or lhs samples; a grid runs every combination")
        return Plan(tuple(paths), tuple(itertools.product(*(a.values for a in axes))))
    listed = [a.path for a in axes if a.values is not None]
    if listed:
        raise UsageError(f"--set {listed[0]}: {sample} samples draw from a box: give low:high")
    if runs is None or runs < 1:
        raise UsageError(f"{sample} samples need --runs N (N >= 1)")
    if seed is None:
        raise UsageError(f"{sample} samples need --seed S, so that the plan (and --resume) is reproducible")
    if sample == "random":
        unit = np.random.default_rng(seed).random((runs, len(axes)))
    else:
        from scipy.stats import qmc
        unit = qmc.LatinHypercube(d=len(axes), rng=seed).random(runs)
    low = np.array([a.low for a in axes])
    high = np.array([a.high for a in axes])
    pts = low + unit * (high - low)
    return Plan(tuple(paths), tuple(tuple(float(x) for x in row) for row in pts))


def read_plan_file(path: str | Path) -> dict:
    """A sweep file (TOML): ``[set]`` paths to values (a list, ``{start, stop, count}`` or
    ``{low, high}``), and optionally ``sample``, ``runs``, ``seed``, ``collect``, ``t_end``."""
    import tomllib
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UsageError(f"{path}: sweep file not found") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path}: not valid TOML: {exc}") from None
    from ..scene import schema as S
    keys = [S.Key("set", "table", doc="value path = values"), S.Key("sample", "str", required=False,
            default="grid", check=S.one_of(*SAMPLES)), S.Key("runs", "int", required=False, check=S.positive),
            S.Key("seed", "int", required=False), S.Key("collect", "list", required=False, default=[],
            check=S.names_list), S.Key("t_end", "number", required=False, check=S.positive)]
    problems = S.Problems(str(path))
    out = S.check_table(raw, keys, "", problems)
    if problems:
        raise UsageError(problems.items)
    out["axes"] = [axis_from_spec(p, spec, f"{path}: set.{p}") for p, spec in out.pop("set").items()]
    return out
