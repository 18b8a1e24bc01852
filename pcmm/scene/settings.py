"""Solver settings: one declaration each, from which everything else is generated.

A :class:`Setting` names a knob of the run (``rtol``, ``event_tol``, ...) with
its kind, default, check and help text.  From the registry :data:`SETTINGS`
come, and nowhere else is a setting listed:

* the scene's ``[solver]`` keys and their validation (:func:`solver_keys`);
* :class:`SolverSettings`, the validated ``[solver]`` table of a scene;
* :class:`RunOptions`, the run's overrides (``None``: the scene's value);
* the ``pcmm run`` flags (:func:`add_arguments`), with their help and checks;
* :func:`resolve`, which merges scene and options and checks every value.

Adding a setting is one more entry in :data:`SETTINGS`; the integrators and the
run loop read it from the resolved settings by name.  The derived classes are
built from the registry as it is when they are asked for (and cached), so a
test can extend the registry and see the new setting everywhere.
"""
from __future__ import annotations

import argparse
import functools
import math
from dataclasses import dataclass, field, make_dataclass
from typing import Any, Callable, Sequence

from . import schema as S
from ..errors import UsageError
from ..ode.methods import METHODS

_PYTHON_TYPE = {"str": str, "number": float, "int": int, "bool": bool}


@dataclass(frozen=True)
class Setting:
    """One solver setting.

    ``kind`` is a schema kind (``"str" "number" "int" "bool"``); ``check`` returns a
    problem text (``"must be > 0"``) or ``None``; ``choices`` (a callable, so a registry
    filled later is seen) lists the allowed strings; ``help`` is the text of the CLI flag,
    the scene schema and :class:`RunOptions`' docstring.
    """

    name: str
    kind: str
    default: Any
    help: str
    check: Callable[[Any], str | None] | None = None
    choices: Callable[[], Sequence[str]] | None = None

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")

    def problem(self, value) -> str | None:
        """What is wrong with ``value`` (``None`` if nothing): its kind, NaN, choices, check."""
        if not S._type_ok(self.kind, value):
            return f"must be {S._KIND_WORDS[self.kind]}"
        if self.kind == "number" and math.isnan(value):
            return "must be a number, not NaN"
        if self.choices is not None and value not in self.choices():
            return f"must be one of {', '.join(self.choices())}"
        return self.check(value) if self.check is not None else None


def _methods() -> tuple[str, ...]:
    return tuple(METHODS)  # "auto" and every integrator of the registry


SETTINGS: tuple[Setting, ...] = (
    Setting("method", "str", "auto", "integrator; 'auto': DOP853F on trees, DOP853 with loops or drives "
            "(the cheaper at equal accuracy, docs/benchmarks/work_precision.md)", choices=_methods),
    Setting("rtol", "number", 1e-10, "relative tolerance", S.positive),
    Setting("atol", "number", 1e-12, "absolute tolerance", S.positive),
    Setting("max_step", "number", math.inf, "largest step in s", S.positive),
    Setting("step", "number", 1e-3, "step of fixed-step methods (RK4) in s", S.positive),
    Setting("event_tol", "number", 1e-14, "how precisely an event time is located on the dense output, in s",
            S.positive),
    Setting("max_steps", "int", 1_000_000, "stop with an error after this many steps in a segment "
            "(a run that needs more is too stiff for its method)", S.positive),
    Setting("accumulation_speed", "number", 1e-6,
            "post-impact normal speed below which repeated stop impacts end in a merge: m/s at a point "
            "contact; at a joint stop the joint's own rate (rad/s, or m/s for a prismatic joint), whatever its "
            "arm", S.non_negative),
    Setting("accumulation_interval", "number", 1e-9,
            "impact interval (s) below which repeated stop impacts end in a merge", S.non_negative),
    Setting("max_events", "int", 10_000, "stop with an error after this many events", S.positive),
    Setting("unmerge", "bool", True, "undo a stop-merge when the contact force holding it turns tensile"),
)


# ---- what the registry generates -------------------------------------------------------------------
@dataclass(frozen=True)
class _Derived:
    solver: type
    options: type
    resolved: type


def _options_doc(settings) -> str:
    lines = ["Accuracy and mode knobs of one run; ``None`` means the scene's ``[solver]`` value.",
             "", "Parameters", "----------",
             "t_end : float or None", "    End time of the run in s (default: the scene's ``t_end``)."]
    for s in settings:
        lines += [f"{s.name} : {_PYTHON_TYPE[s.kind].__name__} or None",
                  f"    {s.help[0].upper()}{s.help[1:]} (scene default {s.default!r})."]
    lines += ["impact : bool", "    ``False``: switch configurations without impulse (the paper's comparison runs).",
              "", "Examples", "--------",
              ">>> from pcmm import RunOptions",
              ">>> RunOptions(rtol=1e-9).rtol, RunOptions().rtol  # None: the scene's value",
              "(1e-09, None)"]
    return "\n".join(lines)


