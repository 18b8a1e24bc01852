"""Table-driven validation of TOML data.

A table is checked against a list of :class:`Key` rows.  Every problem is
collected, none stops the check, so a user sees all that is wrong with a file
at once.  Each problem names the file, the dotted field path, the bad value and
what is allowed; an unknown key suggests its closest known neighbour.  A number
may be written as an expression string (``"pi/2"``, ``"30 deg"``;
:mod:`pcmm.expressions`), computed here before the type check.
"""
from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from typing import Any, Callable

from .expressions import ExpressionError, describe, evaluate

_MISSING = object()


@dataclass(frozen=True)
class Key:
    """One allowed key of a table.

    ``kind`` is one of ``"str" "number" "int" "bool" "table" "list"``;
    ``check`` returns a problem text (without location) or ``None``.
    ``default`` is used only when ``required`` is false; docs/scene_format.md documents it (generated).
    """

    name: str
    kind: str
    required: bool = True
    default: Any = None
    check: Callable[[Any], str | None] | None = None
    doc: str = ""


def _type_ok(kind: str, value: Any) -> bool:
    if "|" in kind:  # one of several kinds, e.g. "list|table"
        return any(_type_ok(k, value) for k in kind.split("|"))
    if kind == "number":
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, {"str": str, "bool": bool, "table": dict, "list": list}[kind])


_KIND_WORDS = {"number": "a number", "int": "an integer", "str": "a string",
               "bool": "true or false", "table": "a table", "list": "a list"}


class Problems:
    """Accumulates located problems for one file."""

    def __init__(self, file: str):
        self.file = file
        self.items: list[str] = []

    def add(self, where: str, text: str) -> None:
        loc = f"{self.file}: {where}" if where else self.file
        self.items.append(f"{loc}: {text}")

    def __bool__(self) -> bool:
        return bool(self.items)


def show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_table(table: Any, keys: list[Key], where: str, problems: Problems) -> dict:
    """Return a dict with every key of ``keys`` (defaults filled in).

    Missing, mistyped and failing values are reported and come back as ``None``.
    """
    out: dict[str, Any] = {}
    if not isinstance(table, dict):
        problems.add(where, f"= {show(table)}: must be a table")
        return {k.name: None for k in keys}
    known = {k.name for k in keys}
    for name in table:
        if name not in known:
            close = difflib.get_close_matches(name, sorted(known), n=1, cutoff=0.6)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            problems.add(_join(where, name),
                         f"unknown key{hint}; allowed keys: {', '.join(sorted(known))}")
    for key in keys:
        path = _join(where, key.name)
        value = table.get(key.name, _MISSING)
        if value is not _MISSING and _numeric(key):
            value, bad = numbers(value, key.kind)
            if bad:
                problems.add(path, bad)
                out[key.name] = None
                continue
        if value is _MISSING:
            if key.required:
                problems.add(path, f"missing; {key.doc or 'required'}")
                out[key.name] = None
            else:
                out[key.name] = key.default
            continue
        if not _type_ok(key.kind, value):
            problems.add(path, f"= {show(value)}: must be "
                         f"{' or '.join(_KIND_WORDS[k] for k in key.kind.split('|'))}"
                         + (f" ({key.doc})" if key.doc else ""))
            out[key.name] = None
            continue
        if key.kind == "number" and not math.isfinite(value):
            problems.add(path, f"= {show(value)}: must be finite")
            out[key.name] = None
            continue
        if key.check is not None:
            text = key.check(value)
            if text:
                problems.add(path, f"= {show(value)}: {text}")
                out[key.name] = None
                continue
        out[key.name] = value
    return out


#: How deep a scene's tables and arrays may nest (the deepest scene key is 5 levels down).
MAX_DEPTH = 32
_FLOAT_MAX = 1.7976931348623157e308


def check_plain(doc: Any, file: str) -> None:
    """Refuse, before any table is read, what no scene key can hold: nesting deeper than
    :data:`MAX_DEPTH` and integers beyond a floating-point number's range.  Iterative, so
    a hostile file cannot exhaust the recursion limit."""
    from ..errors import SceneError
    p = Problems(file)
    stack = [(doc, "", 0)]
    while stack:
        value, where, depth = stack.pop()
        if depth > MAX_DEPTH:
            p.add(where, f"nested more than {MAX_DEPTH} levels deep; no scene field nests like this")
            continue
        if isinstance(value, dict):
            stack += [(v, _join(where, str(k)), depth + 1) for k, v in value.items()]
        elif isinstance(value, list):
            stack += [(v, f"{where}[{i}]", depth + 1) for i, v in enumerate(value)]
        elif isinstance(value, int) and not isinstance(value, bool) and abs(value) > _FLOAT_MAX:
            p.add(where, f"= an integer of {len(str(abs(value)))} digits: beyond the range of a "
                  "floating-point number (about 1.8e308)")
        if len(p.items) >= 20:
            break
    if p:
        raise SceneError(p.items)
