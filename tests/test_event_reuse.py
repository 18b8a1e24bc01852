"""The glue of a bounce cut in h-event4: each cut against the route it replaces."""
from __future__ import annotations

import os

import pytest

from pcmm.model import compiled


@pytest.mark.parametrize("value", [None, "0", "1", "", "00", " 0", "0 ", "no", "é"])
def test_enabled_reads_the_environment_as_os_environ_get(monkeypatch, value):
    """``compiled.enabled()`` reads PCMM_COMPILED from the environment's encoded dict: at every call,
    and with the same answer as ``os.environ.get(ENV, "1") != "0"`` (the route it replaces)."""
    if value is None:
        monkeypatch.delenv(compiled.ENV, raising=False)
    else:
        monkeypatch.setenv(compiled.ENV, value)
    want = compiled._tree_dynamics is not None and os.environ.get(compiled.ENV, "1") != "0"
    assert compiled.enabled() is want
    assert compiled.enabled() is (compiled._tree_dynamics is not None and value != "0")


def test_enabled_follows_a_change_of_the_environment(monkeypatch):
    if compiled._tree_dynamics is None:
        pytest.skip("no compiled extension in this tree")
    monkeypatch.setenv(compiled.ENV, "1")
    assert compiled.enabled()
    monkeypatch.setenv(compiled.ENV, "0")
    assert not compiled.enabled()
    monkeypatch.delenv(compiled.ENV)
    assert compiled.enabled()
    os.environ[compiled.ENV] = "0"  # (monkeypatch restores it)
    assert not compiled.enabled()
    del os.environ[compiled.ENV]
    assert compiled.enabled()


CYCLE = __import__("pathlib").Path(__file__).resolve().parents[1] / "examples" / "three_bar_cycle.toml"


def test_rearm_list_taken_in_one_lookup_is_the_component_route(monkeypatch):
    """``loop._guards``' one look-up (``GuardCache.take_last``) gives, at every segment of the cycle, the
    very guard objects, in order, that its two kept sets give (the route before it: the same call on a
    copy of the cache without the last list and the earlier stays' sets), and it is taken at most bounces."""
    from dataclasses import replace

    import pcmm
    from pcmm.run import loop

    original = loop._guards
    seen = {"calls": 0, "one_lookup": 0}

    def both(scene, cfg, holds, t, phase, bounced, fired=(), cache=None):
        before = replace(cache, last=None, made={}) if cache is not None else None  # the route before the last list
        entry = cache.last if cache is not None else None
        got = original(scene, cfg, holds, t, phase, bounced, fired, cache)
        want = original(scene, cfg, holds, t, phase, bounced, fired, before)
        assert len(got) == len(want), (t, cfg.name)
        # (a call that builds or takes a kept set replaces the last list: left as it was, the one look-up was taken)
        if entry is not None and cache.last is entry:
            seen["one_lookup"] += 1
            assert all(a is b for a, b in zip(got, want)), (t, cfg.name)
        else:  # both routes built (or took) the guards: the same transitions, re-armed alike
            assert [(g.transition, g.description) for g in got] == [(g.transition, g.description) for g in want]
        seen["calls"] += 1
        return got

    monkeypatch.setattr(loop, "_guards", both)
    traj = pcmm.simulate(CYCLE)
    assert seen["calls"] == len(traj.segments)
    assert seen["one_lookup"] > len(traj.events) // 2  # (the bounces' re-arms: 524 impacts of 531 events)


def _run_record(traj):
    import numpy as np
    events = [repr(e) for e in traj.events]  # (every number by repr: its bits)
    segments = [tuple(a.tobytes() for a in traj.segments.arrays(i)) for i in range(len(traj.segments))]
    return events, segments


