"""The compiled tree right-hand side: an optional speed-up, never a different answer.

A tree configuration's right-hand side (``TreeCoordinates``) is ``[v, aba(q, v, Q0 - KD y)]``.
From Python it costs about 3.7 us per evaluation, of which Pinocchio's ABA is 0.65 us; Example 1
spends 90 % of its run there.  ``pcmm._tree_dynamics`` (C++, built by ``pip install`` where a
compiler is at hand, against the ``pin`` wheel's own headers and library) does the whole
evaluation in one call with Pinocchio's ``aba``, on a model rebuilt joint by joint from the Python
model's numbers.

It is used only where it is the same function: the extension must load, must have been built
against the Pinocchio version that runs, must support every joint of the model (revolute and
prismatic, aligned or not; no ``nq != nv`` joint), and must agree with the Python right-hand side
at probe states to round-off (:data:`AGREEMENT`) before a configuration uses it.  Otherwise the
Python right-hand side runs and :func:`why_not` says why.  ``PCMM_COMPILED=0`` in the environment
turns it off (benchmarks and tests compare the two).
"""
from __future__ import annotations

import os
import threading
from typing import Callable

import numpy as np
import pinocchio as pin  # loaded first: the extension finds libpinocchio_default by its soname

try:
    from . import _tree_dynamics
except ImportError as exc:  # not built (no compiler at install time) or not loadable here
    _tree_dynamics = None
    _UNAVAILABLE = f"the extension pcmm._tree_dynamics is not available ({exc})"
else:
    _UNAVAILABLE = None


def version_problem(built: str, running: str) -> str | None:
    """Why an extension built against Pinocchio ``built`` must not run beside ``running``."""
    if built != running:
        return (f"pcmm._tree_dynamics was built against Pinocchio {built}, this process runs {running}: "
                "reinstall pcmm (pip install -e .) to rebuild it")
    return None


if _tree_dynamics is not None:
    _UNAVAILABLE = version_problem(_tree_dynamics.PINOCCHIO_VERSION, pin.__version__)
    if _UNAVAILABLE:
        _tree_dynamics = None

ENV = "PCMM_COMPILED"
# |a_compiled - a_python| <= AGREEMENT * (1 + max|a_python|) at every probe state
AGREEMENT = 1e-11
_PROBES = 3
# Built trees per thread (each holds its own Pinocchio Data: scratch space, never shared between
# threads), by model and force elements: a run of a scene seen before reuses its trees (Pinocchio
# 4.1's Data constructor allocates nv^3-sized tensors: 29 ms at nv = 100).
_CACHE = threading.local()
_CACHE_MAX = 32

_last_reason: list[str] = []


def enabled() -> bool:
    """Whether the compiled right-hand side may be used in this process."""
    return _tree_dynamics is not None and os.environ.get(ENV, "1") != "0"


def why_not() -> str | None:
    """Why the last configuration asked for it runs the Python right-hand side (None: it did not)."""
    if _UNAVAILABLE:
        return _UNAVAILABLE
    if os.environ.get(ENV, "1") == "0":
        return f"{ENV}=0 in the environment"
    return _last_reason[-1] if _last_reason else None


def trees_built() -> int:
    """How many compiled trees this thread holds (a run that used none ran Python's)."""
    return sum(len(trees) for _, trees in _CACHE.__dict__.get("trees", {}).values())


def _refuse(reason: str) -> None:
    _last_reason[:] = [reason]


def tree_rhs(model: pin.Model, data: pin.Data, Q0: np.ndarray, KD: np.ndarray) -> Callable | None:
    """The compiled ``rhs(t, y) = [v, aba(q, v, Q0 - KD y)]`` of a tree ``model`` (Pinocchio
    coordinates are the state's: ``nq == nv``), or None where it cannot be the same function.
    ``data`` is the model's scratch data (the agreement check runs ``pin.aba`` on it)."""
    if not enabled():
        return None
    Q0, KD = np.asarray(Q0, float), np.asarray(KD, float)
    cache = _CACHE.__dict__.setdefault("trees", {})
    # the model is held by identity (pcmm never edits a built model's bodies or joints); its
    # gravity and armature, plain arrays a caller may set, are part of the key
    key = (Q0.tobytes(), KD.tobytes(), model.gravity.linear.tobytes(), np.asarray(model.armature).tobytes())
    held, trees = cache.get(id(model), (None, {}))
    if held is model and key in trees:
        _last_reason.clear()
        return trees[key]
    rhs = _build(model, data, Q0, KD)
    if rhs is not None:
        if len(cache) >= _CACHE_MAX and id(model) not in cache:
            cache.pop(next(iter(cache)))
        cache.setdefault(id(model), (model, {}))[1][key] = rhs  # the model is held: its id stays its own
    return rhs


def _build(model: pin.Model, data: pin.Data, Q0: np.ndarray, KD: np.ndarray) -> Callable | None:
    nv = model.nv
    if model.nq != nv or nv == 0:
        _refuse(f"nq = {model.nq}, nv = {nv}: only nq == nv > 0 is compiled")
        return None
    if np.any(model.gravity.angular != 0):
        _refuse("gravity with an angular part")
        return None
    tree = _tree_dynamics.Tree()
    try:
        for j in range(1, model.njoints):
            joint = model.joints[j]
            if joint.nv != 1 or joint.nq != 1:
                raise ValueError(f"joint {model.names[j]!r} ({joint.shortname()}) has nq = {joint.nq}, nv = {joint.nv}")
            kind = joint.shortname()
            axis = joint.extract().axis if kind.endswith("Unaligned") else np.zeros(3)
            placement = model.jointPlacements[j]
            added = tree.add_joint(kind, int(model.parents[j]), placement.rotation, placement.translation,
                                   np.asarray(axis, float), float(model.armature[joint.idx_v]))
            if added != j:
                raise ValueError(f"joint {model.names[j]!r} came out as joint {added}")
            inertia = model.inertias[j]
            tree.set_inertia(j, inertia.mass, inertia.lever, inertia.inertia)
        tree.finalize(model.gravity.linear, Q0, KD)
    except ValueError as exc:
        _refuse(str(exc))
        return None
    if not _agrees(model, data, Q0, KD, tree.rhs):
        return None
    _last_reason.clear()
    return tree.rhs


def _agrees(model: pin.Model, data: pin.Data, Q0, KD, rhs) -> bool:
    """The compiled and the Python right-hand side at probe states (fixed seed, angles over a
    turn, velocities of order one), to round-off."""
    nv = model.nv
    rng = np.random.default_rng(20201001)
    for _ in range(_PROBES):
        y = np.concatenate([rng.uniform(-np.pi, np.pi, nv), rng.uniform(-2.0, 2.0, nv)])
        with np.errstate(all="ignore"):
            a = pin.aba(model, data, y[:nv], y[nv:], Q0 - KD @ y)
        expected = np.concatenate([y[nv:], a])
        if not np.all(np.isfinite(expected)):  # non-finite forces: the Python path reports them
            _refuse("the right-hand side is not finite at a probe state")
            return False
        got = rhs(0.0, y)
        scale = 1.0 + float(np.max(np.abs(expected)))
        if not np.all(np.abs(got - expected) <= AGREEMENT * scale):
            _refuse(f"it disagrees with the Python right-hand side by {np.max(np.abs(got - expected)):.3g} "
                    f"(allowed {AGREEMENT * scale:.3g})")
            return False
    return True
