"""The recorded series over a whole segment at once (pcmm/run/series.py: one compiled pass for the link
positions and energies, array expressions for the rest) against the per-sample reference, on every
example and on mechanisms of this file's own; a planted fault the comparison catches; and the
compiled pass refused where it disagrees with the Python evaluation.

The bound: every derived series equal to the reference's within ``REL`` relative to the series'
largest magnitude (1 where it is smaller): 1e-12.
"""
from __future__ import annotations

import math

import builders
import numpy as np
import pytest
from builders import EXAMPLES, bar_xml, base_doc, joint_xml, link_xml, robot_xml, solid_xml, write_scene

import pcmm
from pcmm.errors import SimulationError
from pcmm.model import compiled
from pcmm.run import series

REL = 1e-12
KEYS = ("q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces")
#: each example's short run (the oracle's, tests/test_oracle.py) and whether its configurations
#: include one the whole-segment route serves (a tree or drives without a loop, no planar joint)
EXAMPLE_RUNS = {
    "three_bar.toml": (0.4, True),
    "three_bar_stop.toml": (0.5, True),
    "three_bar_cycle.toml": (1.3, True),  # drives without a loop
    "andrews.toml": (0.03, False),  # a loop: the per-sample route
    "double_folded.toml": (3.2, False),  # a driven loop, and loops in its merged configuration
    "double_folded_cycle.toml": (3.3, False),
    "rimless_wheel.toml": (2.5, False),  # a planar base pinned by a cut joint
    "compass_gait.toml": (1.6, False),
}

needs_compiled = pytest.mark.skipif(not compiled.enabled() or not hasattr(compiled._tree_dynamics, "series"),
                                    reason="the compiled series are not built here")


def difference(whole: dict, reference: dict) -> dict:
    """{series: its largest difference relative to max(1, its largest magnitude)}."""
    assert list(whole) == list(reference)
    out = {}
    for key in KEYS:
        a, b = np.asarray(whole[key]), np.asarray(reference[key])
        assert a.shape == b.shape, (key, a.shape, b.shape)
        scale = max(1.0, float(np.max(np.abs(b), initial=0.0)))
        out[key] = float(np.max(np.abs(a - b), initial=0.0)) / scale
    return out


def both_routes(monkeypatch) -> list:
    """Derive every segment's series both ways from now on (the run gets the reference's); returns
    the list of (configuration, {series: relative difference}) each whole-segment derivation adds."""
    pairs = []

    def both(cfg, coords, t, y, offsets, forces):
        whole = series.whole_segment_series(cfg, coords, t, y, offsets, forces)
        reference = series.per_sample_series(cfg, coords, t, y, offsets, forces)
        if whole is not None:
            pairs.append((cfg.name, difference(whole, reference)))
        return reference
    monkeypatch.setattr(series, "derived_series", both)
    return pairs


def read_everything(traj, dt=None) -> int:
    """Read every series of every segment (and of the run resampled at ``dt``); the samples read."""
    n = 0
    for run in (traj, traj.resampled(dt)) if dt else (traj,):
        for seg in run.segments:
            for key in KEYS:
                getattr(seg, key)
            n += len(seg.t)
    return n


def run(path, t_end=None):
    scene = pcmm.load_scene(path)
    try:
        return pcmm.simulate(scene, pcmm.RunOptions(t_end=t_end) if t_end else pcmm.RunOptions())
    except SimulationError as exc:  # a run that stops keeps its partial trajectory
        if exc.partial is None:
            raise
        return exc.partial


def worst(pairs) -> float:
    return max((d for _, diffs in pairs for d in diffs.values()), default=0.0)


@needs_compiled
@pytest.mark.parametrize("name", sorted(EXAMPLE_RUNS))
def test_every_example_derives_the_reference_series(name, monkeypatch):
    t_end, served = EXAMPLE_RUNS[name]
    pairs = both_routes(monkeypatch)
    traj = run(EXAMPLES / name, t_end)
    assert read_everything(traj, dt=0.05) > 0
    assert worst(pairs) <= REL, [p for p in pairs if max(p[1].values()) > REL][:3]
    assert bool(pairs) == served, {seg.configuration for seg in traj.segments}


