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
