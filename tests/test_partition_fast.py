"""The partition of a configuration with loops (PartitionedCoordinates.partition) made cheaper, with the
same choices and the same bits: its condition check shown by a bound without an SVD where it can be
(``_conditioned``), and a switch's projection choosing the partition once for the next segment's pack at
the same posture.  Checked against numpy's SVD condition number on drawn blocks, against a fresh
partition at every posture it keeps, and on whole runs against the runs with both shortcuts bypassed."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from builders import parallelogram
from hypothesis import given, settings
from hypothesis import strategies as st

import pcmm
from pcmm.errors import SimulationError
from pcmm.model import partitioned
from pcmm.model.mechanism import Mechanism
from pcmm.model.partitioned import SINGULAR_COND, PartitionedCoordinates, _conditioned

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 4), seed=st.integers(0, 2 ** 32 - 1), smallest=st.floats(-14.0, 0.0), scale=st.floats(-3, 3))
def test_the_bound_passes_no_block_the_svd_refuses(n, seed, smallest, scale):
    """A block U diag(s) V^T with drawn singular values (the smallest 10^smallest of the largest, so
    condition numbers 1 to 1e14), drawn rotations and scale: where the bound passes it, numpy's
    SVD condition number is at most SINGULAR_COND; and it passes every block whose condition number is
    below SINGULAR_COND / n (||A||_F ||A^-1||_F <= n cond_2(A))."""
    rng = np.random.default_rng(seed)
    U, _ = np.linalg.qr(rng.standard_normal((n, n)))
    V, _ = np.linalg.qr(rng.standard_normal((n, n)))
    s = np.sort(10.0 ** rng.uniform(smallest, 0.0, n))[::-1]
    s[0], s[-1] = 1.0, 10.0 ** smallest if n > 1 else 1.0
    A = 10.0 ** scale * (U * s) @ V.T
    cond = np.linalg.cond(A)
    if _conditioned(A):
        assert cond <= SINGULAR_COND
    if cond < 0.5 * SINGULAR_COND / n:  # a margin for the rounding of the inverse
        assert _conditioned(A)


def test_singular_and_empty_blocks_are_left_to_the_svd():
    assert not _conditioned(np.zeros((2, 2)))
    assert not _conditioned(np.array([[1.0, 2.0], [2.0, 4.0]]))
    assert not _conditioned(np.array([[math.nan, 0.0], [0.0, 1.0]]))
    assert not _conditioned(np.zeros((0, 0)))
    assert _conditioned(np.eye(3))


def test_a_singular_posture_still_stops_with_its_condition_number(tmp_path):
    """The parallelogram with every link collinear (theta = 0): its loop rows lose rank, so every
    dependent block is singular; the partition stops with the configuration, the time and the SVD's
    condition number, as before."""
    cfg = Mechanism(pcmm.load_scene(parallelogram(tmp_path, 0.0, 1.0)))["c"]
    with pytest.raises(SimulationError, match=r"constraints are singular at t = 0.25 s \(condition number"):
        cfg.coords.partition(0.25, np.zeros(cfg.nv))


def _fresh_partitions(monkeypatch):
    """Each partition project() lets the next pack keep is chosen again there: it must be the same."""
    kept = []
    real = PartitionedCoordinates.partition

    def checked(self, t, q, prefer_independent=()):
        memo = self._projected
        if memo is not None and not prefer_independent and memo[0] == t and memo[1] == q.tobytes():
            D, I = self.D.copy(), self.I.copy()
            self._projected = None
            real(self, t, q, prefer_independent)
            kept.append(np.array_equal(D, self.D) and np.array_equal(I, self.I))
            return None
        return real(self, t, q, prefer_independent)
    monkeypatch.setattr(PartitionedCoordinates, "partition", checked)
    return kept


@pytest.mark.parametrize("name, switches", [("double_folded.toml", 47), ("andrews.toml", 0)])
def test_the_partition_a_switch_keeps_is_the_one_chosen_again(monkeypatch, name, switches):
    """Example 2's 47 bounces (each: project at the impact, then pack at the same posture) keep their
    partition for the next segment, and it is the one a fresh partition chooses there."""
    kept = _fresh_partitions(monkeypatch)
    traj = pcmm.simulate(pcmm.load_scene(EXAMPLES / name))
    assert len(traj.events) == switches
    assert len(kept) >= switches and all(kept)


def test_runs_are_the_same_bits_with_both_shortcuts_bypassed(monkeypatch):
    """Example 2 and its working cycle (to 9 s) with the SVD at every partition and the partition chosen
    again at every pack: the same events and final states, byte for byte."""
    scenes = [(EXAMPLES / "double_folded.toml", None), (EXAMPLES / "double_folded_cycle.toml", 9.0)]
    fast = [pcmm.simulate(pcmm.load_scene(p), pcmm.RunOptions(t_end=t) if t else pcmm.RunOptions()) for p, t in scenes]
    real_project = PartitionedCoordinates.project

    def project(self, *args, **kwargs):
        out = real_project(self, *args, **kwargs)
        self._projected = None
        return out
    monkeypatch.setattr(PartitionedCoordinates, "project", project)
    monkeypatch.setattr(partitioned, "_conditioned", lambda JD: False)
    slow = [pcmm.simulate(pcmm.load_scene(p), pcmm.RunOptions(t_end=t) if t else pcmm.RunOptions()) for p, t in scenes]
    for a, b in zip(fast, slow):
        assert len(a.events) == len(b.events) > 40
        for x, y in zip(a.events, b.events):
            assert x["t"] == y["t"] and x["v_after"] == y["v_after"]
        assert a.segments[-1].q[-1].tobytes() == b.segments[-1].q[-1].tobytes()
        assert a.segments[-1].v[-1].tobytes() == b.segments[-1].v[-1].tobytes()
