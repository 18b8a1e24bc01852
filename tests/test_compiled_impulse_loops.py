"""The compiled impulse of a configuration with closed loops (pcmm/model/_impulse.hpp with the loops'
closure rows among its constraint rows) against the Python solve by the cut system, the reference
(:func:`pcmm.events.impulse.solve_impulse_python`): on every impulse of Example 2 and of its working
cycle, at states of Andrews' mechanism (three loops) with joint stops of our own, and at drawn states
of drawn four-bars carrying a pendulum (a joint stop or a point contact, with or without a drive, the
loop's cut joint cut or not).  Two algorithms (the tree's mass matrix restricted by the loop and
drive rows, against the cut system's), so they agree to round-off, not to the bit; both obey
Newton's law (Eq. 21) and leave the loop rows' velocities as they were (Phi_q dv = 0)."""
from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from builders import (
    bar_xml,
    base_doc,
    captured_impulse_solves,
    compiled_and_python_impulses,
    joint_xml,
    link_xml,
    robot_xml,
    stop,
    write_scene,
)
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from test_compiled_impulse import REL, _assert_same, _momenta_match, _newton, _run

import pcmm
from pcmm.events import impulse
from pcmm.events.contact import contact_state
from pcmm.events.impulse_compiled import compiled_impulse, reason, reasons
from pcmm.model import compiled
from pcmm.model.mechanism import Mechanism
from pcmm.scene.spec import ContactSpec

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(not compiled.enabled() or not hasattr(compiled._tree_dynamics, "ImpulsePlan"),
                                reason="the compiled impulse is not built here")


_both = compiled_and_python_impulses  # (compiled, Python) impulses at one state


def _rows_keep(cfg, q, imp):
    """The loop rows' velocities are not changed by the impulse: Phi_q (v+ - v-) = 0, to round-off."""
    _, Jq = cfg.coords.loop_rows(q)
    dv = imp.v_after - imp.v_before
    assert np.max(np.abs(Jq @ dv)) <= 1e-12 * max(1.0, float(np.max(np.abs(Jq))) * float(np.max(np.abs(dv))))


def _amplification(cfg, q, v, contact, ref, e) -> float:
    """How much the loop and drive rows amplify round-off in the impulse: J M^-1 J^T (the inverse mass
    the contact's row meets without rows) over J W_eff J^T = -(1 + e) vn- / P (with them), at least 1.
    Both solves form W_eff = W - W A^T S^-1 A W; where the rows leave the contact little motion (a
    pendulum tip whose crank is driven, grazing along its normal) the difference cancels to that
    ratio (a drawn case: 2e3, the two solves 1.02e-12 of the speeds apart)."""
    Jn = contact_state(cfg, q, v, contact)[3]
    free = float(Jn @ np.linalg.solve(cfg.mass_matrix(q), Jn))
    held = -(1.0 + e) * ref.vn_before / ref.P
    return max(1.0, free / held)


@pytest.mark.parametrize("name", ["double_folded", "double_folded_cycle"])
def test_every_impulse_of_example_2_is_the_python_solve(name, monkeypatch):
    """Example 2 (the slider's stop E, the loop closed at C, the crank driven) and its cycle solve their
    impulses compiled; replayed at each of their states, the two solves agree to 1e-12 of their scale,
    obey Newton's law, keep the loop closed in velocity and the drive's joint at its speed."""
    traj, calls = captured_impulse_solves(ROOT / "examples" / f"{name}.toml", monkeypatch)
    assert len(calls) >= traj.stats["impacts"] >= 40
    for cfg, t, q, v, contact, e, cut in calls:
        a, b = _both(cfg, t, q, v, contact, e, cut)
        _assert_same(a, b)
        _momenta_match(cfg, q, a)
        for imp in (a, b):
            _newton(imp, e)
            _rows_keep(cfg, q, imp)
        assert abs(a.v_after[0] - v[0]) <= 1e-12 * abs(v[0])  # the drive holds A'
        assert a.energy_dissipated >= -1e-12 * a.ke_before
        assert set(a.constraint_impulses) == {"C", "A.drive"}
    assert {what for cfg, *_ in calls for what in reasons(cfg).values()} == {"compiled"}