def _numeric(key: Key) -> bool:
    return key.kind == "number" or getattr(key.check, "numeric", False)


def numbers(value: Any, kind: str = "number") -> tuple[Any, str | None]:
    """Expression strings in a number (or in a list of numbers) computed to floats
    (:mod:`pcmm.expressions`); returns (value, problem text or None).  Anything else
    comes back unchanged for the type check to judge."""
    try:
        if isinstance(value, str) and kind == "number":
            return evaluate(value), None
        if isinstance(value, list):
            return [evaluate(x) if isinstance(x, str) else x for x in value], None
    except ExpressionError as exc:
        return value, describe(exc)
    return value, None


def _join(where: str, name: str) -> str:
    return f"{where}.{name}" if where else name


# ---- reusable checks -------------------------------------------------------
def positive(v):
    return None if v > 0 else "must be > 0"


def non_negative(v):
    return None if v >= 0 else "must be >= 0"


def unit_interval(v):
    return None if 0.0 <= v <= 1.0 else "must be in [0, 1]"


def friction_coefficient(v):
    """Coulomb's coefficient: a number >= 0, or "stick" (no slip, mu = infinity)."""
    if isinstance(v, str):
        return None if v == "stick" else 'must be a number >= 0 or "stick" (no slip)'
    return None if v >= 0 else 'must be >= 0 (or "stick": no slip)'


def one_of(*choices):
    def check(v):
        return None if v in choices else f"must be one of {', '.join(map(repr, choices))}"
    return check


def _numeric_check(check):
    """Mark a list check as one of numbers: its string entries are expressions."""
    check.numeric = True
    return check


def vector(n: int):
    def check(v):
        if len(v) != n or not all(_type_ok("number", x) and math.isfinite(x) for x in v):
            return f"must be a list of {n} finite numbers"
        return None
    return _numeric_check(check)


def vector_or(n: int, *words: str):
    """A list of ``n`` finite numbers, or one of the strings ``words``."""
    base = vector(n)

    def check(v):
        if isinstance(v, str):
            return None if v in words else (f"must be a list of {n} finite numbers or "
                                            + " or ".join(repr(w).replace("'", '"') for w in words))
        return base(v)
    return _numeric_check(check)


def nonzero_vector(n: int):
    base = vector(n)

    def check(v):
        return base(v) or (None if any(x != 0 for x in v) else "must not be the zero vector")
    return _numeric_check(check)


def point_or_entry(v):
    """A cut joint's point_a: [x, y], or "entry" (where b's point is when the configuration is entered)."""
    if isinstance(v, str):
        return None if v == "entry" else 'must be [x, y] or "entry" (anchored where b\'s point is at entry)'
    return vector(2)(v)


point_or_entry.numeric = True


@_numeric_check
def numbers_list(v):
    return None if v and all(_type_ok("number", x) and math.isfinite(x) for x in v) \
        else "must be a non-empty list of numbers"


def names_list(v):
    return None if all(isinstance(x, str) for x in v) else "must be a list of names (strings)"


def distinct_names(v):
    """A list of names each given once: a name listed twice is a slip (a joint cut twice gave a
    singular impulse solve), never a meaning."""
    dup = sorted({x for x in v if isinstance(x, str) and v.count(x) > 1})
    return names_list(v) or (f"names {', '.join(dup)} more than once" if dup else None)


def configuration_names(v):
    """The configurations an element acts in: distinct names, and at least one (an empty list
    was read as "every configuration", the opposite of what it says)."""
    if not v:
        return ("an empty list names no configuration, so the element would act in none; leave configurations "
                "out for every configuration, or remove the element")
    return distinct_names(v)


def name(v):
    """The name of a scene element: what its events, series and messages are named by."""
    return None if v.strip() else "must not be empty (the element's events, series and messages are named by it)"