def cart_pendulum_tree(folder, axis=(0.6, 0.8, 0.0), t_end=1.0):
    """A cart on a prismatic joint X along ``axis`` (an unaligned axis by default) on a linear spring
    with a damper, a bar on the revolute J1 at an offset (0.1, 0.05) turned by 0.3 rad on the cart,
    a torsion spring and a constant torque on J1, under gravity: a tree with no event."""
    urdf = robot_xml("cart_tree", link_xml("frame"),
                     joint_xml("X", "prismatic", "frame", "cart", xyz=(0.2, -0.1), axis=axis),
                     solid_xml("cart", 1.3, 0.05),
                     joint_xml("J1", "revolute", "cart", "link1", xyz=(0.1, 0.05), yaw=0.3), bar_xml("link1", 0.5, 0.8))
    forces = [{"name": "slide_spring", "type": "linear", "on": {"joint": "X"}, "measure": {"joint": "X"},
               "k": 40.0, "rest": 0.05, "c": 0.3},
              {"name": "hinge_spring", "type": "spring", "on": {"joint": "J1"}, "measure": {"joint": "J1"},
               "k": 2.5, "rest": 0.2},
              {"name": "motor", "type": "torque", "on": {"joint": "J1"}, "value": 0.4}]
    doc = base_doc("cart_tree", "free", {"free": "cart.urdf"}, {"X": 0.1, "J1": -0.7}, {"X": 0.4, "J1": 1.5},
                   t_end=t_end, forces=forces)
    return write_scene(folder, doc, {"cart.urdf": urdf})


@needs_compiled
def test_own_tree_prismatic_revolute_springs(tmp_path, monkeypatch):
    """A tree of a prismatic (unaligned axis) and a revolute joint with springs, a damper and a torque:
    the whole-segment route serves it, compiled, and equals the reference sample by sample."""
    pairs = both_routes(monkeypatch)
    compiled.forget_trees()
    traj = run(cart_pendulum_tree(tmp_path))
    assert read_everything(traj, dt=0.01) > 100
    assert compiled.trees_built() > 0 and compiled.why_not() is None
    assert pairs and worst(pairs) <= REL


