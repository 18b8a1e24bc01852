"""The event path's glue cut without changing a bit: a bounce re-arms with the guards of the bounce
before it (pcmm.run.loop._guards), ... Each against the route it replaces, on whole runs."""
from __future__ import annotations

import numpy as np
from builders import EXAMPLES, pendulum

import pcmm
from pcmm.run import loop


def _run(path, monkeypatch, reuse: bool, t_end=None):
    built = []
    make = loop.make_guard

    def counted(cfg, tr, rearm=False, context=None):
        built.append((cfg.name, tr.name, rearm))
        return make(cfg, tr, rearm=rearm, context=context)
    monkeypatch.setattr(loop, "make_guard", counted)
    if not reuse:
        guards = loop._guards
        monkeypatch.setattr(loop, "_guards", lambda *args: guards(*args[:7]))  # kept=None: built every time
    opts = pcmm.RunOptions(t_end=t_end) if t_end is not None else None
    traj = pcmm.simulate(pcmm.load_scene(path), opts) if opts else pcmm.simulate(pcmm.load_scene(path))
    monkeypatch.undo()
    return traj, built


def _same_run(a, b):
    assert len(a.events) == len(b.events)
    for ea, eb in zip(a.events, b.events):
        assert ea == eb
    assert len(a.segments) == len(b.segments)
    for sa, sb in zip(a.segments, b.segments):
        assert np.array_equal(sa.t, sb.t) and np.array_equal(sa.q, sb.q)


def test_a_bounce_sequence_builds_its_guards_once(monkeypatch):
    """three_bar_cycle's first 1.5 s: O2 and O3 bounce on their pins dozens of times each; the
    re-armed stop's guards are built at the first bounce of each sequence only, and the run is the
    one that builds them at every bounce, bit for bit."""
    path = EXAMPLES / "three_bar_cycle.toml"
    fast, built_fast = _run(path, monkeypatch, True, t_end=1.5)
    slow, built_slow = _run(path, monkeypatch, False, t_end=1.5)
    assert fast.stats["impacts"] > 50
    assert len(built_slow) > 50 and len(built_fast) < len(built_slow) / 5
    _same_run(fast, slow)


def test_a_pendulum_bouncing_on_its_stop(tmp_path, monkeypatch):
    """A tree (the compiled loop, its stop guard re-armed): three bounces in 2 s; the plain guard
    built for the first approach, the re-armed one once for the next three segments (against once
    per bounce without reuse), and the same run bit for bit."""
    path = pendulum(tmp_path, 0.9, q0=0.0, t_end=2.0)
    fast, built_fast = _run(path, monkeypatch, True)
    slow, built_slow = _run(path, monkeypatch, False)
    assert fast.stats["impacts"] == 3
    assert built_fast == [("c1", "stop", False), ("c1", "stop", True)]
    assert built_slow == [("c1", "stop", False)] + [("c1", "stop", True)] * 3
    _same_run(fast, slow)


def test_the_guard_residual_read_from_the_state_is_the_rebuilt_guards(monkeypatch):
    """At each of three_bar_cycle's impacts (to 1.5 s), and at states moved off them at random, the
    residual read off the state entry (actions._residual) is the value of the guard built again
    (guards.guard_residual), to the bit."""
    from types import SimpleNamespace

    from pcmm.run import actions
    seen = []
    fast = actions._residual

    def kept(run, guard):
        seen.append((run.cfg, run.t, np.array(run.y), guard))
        return fast(run, guard)
    monkeypatch.setattr(actions, "_residual", kept)
    pcmm.simulate(pcmm.load_scene(EXAMPLES / "three_bar_cycle.toml"), pcmm.RunOptions(t_end=1.5))
    assert len(seen) > 50 and all(g.linear is not None for *_, g in seen)
    rng = np.random.default_rng(1)
    nonzero = 0
    for cfg, t, y, guard in seen:
        for state in (y, y + rng.normal(scale=1e-3, size=y.shape)):
            got = fast(SimpleNamespace(cfg=cfg, t=t, y=state), guard)
            want = actions.guard_residual(cfg, guard.transition, t, state)
            assert type(got) is float and got == want
            nonzero += got != 0.0
    assert nonzero >= len(seen)


# ---- the event log's generated readers (pcmm.results.event_log._flattener) -------------------------
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from pcmm.results import event_log  # noqa: E402


def _typed(x):
    """``x`` with every value's exact type beside it (``1 == 1.0 == True``, a log must not mix them)."""
    if isinstance(x, dict):
        return ("dict", [(k, _typed(v)) for k, v in x.items()])
    if isinstance(x, (list, tuple)):
        return (type(x).__name__, [_typed(v) for v in x])
    name = "float" if isinstance(x, np.float64) else type(x).__name__  # the log keeps a numpy float as a float
    return (name, x if x == x else "nan")


leaf = st.one_of(st.floats(allow_nan=False), st.integers(-2 ** 60, 2 ** 60), st.booleans(), st.none(),
                 st.sampled_from(["O2 pin", "stop", "x" * 60]), st.floats(-10, 10).map(np.float64),
                 st.integers(-5, 5).map(np.int64))
record = st.recursive(leaf, lambda inner: st.one_of(
    st.lists(inner, max_size=3), st.lists(inner, max_size=3).map(tuple),
    st.dictionaries(st.sampled_from(["t", "a", "b", "v"]), inner, max_size=3)), max_leaves=12)


