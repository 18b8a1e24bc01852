"""The switch, the entry and the re-arm of an event take shortcuts that give the very bits of the
general route they skip (issue 26 item 2, branch h-entry): a drives-only partition's projection
(:meth:`PartitionedCoordinates.project`: the prescribed coordinates, no new partition, no unpack
dispatch), the entry's rows read as the constant drive rows (``time_rows``), a bounce's state
taken without the mapping's copies.  Checked against the general route call by call, with the
closed form of the drives, and on whole runs with every shortcut bypassed: the cycle of
``examples/three_bar_cycle.toml`` and mechanisms of this file's own (a bar swinging on a driven
crank, bouncing on a joint stop on the crank; a double pendulum bouncing under a merge held by
compression only)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import pcmm
from pcmm.events import entry
from pcmm.model.mechanism import Mechanism
from pcmm.model.partitioned import PartitionedCoordinates

from builders import bar_xml, base_doc, joint_xml, link_xml, robot_xml, stop, write_scene

ROOT = Path(__file__).resolve().parents[1]
CYCLE = ROOT / "examples" / "three_bar_cycle.toml"
CRANK = (0.3, 2.5, 0.0, -0.4)  # the crank's drive: theta(t) = 0.3 + 2.5 t - 0.4 t^3


def crank_with_bar(folder: Path, e: float = 0.4, q_stop: float = -0.9, t_end: float = 2.0, planar: bool = False) -> Path:
    """A crank ``J0`` (a bar of 0.4 m, 1.2 kg) DRIVEN at theta(t) = CRANK; at its tip the bar ``link1``
    (0.3 m, 0.7 kg) on the revolute ``J1``, released at J1 = 0 relative to the crank with the crank's
    own angular velocity; it swings back under gravity onto a stop on the crank at J1 = q_stop
    (restitution e), whose bounces merge into 'rest' (J1 locked: every coordinate driven).  With
    ``planar`` the crank's pivot is a free body (a 2 kg block on a planar joint ``P``), not the
    frame: a drives-only partition whose velocity is not its coordinates' rates."""
    base = "block" if planar else "frame"
    parts = [link_xml("frame")]
    if planar:
        parts += [joint_xml("P", "planar", "frame", "block"), link_xml("block", 2.0, (0.0, 0.0), 0.05)]
    parts += [joint_xml("J0", "revolute", base, "crank"), bar_xml("crank", 0.4, 1.2),
              joint_xml("J1", "revolute", "crank", "link1", xyz=(0.4, 0.0)), bar_xml("link1", 0.3, 0.7)]
    urdf = robot_xml("crank_bar", *parts)
    tr = stop("pin", "swing", e, {"type": "coordinate", "measure": {"joint": "J1"}, "value": q_stop,
                                  "direction": "decreasing"},
              {"joint": "J1", "arm": 0.15}, merge_to="rest", cut=["J1"])
    q0 = {"J0": CRANK[0], "J1": 0.0}
    v0 = {"J0": CRANK[1], "J1": 0.0}
    if planar:
        q0["P"], v0["P"] = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
    doc = base_doc("crank_bar", "swing", {"swing": "crank.urdf", "rest": {"from": "swing", "lock": {"J1": q_stop}}},
                   q0, v0, t_end=t_end, transitions=[tr], drives=[{"joint": "J0", "coefficients": list(CRANK)}])
    return write_scene(folder, doc, {"crank.urdf": urdf})


