"""The run's guard cache (pcmm.run.guard_cache.GuardCache) by its named behaviours, on a pendulum
bouncing at its stop (builders.pendulum): ``loop._guards`` called as the run calls it, its work
counted by the ``make_guard`` and ``unmerge_guards`` calls it makes (not timed), and its guards
against the ones built afresh without a cache."""
from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
from builders import pendulum

import pcmm
from pcmm.run import loop
from pcmm.run.guard_cache import MADE_GUARDS, GuardCache


class CountedHolds:
    """Holds in force as the run loop reads them: the ``Hold`` objects (their identity is all the
    cache looks at) and the merges' guards, one per hold, each call counted."""

    def __init__(self, n: int):
        self.items = [object() for _ in range(n)]
        self.asked = 0

    def unmerge_guards(self, cfg):
        self.asked += 1
        return [SimpleNamespace(hold=h) for h in self.items]


@pytest.fixture
def bouncing(tmp_path, monkeypatch):
    """(scene, configuration, its stop transition, the make_guard calls so far)."""
    run = loop.start(pcmm.load_scene(pendulum(tmp_path, 0.9, q0=0.0, t_end=2.0)), pcmm.RunOptions())
    built = []
    make = loop.make_guard

    def counted(cfg, tr, rearm=False, context=None):
        built.append((tr.name, rearm))
        return make(cfg, tr, rearm=rearm, context=context)
    monkeypatch.setattr(loop, "make_guard", counted)
    (stop,) = run.scene.transitions_from(run.cfg.name)
    return run.scene, run.cfg, stop, built


def _described(guards):
    return [(getattr(g, "transition", None), getattr(g, "description", g)) for g in guards]


def test_a_bounce_at_one_stop_takes_the_same_list_again(bouncing):
    scene, cfg, stop, built = bouncing
    holds, cache = CountedHolds(1), GuardCache()
    first = loop._guards(scene, cfg, holds, 0.1, None, stop, (), cache)
    assert built == [("stop", True)] and holds.asked == 1  # the re-armed stop guard and the merge's: built
    kept = cache.last
    assert kept is not None and kept.guards == first
    for t in (0.2, 0.3, 0.4):  # the next bounces at the same stop
        again = loop._guards(scene, cfg, holds, t, None, stop, (), cache)
        assert cache.last is kept  # the last list taken, not rebuilt
        assert all(a is b for a, b in zip(again, first)) and len(again) == len(first) == 2
        assert again is not first and again is not kept.guards  # (each call's list its own)
    assert built == [("stop", True)] and holds.asked == 1
    # the route without the cache builds at every call, and the same guards
    fresh = loop._guards(scene, cfg, holds, 0.5, None, stop, ())
    assert built == [("stop", True)] * 2 and holds.asked == 2
    assert _described(fresh)[0] == _described(first)[0]


def test_another_bounced_stop_is_not_the_same_list(bouncing):
    """The approach before the first bounce watches the plain guard; the re-armed one is another."""
    scene, cfg, stop, built = bouncing
    holds, cache = CountedHolds(0), GuardCache()
    plain = loop._guards(scene, cfg, holds, 0.0, None, None, (), cache)
    rearmed = loop._guards(scene, cfg, holds, 0.1, None, stop, (), cache)
    assert built == [("stop", False), ("stop", True)]
    assert plain[0].linear[5] is False and rearmed[0].linear[5] is True  # (read plain, then re-armed)
    # back to either: taken again (the earlier stay's set, then the last list), nothing built
    assert loop._guards(scene, cfg, holds, 0.2, None, None, (), cache)[0] is plain[0]
    assert loop._guards(scene, cfg, holds, 0.3, None, None, (), cache)[0] is plain[0]
    assert loop._guards(scene, cfg, holds, 0.4, None, stop, (), cache)[0] is rearmed[0]
    assert len(built) == 2


def test_holds_that_change_rebuild_the_merges_guards_not_the_transitions(bouncing):
    scene, cfg, stop, built = bouncing
    holds, cache = CountedHolds(1), GuardCache()
    first = loop._guards(scene, cfg, holds, 0.1, None, stop, (), cache)
    kept = cache.last
    holds.items.append(object())  # a lock: one more Hold
    locked = loop._guards(scene, cfg, holds, 0.2, None, stop, (), cache)
    assert holds.asked == 2 and cache.last is not kept  # the merges' guards built again, a new list
    assert built == [("stop", True)] and locked[0] is first[0]  # the transitions' kept
    assert [g.hold for g in locked[1:]] == holds.items
    holds.items[1] = object()  # as many holds, another object (a release and a lock): rebuilt too
    loop._guards(scene, cfg, holds, 0.3, None, stop, (), cache)
    assert holds.asked == 3 and len(built) == 1
    loop._guards(scene, cfg, holds, 0.4, None, stop, (), cache)  # unchanged since: taken
    assert holds.asked == 3 and len(built) == 1


def test_a_contact_phase_builds_and_keeps_nothing_for_the_next_segment(bouncing):
    scene, cfg, stop, built = bouncing
    holds, cache = CountedHolds(1), GuardCache()
    loop._guards(scene, cfg, holds, 0.1, None, stop, (), cache)
    phase = SimpleNamespace(tr=None)  # (a collision under way, resolved by a contact law)
    during = loop._guards(scene, cfg, holds, 0.2, phase, stop, (), cache)
    assert built == [("stop", True)] * 2 and holds.asked == 2  # built, nothing taken
    assert cache.last is None and cache.merges is None and cache.transitions_key is None
    after = loop._guards(scene, cfg, holds, 0.3, None, stop, (), cache)
    # the transitions' guards of the earlier stay taken again, the merges' built anew
    assert len(built) == 2 and holds.asked == 3 and after[0] is not during[0]


def test_at_most_made_guards_sets_are_kept(bouncing):
    """An angle offset that grows by a turn at every stay makes a new key each time: the kept sets
    stay at most MADE_GUARDS, the newest ones taken again, the forgotten ones built again."""
    scene, cfg, stop, built = bouncing
    holds, cache = CountedHolds(0), GuardCache()
    turns = MADE_GUARDS + 5
    guards = {}
    for k in range(1, turns + 1):
        cfg.continue_angles({"link1": 2 * math.pi * k})
        guards[k] = loop._guards(scene, cfg, holds, 0.1, None, stop, (), cache)[0]
        assert len(cache.made) <= MADE_GUARDS
    assert len(built) == turns  # every new offset built its guards
    cfg.continue_angles({"link1": 2 * math.pi * (turns - 2)})  # a recent one: kept
    assert loop._guards(scene, cfg, holds, 0.2, None, stop, (), cache)[0] is guards[turns - 2]
    assert len(built) == turns
    cfg.continue_angles({"link1": 2 * math.pi})  # the first: forgotten, built again
    again = loop._guards(scene, cfg, holds, 0.3, None, stop, (), cache)[0]
    assert len(built) == turns + 1 and again is not guards[1]
    assert _described([again]) == _described([guards[1]])