def test_example_2_runs_with_the_compiled_impulse_and_keeps_its_events(monkeypatch):
    """Example 2 whole, with the compiled and with the Python impulse: the same events in number, order
    and kind; the event times within ten times what a one-ulp nudge of the Python path's post-impact
    velocities moves them (the macro-impact's bounces amplify round-off), the final state within 1e-10."""
    scene = pcmm.load_scene(ROOT / "examples" / "double_folded.toml")
    python = impulse.solve_impulse_python
    count = []

    def counted(*args, **kwargs):
        count.append(1)
        return python(*args, **kwargs)
    monkeypatch.setattr(impulse, "solve_impulse_python", counted)
    fast = _run(scene, monkeypatch, "compiled")
    assert len(count) <= 1  # the plan's check at its first impact, then compiled only
    monkeypatch.setattr(impulse, "solve_impulse_python", python)
    ref = _run(scene, monkeypatch, "python")
    key = [(e["name"], e["from"], e["to"], e["merge"], e["impact"]) for e in ref.events]
    assert [(e["name"], e["from"], e["to"], e["merge"], e["impact"]) for e in fast.events] == key
    dt = max(abs(a["t"] - b["t"]) for a, b in zip(fast.events, ref.events))
    if dt > 1e-12:
        nudged = _run(scene, monkeypatch, "nudged")
        own = max(abs(a["t"] - b["t"]) for a, b in zip(nudged.events, ref.events))
        assert dt <= 10 * max(own, 1e-12), (dt, own)
    a, b = fast.segments[-1], ref.segments[-1]
    assert a.configuration == b.configuration and a.t[-1] == b.t[-1]
    assert np.max(np.abs(a.q[-1] - b.q[-1])) <= 1e-10 and np.max(np.abs(a.v[-1] - b.v[-1])) <= 1e-10