@needs_compiled
def test_own_tree_against_closed_form(tmp_path):
    """The whole-segment route's positions, energies and force elements of the cart and bar, written by
    hand from the URDF: cart origin p = o + x u, bar origin b = p + (0.1, 0.05), bar angle 0.3 + q1."""
    traj = run(cart_pendulum_tree(tmp_path, t_end=0.5))
    seg = traj.segments[0]
    x, q1 = seg.q[:, 0], seg.q[:, 1]
    xd, w = seg.v[:, 0], seg.v[:, 1]
    u = np.array([0.6, 0.8])
    cart = np.array([0.2, -0.1]) + x[:, None] * u
    bar = cart + np.array([0.1, 0.05])
    th = 0.3 + q1
    com = bar + 0.25 * np.stack([np.cos(th), np.sin(th)], axis=1)
    vcom = xd[:, None] * u + 0.25 * w[:, None] * np.stack([-np.sin(th), np.cos(th)], axis=1)
    m_cart, m_bar, L = 1.3, 0.8, 0.5
    kinetic = 0.5 * m_cart * xd ** 2 + 0.5 * m_bar * np.sum(vcom ** 2, axis=1) + 0.5 * (m_bar * L * L / 12) * w ** 2
    gravity = 9.81 * (m_cart * cart[:, 1] + m_bar * com[:, 1])
    springs = 0.5 * 40.0 * (x - 0.05) ** 2 + 0.5 * 2.5 * (q1 - 0.2) ** 2
    elements = np.stack([-40.0 * (x - 0.05) - 0.3 * xd, -2.5 * (q1 - 0.2), np.full_like(x, 0.4)], axis=1)
    whole = series.whole_segment_series(*_context_of(traj, tmp_path))
    assert whole is not None
    np.testing.assert_allclose(whole["xy"][:, list(seg.links).index("cart")], cart, rtol=0, atol=1e-14)
    np.testing.assert_allclose(whole["xy"][:, list(seg.links).index("link1")], bar, rtol=0, atol=1e-14)
    np.testing.assert_allclose(whole["kinetic"], kinetic, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(whole["potential"], gravity + springs, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(whole["forces"], elements, rtol=1e-13, atol=1e-13)
    assert len(seg.t) > 10 and len(whole["kinetic"]) == len(seg.t)


def _context_of(traj, folder):
    """(cfg, coords, t, y, offsets, forces) of the run's first segment, for a direct call: the
    configuration built again from the scene, the tree's state [q, v] from the recorded series."""
    scene = pcmm.load_scene(folder / "scene.toml")
    from pcmm.model.mechanism import Mechanism
    cfg = Mechanism(scene)["free"]
    seg = traj.segments[0]
    y = np.vstack([seg.q.T, seg.v.T])
    return cfg, cfg.coords, seg.t, y, {}, cfg.forces


@needs_compiled
def test_own_driven_cart_with_a_spring(tmp_path, monkeypatch):
    """Drives without a loop (a prismatic cart driven along x, a bar on a revolute joint with a torsion
    spring, a joint stop with bounces and a merge): the whole-segment route, the drive's force one
    constrained solve a sample, equals the reference."""
    path = builders.driven_cart_pendulum(tmp_path, e=0.6, forces=[
        {"name": "hinge_spring", "type": "spring", "on": {"joint": "J1"}, "measure": {"joint": "J1"}, "k": 0.8,
         "rest": 0.1, "configurations": ["swing"]}])
    pairs = both_routes(monkeypatch)
    traj = run(path)
    assert read_everything(traj, dt=0.02) > 100
    assert any(seg.constraint_labels for seg in traj.segments) and traj.events
    assert pairs and worst(pairs) <= REL


@needs_compiled
def test_a_planted_wrong_link_offset_is_caught(tmp_path, monkeypatch):
    """A compiled tree whose bar frame sits 1e-9 m off (a wrong link offset), used without the probe
    check: the comparison with the reference sees it in the positions (and nowhere else)."""
    cfg, coords, t, y, offsets, forces = _context_of(run(cart_pendulum_tree(tmp_path, t_end=0.2)), tmp_path)
    model, frames = cfg.model, [cfg.link_frame[link] for link in cfg.links]
    wrong = cfg.links.index("link1")

    def build(tree):
        for k, f in enumerate(frames):
            frame = model.frames[f]
            shift = np.array([1e-9, 0.0, 0.0]) if k == wrong else 0.0
            tree.add_frame(int(frame.parentJoint), frame.placement.rotation, frame.placement.translation + shift)
        tree.finalize(model.gravity.linear, np.zeros(model.nv), np.zeros((model.nv, 2 * model.nv)))
    planted = compiled._tree(model, ("planted series", tuple(frames)), build)[0]
    monkeypatch.setattr(series, "_series_tree", lambda cfg: planted)
    whole = series.whole_segment_series(cfg, coords, t, y, offsets, forces)
    diffs = difference(whole, series.per_sample_series(cfg, coords, t, y, offsets, forces))
    assert diffs["xy"] > REL and diffs["xy"] == pytest.approx(1e-9, rel=1e-3)
    assert all(d <= REL for key, d in diffs.items() if key != "xy")


@needs_compiled
def test_a_compiled_pass_that_disagrees_is_refused(tmp_path):
    """The probe check before a configuration uses the compiled pass: against a reference 1e-9 m off
    it refuses the tree, says why, and the per-sample route serves."""
    cfg, coords, t, y, offsets, forces = _context_of(run(cart_pendulum_tree(tmp_path, t_end=0.2)), tmp_path)
    compiled.forget_trees()
    frames = [cfg.link_frame[link] for link in cfg.links]

    def off_reference(Q, V):
        xy, ke, pe = series._python_series(cfg, Q, V)
        return xy + 1e-9, ke, pe
    assert compiled.series_tree(cfg.model, frames, off_reference) is None
    assert "recorded series" in compiled.why_not() and "disagrees" in compiled.why_not()
    assert compiled.series_tree(cfg.model, frames, lambda Q, V: series._python_series(cfg, Q, V)) is not None
    compiled.forget_trees()


def test_without_the_compiled_pass_the_reference_serves(tmp_path, monkeypatch):
    """PCMM_COMPILED=0: no whole-segment series, every segment derived sample by sample."""
    monkeypatch.setenv("PCMM_COMPILED", "0")
    pairs = both_routes(monkeypatch)
    traj = run(cart_pendulum_tree(tmp_path, t_end=0.2))
    assert read_everything(traj) > 0 and pairs == []
    assert math.isfinite(float(traj.segments[0].kinetic[-1]))


def _counted(monkeypatch) -> list:
    """Count the calls of ``derived_series`` from now on (and the samples each derives)."""
    calls = []
    default = series.derived_series

    def counted(cfg, coords, t, y, offsets, forces):
        calls.append(len(t))
        return default(cfg, coords, t, y, offsets, forces)
    monkeypatch.setattr(series, "derived_series", counted)
    return calls


def test_a_stored_chunks_segments_of_one_context_are_derived_together(tmp_path, monkeypatch):
    """A bouncing ball (e = 1, 30 bounces) stored in chunks of at most 8 segments or events: each
    chunk's flights (one context: the same configuration, forces, offsets and stepping) derived in one call
    (store.derive_together), not one a segment; every series the same bits as the run kept in memory
    derives segment by segment."""
    from pcmm.results.store import StoreWriter
    scene = pcmm.load_scene(builders.ball(tmp_path, 1.0, merge=False))
    period = 2.0 * math.sqrt(2.0 / 9.81)
    opts = pcmm.RunOptions(t_end=29.5 * period)
    kept = pcmm.simulate(scene, opts)
    read_everything(kept)  # (derived segment by segment, before the count)
    calls = _counted(monkeypatch)
    stored = pcmm.simulate(scene, opts, store=StoreWriter(tmp_path / "store", chunk_samples=10 ** 6, chunk_records=8))
    chunks = len(list((tmp_path / "store").glob("chunk-*.npz")))
    assert len(kept.events) == 30 and len(stored.segments) == 31 and chunks >= 4
    # one derivation a chunk, and one more for the first fall (its own context: not a flight between
    # bounces, whose states carry their work)
    assert len(calls) <= chunks + 1 < len(stored.segments)
    assert sum(calls) == sum(len(s.t) for s in kept.segments)  # every sample derived once
    derived_when_read = len(calls)
    back = pcmm.Trajectory.load(tmp_path / "store")
    for run_back in (stored, back):
        for x, y in zip(kept.segments, run_back.segments):
            for key in KEYS:
                np.testing.assert_array_equal(getattr(x, key), getattr(y, key), err_msg=key)
    assert len(calls) == derived_when_read  # nothing derived again when read back


def test_a_constrained_configurations_segments_are_derived_one_by_one(tmp_path):
    """Drives (constrained: the store does not assume a sample's series stand alone): derive_together
    leaves every segment to derive its own, and a tree's segments of one context are derived in one
    call, with the series each segment derives alone."""
    from pcmm.results import store
    driven = pcmm.simulate(pcmm.load_scene(builders.driven_cart_pendulum(tmp_path / "driven", e=0.6)))
    assert len(driven.segments) > 4 and store.derive_together(driven.segments) == 0
    assert all("_derive" in driven.segments[i].__dict__ for i in range(len(driven.segments)))
    tree = pcmm.simulate(pcmm.load_scene(builders.ball(tmp_path / "ball", 1.0, merge=False)),
                         pcmm.RunOptions(t_end=6.0))
    alone = [{key: getattr(seg, key) for key in KEYS} for seg in tree.segments]
    tree.segments._records.clear()  # the same segments, not yet derived
    # one call: the flights between bounces (the first fall, alone in its context, derives its own when read)
    assert store.derive_together(tree.segments) == 1
    assert "_derive" in tree.segments[0].__dict__
    for mine, seg in zip(alone, tree.segments):
        assert seg is tree.segments[0] or "_derive" not in seg.__dict__
        for key in KEYS:
            np.testing.assert_array_equal(mine[key], getattr(seg, key), err_msg=key)


def _count_accelerations(monkeypatch) -> list:
    from pcmm.model.partitioned import PartitionedCoordinates
    calls = []
    solve = PartitionedCoordinates.accelerations

    def counted(self, t, q, v, extra=None):
        calls.append(t)
        return solve(self, t, q, v, extra)
    monkeypatch.setattr(PartitionedCoordinates, "accelerations", counted)
    return calls


@needs_compiled
def test_a_drives_moments_come_from_one_compiled_call_a_segment(tmp_path, monkeypatch):
    """The driven cart's drive force at every sample from one compiled KKT solve a segment (checked
    at 3 probe states first), not one Python solve a sample; the same numbers as the reference."""
    if not compiled.has_multipliers():
        pytest.skip("this build has no compiled multipliers")
    traj = run(builders.driven_cart_pendulum(tmp_path, e=0.6))
    series._HELD.multipliers.clear()
    calls = _count_accelerations(monkeypatch)
    samples = read_everything(traj)
    assert samples > 40 and 0 < len(calls) <= 3, len(calls)  # the probe check's three, once
    calls.clear()
    pairs = both_routes(monkeypatch)
    traj.segments._records.clear()
    read_everything(traj)
    assert pairs and worst(pairs) <= REL


@needs_compiled
def test_compiled_multipliers_that_disagree_are_refused(tmp_path, monkeypatch):
    """A planted fault in the compiled drive moments (their sign flipped): the probe check refuses
    them, every sample is solved in Python, and the series still equal the reference."""
    if not compiled.has_multipliers():
        pytest.skip("this build has no compiled multipliers")
    traj = run(builders.driven_cart_pendulum(tmp_path, e=0.6))
    series._HELD.multipliers.clear()
    right = compiled.multipliers
    monkeypatch.setattr(compiled, "multipliers", lambda *a: -right(*a))
    calls = _count_accelerations(monkeypatch)
    samples = read_everything(traj)
    assert "disagrees" in compiled.why_not() and "constraint forces" in compiled.why_not()
    assert len(calls) >= samples  # every sample solved in Python (and the probes)
    pairs = both_routes(monkeypatch)
    traj.segments._records.clear()
    read_everything(traj)
    assert pairs and worst(pairs) <= REL
    series._HELD.multipliers.clear()
