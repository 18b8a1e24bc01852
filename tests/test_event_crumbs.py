"""Small per-event cuts (issue 26, item 2: the crumbs) give the same bits as the route they shortcut,
on ``examples/three_bar_cycle.toml`` (drives without a loop, locks taken and released, hundreds of
flights), and do the work they skip only where it is needed.

* The flight audit's compiled drive powers are checked against Python's once per compiled tree; the
  probe states of that check are made only where it runs (``compiled.agrees_on`` with a function
  for its probes), not at every flight.
* ``PartitionedCoordinates.pack`` keeps the partition of drives without a loop once chosen (the
  driven coordinates are the dependent ones whatever the posture), as ``project`` does.
* ``PartitionedCoordinates.time_rows`` forms its constant Jacobian once per coordinates (read-only)
  and hands the drives' bias as a method, not a concatenation and a closure at every call.
* ``signals.deferred``, which every recorded segment passes, is a plain class's enter and exit on the
  signals' numbers, not a generator's context manager on ``signal``'s enum members: a Ctrl-C while a
  segment is recorded still waits until it is kept.
"""
from __future__ import annotations

import _signal
import contextlib
import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from builders import driven_cart_pendulum

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
    if not compiled.enabled():
        pytest.skip("the compiled drive powers are off (PCMM_COMPILED=0 or no extension)")
    traj = _cycle()
    flights = sum(m["flights"] for m in traj.stats["macro_impacts"])
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


def _time_rows_formed_at_every_call(self):
    """``time_rows`` as before the cut."""
    if self.closure.size:
        return None
    Jq = np.concatenate((self._no_jacobian, self._drive_rows)) if self.drives.size else self._no_jacobian
    if not self.drives.size:
        return Jq, lambda t: self._no_rows
    return Jq, lambda t: np.concatenate((self._no_rows, -self.drives.values(t)[2]))


@pytest.mark.parametrize("scene", ["three_bar_cycle", "driven cart pendulum"])
def test_time_rows_are_formed_once_and_are_the_rows_to_the_bit(scene, tmp_path):
    """Each configuration (the cycle's four, theta1 = pi t: no bias; the cart's two, a cubic drive:
    ``-f''(t)`` not zero): the same read-only Phi_q at every call, and ``(Phi_q, bias_of(t))`` equal
    to ``rows(t, q, v)`` to the bit at states and times of its own, and to the route before the cut."""
    from pcmm.model.mechanism import Mechanism
    scene = pcmm.load_scene(CYCLE if scene == "three_bar_cycle" else driven_cart_pendulum(tmp_path, e=0.8))
    mech = Mechanism(scene)
    rng = np.random.default_rng(26)
    source = mech[next(n for n, c in scene.configurations.items() if c.derivation is None)]
    cfgs = [mech.enter(name, source, rng.uniform(-1, 1, source.nv)) for name in scene.configurations]
    assert len({id(c.coords) for c in cfgs}) == len(cfgs) >= 2
    biased = 0
    for cfg in cfgs:
        coords = cfg.coords
        timed = coords.time_rows()
        assert timed is not None  # drives without a loop
        Jq, bias_of = timed
        assert coords.time_rows()[0] is Jq and not Jq.flags.writeable
        old_Jq, old_bias = _time_rows_formed_at_every_call(coords)
        assert Jq.tobytes() == old_Jq.tobytes() and Jq.shape == old_Jq.shape
        for t in rng.uniform(0.0, 7.5, 5):
            q, v = rng.uniform(-3, 3, cfg.nv), rng.uniform(-3, 3, cfg.nv)
            rows_J, rows_b = coords.rows(t, q, v)
            b = bias_of(t)
            assert rows_J.tobytes() == Jq.tobytes() and rows_b.tobytes() == b.tobytes() == old_bias(t).tobytes()
            assert b.dtype == rows_b.dtype and b.shape == rows_b.shape
            biased += bool(np.any(b != 0.0))
    assert biased or scene.name == "three_bar_cycle"  # the cart's: a bias that could differ


def test_time_rows_formed_once_is_the_same_run_to_the_bit(monkeypatch):
    once = _cycle()
    monkeypatch.setattr(PartitionedCoordinates, "time_rows", _time_rows_formed_at_every_call)
    every_call = _cycle()
    _same_run(once, every_call)


@contextlib.contextmanager
def _deferred_as_before():
    """``signals.deferred`` before the cut (a generator's context manager, ``signal``'s look-ups)."""
    from pcmm import signals
    held = signals._Held()
    old = {}
    if signals._main_thread():
        for sig in signals._signals(signals._NAMES):
            with contextlib.suppress(ValueError, OSError):
                old[sig] = _signal.signal(sig, held)
    try:
        yield held
    finally:
        for sig, handler in old.items():
            _signal.signal(sig, handler)


def test_deferred_as_a_class_is_the_same_run_to_the_bit(monkeypatch):
    from pcmm.run import recording
    now = _cycle()
    monkeypatch.setattr(recording, "deferred", _deferred_as_before)
    before = _cycle()
    _same_run(now, before)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_while_a_segment_of_the_cycle_is_recorded_waits_until_it_is_kept(signum, monkeypatch):
    """The 40th segment's recording receives the signal: the run stops once that segment is kept, its
    partial ends with it (40 segments, the last one's end), and the handler before is back."""
    from pcmm.run import recording
    from pcmm.signals import as_interrupts
    real, state = recording.record_samples, {"n": 0, "t": None}

    def record(traj, cfg, seg, *rest):
        state["n"] += 1
        if state["n"] == 40:
            state["t"] = float(seg.t[-1])
            os.kill(os.getpid(), signum)
            time.sleep(0.02)  # the handler runs meanwhile (held, not raised)
        return real(traj, cfg, seg, *rest)
    monkeypatch.setattr(recording, "record_samples", record)
    # a shell without job control starts its background jobs with SIGINT ignored (so does pytest
    # launched with `... &`): the test is about Python's own Ctrl-C handler, so it puts that in place
    sigint = _signal.signal(signal.SIGINT, _signal.default_int_handler)
    before = _signal.getsignal(signal.SIGINT), _signal.getsignal(signal.SIGTERM)
    try:
        with as_interrupts(), pytest.raises(pcmm.SimulationError) as info:
            pcmm.simulate(pcmm.load_scene(CYCLE), OPTS)
        assert (_signal.getsignal(signal.SIGINT), _signal.getsignal(signal.SIGTERM)) == before
    finally:
        _signal.signal(signal.SIGINT, sigint)
    partial = info.value.partial
    assert state["n"] == 40 and len(partial.segments) == 40
    assert partial.segments[-1].t[-1] == state["t"] and partial.t[-1] == state["t"]
