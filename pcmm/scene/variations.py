"""Scene variations as data: change any value of a scene by its path.

A *value path* names one value of the scene's TOML, the way a designer reads the
file: tables by key, arrays of tables (``[[forces]]``, ``[[transitions]]``,
``cut_joints``) by their ``name`` (``[[drives]]`` by their ``joint``), and any
list by index::

    forces.tau1.value                       # [[forces]] name = "tau1", key value
    transitions.O3 stop.restitution         # names may hold spaces (and dots)
    scene.gravity[1]   drives[0].coefficients[1]   initial.q.O1

A variation edits a copy of the parsed TOML the scene was loaded from and
rebuilds the scene through the loader, so every value is validated exactly as
the file is, with the same messages.  A path that leads nowhere is reported
with the closest valid keys; a final key the table does not have yet is added
and left to the validator (which names the allowed keys).
"""
from __future__ import annotations

import copy
import difflib
import math
import os
import tomllib
from pathlib import Path
from typing import Any, Mapping

from ..errors import SceneError
from .urdf import read_urdf

#: the key naming an element of an array of tables, per array; the rest go by ``name``
_ITEM_KEY = {"drives": "joint"}


def set_values(raw: dict, values: Mapping[str, Any], file: str | Path = "scene") -> dict:
    """A deep copy of the TOML document ``raw`` with ``values`` set by path."""
    out = copy.deepcopy(raw)
    placed: dict[tuple, str] = {}  # the value each path resolved to -> the path
    for path, value in values.items():
        steps = resolve(out, path, file)
        for where, other in placed.items():
            # two paths to one value ("forces.tau3.value" and "forces[2].value"), or one inside the
            # other's: the later would silently replace what the earlier set, and a sweep's table
            # would list values that no run used
            if where[:len(steps)] == tuple(steps) or tuple(steps[:len(where)]) == where:
                raise SceneError(f"{file}: value paths {other!r} and {path!r} both set {_shown(steps)}"
                                 f"{'' if len(where) == len(steps) else ' (one inside the other)'}: "
                                 "each value may be set by one path only")
        placed[tuple(steps)] = path
        node = out
        for s in steps[:-1]:
            node = node[s]
        node[steps[-1]] = plain(value)
    return out


def _shown(steps: list) -> str:
    """Resolved steps as the indexed path they are: ``forces[2].value``."""
    text = ""
    for s in steps:
        text += f"[{s}]" if isinstance(s, int) else (f".{s}" if text else str(s))
    return text


def resolve(raw: dict, path: str, file: str | Path = "scene") -> list:
    """The keys and indices that lead to ``path`` in ``raw``; the last key may be new."""
    if not isinstance(path, str) or not path.strip():
        raise SceneError(f"{file}: value path {path!r}: give a dotted path such as 'forces.tau1.value'")
    steps: list = []
    where = ""
    node: Any = raw
    rest = path
    while True:
        if rest.startswith("["):
            idx, rest = _index(rest, path, file, where)
            if not isinstance(node, list):
                raise SceneError(f"{file}: value path {path!r}: {where or 'the scene'} is not a list; "
                                 f"[{idx}] indexes nothing")
            if not -len(node) <= idx < len(node):
                raise SceneError(f"{file}: value path {path!r}: {where}[{idx}] is out of range "
                                 f"({where} has {len(node)} elements)")
            idx %= len(node)
            steps.append(idx)
            where = f"{where}[{idx}]"
            node = node[idx]
        else:
            labels = _labels(node, steps)
            label = _longest_prefix(rest, labels)
            if label is not None and labels[label] is None:
                raise SceneError(f"{file}: value path {path!r}: several elements of {where} are named "
                                 f"{label!r}; index them instead, e.g. {where}[0]")
            if label is None:
                segment = rest.split(".", 1)[0].split("[", 1)[0]
                last = segment == rest
                if isinstance(node, dict) and last and segment:
                    steps.append(segment)  # a key the table does not have yet: the validator judges it
                    return steps
                raise SceneError(_no_such(file, path, where, segment, node, labels))
            key = labels[label]
            steps.append(key)
            where = f"{where}[{key}]" if isinstance(key, int) else (f"{where}.{key}" if where else key)
            node = node[key]
            rest = rest[len(label):]
        if not rest:
            return steps
        if rest.startswith("."):
            rest = rest[1:]
            if not rest:
                raise SceneError(f"{file}: value path {path!r}: ends with '.'")
        elif not rest.startswith("["):
            raise SceneError(f"{file}: value path {path!r}: cannot read {rest!r} after {where}")


def _labels(node, steps) -> dict[str, Any]:
    """What a path segment may name inside ``node``: its keys, or its tables' names."""
    if isinstance(node, dict):
        return {str(k): k for k in node}
    if isinstance(node, list):
        key = _ITEM_KEY.get(steps[-1] if steps else None, "name")
        out: dict[str, Any] = {}
        for i, item in enumerate(node):
            name = item.get(key) if isinstance(item, dict) else None
            if isinstance(name, str):
                out[name] = i if name not in out else None  # None: two elements share the name
        return out
    return {}


def _longest_prefix(rest: str, labels: dict) -> str | None:
    best = None
    for label in labels:
        if label and (rest == label or rest.startswith(label + ".") or rest.startswith(label + "[")):
            if best is None or len(label) > len(best):
                best = label
    return best


def _index(rest: str, path, file, where) -> tuple[int, str]:
    end = rest.find("]")
    try:
        return int(rest[1:end]), rest[end + 1:]
    except ValueError:
        raise SceneError(f"{file}: value path {path!r}: {rest[:end + 1] or rest!r} after "
                         f"{where or 'the start'} must be an index such as [0]") from None


def _no_such(file, path, where, segment, node, labels) -> str:
    inside = where or "the scene"
    if not isinstance(node, (dict, list)):
        return f"{file}: value path {path!r}: {inside} is a value ({node!r}), it has no {segment!r}"
    names = sorted(k for k in labels if k)
    close = difflib.get_close_matches(segment, names, n=3, cutoff=0.4)
    what = "key" if isinstance(node, dict) else "element named"
    hint = f"; closest: {', '.join(map(repr, close))}" if close else ""
    valid = ", ".join(repr(n) for n in names[:30]) + (" ..." if len(names) > 30 else "")
    index = " (or an index such as [0])" if isinstance(node, list) else ""
    return (f"{file}: value path {path!r}: no {what} {segment!r} in {inside}{hint}; "
            f"valid: {valid or '(none)'}{index}")


def plain(value):
    """A value as TOML data: numpy scalars and arrays become Python numbers and lists."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    return value


def parse_scalar(text: str):
    """A command-line value read as TOML (``0.5``, ``2``, ``true``, ``"x"``); a bare word is a string."""
    text = text.strip()
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def value_text(value) -> str:
    """A value as one table cell, the same text each time (a run's identity on resume)."""
    value = plain(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else str(value)
    return str(value)


# ---- URDFs read once per process -------------------------------------------------------
_URDF_CACHE: dict[tuple, Any] = {}


def read_urdf_cached(path: Path):
    """:func:`pcmm.urdf.read_urdf`, kept per process while the file is unchanged (a sweep
    rebuilds its scene for every run; the URDFs it names are read and checked once)."""
    try:
        st = os.stat(path)
    except OSError:
        return read_urdf(path)  # the reader's own message for a missing file
    key = (str(path), st.st_mtime_ns, st.st_size)
    info = _URDF_CACHE.get(key)
    if info is None:
        info = _URDF_CACHE[key] = read_urdf(path)
    return info
