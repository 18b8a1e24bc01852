"""Small per-event cuts (issue 26, item 2: the crumbs) give the same bits as the route they shortcut,
on ``examples/three_bar_cycle.toml`` (drives without a loop, locks taken and released, hundreds of
flights), and do the work they skip only where it is needed.

* The flight audit's compiled drive powers are checked against Python's once per compiled tree; the
  probe states of that check are made only where it runs (``compiled.agrees_on`` with a function
  for its probes), not at every flight.
* ``PartitionedCoordinates.pack`` keeps the partition of drives without a loop once chosen (the
  driven coordinates are the dependent ones whatever the posture), as ``project`` does.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import pcmm
from pcmm.model import compiled
from pcmm.model.partitioned import PartitionedCoordinates
from pcmm.run import audit

CYCLE = Path(__file__).resolve().parents[1] / "examples" / "three_bar_cycle.toml"
OPTS = pcmm.RunOptions(t_end=2.5)  # locks taken and released, > 100 flights


def _cycle():
    return pcmm.simulate(pcmm.load_scene(CYCLE), OPTS)


def _same_run(a, b) -> None:
    """Every event and every flight's residual, to the bit."""
    assert json.dumps(a.stats["macro_impacts"]) == json.dumps(b.stats["macro_impacts"])
    assert json.dumps(a.events, default=repr) == json.dumps(b.events, default=repr)
    assert len(a.segments) == len(b.segments) > 100
    for x, y in zip(a.segments, b.segments, strict=True):
        assert x.t.tobytes() == y.t.tobytes() and x.q.tobytes() == y.q.tobytes() and x.v.tobytes() == y.v.tobytes()


def test_the_drive_power_probes_are_made_once_per_tree_not_at_every_flight(monkeypatch):
    """A fresh thread's trees: the run checks each once.  The probe states are asked for a handful of
    times (each tree's checks), not once per flight as before the cut; the compiled drive powers are
    what the audit used."""
    compiled.forget_trees()
    asked = []
    real = compiled._probe_states
    monkeypatch.setattr(compiled, "_probe_states", lambda n: asked.append(n) or real(n))
    used = []
    fast = audit._compiled_drive_powers
    monkeypatch.setattr(audit, "_compiled_drive_powers", lambda *a: used.append(fast(*a)) or used[-1])
    traj = _cycle()
    flights = sum(m["flights"] for m in traj.stats["macro_impacts"])
    if not compiled.enabled():
        return
    assert flights > 100 and len(used) >= flights and all(u is not None for u in used)
    assert 1 <= len(asked) < 20 < flights / 5  # each tree's checks; before the cut, one more per flight


def test_the_drive_power_check_made_lazily_is_the_same_run_to_the_bit(monkeypatch):
    """The same events, samples and flight residuals with the probes made at every flight (the route
    before the cut) and made only for the check."""
    lazy = _cycle()
    real = compiled.agrees_on
    monkeypatch.setattr(compiled, "agrees_on", lambda tree, fn, ref, probes, what:
                        real(tree, fn, ref, probes() if callable(probes) else probes, what))
    eager = _cycle()
    _same_run(lazy, eager)


def _pack_choosing_again(self, t, q, v):
    """``pack`` as before the cut: the partition chosen at every segment's start."""
    self.partition(t, q)
    self.seed(q)
    return np.concatenate([q[self.I], self.cfg.qdot(q, v)[self.I]])


def test_pack_chooses_the_partition_of_drives_without_a_loop_once(monkeypatch):
    """Segments by the hundred, every one packed on drives without a loop, and the partition chosen
    at most once per configuration's coordinates (each entered many times)."""
    chosen, packed = [], []
    real_partition, real_pack = PartitionedCoordinates.partition, PartitionedCoordinates.pack
    monkeypatch.setattr(PartitionedCoordinates, "partition", lambda self, *a, **k: chosen.append(id(self)) or
                        real_partition(self, *a, **k))
    monkeypatch.setattr(PartitionedCoordinates, "pack", lambda self, *a: packed.append(
        (id(self), bool(self.closure.size))) or real_pack(self, *a))
    traj = _cycle()
    assert len(traj.segments) > 100 and len(packed) >= len(traj.segments)
    assert not any(loop for _, loop in packed)
    owners = {o for o, _ in packed}
    assert len(chosen) == len(set(chosen)) <= len(owners) <= 4  # at most once each (before the cut: per segment)


def test_pack_keeping_the_partition_is_the_same_run_to_the_bit(monkeypatch):
    kept = _cycle()
    monkeypatch.setattr(PartitionedCoordinates, "pack", _pack_choosing_again)
    chosen_again = _cycle()
    _same_run(kept, chosen_again)
