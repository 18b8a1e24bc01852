"""The compiled evaluations (a tree's right-hand side, a loop's closure rows): an optional
speed-up, never a different answer.

A tree configuration's right-hand side (``TreeCoordinates``) is ``[v, aba(q, v, Q0 - KD y)]``.
From Python it costs about 3.7 us per evaluation, of which Pinocchio's ABA is 0.65 us; Example 1
spends 90 % of its run there.  A loop's Newton solves and constrained accelerations
(``PartitionedCoordinates``) evaluate the revolute cut joints' rows ``p_b - p_a`` and their
Jacobian rows (and the acceleration bias) some 13 000 times in Example 2, each about 11 us through
the binding.  ``pcmm.model._tree_dynamics`` (C++, built by ``pip install`` where a compiler is at hand,
against the ``pin`` wheel's own headers and library) does each evaluation in one call with
Pinocchio's own algorithms, on a model rebuilt joint by joint from the Python model's numbers.

It is used only where it is the same function: the extension must load, must have been built
against the Pinocchio version that runs, must support every joint of the model (revolute and
prismatic, aligned or not; no ``nq != nv`` joint), and must agree with the Python evaluation it
replaces at probe states to round-off (:data:`AGREEMENT`), once per model and thread, before a
configuration uses it.  Otherwise the Python evaluation runs and :func:`why_not` says why.
``PCMM_COMPILED=0`` in the environment turns it off (benchmarks and tests compare the two).
"""
from __future__ import annotations

import functools
import importlib.util
import os
import threading
from typing import Callable

import numpy as np
import pinocchio as pin  # loaded first: the extension finds libpinocchio_default by its soname

if importlib.util.find_spec(f"{__package__}._tree_dynamics") is None:  # pip had no C++ compiler, say
    _tree_dynamics = None
    _UNAVAILABLE = ("pcmm.model._tree_dynamics was not built when pcmm was installed (no C++ compiler?): the Python "
                    "evaluations run, with the same results; with g++ at hand, reinstalling pcmm builds it")
else:
    try:
        from . import _tree_dynamics
    except ImportError as exc:  # built, but not loadable here (another Pinocchio library, say)
        _tree_dynamics = None
        _UNAVAILABLE = f"pcmm.model._tree_dynamics does not load here ({exc}): reinstall pcmm to rebuild it"
    else:
        _UNAVAILABLE = None