def double_pendulum(folder: Path, qA: float = -1.2, qB: float = -1.2, eB: float = 0.6, t_end: float = 2.0) -> Path:
    """Two bars (0.5 m 1 kg on ``J1`` at the frame, 0.4 m 0.8 kg on ``J2`` at its tip) released at
    J1 = -0.3, J2 = 0: ``J1`` falls onto the stop A at qA (plastic), which merges into 'A_locked' held
    by compression only (unmerge), where ``J2`` bounces on the stop B at qB (restitution eB) under
    that hold, until A's holding force turns tensile and the merge is undone."""
    urdf = robot_xml("dp", link_xml("frame"), joint_xml("J1", "revolute", "frame", "link1"), bar_xml("link1", 0.5, 1.0),
                     joint_xml("J2", "revolute", "link1", "link2", xyz=(0.5, 0.0)), bar_xml("link2", 0.4, 0.8))
    A = stop("A", "free", 0.0, {"type": "coordinate", "measure": {"joint": "J1"}, "value": qA, "direction": "decreasing"},
             {"joint": "J1", "arm": 0.25}, merge_to="A_locked", cut=["J1"], unmerge=True)
    B = stop("B", "A_locked", eB, {"type": "coordinate", "measure": {"joint": "J2"}, "value": qB, "direction": "decreasing"},
             {"joint": "J2", "arm": 0.2}, merge_to="both", cut=["J2"])
    doc = base_doc("dp", "free", {"free": "dp.urdf", "A_locked": {"from": "free", "lock": {"J1": qA}},
                                   "B_locked": {"from": "free", "lock": {"J2": qB}},
                                   "both": {"from": "free", "lock": {"J1": qA, "J2": qB}}},
                   {"J1": -0.3, "J2": 0.0}, {"J1": 0.0, "J2": 0.0}, t_end=t_end, transitions=[A, B])
    return write_scene(folder, doc, {"dp.urdf": urdf})


def general_projection(coords: PartitionedCoordinates, t, q, v, prefer_independent=()):
    """The projection's general route (a new partition at q, a seed, the state unpacked)."""
    coords.partition(t, q, prefer_independent)
    coords.seed(q)
    return coords.unpack(t, np.concatenate([q[coords.I], coords.cfg.qdot(q, v)[coords.I]]))


def general_jacobian(dst, t, q, v):
    """The entry's rows by the general route (every row and its bias at (q, v)), and their scale."""
    Jq = dst.coords.rows(t, q, v)[0]
    return Jq, max(1.0, float(np.abs(Jq).max()))


def drive(t: float, k: int) -> float:
    """CRANK's k-th derivative at t, by hand."""
    a0, a1, a2, a3 = CRANK
    return (a0 + a1 * t + a2 * t * t + a3 * t ** 3, a1 + 2 * a2 * t + 3 * a3 * t * t)[k]


@pytest.mark.parametrize("planar", [False, True])
def test_drives_only_projection_is_the_general_route_to_the_bit(tmp_path, planar):
    cfg = Mechanism(pcmm.load_scene(crank_with_bar(tmp_path, planar=planar)))["swing"]
    coords = cfg.coords
    assert isinstance(coords, PartitionedCoordinates) and not coords.closure.size
    j0 = cfg.joint_slice["J0"].start
    rng = np.random.default_rng(26)
    general_projection(coords, 0.0, np.zeros(cfg.nv), np.zeros(cfg.nv))  # partitioned once (as at the start of a run)
    for _ in range(40):
        t = float(rng.uniform(0.0, 2.0))
        q, v = rng.normal(size=cfg.nv), rng.normal(size=cfg.nv) * 3
        v[rng.random(cfg.nv) < 0.3] = -0.0  # signed zeros kept as the general route keeps them
        fast_q, fast_v = coords.project(t, q, v)
        slow_q, slow_v = general_projection(coords, t, q, v)
        assert fast_q.tobytes() == slow_q.tobytes() and fast_v.tobytes() == slow_v.tobytes()
        # new arrays: the state handed in (the run's, the impulse's) is not written over
        assert not np.shares_memory(fast_q, q) and not np.shares_memory(fast_v, v)
        # and by hand: the driven coordinate prescribed, the others (and their rates) kept
        assert math.isclose(fast_q[j0], drive(t, 0), rel_tol=1e-15, abs_tol=1e-15)
        rates = cfg.qdot(fast_q, fast_v)
        assert math.isclose(rates[j0], drive(t, 1), rel_tol=1e-15, abs_tol=1e-15)
        free = [i for i in range(cfg.nv) if i != j0]
        assert np.array_equal(fast_q[free], q[free])
        assert np.allclose(rates[free], cfg.qdot(q, v)[free], rtol=1e-15, atol=1e-15)
        # the entry's rows: the constant drive row, as every row of the general route gives it
        (Jq, scale), (Jq_ref, scale_ref) = entry._jacobian(cfg, t, fast_q, fast_v), general_jacobian(cfg, t, fast_q, fast_v)
        assert Jq.tobytes() == Jq_ref.tobytes() and Jq.shape == Jq_ref.shape and scale == scale_ref == 1.0
        assert entry._jacobian(cfg, t, fast_q, fast_v)[0] is Jq and not Jq.flags.writeable  # kept, read-only