def test_guards_built_at_an_earlier_stay_give_the_run_built_afresh(monkeypatch):
    """``GuardCache.made_for`` hands a stay the transitions' guards built at an earlier stay in the same
    configuration for the same bounced stop and offsets: the cycle's run is the run that builds them
    at every stay, event by event and sample by sample, and the kept sets are taken at most stays."""
    import pcmm
    from pcmm.run.guard_cache import GuardCache

    taken = []
    original = GuardCache.made_for

    def counted(self, cfg, bounced, offsets):
        got = original(self, cfg, bounced, offsets)
        if got is not None:
            taken.append(cfg.name)
        return got

    monkeypatch.setattr(GuardCache, "made_for", counted)
    kept_run = _run_record(pcmm.simulate(CYCLE))
    assert len(taken) >= 20  # (the cycle's periods: 'open''s two stops, each locked configuration's stop)
    monkeypatch.setattr(GuardCache, "made_for", lambda self, cfg, bounced, offsets: None)  # built at every stay
    assert _run_record(pcmm.simulate(CYCLE)) == kept_run


def test_made_guards_are_held_per_configuration_stop_and_offsets():
    from pcmm.run.guard_cache import MADE_GUARDS, GuardCache

    class C:
        name = "c"
    a, b, stop = C(), C(), object()
    cache = GuardCache()
    g = (object(),)
    assert cache.made_for(a, stop, ()) is None
    cache.keep_made(a, stop, (), g)
    assert cache.made_for(a, stop, ()) is g
    assert cache.made_for(b, stop, ()) is None  # another configuration
    assert cache.made_for(a, None, ()) is None  # another bounced stop (or none)
    assert cache.made_for(a, stop, (("L", 6.283185307179586),)) is None  # other offsets
    for k in range(MADE_GUARDS):  # bounded: a growing offset makes new keys
        cache.keep_made(a, stop, (("L", float(k)),), g)
    assert len(cache.made) <= MADE_GUARDS


def _context_ids(f, monkeypatch):
    import pcmm
    from pcmm.results import segment_log

    monkeypatch.setattr(segment_log.SegmentLog, "context_id", f)
    log = pcmm.simulate(CYCLE).segments
    ids = [int(log._row(i)[0]) for i in range(len(log))]
    return ids, [(c, n) for c, n, _ in log._contexts], len(log._names)


def test_segment_contexts_with_the_name_lists_not_looked_up_again(monkeypatch):
    """``SegmentLog.context_id`` skips the name lists' look-up where they are the very lists its latest
    context of the configuration holds: the cycle's segments get the same context ids, the contexts the
    same configurations and name lists, as with the look-up at every segment (the route before)."""
    from pcmm.results import segment_log

    new = segment_log.SegmentLog.context_id

    def before(self, configuration, names, context, keep=None):
        names = self._names.setdefault((configuration, *(tuple(v) for v in names.values())), names)
        k = self._last.get(configuration)
        if k is not None:
            conf, known_names, known = self._contexts[k]
            if known_names is names and known == context:
                return k
        self._contexts.append((configuration, names, context if keep is None else keep(context)))
        self._last[configuration] = len(self._contexts) - 1
        return len(self._contexts) - 1

    assert _context_ids(new, monkeypatch) == _context_ids(before, monkeypatch)


def test_segment_context_name_lists_equal_but_not_the_same_are_the_kept_ones():
    from pcmm.results.segment_log import SegmentLog

    log = SegmentLog()
    names = {"coordinates": ["a"], "links": ["L"]}
    k = log.context_id("c", names, 1.0)
    assert log.context_id("c", names, 1.0) == k  # the same lists: no look-up
    equal = {"coordinates": ["a"], "links": ["L"]}
    assert log.context_id("c", equal, 1.0) == k  # equal lists: looked up, the kept ones found
    assert log.context_id("c", equal, 2.0) == k + 1 and log._contexts[k + 1][1] is names
    other = {"coordinates": ["b"], "links": ["L"]}
    j = log.context_id("c", other, 2.0)
    assert j == k + 2 and log._contexts[j][1] is other
    assert log.context_id("c", names, 2.0) == k + 3 and log._contexts[k + 3][1] is names
