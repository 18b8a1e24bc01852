"""The re-arm after an event reuses what the last re-arm built where nothing it was built from has
changed: the holding-force evaluator of the merges held by compression only (Holds.evaluator) is
built once for a sequence of bounces in one configuration under the same holds, and again when the
configuration or the holds change.  (That the evaluator gives Holds.forces's bits at every guard
value, reused or not, is tests/test_holding_evaluator.py.)"""
from __future__ import annotations

from itertools import pairwise

from builders import EXAMPLES

import pcmm
from pcmm.events import holding


def test_a_bounce_sequence_reuses_the_holding_evaluator(monkeypatch):
    built, calls = holding.Holds.evaluator, []

    def counted(self, cfg):
        fast = built(self, cfg)
        calls.append(((cfg, *self.items), fast))
        return fast
    monkeypatch.setattr(holding.Holds, "evaluator", counted)
    run = pcmm.simulate(pcmm.load_scene(EXAMPLES / "three_bar_cycle.toml"), pcmm.RunOptions(t_end=1.5))
    assert run.stats["impacts"] > 50 and len(calls) >= 2
    for (key, fast), (key2, fast2) in pairwise(calls):
        same = len(key) == len(key2) and all(a is b for a, b in zip(key, key2))
        assert (fast2 is fast) == same  # reused exactly while the configuration and holds are the same
        # and asked again only where they changed: a bounce re-arms with the merges' guards it had
        # (pcmm.run.loop._unmerge_guards), without asking for the evaluator at all
        assert not same