def test_andrews_three_loops_with_joint_stops_of_our_own():
    """Andrews' mechanism (three revolute cut joints at P, six loop rows, one degree of freedom) at
    states of its run, struck at a joint stop of our own on beta (the crank), Theta or epsilon.  One
    degree of freedom: the admissible velocities are a line, so the stop reverses the whole motion,
    v+ = -e v- (the closed form).  On beta and Theta the two solves agree to 1e-12 of their scale.  A
    stop on epsilon at the run's end is ill-conditioned (the reference itself misses the closed form by
    1.7e-9 of the speeds there, the compiled solve by 3.8e-9: both subtract the loop rows' Schur
    complement from M^-1): there each solve is held to the closed form, the compiled one within ten
    times the reference's own error."""
    scene = pcmm.load_scene(ROOT / "examples" / "andrews.toml")
    traj = pcmm.simulate(scene)
    cfg = Mechanism(scene)["squeezer"]
    seg = traj.segments[0]
    parents = {"beta": ("frame", "body1"), "Theta": ("body1", "body2"), "epsilon": ("frame", "body7")}
    names = cfg.joint_names
    checked = 0
    for joint, (pa, pb) in parents.items():
        j = names.index(joint)
        for k in (len(seg.t) // 3, len(seg.t) - 1):
            q, v = seg.q[k].copy(), seg.v[k].copy()
            sign = -1 if v[j] < 0 else 1  # the stop on the side the joint moves towards
            contact = ContactSpec(a=pa, point_a=None, b=pb, point_b=None, normal=None, joint=joint, arm=0.01,
                                  stop_value=float(q[j]), stop_sign=sign)
            for e in (0.0, 0.6):
                a, b = _both(cfg, float(seg.t[k]), q, v, contact, e, (joint,))
                scale = float(np.max(np.abs(v)))
                own = float(np.max(np.abs(b.v_after + e * v)))  # the reference's distance to the closed form
                if joint == "epsilon":
                    assert own <= 1e-8 * scale
                    assert float(np.max(np.abs(a.v_after + e * v))) <= 10 * max(own, 1e-15 * scale)
                else:
                    assert own <= 1e-14 * scale
                    _assert_same(a, b)
                    _newton(a, e)
                _rows_keep(cfg, q, a)
                checked += 1
    assert checked == 12


def _pendulum_four_bar(folder: Path, a, b, c, d, p, masses, contact: str, drive: bool, cut_loop: bool):
    """A four-bar (crank a on A at the origin, coupler b on B, rocker c on D at (d, 0), the loop closed at
    C: coupler tip on rocker tip) whose rocker carries a pendulum p on E at its tip; two degrees of
    freedom, one with a drive on A.  ``contact``: "stop E" (a joint stop of the pendulum on the rocker),
    "stop D" (the rocker's joint stop) or "point" (the pendulum's tip against the frame, normal +y)."""
    m1, m2, m3, m4 = masses
    urdf = robot_xml("pfb", link_xml("frame"), joint_xml("A", "revolute", "frame", "crank"), bar_xml("crank", a, m1),
                     joint_xml("B", "revolute", "crank", "coupler", xyz=(a, 0.0)), bar_xml("coupler", b, m2),
                     joint_xml("D", "revolute", "frame", "rocker", xyz=(d, 0.0)), bar_xml("rocker", c, m3),
                     joint_xml("E", "revolute", "rocker", "pendulum", xyz=(c, 0.0)), bar_xml("pendulum", p, m4))
    cut = [{"name": "C", "type": "revolute", "a": "coupler", "point_a": [b, 0.0], "b": "rocker", "point_b": [c, 0.0]}]
    joint = {"stop E": "E", "stop D": "D", "point": "E"}[contact]
    ct = {"joint": joint, "arm": 0.05} if contact != "point" else {
        "a": "frame", "point_a": [0.0, -1.0], "b": "pendulum", "point_b": [p, 0.0], "normal": [0.0, 1.0]}
    tr = stop("hit", "c", 0.5, {"type": "coordinate", "measure": {"joint": joint}, "value": 0.0,
                                "direction": "decreasing"}, ct, cut=[joint] + (["C"] if cut_loop else []))
    more = {"transitions": [tr]}
    if drive:
        more["drives"] = [{"joint": "A", "coefficients": [0.0, 1.3]}]
    doc = base_doc("pfb", "c", {"c": {"urdf": "pfb.urdf", "cut_joints": cut}}, {"A": 0.0, "B": 0.0, "D": 0.0, "E": 0.0},
                   {"A": 0.0, "B": 0.0, "D": 0.0, "E": 0.0}, g=0.0, **more)
    doc["initial"]["independent"] = ["E"] if drive else ["A", "E"]
    return write_scene(folder, doc, {"pfb.urdf": urdf})


def _assembled(a, b, c, d, theta, branch):
    """(A, B, D) closing the four-bar at crank angle theta, or None where it does not close or lies near
    a singular posture (the transmission angle at C, between coupler and rocker, within 18 degrees of 0
    or pi: the loop rows lose rank there)."""
    bx, by = a * math.cos(theta), a * math.sin(theta)
    rx, ry = d - bx, -by
    r = math.hypot(rx, ry)
    if not r > 1e-6:
        return None
    cos_ = (b * b + r * r - c * c) / (2 * b * r)
    transmission = (b * b + c * c - r * r) / (2 * b * c)
    if not (-0.95 < cos_ < 0.95 and -0.95 < transmission < 0.95):
        return None
    phi = math.atan2(ry, rx) + branch * math.acos(cos_)
    cx, cy = bx + b * math.cos(phi), by + b * math.sin(phi)
    return theta, phi - theta, math.atan2(cy, cx - d)


lengths = st.floats(0.1, 0.6)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(geometry=st.tuples(st.floats(0.05, 0.3), lengths, lengths, lengths, lengths),
       masses=st.tuples(*[st.floats(0.05, 5.0)] * 4), contact=st.sampled_from(["stop E", "stop D", "point"]),
       drive=st.booleans(), cut_loop=st.booleans(), e=st.floats(0.0, 1.0), data=st.data())
def test_drawn_loops_agree_with_the_python_solve(geometry, masses, contact, drive, cut_loop, e, data):
    """Drawn four-bars carrying a pendulum, struck at a joint stop or at a point contact, with or
    without a drive on the crank, the loop's cut joint C cut with the struck joint or not, at drawn
    assembled states approaching the stop: the two solves agree to 1e-12 of their scale, both obey
    Newton's law and keep the loop closed in velocity."""
    if drive and contact == "stop D":  # the rocker is then held by the loop and the drive: no impulse
        contact = "stop E"
    a, b, c, d, p = geometry
    posture = _assembled(a, b, c, d, data.draw(st.floats(-math.pi, math.pi), label="theta"),
                         data.draw(st.sampled_from([-1, 1]), label="branch"))
    assume(posture is not None)
    with tempfile.TemporaryDirectory() as folder:
        scene = pcmm.load_scene(_pendulum_four_bar(Path(folder), a, b, c, d, p, masses, contact, drive, cut_loop))
        cfg = Mechanism(scene)["c"]
    tr = scene.transitions[0]
    names = cfg.joint_names
    q = np.zeros(4)
    for name, x in zip(("A", "B", "D"), posture):
        q[names.index(name)] = x
    q[names.index("E")] = data.draw(st.floats(-math.pi, math.pi), label="E")
    # a velocity the loop admits: drawn rates of A and E, B and D from the closure rows
    _, Jq = cfg.coords.loop_rows(q)
    iA, iE = names.index("A"), names.index("E")
    dep = [names.index("B"), names.index("D")]
    v = np.zeros(4)
    v[iA] = data.draw(st.floats(-3.0, 3.0), label="A'")
    v[iE] = data.draw(st.floats(-3.0, 3.0), label="E'")
    assume(max(abs(v[iA]), abs(v[iE])) > 1e-3)  # (no subnormal speeds)
    v[dep] = np.linalg.solve(Jq[:, dep], -(Jq[:, [iA, iE]] @ v[[iA, iE]]))
    vn = contact_state(cfg, q, v, tr.contact)[2]
    if vn > 0:  # approaching the stop: the motion reversed
        v, vn = -v, -vn
    assume(vn < -1e-3 * float(np.max(np.abs(v))))
    J = impulse._plan(cfg, tr.contact, tuple(tr.cut))
    got, ref = _both(cfg, 0.2, q, v, tr.contact, e, tr.cut)
    assert J.cut_loops == (("C",) if cut_loop else ())
    _assert_same(got, ref, REL * _amplification(cfg, q, v, tr.contact, ref, e))
    _momenta_match(cfg, q, got)
    for imp in (got, ref):
        _newton(imp, e)
        _rows_keep(cfg, q, imp)
    if cut_loop:
        assert got.cut_impulses["C"] == got.constraint_impulses["C"]


def test_prismatic_loop_cut_joints_stay_in_python_and_say_why(tmp_path):
    """A loop closed by a prismatic cut joint has rows the compiled impulse does not form: the Python
    solve, with the reason."""
    urdf = robot_xml("sc", link_xml("frame"), joint_xml("A", "revolute", "frame", "crank"), bar_xml("crank", 0.1, 1.0),
                     joint_xml("B", "revolute", "crank", "rod", xyz=(0.1, 0.0)), bar_xml("rod", 0.3, 1.0))
    cut = [{"name": "S", "type": "prismatic", "a": "frame", "point_a": [0.0, 0.0], "b": "rod", "point_b": [0.3, 0.0],
            "axis": [1.0, 0.0], "angle": -0.5}]
    tr = stop("hit", "c", 0.5, {"type": "coordinate", "measure": {"joint": "B"}, "value": -0.5,
                                "direction": "decreasing"}, {"joint": "B", "arm": 0.05}, cut=["B"])
    doc = base_doc("sc", "c", {"c": {"urdf": "sc.urdf", "cut_joints": cut}}, {"A": 0.5, "B": -1.0}, {"A": 0.0, "B": 0.0},
                   g=0.0, transitions=[tr])
    scene = pcmm.load_scene(write_scene(tmp_path, doc, {"sc.urdf": urdf}))
    cfg = Mechanism(scene)["c"]
    plan = impulse._plan(cfg, scene.transitions[0].contact, ("B",))
    assert compiled_impulse(cfg, plan) is None
    assert "prismatic or weld loop cut joints" in reason(cfg, plan)