def _mutations(rec):
    """``rec`` and records one leaf away from it: each number as an int, a bool, None, a numpy scalar."""
    yield rec
    if isinstance(rec, dict):
        for k, v in rec.items():
            for m in _mutations(v):
                yield {**rec, k: m}
        if len(rec) > 1:
            yield dict(reversed(rec.items()))  # the same items, another key order: another layout
    elif isinstance(rec, (list, tuple)):
        for i, v in enumerate(rec):
            for m in _mutations(v):
                yield type(rec)([*rec[:i], m, *rec[i + 1:]])
        yield type(rec)([*rec, 1.0])
    else:
        yield from (1, 1.0, True, None, np.float64(1.0), np.int64(1), "O2 pin")


@settings(max_examples=120, deadline=None)
@given(st.lists(st.dictionaries(st.sampled_from(["t", "name", "impulse", "v"]), record, min_size=1, max_size=4),
                min_size=1, max_size=4))
def test_the_log_gives_back_every_record_with_its_types(records):
    """Records of a few layouts, each followed by records one leaf away (an int for a float, a bool,
    None, a numpy scalar, another key order, one more item): each read back as appended, types and
    all, and each stored as the general encoder (_layout) stores it (the values kept aside apart)."""
    sequence = [m for rec in records for m in _mutations(rec)][:200]
    log = event_log.EventLog()
    for rec in sequence:
        log.append(rec)
    assert [_typed(r) for r in log] == [_typed(r) for r in sequence]
    for i, rec in enumerate(sequence):  # the same table and row as _layout gives
        numbers, aside = [], []
        layout = event_log._layout(rec, numbers, aside)
        k, row = log._index[i // event_log.BLOCK][i % event_log.BLOCK]
        table = log._tables[k]
        assert table.layout == layout
        assert table.row(int(row)).tolist()[:len(numbers)][:len(numbers) if not aside else 0] == \
            [float(x) for x in numbers][:len(numbers) if not aside else 0]


def test_a_run_of_bounces_appends_by_the_generated_reader(monkeypatch):
    """three_bar_cycle's records go through the generated readers (the general encoder runs once
    per layout, not once per impact), and come back as the run's records."""
    calls = []
    general = event_log._layout

    def counted(obj, numbers, aside):
        if type(obj) is dict and "name" in obj:  # a record, not one of its containers
            calls.append(1)
        return general(obj, numbers, aside)
    traj = pcmm.simulate(pcmm.load_scene(EXAMPLES / "three_bar_cycle.toml"), pcmm.RunOptions(t_end=1.5))
    records = list(traj.events)
    monkeypatch.setattr(event_log, "_layout", counted)
    log = event_log.EventLog()
    for r in records:
        log.append(r)
    assert len(records) > 50 and 0 < len(calls) < 10
    assert [_typed(r) for r in log] == [_typed(r) for r in records]


def test_segments_under_the_same_holds_share_one_context():
    """three_bar_cycle's bounces under a held merge (O3 on its pin while O2 bounces, and the other
    way round) record their segments with one context per stay, not one each: the holds' applied
    force elements (a dataclass of values) compare by value (recording._same).  Before, 464
    contexts for 532 segments."""
    from pcmm.events.holding import Applied
    from pcmm.run import recording
    traj = pcmm.simulate(pcmm.load_scene(EXAMPLES / "three_bar_cycle.toml"), pcmm.RunOptions(t_end=3.0))
    n, contexts = len(traj.segments), len(traj.segments._contexts)
    assert n > 150 and contexts < n / 5, (n, contexts)
    kept = [c for _, _, c in traj.segments._contexts if c.applied is not None]
    assert kept and all(isinstance(c.applied, Applied) for c in kept)
    a = kept[0].applied
    twin = Applied(a.reference, {k: (np.array(v) if isinstance(v, np.ndarray) else v) for k, v in a.frozen.items()},
                   a.forces, a.acting, a.springs)
    assert recording._same(a, twin)
    assert not recording._same(a, Applied(a.reference, {**a.frozen, "ny": -1}, a.forces, a.acting, a.springs))


def test_same_compares_values_as_a_context_needs():
    """recording._same, asked at every segment: arrays element by element (-0.0 equals 0.0, NaN
    never equals), dicts by keys and values, a list never equals a tuple, numbers and texts by
    value, a dataclass field by field, anything else by identity."""
    from dataclasses import dataclass

    from pcmm.run.recording import _same

    @dataclass
    class Rec:
        a: object
        b: object
    marker = object()
    cases = [
        (np.array([0.0, 1.0]), np.array([-0.0, 1.0]), True),
        (np.array([np.nan]), np.array([np.nan]), False),
        (np.array([1, 2]), np.array([[1, 2]]), False),
        (np.array([1, 2]), [1, 2], False),
        ({"I": np.array([0, 2]), "ny": 4}, {"I": np.array([0, 2]), "ny": 4}, True),
        ({"I": np.array([0, 2]), "ny": 4}, {"I": np.array([0, 2]), "ny": 5}, False),
        ({"a": 1}, {"b": 1}, False),
        ([1, (2.0, "x")], [1, (2.0, "x")], True),
        ([1, 2], (1, 2), False),
        ([1, 2], [1, 2, 3], False),
        (1, 1.0, True),
        ("x", "y", False),
        (Rec(marker, {"k": np.array([1.0])}), Rec(marker, {"k": np.array([1.0])}), True),
        (Rec(marker, 1), Rec(object(), 1), False),
        (marker, marker, True),
        (object(), object(), False),
        (Rec, Rec, True),
    ]
    for a, b, want in cases:
        assert _same(a, b) is want, (a, b)
        assert _same(b, a) is want, (b, a)
