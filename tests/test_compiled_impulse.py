"""The compiled impulse (pcmm/model/_impulse.hpp, :mod:`pcmm.events.impulse_compiled`) against the
Python solve by the cut system (:func:`pcmm.events.impulse.solve_impulse_python`), the reference:
on every impulse of ``three_bar_cycle`` and at drawn states of drawn chains (joint stops, point
contacts, with and without a drive).  The compiled route is the tree's own mass matrix restricted
by the drive rows, the cut joint's impulse read from RNEA: a second algorithm, so the two agree to
round-off, not to the bit.  Both also obey Newton's law (Eq. 21) and the impulse-momentum balance."""
from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from builders import (
    Bar,
    base_doc,
    captured_impulse_solves,
    chain_urdf,
    compiled_and_python_impulses,
    nudge_impulses,
    stop,
    write_scene,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pcmm
from pcmm.events import impulse
from pcmm.events.impulse_compiled import compiled_impulse, reason, reasons
from pcmm.model import compiled
from pcmm.model.mechanism import Mechanism

ROOT = Path(__file__).resolve().parents[1]
REL = 1e-12

pytestmark = pytest.mark.skipif(not compiled.enabled() or not hasattr(compiled._tree_dynamics, "ImpulsePlan"),
                                reason="the compiled impulse is not built here")


_both = compiled_and_python_impulses  # (compiled, Python) impulses at one state


def _assert_same(a, b, rel=REL):
    """Velocities, impulses and energies of two solves to ``rel`` of their scale (REL; more where the
    contact is ill-conditioned: tests/test_compiled_impulse_loops.py)."""
    v_scale = float(np.max(np.abs(np.concatenate([b.v_before, b.v_after]))))
    assert np.max(np.abs(a.v_after - b.v_after)) <= rel * v_scale
    # impulses against the momentum scale of the state: the largest impulse, what the contact's
    # effective mass takes at the state's largest speed (P v_scale / |vn-|: vn- is formed from
    # velocities of that size, and at the end of an accumulation it is 1e-6 of them), and the
    # momentum 2 KE- / v_scale (a light link struck beside heavy ones: the joint impulses are sums
    # of the heavy links' terms; the Python route's own RNEA residual on its passive joints, zero
    # in exact arithmetic, is 3e-15 there against impulses of 1e-3)
    p_scale = max([abs(b.P), abs(b.P) * v_scale / abs(b.vn_before), 2.0 * b.ke_before / v_scale]
                  + [abs(x) for f in b.joint_impulses.values() for x in f])
    assert abs(a.P - b.P) <= rel * p_scale
    assert np.max(np.abs(a.normal - b.normal)) <= REL and np.max(np.abs(a.point - b.point)) <= REL * (
        1.0 + float(np.max(np.abs(b.point))))
    for group in ("joint_impulses", "cut_impulses", "constraint_impulses", "constraint_rows"):
        ga, gb = getattr(a, group), getattr(b, group)
        assert ga.keys() == gb.keys(), group
        for k in gb:
            assert np.max(np.abs(np.subtract(ga[k], gb[k]))) <= rel * p_scale, (group, k, ga[k], gb[k])
    assert np.max(np.abs(a.rnea_residual - b.rnea_residual)) <= rel * p_scale
    e_scale = max(b.ke_before, b.ke_after, abs(b.drive_work), 1e-300)
    for x, y in ((a.ke_before, b.ke_before), (a.ke_after, b.ke_after), (a.drive_work, b.drive_work)):
        assert abs(x - y) <= rel * e_scale
    assert abs(a.vn_before - b.vn_before) <= rel * v_scale and abs(a.vn_after - b.vn_after) <= rel * v_scale


def _momenta_match(cfg, q, imp):
    """The compiled solve's momenta about the origin are pcmm.events.momentum.momenta's (to round-off)."""
    from pcmm.events.momentum import momenta
    for k, v in enumerate((imp.v_before, imp.v_after)):
        L, H0 = momenta(cfg, q, v, np.zeros(2))
        scale = max(1.0, float(np.max(np.abs(L))), abs(H0))
        got = np.array(imp.momenta[3 * k:3 * k + 3])
        assert np.max(np.abs(got - np.array([L[0], L[1], H0]))) <= 1e-13 * scale


def _newton(imp, e):
    """Newton's restitution law on the normal, Eq. 21: vn+ = -e vn-, to round-off of the state's speeds."""
    assert imp.vn_before < 0
    v_scale = float(np.max(np.abs(np.concatenate([imp.v_before, imp.v_after]))))
    assert abs(imp.vn_after + e * imp.vn_before) <= 1e-12 * max(abs(imp.vn_before), v_scale)


def test_every_impulse_of_the_cycle_is_the_python_solve(monkeypatch):
    """three_bar_cycle's run solves its impulses compiled (the drive on O1 a row, O2 or O3 cut);
    replayed at each of its states, the compiled and Python solves agree to 1e-12 of their
    scale, each obeys Newton's law (a bounce, e = 0.8, or a merge's plastic impact, e = 0) and
    keeps the drive's joint at its prescribed speed; the run's events balance momentum."""
    traj, calls = captured_impulse_solves(ROOT / "examples" / "three_bar_cycle.toml", monkeypatch)
    assert len(calls) >= traj.stats["impacts"] >= 500  # the bounces, and the merges' plastic impacts
    plans = {}
    for cfg, t, q, v, contact, e, cut in calls:
        plan = impulse._plan(cfg, contact, tuple(cut))
        plans[id(plan)] = compiled_impulse(cfg, plan)
        a, b = _both(cfg, t, q, v, contact, e, cut)
        _assert_same(a, b)
        _momenta_match(cfg, q, a)
        _newton(a, e)
        _newton(b, e)
        assert a.v_after[0] == v[0] or abs(a.v_after[0] - v[0]) <= 1e-12 * abs(v[0])  # the drive holds O1'
        assert a.energy_dissipated >= -1e-12 * a.ke_before
    assert all(fast is not None and fast.checked for fast in plans.values())  # the run took the compiled solves
    assert {what for cfg, *_ in calls for what in reasons(cfg).values()} == {"compiled"}
    for event in traj.events:
        if event["impact"]:
            dL, dH = pcmm.events.momentum.balance(event)
            scale = max(abs(event["impulse"].get("moment", 0.0)), abs(event["impulse"]["normal"]), 1e-3)
            assert np.max(np.abs(dL)) <= 1e-9 * scale and abs(dH) <= 1e-9 * scale


def _chain_scene(folder: Path, bars, k: int, kind: str, drive: bool):
    """A chain of ``bars`` (revolute J1..Jn, no gravity), a stop of joint ``k`` (2 <= k <= n) cut at Jk:
    a joint stop (``kind`` "joint") or the tip of link k against a point of link k-1 ("point");
    ``drive``: J1 turned by a drive."""
    n = len(bars)
    if kind == "joint":
        contact = {"joint": f"J{k}", "arm": 0.1}
    else:  # link k's point at (0.2, 0) against link k-1 where it lies at J_k = 0.3, normal against the approach
        a_len = bars[k - 2].length
        contact = {"a": f"link{k - 1}", "point_a": [a_len + 0.2 * math.cos(0.3), 0.2 * math.sin(0.3)],
                   "b": f"link{k}", "point_b": [0.2, 0.0], "normal": [-math.sin(0.3), math.cos(0.3)]}
    tr = stop("hit", "c", 0.5, {"type": "coordinate", "measure": {"joint": f"J{k}"}, "value": 0.3,
                                "direction": "decreasing"}, contact, cut=[f"J{k}"])
    more = {"transitions": [tr]}
    if drive:
        more["drives"] = [{"joint": "J1", "coefficients": [0.0, 1.3]}]
    doc = base_doc("chain", "c", {"c": "chain.urdf"}, {f"J{i}": 0.0 for i in range(1, n + 1)},
                   {f"J{i}": 0.0 for i in range(1, n + 1)}, g=0.0, **more)
    return write_scene(folder, doc, {"chain.urdf": chain_urdf(bars)})


bars = st.builds(Bar, length=st.floats(0.1, 1.0), mass=st.floats(0.05, 5.0))


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(chain=st.lists(bars, min_size=2, max_size=4), data=st.data(), kind=st.sampled_from(["joint", "point"]),
       drive=st.booleans(), e=st.floats(0.0, 1.0))
def test_drawn_chains_agree_with_the_python_solve(chain, data, kind, drive, e):
    """Drawn chains of 2-4 bars, a joint stop or a point contact at a drawn joint, with or
    without a drive on J1, at drawn approaching states: the two solves agree to 1e-12 of their
    scale and both obey Newton's law."""
    k = data.draw(st.integers(2, len(chain)), label="stopped joint")
    with tempfile.TemporaryDirectory() as folder:
        scene = pcmm.load_scene(_chain_scene(Path(folder), chain, k, kind, drive))
        cfg = Mechanism(scene)["c"]
    tr = scene.transitions[0]
    n = len(chain)
    for _ in range(3):
        q = np.array(data.draw(st.lists(st.floats(-math.pi, math.pi), min_size=n, max_size=n), label="q"))
        q[k - 1] = 0.3
        v = np.array(data.draw(st.lists(st.floats(-3.0, 3.0), min_size=n, max_size=n), label="v"))
        v[k - 1] = -data.draw(st.floats(0.1, 3.0), label="approach")  # J_k decreasing: towards the stop
        a, b = _both(cfg, 0.2, q, v, tr.contact, e, tr.cut)
        _assert_same(a, b)
        _momenta_match(cfg, q, a)
        _newton(a, e)
        _newton(b, e)


def test_cases_it_does_not_take_stay_in_python_and_say_why(monkeypatch, tmp_path):
    """PCMM_COMPILED=0 and a driven cut joint run the Python solve, each with its reason."""
    bars_ = [Bar(0.5, 1.0), Bar(0.4, 0.7)]
    scene = pcmm.load_scene(_chain_scene(tmp_path, bars_, 2, "joint", drive=False))
    cfg = Mechanism(scene)["c"]
    tr = scene.transitions[0]
    plan = impulse._plan(cfg, tr.contact, tuple(tr.cut))
    assert compiled_impulse(cfg, plan) is not None and reason(cfg, plan) is None
    monkeypatch.setenv("PCMM_COMPILED", "0")
    assert compiled_impulse(cfg, plan) is None and "PCMM_COMPILED=0" in reason(cfg, plan)
    monkeypatch.delenv("PCMM_COMPILED")
    plan1 = impulse._plan(cfg, tr.contact, ("J1", "J2"))  # J1 not driven here: taken
    assert compiled_impulse(cfg, plan1) is not None
    scene_d = pcmm.load_scene(_chain_scene(tmp_path / "d", bars_, 2, "joint", drive=True))
    cfg_d = Mechanism(scene_d)["c"]
    plan_d = impulse._plan(cfg_d, scene_d.transitions[0].contact, ("J1", "J2"))
    assert compiled_impulse(cfg_d, plan_d) is None and "driven joint is cut" in reason(cfg_d, plan_d)
    assert reasons(cfg_d) == {"joint stop J2 (cut J1, J2)": "a driven joint is cut: solved in Python"}
    assert reasons(cfg) == {"joint stop J2 (cut J2)": "compiled, not yet checked",
                            "joint stop J2 (cut J1, J2)": "compiled, not yet checked"}


def _run(scene, monkeypatch, mode: str):
    """A run with the compiled impulse, the Python one ("python"), or the Python one with every
    post-impact velocity nudged by one ulp ("nudged"): the reference's own round-off sensitivity."""
    with monkeypatch.context() as m:
        if mode != "compiled":
            m.setattr(impulse, "compiled_impulse", lambda cfg, plan: None)
        if mode == "nudged":
            nudge_impulses(m)
        return pcmm.simulate(scene)


@pytest.mark.slow  # each example run whole, twice (three_bar_cycle: 10.9 s)
@pytest.mark.parametrize("name", ["three_bar", "three_bar_stop", "three_bar_cycle"])
def test_whole_runs_keep_their_events(name, monkeypatch):
    """Every shipped example with a compiled impulse: the same events (number, order, kind) as with
    the Python impulse, their times within 1e-12 s - or, where accumulations amplify round-off
    (three_bar_cycle), within ten times what a one-ulp nudge of the Python path's post-impact
    velocities moves them (5.2e-10 s) - and the final state within 1e-10."""
    scene = pcmm.load_scene(ROOT / "examples" / f"{name}.toml")
    ref, fast = _run(scene, monkeypatch, "python"), _run(scene, monkeypatch, "compiled")
    assert [(e["name"], e["from"], e["to"], e["merge"], e["impact"]) for e in fast.events] == \
        [(e["name"], e["from"], e["to"], e["merge"], e["impact"]) for e in ref.events]
    dt = max(abs(a["t"] - b["t"]) for a, b in zip(fast.events, ref.events))
    if dt > 1e-12:
        nudged = _run(scene, monkeypatch, "nudged")
        own = max(abs(a["t"] - b["t"]) for a, b in zip(nudged.events, ref.events))
        assert 1e-12 < own and dt <= 10 * own, (dt, own)
    a, b = fast.segments[-1], ref.segments[-1]
    assert a.configuration == b.configuration and a.t[-1] == b.t[-1]
    assert np.max(np.abs(a.q[-1] - b.q[-1])) <= 1e-10 and np.max(np.abs(a.v[-1] - b.v[-1])) <= 1e-10


def test_a_study_checks_each_compiled_plan_once(monkeypatch):
    """The runs of a study load their own scenes (their own contacts): the second run of Example 1
    takes the first run's compiled plan of its equal contact, checked already, and so solves its
    latch without the Python solve; its events are the first run's to the bit."""
    python, calls = impulse.solve_impulse_python, []

    def counted(*args, **kwargs):
        calls.append(args[1])
        return python(*args, **kwargs)
    monkeypatch.setattr(impulse, "solve_impulse_python", counted)
    path = ROOT / "examples" / "three_bar.toml"
    first = pcmm.simulate(pcmm.load_scene(path))
    checked = len(calls)
    second = pcmm.simulate(pcmm.load_scene(path))
    assert checked <= 1 and len(calls) == checked  # no Python solve in the second run
    assert [e["t"] for e in second.events] == [e["t"] for e in first.events]
    assert second.events[0]["v_after"] == first.events[0]["v_after"]


def test_a_plan_that_disagrees_at_its_first_impact_is_dropped(monkeypatch, tmp_path):
    """The first impact of a plan compares the two solves: a compiled answer off by 1e-6 is
    refused, that impact gets the Python solve's answer, and so do the later ones, with the reason.
    (A chain of its own: no other test has checked a plan on its model.)"""
    scene = pcmm.load_scene(_chain_scene(tmp_path, [Bar(0.47, 1.13), Bar(0.37, 0.61)], 2, "joint", drive=False))
    cfg = Mechanism(scene)["c"]
    tr = scene.transitions[0]
    compiled_solve = impulse._compiled_solve

    def off(*args):
        out = compiled_solve(*args)
        out.v_after = out.v_after * (1.0 + 1e-6)
        return out
    monkeypatch.setattr(impulse, "_compiled_solve", off)
    q, v = np.array([0.2, 0.3]), np.array([0.5, -1.5])
    want = impulse.solve_impulse_python(cfg, 0.1, q, v, tr.contact, 0.5, tuple(tr.cut))
    for _ in range(2):
        got = impulse.solve_impulse(cfg, 0.1, q, v, tr.contact, 0.5, tuple(tr.cut))
        assert got.v_after.tobytes() == want.v_after.tobytes()
    plan = impulse._plan(cfg, tr.contact, tuple(tr.cut))
    assert compiled_impulse(cfg, plan) is None and "disagrees with the Python solve: v_after" in reason(cfg, plan)
