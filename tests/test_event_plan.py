"""The event path's plans and lean reads give the very bits of the routes they replace (issue 26
item 2): the impulse solve with its kept plan and one kinematics pass against the plain solve
(written out here as the paper's formulas, Eqs. 21-43, with numpy's own routines), the compact
event log's encoding and its times read without building a record."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

import pcmm
from pcmm.events.contact import contact_state, joint_stop_row
from pcmm.events.cutting import cut
from pcmm.events.impulse import solve_impulse
from pcmm.model.mechanism import Mechanism
from pcmm.results import event_log
from pcmm.results.event_log import EventLog

ROOT = Path(__file__).resolve().parents[1]


def _plain_stop_impulse(cfg, t, q, v, contact, e, cut_joints):
    """A joint stop's impulse by the plain route: the tree's kinematics, the cut system built
    with its own kinematics pass, numpy's inverse, solve and least squares (Eqs. 24-30)."""
    _, _, vn, _ = contact_state(cfg, q, v, contact)
    cs = cut(cfg, q, cut_joints)  # kinematics computed again
    v_f = cs.T @ v
    M_f = pin.crba(cs.model, cs.data, cs.q)
    M_f = np.triu(M_f) + np.triu(M_f, 1).T
    J_n = joint_stop_row(cfg, cs.model, cs.data, contact)[1][None, :]
    G = np.vstack([cs.J_cut, cfg.coords.equality(t, cs.model, cs.data)])
    W = np.linalg.inv(M_f)
    WGt = W @ G.T
    W_eff = W - WGt @ np.linalg.solve(G @ WGt, WGt.T)
    P = -(1.0 + e) * (J_n @ v_f) / (J_n @ W_eff @ J_n.T)[0]
    v_f_after = v_f + W_eff @ J_n.T @ P
    v_after = np.linalg.lstsq(cs.T, v_f_after, rcond=None)[0]
    mult = -np.linalg.solve(G @ WGt, G @ W @ J_n.T @ P)
    return vn, float(P[0]), v_after, mult


def test_planned_impulse_is_the_plain_route_and_its_own_repeat():
    """At a three-bar pin's strike (a drive on O1, O2 cut): the planned solve agrees with the
    plain route to round-off, keeps the drive's work mu q' and the momentum balance about the
    pivot, and a second solve at the same state (plan kept, kinematics already there) gives the
    same bits."""
    scene = pcmm.load_scene(ROOT / "examples" / "three_bar_cycle.toml")
    cfg = Mechanism(scene)["open"]
    tr = next(s for s in scene.transitions if s.name == "O2 pin")
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = np.array([rng.uniform(-np.pi, np.pi), np.pi / 2, np.pi - rng.uniform(0.0, 0.3)])
        v = np.array([np.pi, rng.uniform(0.2, 2.0), rng.uniform(-2.0, 2.0)])
        t = float(rng.uniform(0.0, 1.0))
        imp = solve_impulse(cfg, t, q, v, tr.contact, tr.restitution, tr.cut, name=tr.name)
        again = solve_impulse(cfg, t, q, v, tr.contact, tr.restitution, tr.cut, name=tr.name)
        assert imp.v_after.tobytes() == again.v_after.tobytes() and imp.P == again.P
        assert imp.joint_impulses == again.joint_impulses and imp.drive_work == again.drive_work
        vn, P, v_after, mult = _plain_stop_impulse(cfg, t, q, v, tr.contact, tr.restitution, tr.cut)
        assert imp.vn_before == vn < 0
        assert abs(imp.P - P) <= 1e-12 * abs(P)
        assert np.allclose(imp.v_after, v_after, rtol=0, atol=1e-12 * np.max(np.abs(v)))
        assert abs(imp.vn_after + tr.restitution * vn) <= 1e-12 * abs(vn)  # Newton's law, Eq. 21
        assert abs(imp.v_after[0] - v[0]) <= 1e-12 * abs(v[0])  # the drive holds O1'
        mu = imp.constraint_rows["O1.drive"]
        assert abs(mu - mult[-1]) <= 1e-12 * max(abs(mu), 1e-12)
        assert imp.drive_work == mu * float(v[0])


