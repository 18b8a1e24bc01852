"""The event path's per-configuration caches and direct LAPACK calls give the very numbers of the
uncached, checked route (issue 26 item 2: the impulse solve made cheaper without changing a bit)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla

import pcmm
from pcmm.errors import SimulationError
from pcmm.events import cutting
from pcmm.events.impulse import _inverse_mass
from pcmm.model.mechanism import Mechanism

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def config1():
    return Mechanism(pcmm.load_scene(ROOT / "examples" / "three_bar.toml"))["config1"]


def _uncached_rows(cfg, q, joints):
    """J_cut with every cut joint's forbidden motions recomputed (nothing kept between impacts)."""
    saved = dict(cfg.cut_models)
    cfg.cut_models.clear()
    try:
        return cutting.cut(cfg, q, joints).J_cut
    finally:
        cfg.cut_models.clear()
        cfg.cut_models.update(saved)


def test_cut_rows_with_kept_complements_are_the_recomputed_ones(config1):
    rng = np.random.default_rng(7)
    for _ in range(5):  # the complement kept from the first pose serves every later pose exactly
        q = rng.uniform(-3.0, 3.0, config1.nv)
        kept = cutting.cut(config1, q, ("O3",)).J_cut
        assert kept.tobytes() == _uncached_rows(config1, q, ("O3",)).tobytes()
    # a revolute joint forbids the two translations of its child relative to its parent: two rows
    assert kept.shape == (2, config1.nv + 2)


def test_inverse_mass_is_scipys_cholesky_inverse_to_the_bit():
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 6):
        A = rng.normal(size=(n, n))
        M = A @ A.T + n * np.eye(n)
        W = _inverse_mass(M, "c")
        assert W.tobytes() == sla.cho_solve(sla.cho_factor(M), np.eye(n)).tobytes()
        assert np.allclose(W @ M, np.eye(n), atol=1e-12)


def test_inverse_mass_of_a_massless_link_says_so():
    M = np.diag([1.0, 0.0, 2.0])  # a link without mass or inertia: not positive definite
    with pytest.raises(SimulationError, match="configuration 'folded': the mass matrix is not positive definite"):
        _inverse_mass(M, "folded")


def test_a_study_varying_a_torque_holds_a_bounded_number_of_compiled_trees():
    """Each torque value is a new key of the compiled trees (a sweep's worker held 523 trees after
    300 runs): per model at most compiled._KEYS_MAX are kept, and a run whose key was dropped
    gives the same event again (the tree is rebuilt with the same numbers)."""
    import pcmm
    from pcmm.model import compiled
    if not compiled.enabled():
        pytest.skip(compiled.why_not())
    compiled.forget_trees()
    scene = pcmm.load_scene(ROOT / "examples" / "three_bar.toml")
    first = pcmm.simulate(scene.with_values({"forces.tau1.value": 1.955}), pcmm.RunOptions(t_end=0.2))
    for k in range(compiled._KEYS_MAX + 8):
        pcmm.simulate(scene.with_values({"forces.tau1.value": 1.9 + 0.001 * k}), pcmm.RunOptions(t_end=0.2))
    held = [len(built) for _, built in compiled._CACHE.trees.values()]
    assert held and max(held) <= compiled._KEYS_MAX
    again = pcmm.simulate(scene.with_values({"forces.tau1.value": 1.955}), pcmm.RunOptions(t_end=0.2))
    assert again.events[0]["t"] == first.events[0]["t"]
    assert np.array_equal(again.segments[-1].q, first.segments[-1].q)