@functools.cache
def _derive(settings: tuple[Setting, ...]) -> _Derived:
    solver = make_dataclass(
        "SolverSettings", [(s.name, _PYTHON_TYPE[s.kind], field(default=s.default)) for s in settings],
        frozen=True)
    solver.__doc__ = "A scene's validated ``[solver]`` table (every key at its default unless given)."
    options = make_dataclass(
        "RunOptions", [("t_end", "float | None", field(default=None))]
        + [(s.name, f"{_PYTHON_TYPE[s.kind].__name__} | None", field(default=None)) for s in settings]
        + [("impact", bool, field(default=True))], frozen=True)
    options.__doc__ = _options_doc(settings)
    resolved = make_dataclass(
        "Resolved", [("t_end", float), ("impact", bool)] + [(s.name, _PYTHON_TYPE[s.kind]) for s in settings],
        frozen=True)
    resolved.__doc__ = "The settings a run uses: the scene's ``[solver]`` overridden by the run's options."
    for cls in (solver, options, resolved):
        cls.__module__ = __name__
    return _Derived(solver, options, resolved)


def solver_settings_type() -> type:
    return _derive(SETTINGS).solver


def run_options_type() -> type:
    return _derive(SETTINGS).options


SolverSettings = solver_settings_type()
RunOptions = run_options_type()
Resolved = _derive(SETTINGS).resolved


def solver_keys() -> list[S.Key]:
    """The scene's ``[solver]`` table schema: every key optional, at its default."""
    return [S.Key(s.name, s.kind, required=False, default=s.default, check=_scene_check(s), doc=s.help)
            for s in SETTINGS]


def _scene_check(s: Setting):
    if s.check is None and s.choices is None:
        return None
    return lambda value: s.problem(value)


def resolve(scene, options) -> Any:
    """The settings of a run: each option that is not ``None`` overrides the scene's
    ``[solver]`` value; every value is checked (:class:`~pcmm.errors.UsageError` lists
    each one at fault, by name)."""
    derived = _derive(SETTINGS)
    values = {"t_end": scene.t_end if getattr(options, "t_end", None) is None else options.t_end,
              "impact": getattr(options, "impact", True)}
    problems = []
    t_end = values["t_end"]
    if not (S._type_ok("number", t_end) and t_end > 0 and not math.isnan(t_end)):
        problems.append(f"t_end = {t_end!r}: must be a number > 0")
    for s in SETTINGS:
        given = getattr(options, s.name, None)
        value = getattr(scene.solver, s.name, s.default) if given is None else given
        text = s.problem(value)
        if text:
            problems.append(f"{s.name} = {value!r}: {text}")
        values[s.name] = value
    if problems:
        raise UsageError(problems)
    return derived.resolved(**values)


# ---- command line ------------------------------------------------------------------------------------
def _cli_type(s: Setting):
    """argparse type of a setting's flag: parsed, finite, checked, each error naming the flag."""
    name = s.flag[2:]

    def parse(text):
        if s.kind == "int":
            try:
                value = int(text)
            except ValueError:
                raise argparse.ArgumentTypeError(f"{name} = {text!r}: must be a whole number") from None
        elif s.kind == "number":
            try:
                value = float(text)
            except ValueError:
                raise argparse.ArgumentTypeError(f"{name} = {text!r}: must be a number") from None
            if not math.isfinite(value):
                raise argparse.ArgumentTypeError(f"{name} = {text!r}: must be a finite number")
        else:
            value = text
        problem = s.problem(value)
        if problem:
            raise argparse.ArgumentTypeError(f"{name} = {text!r}: {problem}")
        return value
    return parse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """One ``pcmm run`` flag per setting (``--rtol``, ``--unmerge/--no-unmerge``, ...)."""
    for s in SETTINGS:
        text = f"{s.help} (default: the scene's, else {s.default!r})".replace("%", "%%")
        if s.kind == "bool":
            parser.add_argument(s.flag, dest=s.name, action=argparse.BooleanOptionalAction, default=None, help=text)
        elif s.choices is not None:
            parser.add_argument(s.flag, dest=s.name, choices=list(s.choices()), default=None, help=text)
        else:
            parser.add_argument(s.flag, dest=s.name, type=_cli_type(s), default=None, help=text)


def options_from_arguments(args: argparse.Namespace, **run) -> Any:
    """The :class:`RunOptions` of parsed ``pcmm run`` flags; ``run`` gives t_end and impact."""
    return run_options_type()(**run, **{s.name: getattr(args, s.name) for s in SETTINGS})