def test_event_log_reads_a_time_without_building_the_record(monkeypatch):
    """``EventLog.time(i)`` is ``log[i]["t"]`` for records of several layouts (a record read and
    kept by index: its own dict's), and builds no record where the layout starts with ``t``."""
    records = [{"t": 0.5 * k, "name": "pin", "impulse": {"normal": float(k), "vector": [0.0, float(k)]}}
               for k in range(300)]
    records[7] = {"t": 3.5, "name": "other", "warnings": ["a message"]}
    records[9] = {"name": "no time first", "t": 4.5}
    log = EventLog(records)
    log[11]["t"] = 99.0  # a record changed through the log, as a list's would be
    built = []
    original = EventLog._event
    monkeypatch.setattr(EventLog, "_event", lambda self, i: built.append(i) or original(self, i))
    assert [log.time(i) for i in range(len(log))] == [99.0 if i == 11 else r["t"] for i, r in enumerate(records)]
    assert built == [9]  # only the record whose layout does not start with t
    assert log.time(-1) == 149.5


def test_fast_layout_encodes_as_the_type_checks_do():
    """The layout dispatched on exact types is the one of the checks in order (float or numpy
    float64, bool or None, int within 2**53, short text, containers, anything else kept aside)."""
    class Sub(float):
        pass
    value = {"t": 1.0, "x": np.float64(2.5), "b": True, "n": None, "i": 3, "big": 2 ** 60, "s": "short",
             "long": "x" * 60, "l": [1.0, (2, "a")], "sub": Sub(1.5), "arr": np.zeros(2), "z": -0.0}
    numbers, aside = [], []
    layout = event_log._layout(value, numbers, aside)
    F, I, O = event_log._F, event_log._I, event_log._O
    assert layout == ("d", tuple(value), (F, F, ("c", True), ("c", None), I, O, ("c", "short"), O,
                                          ("l", (F, ("t", (I, ("c", "a"))))), O, O, F))
    assert numbers[:5] == [1.0, 2.5, 3, 0, 1] and aside[0] == 2 ** 60 and aside[1] == "x" * 60
    log = EventLog([value])
    back = log[0]
    assert back["z"] == 0.0 and str(back["z"]) == "-0.0" and back["big"] == 2 ** 60 and back["l"] == [1.0, (2, "a")]


def test_a_one_by_one_dgesv_is_the_division():
    """The normal impulse of Eqs. 29 and 42 divides by the 1 x 1 denominator where it was solved by
    LAPACK's dgesv: the same bits (LU of one entry, then b / a), over magnitudes from 1e-8 to 1e8
    and both signs, where multiplying by the reciprocal differs in about a quarter of the cases."""
    from pcmm.model.rows import solve
    rng = np.random.default_rng(5)
    a = rng.normal(size=4000) * 10.0 ** rng.uniform(-8, 8, 4000)
    b = rng.normal(size=4000) * 10.0 ** rng.uniform(-8, 8, 4000)
    by_lapack = np.array([solve(np.array([[x]]), np.array([y]))[0] for x, y in zip(a, b)])
    assert by_lapack.tobytes() == (b / a).tobytes()
    assert np.count_nonzero(by_lapack != b * (1.0 / a)) > 400  # the test can tell the two apart


def test_a_frictional_refusal_names_its_transition_when_joints_are_cut(make_scene):
    """The reference rod's ENERGY_GAIN strike (Newton's law with friction gains energy), with the
    bar's own free joint listed as cut (a planar joint forbids nothing: no row): the refusal names
    the transition, not the last cut joint (the plan's loop over the cut joints reused the name)."""
    import re

    import pytest

    import reference_rod_friction as rf
    import test_point_impacts as tp
    from pcmm.errors import SimulationError
    keep = tp.M, tp.L
    tp.M, tp.L = 1.0, 1.0
    try:
        g = rf.ENERGY_GAIN
        path, _ = tp.rod_scene(make_scene, g["theta"], g["mu"], g["e"], vG=g["vG"])
        text = path.read_text()
        cut = re.sub(r"cut = \[\s*\]", 'cut = ["P"]', text)
        assert cut != text
        path.write_text(cut)
        with pytest.raises(SimulationError, match=r"transition 'floor': Newton's kinematic restitution with friction"):
            pcmm.simulate(pcmm.load_scene(path))
    finally:
        tp.M, tp.L = keep