def version_problem(built: str, running: str) -> str | None:
    """Why an extension built against Pinocchio ``built`` must not run beside ``running``."""
    if built != running:
        return (f"pcmm.model._tree_dynamics was built against Pinocchio {built}, this process runs {running}: "
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
# Above this many coordinates the compiled evaluations are not worth their memory: Pinocchio's own
# aba dominates (a chain's right-hand side, compiled against Python: 2.8 vs 6.2 us at nv = 5,
# 8.9 vs 9.7 at 20, 16 vs 18 at 40, 42 vs 45 at 100), while each compiled tree holds a Pinocchio
# 4.1 Data with nv^3-sized tensors (266 MB at nv = 200, beside the Python model's own).
MAX_NV = 32
# Built trees per thread (each holds its own Pinocchio Data: scratch space, never shared between
# threads), by model and force elements: a run of a scene seen before reuses its trees (Pinocchio
# 4.1's Data constructor allocates nv^3-sized tensors: 29 ms at nv = 100).
class _Trees(threading.local):
    """This thread's compiled trees: ``trees = {id(model): (model, {key: (tree, names checked)})}``."""

    def __init__(self):
        self.trees: dict = {}


_CACHE = _Trees()
_CACHE_MAX = 32
# ... and at most this many force-element keys per model: a study that varies a torque or a
# preload makes a new key every run (a sweep's worker held 523 trees after 300 runs, 88 KiB per
# run); the oldest key goes first, and a key seen again is rebuilt with the same numbers
_KEYS_MAX = 16

_last_reason: list[str] = []


def _environ_reader():
    """``() -> whether PCMM_COMPILED is not "0"``, read from the environment at every call.
    ``os.environ.get`` encodes the name and decodes the value at each read (about 1.7 us, asked about
    twice per event: the location, the flight audit); CPython's mapping keeps them encoded in the dict
    ``os.environ._data`` that ``setenv``/``putenv`` and ``del`` write, so the name and "0" are encoded
    once and that dict is read (a plain dict look-up, about 0.1 us).  The encodings are injective
    (``surrogateescape``), so the bytes compare as the strings did.  Where the mapping lacks them (another
    interpreter), ``os.environ.get``."""
    environ = os.environ
    data = getattr(environ, "_data", None)
    encodekey, encodevalue = getattr(environ, "encodekey", None), getattr(environ, "encodevalue", None)
    if not isinstance(data, dict) or encodekey is None or encodevalue is None:
        return lambda: environ.get(ENV, "1") != "0"
    key, off, unset = encodekey(ENV), encodevalue("0"), encodevalue("1")
    return lambda: data.get(key, unset) != off


_compiled_allowed = _environ_reader()


def enabled() -> bool:
    """Whether the compiled evaluations may be used in this process (``PCMM_COMPILED`` read now)."""
    return _tree_dynamics is not None and _compiled_allowed()


def why_not() -> str | None:
    """Why the last configuration that asked runs the Python evaluations (None: it runs the compiled ones)."""
    if _UNAVAILABLE:
        return _UNAVAILABLE
    if os.environ.get(ENV, "1") == "0":
        return f"{ENV}=0 in the environment"
    return _last_reason[-1] if _last_reason else None


def trees_built() -> int:
    """How many compiled objects this thread holds (a run that built none ran Python's)."""
    return sum(1 for _, built in _CACHE.trees.values() for _, checked in built.values() if checked)


def forget_trees() -> None:
    """Drop this thread's compiled trees (the next run builds its own: what :func:`trees_built` counts)."""
    _CACHE.trees.clear()


def _refuse(reason: str) -> None:
    _last_reason[:] = [reason]


def tree_rhs(model: pin.Model, Q0: np.ndarray, KD: np.ndarray, reference: Callable) -> Callable | None:
    """The compiled ``rhs(t, y) = [v, aba(q, v, Q0 - KD y)]`` of a tree ``model`` (Pinocchio
    coordinates are the state's: ``nq == nv``), or None where it cannot be ``reference``, the
    Python right-hand side it replaces."""
    Q0, KD = np.asarray(Q0, float), np.asarray(KD, float)
    entry = _tree(model, ("rhs", Q0.tobytes(), KD.tobytes()), lambda tree: tree.finalize(model.gravity.linear, Q0, KD))
    if entry is None:
        return None
    tree, checked = entry
    probes = [(0.0, y) for y in _probe_states(model.nv)]
    if not _agrees(checked, tree.rhs, reference, probes, "right-hand side"):
        return None
    _register_segment_loop()
    return tree.rhs


def tree_power(model: pin.Model, Q0: np.ndarray, KD: np.ndarray, reference: Callable, reference_power: Callable):
    """The compiled tree of :func:`tree_rhs` (the same one: the same key) whose
    ``rhs_with_power(t, [q, v, W]) = [v, aba(q, v, tau), tau . v]``, tau = Q0 - KD y (a flight's
    state with its work appended, :meth:`pcmm.model.tree.TreeCoordinates.rhs_with_power`), checked
    against ``reference`` and ``reference_power``, the Python evaluations; or None (why_not says)."""
    if enabled() and not getattr(_tree_dynamics, "TREE_POWER", 0):  # built before trees had it
        _refuse("this build of pcmm.model._tree_dynamics has no compiled flights of a tree (built from older "
                "sources): reinstall pcmm (pip install -e .) to rebuild it")
        return None
    Q0, KD = np.asarray(Q0, float), np.asarray(KD, float)
    entry = _tree(model, ("rhs", Q0.tobytes(), KD.tobytes()), lambda tree: tree.finalize(model.gravity.linear, Q0, KD))
    if entry is None:
        return None
    tree, checked = entry
    states = _probe_states(model.nv)
    if not (_agrees(checked, tree.rhs, reference, [(0.0, y) for y in states], "right-hand side")
            and _agrees(checked, tree.rhs_with_power, reference_power,
                        [(0.0, np.append(y, 0.0)) for y in states], "right-hand side with power")):
        return None
    return tree


def _register_segment_loop(owner: type | None = None, make: Callable | None = None) -> None:
    """Tell the integrators (a lower layer) that a tree's compiled right-hand side has a compiled
    segment loop (DOP853 in C++, pcmm/model/_segment_loop.hpp), where this build has one; and that
    ``owner``'s right-hand sides have ``make`` (called as :data:`pcmm.ode.integrators.SEGMENT_LOOPS`
    says; it ends in :func:`segment_loop`)."""
    locate = getattr(_tree_dynamics, "locate", None)
    if locate is not None:  # the event locator (_locate.hpp), for every configuration's guards from now on
        from ..ode.integrators import COMPILED_LOCATE
        # (and of a guard read by its evaluator: a contact gap, _guard_eval.hpp)
        COMPILED_LOCATE[:] = [locate, enabled, getattr(_tree_dynamics, "locate_guard", None)]
    loop = getattr(_tree_dynamics, "SegmentLoop", None)
    if loop is not None:
        from ..ode.integrators import SEGMENT_LOOPS
        SEGMENT_LOOPS[_tree_dynamics.Tree] = loop
        if owner is not None:
            SEGMENT_LOOPS[owner] = make


def segment_loop(tree, *args, **options):
    """A compiled segment loop over ``tree`` (a tree from :func:`drive_tree` or :func:`tree_power`), the arguments
    those of :data:`pcmm.ode.integrators.SEGMENT_LOOPS`."""
    return _tree_dynamics.SegmentLoop(tree, *args, **options)


def drive_tree(model: pin.Model, Q0: np.ndarray, KD: np.ndarray, driven, laws, reference: Callable,
               reference_power: Callable):
    """The compiled tree of a configuration whose coordinates ``driven`` are prescribed (drives
    without loops: ``laws``, each drive's (f, f', f'') coefficients, low order first, as
    :class:`pcmm.model.rows.Drives` evaluates them), whose ``rhs(t, [q_I, v_I])`` and
    ``rhs_with_power(t, [q_I, v_I, W])`` equal ``reference`` and ``reference_power``, the Python
    evaluations they replace (checked at probe states and times); or None (why_not says)."""
    Q0, KD = np.asarray(Q0, float), np.asarray(KD, float)
    driven, laws = drives_key(driven, laws)
    if enabled() and not hasattr(_tree_dynamics.Tree, "set_drives"):  # an extension built before drives were
        _refuse("this build of pcmm.model._tree_dynamics has no compiled drives (built from older sources): "
                "reinstall pcmm (pip install -e .) to rebuild it")
        return None
    if len(driven) >= model.nv:
        _refuse("every coordinate is driven: nothing to integrate")
        return None

    def build(tree):
        tree.finalize(model.gravity.linear, Q0, KD)
        tree.set_drives(driven, laws)
    entry = _tree(model, ("drives", Q0.tobytes(), KD.tobytes(), driven, laws), build)
    if entry is None:
        return None
    tree, checked = entry
    k = model.nv - len(driven)
    states = _probe_states(k)
    probes = [(0.37 * (j + 1), y) for j, y in enumerate(states)]  # the drives are functions of time
    if not (_agrees(checked, tree.rhs, reference, probes, "right-hand side with drives")
            and _agrees(checked, tree.rhs_with_power, reference_power,
                        [(t, np.append(y, 0.0)) for t, y in probes], "right-hand side with drives and power")):
        return None
    return tree


def holding_forces(model: pin.Model, Q0: np.ndarray, KD: np.ndarray, J: np.ndarray, m: int, f2, mine, theirs,
                   held: np.ndarray, cfg_nv: int, own=None):
    """(a compiled HoldingForces (pcmm/model/_holding.hpp), the names checked on its tree) for the
    holding forces of the locks in force, solved on the reference configuration ``model`` with its
    force elements ``Q0``, ``KD``: the rows ``J`` (its ``m`` drive rows, their f'' coefficients
    ``f2``, then one constant row per lock), the configuration's coordinates ``mine`` at the
    reference's ``theirs``, the held joints at ``held``, and ``own`` = (Q0, KD) of the force elements
    acting while the configuration holds where they differ from the reference's (None: the same);
    or None (why_not says).  It is not checked here: :meth:`pcmm.events.holding.Holds.evaluator`
    checks it against the Python evaluator it replaces before a guard uses it."""
    if enabled() and not hasattr(_tree_dynamics, "HoldingForces"):  # an extension built before it was
        _refuse("this build of pcmm.model._tree_dynamics has no compiled holding forces (built from older sources): "
                "reinstall pcmm (pip install -e .) to rebuild it")
        return None
    Q0, KD = np.asarray(Q0, float), np.asarray(KD, float)
    entry = _tree(model, ("holding", Q0.tobytes(), KD.tobytes()), lambda tree: tree.finalize(model.gravity.linear, Q0, KD))
    if entry is None:
        return None
    tree, checked = entry
    own_q0, own_kd = (None, None) if own is None else (np.asarray(own[0], float), np.asarray(own[1], float))
    try:
        fast = _tree_dynamics.HoldingForces(tree, np.asarray(J, float), int(m), [tuple(map(float, c)) for c in f2],
                                            [int(i) for i in mine], [int(i) for i in theirs], np.asarray(held, float),
                                            int(cfg_nv), own_q0, own_kd)
    except (ValueError, TypeError) as exc:
        _refuse(f"the compiled holding forces refused the configuration: {exc}")
        return None
    return fast, checked


def gap_tree(model: pin.Model):
    """(compiled tree holding every frame of ``model`` at its own index, the names of what was checked on it)
    for the guards a compiled segment loop and locator read at a state (pcmm/model/_guard_eval.hpp: a
    contact gap, pcmm.events.guards); its Pinocchio Data is the scratch space of those evaluations alone.
    None where it cannot be built (why_not says)."""
    if enabled() and not hasattr(_tree_dynamics, "normal_speed"):  # an extension built before these guards
        _refuse("this build of pcmm.model._tree_dynamics has no compiled contact gap (built from older sources): "
                "reinstall pcmm (pip install -e .) to rebuild it")
        return None
    nframes, nv = len(model.frames), model.nv

    def build(tree):
        for f in range(1, nframes):  # frame 0 is the universe in both: frame f of the model is frame f here
            frame = model.frames[f]
            got = tree.add_frame(int(frame.parentJoint), frame.placement.rotation, frame.placement.translation)
            if got != f:
                raise ValueError(f"frame {frame.name!r} came out as frame {got}")
        tree.finalize(np.zeros(3), np.zeros(nv), np.zeros((nv, 2 * nv)))
    return _tree(model, ("frames", nframes), build)


def gap_guard(model: pin.Model, frame_a: int, frame_b: int, frame_link: int, normal, value: float,
              reference: Callable) -> tuple | None:
    """The description of a point contact's gap guard for the compiled evaluator
    (``("gap", tree, frame_a, frame_b, frame_link, nx, ny, value)``, pcmm/model/_guard_eval.hpp): points a
    and b and link a's frame (frames of ``model``), the normal fixed in link a, the guard's value; checked
    against ``reference(t, y) -> (value, rate, normal speed)``, the Python guard and contact at a tree's state
    ``[q, v]``, at probe states (once per tree and contact).  None where it is not compiled or disagrees (why_not says)."""
    entry = gap_tree(model)
    if entry is None:
        return None
    tree, checked = entry
    desc = ("gap", tree, int(frame_a), int(frame_b), int(frame_link), float(normal[0]), float(normal[1]), float(value))
    if not _agrees(checked, lambda t, y: (*_tree_dynamics.guard_value(desc, y), _tree_dynamics.normal_speed(desc, y)),
                   reference, [(0.0, y) for y in _probe_states(model.nv)], "contact gap", key=("gap", *desc[2:])):
        return None
    return desc


def guard_value(desc: tuple, y) -> tuple[float, float]:
    """(value, rate) at the state ``y`` of the guard a compiled description reads (:func:`gap_guard`)."""
    return _tree_dynamics.guard_value(desc, y)


def normal_speed(desc: tuple, y) -> float:
    """The normal speed ``n . (v_b - v_a)`` at the state ``y`` of a contact gap's description (:func:`gap_guard`)."""
    return _tree_dynamics.normal_speed(desc, y)


def impulse_tree(model: pin.Model, frames, pairs=()) -> tuple | None:
    """(compiled tree of ``model`` with the frames ``frames`` of the Python model added, {Python frame:
    its frame in the tree}, the names of what was checked on it) for an impulse plan
    (:mod:`pcmm.events.impulse_compiled`): zero gravity and no force element (the impulse's joint
    impulses are RNEA's at zero velocity and gravity); or None (why_not says).  ``pairs``: the loops'
    revolute cut joints as (frame of point a, frame of point b) of the Python model (their frames are
    added too), whose closure rows the plan puts among its constraint rows.  Its joints, inertias and
    frames are the model's numbers; the impulse plan itself is checked against the Python solve at its
    first impact."""
    if enabled() and not hasattr(_tree_dynamics, "ImpulsePlan"):  # an extension built before impulses were
        _refuse("this build of pcmm.model._tree_dynamics has no compiled impulse (built from older sources): "
                "reinstall pcmm (pip install -e .) to rebuild it")
        return None
    if np.any(np.asarray(model.armature) != 0):  # the cut system the Python solve forms has none
        _refuse("a joint with armature: the cut system of the Python impulse solve carries none")
        return None
    pairs = tuple((int(a), int(b)) for a, b in pairs)
    frames = tuple(sorted({int(f) for f in frames} | {f for pair in pairs for f in pair}))
    index = {f: k + 1 for k, f in enumerate(frames)}  # frame 0 is the universe; add_frame numbers on from it
    nv = model.nv

    def build(tree):
        for f in frames:
            frame = model.frames[f]
            got = tree.add_frame(int(frame.parentJoint), frame.placement.rotation, frame.placement.translation)
            if got != index[f]:
                raise ValueError(f"frame {model.frames[f].name!r} came out as frame {got}")
        for a, b in pairs:
            tree.add_pair(index[a], index[b])
        tree.finalize(np.zeros(3), np.zeros(nv), np.zeros((nv, 2 * nv)))
    entry = _tree(model, ("impulse", frames, pairs) if pairs else ("impulse", frames), build)
    if entry is None:
        return None
    return entry[0], index, entry[1]


def closure_kinematics(model: pin.Model, frames_a, frames_b, rows: Callable, rows_and_bias: Callable):
    """A compiled object whose ``point_rows(q) -> (Phi, Phi_q)`` and ``point_rows_and_bias(q, v)
    -> (Phi_q, bias)`` are the kinematic constraint of each revolute cut joint (point ``b`` on
    point ``a``, frames of ``model``), equal to ``rows`` and ``rows_and_bias``, their Python
    evaluation; or None."""
    frames_a, frames_b = tuple(map(int, frames_a)), tuple(map(int, frames_b))
    nv = model.nv

    def build(tree):
        index = {f: tree.add_frame(int(model.frames[f].parentJoint), model.frames[f].placement.rotation,
                                   model.frames[f].placement.translation) for f in sorted({*frames_a, *frames_b})}
        for fa, fb in zip(frames_a, frames_b):
            tree.add_pair(index[fa], index[fb])
        tree.finalize(model.gravity.linear, np.zeros(nv), np.zeros((nv, 2 * nv)))
    entry = _tree(model, ("closure", frames_a, frames_b), build)
    if entry is None:
        return None
    tree, checked = entry
    states = _probe_states(nv)
    if not (_agrees(checked, tree.point_rows, rows, [(y[:nv],) for y in states], "closure rows")
            and _agrees(checked, tree.point_rows_and_bias, rows_and_bias, [(y[:nv], y[nv:]) for y in states],
                        "closure rows and bias")):
        return None
    return tree


def loop_tree(model: pin.Model, frames_a, frames_b, Q0: np.ndarray, KD: np.ndarray, points=None):
    """((compiled tree, the names of its functions checked so far), its springs) of a configuration
    with closed loops: its revolute cut joints' point pairs (frames of ``model``), its linear force
    elements and its point springs ``points`` (a :class:`pcmm.model.forces.PointSprings` or None),
    for a :func:`loop`; or None (why_not says)."""
    if enabled() and not hasattr(getattr(_tree_dynamics, "Loop", None), "rows"):  # built before loops (or their rows) were
        _refuse("this build of pcmm.model._tree_dynamics has no compiled loops (built from older sources): "
                "reinstall pcmm (pip install -e .) to rebuild it")
        return None
    frames_a, frames_b = tuple(map(int, frames_a)), tuple(map(int, frames_b))
    spring_frames = () if points is None else (tuple(map(int, points.frames_a)), tuple(map(int, points.frames_b)))
    Q0, KD = np.asarray(Q0, float), np.asarray(KD, float)
    # the frames in this order, added to a tree that has none: frame i + 1 (checked as they are added)
    frames = sorted({*frames_a, *frames_b, *(f for fs in spring_frames for f in fs)})
    index = {f: i + 1 for i, f in enumerate(frames)}

    def build(tree):
        for f in frames:
            if tree.add_frame(int(model.frames[f].parentJoint), model.frames[f].placement.rotation,
                              model.frames[f].placement.translation) != index[f]:
                raise ValueError(f"frame {f} of the model came out as another frame of the compiled tree")
        for fa, fb in zip(frames_a, frames_b):
            tree.add_pair(index[fa], index[fb])
        tree.finalize(model.gravity.linear, Q0, KD)
    springs = () if points is None else tuple(
        (index[int(fa)], index[int(fb)], float(f0), float(k), float(rest), float(c))
        for fa, fb, f0, k, rest, c in zip(points.frames_a, points.frames_b, points.f0, points.k, points.rest, points.c))
    # the springs are in the key: a tree's checks (its probe states) hold for its own force elements
    entry = _tree(model, ("loop", frames_a, frames_b, springs, Q0.tobytes(), KD.tobytes()), build)
    return None if entry is None else (entry, springs)


def loop(tree, driven, laws, springs=()):
    """A compiled right-hand side of closed loops (pcmm/model/_loops.hpp) on ``tree`` and its point
    ``springs`` (a :func:`loop_tree`), its drives' coordinates ``driven`` and ``laws`` ((f, f', f'')
    coefficients, low order first, as :class:`pcmm.model.rows.Drives` evaluates them): it holds its
    own warm starts, seeded with ``seed(q, I, D)``."""
    return _tree_dynamics.Loop(tree, *drives_key(driven, laws), springs)


def drives_key(driven, laws) -> tuple:
    """(driven coordinates, laws) as plain ints and floats: what a compiled evaluation with drives
    is built from, hashable (a key of what was checked)."""
    return (tuple(int(i) for i in driven),
            tuple(tuple(tuple(float(c) for c in cs) for cs in law) for law in laws))


def agrees(checked: set, fn, reference, probes, what: str, key=None) -> bool:
    """Whether ``fn`` equals ``reference`` at the probe arguments to :data:`AGREEMENT` (once per
    compiled tree and ``key``, ``what`` where None: the key holds every input of ``fn`` that the
    tree's own key does not); where not, why_not says by how much (naming ``what``)."""
    return _agrees(checked, fn, reference, probes, what, key)


def agrees_on(tree, fn, reference, probes, what: str) -> bool:
    """:func:`agrees` for a function of ``tree``, a compiled tree this thread built (the names checked
    on it are its own): False for a tree it does not hold.  ``probes`` may be a function that makes
    them, called only where the check runs (not once ``what`` is checked on the tree: a caller asking
    at every flight builds no probe states)."""
    for _, built in _CACHE.trees.values():
        for held, checked in built.values():
            if held is tree:
                return _agrees(checked, fn, reference, probes, what)
    return False


def refuse(reason: str) -> None:
    """Record why a configuration runs its Python evaluations (what why_not answers next)."""
    _refuse(reason)


@functools.cache
def _probe_states(nv: int) -> tuple[np.ndarray, ...]:
    """Fixed states: angles over a turn, velocities of order one, every component a different
    irrational rotation (the additive recurrence of the generalized golden ratio: ``k alpha_j``
    mod 1, alpha_j = g^-j with g^(d+1) = g + 1), so no two coordinates move alike.  Not
    numpy.random: importing it costs a run about 13 ms of start-up."""
    d = 2 * nv
    g = 2.0
    for _ in range(40):  # the fixed point of g = (1 + g)^(1 / (d + 1))
        g = (1.0 + g) ** (1.0 / (d + 1))
    alpha = (1.0 / g) ** np.arange(1, d + 1) % 1.0
    u = (0.5 + np.outer(np.arange(1, _PROBES + 1), alpha)) % 1.0
    states = tuple(np.concatenate([-np.pi + 2 * np.pi * row[:nv], -2.0 + 4.0 * row[nv:]]) for row in u)
    for y in states:  # computed once per size (every configuration of every run asks): shared, read-only
        y.flags.writeable = False
    return states


def _tree(model: pin.Model, key: tuple, finalize: Callable):
    """(compiled tree, the names of its functions checked so far) for ``key`` on ``model``: built
    once per thread (the model's joints and bodies, then ``finalize(tree)``), or None (why_not says)."""
    if not enabled():
        return None
    cache = _CACHE.trees
    # the model is held by identity (pcmm never edits a built model's bodies or joints); its
    # gravity and armature, plain arrays a caller may set, are part of the key
    key = (*key, model.gravity.linear.tobytes(), np.asarray(model.armature).tobytes())
    held, built = cache.get(id(model), (None, {}))
    if held is model and key in built:
        return built[key]
    tree = _rebuild(model)
    if tree is None:
        return None
    try:
        finalize(tree)
    except ValueError as exc:
        _refuse(str(exc))
        return None
    if held is not model:
        if len(cache) >= _CACHE_MAX:
            cache.pop(next(iter(cache)))
        built = {}
        cache[id(model)] = (model, built)  # the model is held: its id stays its own
    while len(built) >= _KEYS_MAX:
        built.pop(next(iter(built)))
    built[key] = (tree, set())
    return built[key]


def _rebuild(model: pin.Model):
    """The model's joints and bodies in a compiled tree (not finalized), or None (why_not says)."""
    nv = model.nv
    if model.nq != nv or nv == 0:
        _refuse(f"nq = {model.nq}, nv = {nv}: only nq == nv > 0 is compiled")
        return None
    if nv > MAX_NV:
        _refuse(f"nv = {nv} > {MAX_NV}: Pinocchio's aba dominates there, and a compiled tree's Data would "
                "hold nv^3-sized tensors")
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
    except ValueError as exc:
        _refuse(str(exc))
        return None
    return tree


def _agrees(checked: set, fn, reference, probes, what: str, key=None) -> bool:
    """``fn`` and ``reference`` at the probe arguments (``probes``, or ``probes()`` where it is a
    function), output by output, to round-off; once per compiled tree and function (``checked``
    remembers ``key``, ``what`` where None)."""
    key = what if key is None else key
    if key in checked:
        _last_reason.clear()
        return True
    if callable(probes):
        probes = probes()
    for args in probes:
        with np.errstate(all="ignore"):
            expected = reference(*args)
        expected = expected if isinstance(expected, tuple) else (expected,)
        if not all(np.all(np.isfinite(e)) for e in expected):  # non-finite forces: Python reports them
            _refuse(f"the Python {what} is not finite at a probe state")
            return False
        got = fn(*args)
        got = got if isinstance(got, tuple) else (got,)
        for g, e in zip(got, expected, strict=True):
            e = np.asarray(e, float)
            scale = 1.0 + float(np.max(np.abs(e), initial=0.0))
            if np.shape(g) != e.shape:
                _refuse(f"it disagrees with the Python {what}: shape {np.shape(g)} against {e.shape}")
                return False
            if not np.all(np.abs(g - e) <= AGREEMENT * scale):
                _refuse(f"it disagrees with the Python {what} by {np.max(np.abs(g - e)):.3g} "
                        f"(allowed {AGREEMENT * scale:.3g})")
                return False
    checked.add(key)
    _last_reason.clear()
    return True


def series_tree(model: pin.Model, frames, reference: Callable):
    """A compiled tree of ``model`` with the body frames ``frames`` (the links', in order) added as
    its frames 1, 2, ... and the model's gravity, whose :func:`series` over many samples equals
    ``reference(Q, V) -> (xy, kinetic, gravity potential)``, the Python evaluation sample by sample
    (checked at probe states, once per tree); or None (why_not says).  What
    :mod:`pcmm.run.series` derives a tree's recorded series with (pcmm/model/_series.hpp)."""
    if enabled() and not hasattr(_tree_dynamics, "series"):  # an extension built before it was
        _refuse("this build of pcmm.model._tree_dynamics has no compiled series (built from older sources): "
                "reinstall pcmm (pip install -e .) to rebuild it")
        return None
    frames, nv = tuple(int(f) for f in frames), model.nv

    def build(tree):
        for k, f in enumerate(frames):
            frame = model.frames[f]
            if tree.add_frame(int(frame.parentJoint), frame.placement.rotation, frame.placement.translation) != k + 1:
                raise ValueError(f"frame {frame.name!r} came out as another frame of the compiled tree")
        tree.finalize(model.gravity.linear, np.zeros(nv), np.zeros((nv, 2 * nv)))
    entry = _tree(model, ("series", frames), build)
    if entry is None:
        return None
    tree, checked = entry
    probes = lambda: [(y[None, :nv], y[None, nv:]) for y in _probe_states(nv)]  # noqa: E731 (made where checked)
    if not _agrees(checked, lambda Q, V: _tree_dynamics.series(tree, Q, V), reference, probes, "recorded series"):
        return None
    return tree


def series(tree, Q: np.ndarray, V: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xy (n, frames, 2), kinetic energy (n), gravity potential (n)) at the rows of ``Q`` and ``V``
    (n x nv) on a :func:`series_tree`: Pinocchio's forward kinematics, kinetic and potential energy
    and frame placements, sample by sample in one compiled call."""
    return _tree_dynamics.series(tree, Q, V)


def multipliers(tree, Q: np.ndarray, V: np.ndarray, TAU: np.ndarray, J: np.ndarray, GAMMA: np.ndarray) -> np.ndarray:
    """(n, m) multipliers ``lam`` of ``M a + h = tau + J^T lam``, ``J a + gamma = 0`` at the rows of ``Q``,
    ``V``, ``TAU`` (n x nv) and ``GAMMA`` (n x m) with the constant rows ``J`` (m x nv), on a
    :func:`series_tree` (pcmm/model/_series.hpp); NaN in a row where Pinocchio's solve failed."""
    return _tree_dynamics.multipliers(tree, Q, V, TAU, J, GAMMA)


def probe_states(nv: int) -> tuple[np.ndarray, ...]:
    """The fixed probe states ``[q, v]`` of ``nv`` coordinates every compiled evaluation is checked at."""
    return _probe_states(nv)


def has_multipliers() -> bool:
    """Whether this build of the extension has :func:`multipliers`."""
    return hasattr(_tree_dynamics, "multipliers")