def run_bits(scene, t_end=None):
    """Every event's time, kind and state after, and the final state, as bytes."""
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=t_end)) if t_end is not None else pcmm.simulate(scene)
    out = [(e["t"], e["name"], e["from"], e["to"], repr(e.get("v_after")), repr(e.get("omega_after")))
           for e in traj.events]
    last = traj.segments[-1]
    return out, np.asarray(last.t).tobytes(), np.asarray(last.q).tobytes(), np.asarray(last.v).tobytes(), \
        traj.stats["impacts"]


@pytest.mark.parametrize("which", ["cycle", "crank", "double pendulum"])
def test_runs_are_the_same_bits_with_every_shortcut_bypassed(tmp_path, monkeypatch, which):
    """Each shortcut bypassed for its general route: the same events and final state, byte for byte."""
    path = {"cycle": CYCLE, "crank": None, "double pendulum": None}[which] or (
        crank_with_bar(tmp_path) if which == "crank" else double_pendulum(tmp_path))
    scene = pcmm.load_scene(path)
    t_end = 2.5 if which == "cycle" else None
    fast = run_bits(scene, t_end)
    monkeypatch.setattr(PartitionedCoordinates, "project", general_projection)
    monkeypatch.setattr(entry, "_jacobian", general_jacobian)
    slow = run_bits(scene, t_end)
    assert len(fast[0]) == len(slow[0]) and fast[4] == slow[4] > {"cycle": 100, "crank": 10, "double pendulum": 3}[which]
    assert fast == slow
    if which == "double pendulum":  # bounces under a merge held by compression only, released in between
        kinds = [(e[1], e[2], e[3]) for e in fast[0]]
        assert ("B", "A_locked", "A_locked") in kinds and ("A", "A_locked", "free") in kinds


def test_a_guard_on_a_longer_state_is_the_replaced_guard(tmp_path):
    """``Guard.on_state`` (a flight's guards, its work appended to the state) copies the fields instead
    of ``dataclasses.replace``: every field the same object but the three read on the state's head, and
    those give the guard's own values on it."""
    from dataclasses import fields, replace
    from pcmm.ode.witness import Guard
    calls = []

    def value(t, y):
        calls.append(len(y))
        return float(y[0] - 0.25 * y[1] + t)
    g = Guard("probe", value, -1, "unmerge", transition="tr", payload=("p",), rate=lambda t, y, f: float(y[1]),
              many=lambda ts, ys: list(ys[0] - 0.25 * ys[1] + ts), affine=(np.array([1.0, -0.25]), 1.0, 0.0),
              holding=("h", 0, 0.0))
    wide, ref = g.on_state(2), replace(g)
    assert type(wide) is Guard
    for f in fields(Guard):
        if f.name not in ("value", "rate", "many"):
            assert getattr(wide, f.name) is getattr(ref, f.name), f.name
    y = np.array([0.7, -1.3, 42.0])  # the work appended: never read
    assert wide(0.5, y) == g(0.5, y[:2]) == 0.7 + 0.325 + 0.5 and calls == [2, 2]
    assert wide.rate(0.5, y, None) == -1.3 and wide.rate(0.5, y, np.ones(3)) == -1.3
    ys = np.array([[0.7, 0.1], [-1.3, 2.0], [9.0, 9.0]])
    assert wide.many(np.array([0.5, 1.0]), ys) == g.many(np.array([0.5, 1.0]), ys[:2])
    plain = Guard("plain", value, 1)
    assert plain.on_state(2).rate is None and plain.on_state(2).many is None
