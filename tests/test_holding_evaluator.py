"""The holding forces a reaction or unmerge guard evaluates at every step (Holds.evaluator) are
Holds.forces's to the bit: the same system solved with the same arrays, only built once per
segment.  Checked at every guard evaluation of a run of the working cycle to its first releases
and re-locks (a drive without a loop: the prepared path), and the prepared path really ran (the
guards never fell back to Holds.forces).  This is the prepared Python evaluator, the compiled one
switched off (it is Holds.forces's to round-off: tests/test_compiled_holding.py)."""
from __future__ import annotations

import numpy as np
from builders import EXAMPLES

import pcmm
from pcmm.events import holding

#: the working cycle to 1.5 s (its first merges, the O2 release at 1.199 s, re-locks): the run's
#: common part with the whole cycle, the t_end given as a run option
CYCLE, SHORT = EXAMPLES / "three_bar_cycle.toml", pcmm.RunOptions(t_end=1.5)


def test_guard_holding_forces_are_forces_to_the_bit(monkeypatch):
    seen, slow = [], [0]
    prepared, reference = holding.Holds.evaluator, holding.Holds.forces

    def counted_forces(self, *args, **kw):
        slow[0] += 1
        return reference(self, *args, **kw)

    def checked(self, cfg):
        fast = prepared(self, cfg)

        def forces(t, q, v):
            got = fast(t, q, v)
            calls = slow[0]
            want = reference(self, cfg, t, q, v)
            slow[0] = calls  # the check's own call is not a fallback
            # a state off the trajectory too: the map and rows must not depend on where it was built
            q2, v2 = q + 0.01 * np.arange(1, q.size + 1), v - 0.1
            seen.append((got, want, fast(t + 1e-3, q2, v2), reference(self, cfg, t + 1e-3, q2, v2)))
            slow[0] = calls
            return got
        return forces

    monkeypatch.setattr(holding, "_compiled_evaluator", lambda *args: (None, "the prepared Python evaluator"))
    monkeypatch.setattr(holding.Holds, "evaluator", checked)
    monkeypatch.setattr(holding.Holds, "forces", counted_forces)
    run = pcmm.simulate(pcmm.load_scene(CYCLE), SHORT)
    names = [e["name"] for e in run.events]
    assert any("O2" in n for n in names) and len(seen) > 100  # the O2 release at 1.199 s was watched
    for got, want, got2, want2 in seen:
        assert got and got.keys() == want.keys()
        assert all(np.float64(got[k]).tobytes() == np.float64(want[k]).tobytes() for k in got)
        assert all(np.float64(got2[k]).tobytes() == np.float64(want2[k]).tobytes() for k in got2)
    assert slow[0] == 0  # every guard value came from the prepared path
