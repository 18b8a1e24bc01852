"""A bounce in one compiled call (issue 26, item 2): ``BouncePlan.solve`` (pcmm/model/_impulse.hpp) does a
stop's impulse, the velocity jump, the event record's numbers and the projection onto the drives at once.
It must give the Python route's bits at every bounce (the route it replaces: the impulse solve, the record
formed from its arrays, the bounce's entry), and the per-bounce physics checks must still run on its
numbers and still stop a wrong bounce."""
from __future__ import annotations

import math

import numpy as np
import pytest

import builders
import pcmm
from pcmm.errors import SimulationError
from pcmm.events import entry, records, transitions
from pcmm.model import compiled

pytestmark = pytest.mark.skipif(not compiled.enabled() or not hasattr(compiled._tree_dynamics, "BouncePlan"),
                                reason="the compiled bounce does not run here")


def _events(traj) -> list[str]:
    """Every event as the text of its dict: keys, order, types and numbers (repr: to the bit)."""
    return [repr(dict(e)) for e in traj.events]


def _bits(x) -> bytes:
    return np.float64(x).tobytes()


def driven_elbow(folder, e: float = 0.7, t_end: float = 2.0):
    """A mechanism of this test's own: a bar (0.5 m, 1.2 kg) on revolute J1 at the origin DRIVEN at
    q1 = 0.3 + 1.5 t - 0.2 t^2, and a second bar (0.4 m, 0.7 kg) on J2 at its tip, falling under gravity
    onto a joint stop at q2 = -0.8 (the stop's arm 0.25 m, restitution e, J2 cut), whose bounces merge
    into 'locked' (J2 locked at the stop)."""
    urdf = builders.robot_xml("elbow", builders.link_xml("frame"),
                              builders.joint_xml("J1", "revolute", "frame", "link1"), builders.bar_xml("link1", 0.5, 1.2),
                              builders.joint_xml("J2", "revolute", "link1", "link2", xyz=(0.5, 0.0)),
                              builders.bar_xml("link2", 0.4, 0.7))
    tr = builders.stop("elbow_stop", "swing", e, {"type": "coordinate", "measure": {"joint": "J2"}, "value": -0.8,
                                                   "direction": "decreasing"},
                       {"joint": "J2", "arm": 0.25}, merge_to="locked", cut=["J2"])
    doc = builders.base_doc("driven_elbow", "swing",
                            {"swing": "elbow.urdf", "locked": {"from": "swing", "lock": {"J2": -0.8}}},
                            {"J1": 0.3, "J2": 0.0}, {"J1": 1.5, "J2": 0.0}, t_end=t_end, transitions=[tr],
                            drives=[{"joint": "J1", "coefficients": [0.3, 1.5, -0.2]}])
    return builders.write_scene(folder, doc, {"elbow.urdf": urdf})


def falling_elbow(folder, e: float = 0.6, t_end: float = 4.0):
    """Another of this test's own: a double pendulum under gravity (bars 0.5 m, 2 kg on J1 at the origin and
    0.4 m, 0.6 kg on J2 at its tip, both free), link 2's tip striking a point of link 1 where J2 = -0.3 (a
    mobile point contact between two moving links, restitution e), the bounces merging into 'locked'."""
    L1, L2, q2s = 0.5, 0.4, -0.3
    urdf = builders.robot_xml("fall", builders.link_xml("frame"),
                              builders.joint_xml("J1", "revolute", "frame", "link1"), builders.bar_xml("link1", L1, 2.0),
                              builders.joint_xml("J2", "revolute", "link1", "link2", xyz=(L1, 0.0)),
                              builders.bar_xml("link2", L2, 0.6))
    tip = [L1 + L2 * math.cos(q2s), L2 * math.sin(q2s)]
    tr = builders.stop("hit", "c1", e, {"type": "coordinate", "measure": {"joint": "J2"}, "value": q2s,
                                         "direction": "decreasing"},
                       {"a": "link1", "point_a": tip, "b": "link2", "point_b": [L2, 0.0],
                        "normal": [-math.sin(q2s), math.cos(q2s)]}, merge_to="locked")
    doc = builders.base_doc("falling_elbow", "c1", {"c1": "fall.urdf", "locked": {"from": "c1", "lock": {"J2": q2s}}},
                            {"J1": -0.2, "J2": 0.9}, {"J1": 0.0, "J2": 0.0}, t_end=t_end, transitions=[tr])
    return builders.write_scene(folder, doc, {"fall.urdf": urdf})


def slider_arm(folder, e: float = 0.5, t_end: float = 2.0, driven: bool = True):
    """A third: an arm (1 m, 2 kg) on revolute J1 at the origin, driven at 6 rad/s (or free, at 3 rad/s at
    the start), and a slider (0.5 kg) on the prismatic J2 along it, thrown outward onto a joint stop at
    J2 = 0.8 m (a prismatic stop, restitution e, J2 cut), its bounces merging into 'locked'."""
    urdf = builders.robot_xml("slider", builders.link_xml("frame"),
                              builders.joint_xml("J1", "revolute", "frame", "arm"), builders.bar_xml("arm", 1.0, 2.0),
                              builders.joint_xml("J2", "prismatic", "arm", "slider", axis=(1.0, 0.0, 0.0)),
                              builders.solid_xml("slider", 0.5, 0.01))
    tr = builders.stop("end_stop", "c1", e, {"type": "coordinate", "measure": {"joint": "J2"}, "value": 0.8,
                                               "direction": "increasing"},
                       {"joint": "J2"}, merge_to="locked", cut=["J2"])
    more = {"drives": [{"joint": "J1", "coefficients": [0.0, 6.0]}]} if driven else {}
    doc = builders.base_doc("slider_arm", "c1", {"c1": "s.urdf", "locked": {"from": "c1", "lock": {"J2": 0.8}}},
                            {"J1": 0.0, "J2": 0.3}, {"J1": 6.0 if driven else 3.0, "J2": 0.0}, t_end=t_end,
                            transitions=[tr], **more)
    return builders.write_scene(folder, doc, {"s.urdf": urdf})


def _scenes(tmp_path):
    return {
        "three_bar_cycle": (pcmm.load_scene(builders.EXAMPLES / "three_bar_cycle.toml"), pcmm.RunOptions(t_end=2.5)),
        # a point contact on a tree (no drive, no projection): a bar onto a stop on the frame
        "pendulum": (pcmm.load_scene(builders.pendulum(tmp_path, 0.85, qs=-0.3, t_end=3.0)), pcmm.RunOptions()),
        # a mobile point contact between two moving links of a tree
        "falling_elbow": (pcmm.load_scene(falling_elbow(tmp_path)), pcmm.RunOptions()),
        "driven_elbow": (pcmm.load_scene(driven_elbow(tmp_path)), pcmm.RunOptions()),
        # a prismatic joint stop, beside a revolute drive and without one
        "slider_arm": (pcmm.load_scene(slider_arm(tmp_path / "driven")), pcmm.RunOptions()),
        "free_slider_arm": (pcmm.load_scene(slider_arm(tmp_path / "free", driven=False)), pcmm.RunOptions()),
    }


@pytest.mark.parametrize("name", ["three_bar_cycle", "pendulum", "falling_elbow", "driven_elbow", "slider_arm",
                                  "free_slider_arm"])
def test_every_compiled_bounce_is_the_python_route_to_the_bit(name, tmp_path, monkeypatch):
    """At every bounce the compiled call takes, the Python route is run at the same located state (the
    impulse solve, the record's numbers from its arrays, the bounce's entry) and gives the same bits:
    the record's numbers, the state entered, the impulse's numbers.  The whole run is the run of the
    Python route alone (``compiled_bounce`` answering None), event by event and sample by sample."""
    scene, options = _scenes(tmp_path)[name]
    taken = []
    handle = transitions._compiled_bounce

    def compared(cfg, tr, plan, t, q, v, got):
        imp = transitions.solve_impulse(cfg, t, q, v, tr.contact, tr.restitution, tr.cut, name=tr.name)
        record = records.bounce_record(cfg, tr, t, imp, q)
        q_new, v_new, _ = entry.enter_bounce(cfg, t, q, imp.v_after)
        numbers, q_c, v_c, v_after, scalars, moved, residual = got
        assert isinstance(record, records.BounceRecord)
        assert [_bits(x) for x in numbers] == [_bits(x) for x in record.numbers]
        assert all(type(x) is float for x in numbers)
        assert v_after.tobytes() == imp.v_after.tobytes()
        assert q_c.tobytes() == q_new.tobytes() and v_c.tobytes() == v_new.tobytes()
        assert [_bits(x) for x in scalars] == [_bits(x) for x in (imp.P, imp.vn_before, imp.vn_after, imp.ke_before,
                                                                     imp.ke_after, imp.drive_work)]
        assert moved is False and residual <= 1e-15
        taken.append(t)
        return handle(cfg, tr, plan, t, q, v, got)
    monkeypatch.setattr(transitions, "_compiled_bounce", compared)
    records.COMPILED_BOUNCE_REFUSED.clear()
    fast = pcmm.simulate(scene, options)
    bounces = sum(e["transition"] == "stop" and not e["merge"] and e["from"] == e["to"] for e in fast.events)
    stops = {(e["from"], e["name"]) for e in fast.events if e["transition"] == "stop" and not e["merge"]}
    assert bounces >= 5 and len(taken) == bounces - len(stops)  # each stop's first bounce: the Python route, checked
    assert records.COMPILED_BOUNCE_REFUSED == {}
    monkeypatch.setattr(transitions, "compiled_bounce", lambda cfg, tr: None)
    python = pcmm.simulate(scene, options)
    assert _events(fast) == _events(python)
    assert len(fast.segments) == len(python.segments)
    for a, b in zip(fast.segments, python.segments):
        assert a.t.tobytes() == b.t.tobytes() and a.q.tobytes() == b.q.tobytes() and a.v.tobytes() == b.v.tobytes()


def test_a_driven_bounce_writes_the_drives_values():
    """The projection onto the drives in the compiled call: q1 = f(t), q1' = f'(t) of the elbow's crank
    by Horner's rule, written over the state (here the located state already holds them to the bit: the
    posture is not moved, and the residual of the drive row is 0)."""
    import tempfile
    from pathlib import Path
    with tempfile.TemporaryDirectory() as d:
        scene = pcmm.load_scene(driven_elbow(Path(d)))
        seen = []
        handle = transitions._compiled_bounce
        mp = pytest.MonkeyPatch()
        try:
            mp.setattr(transitions, "_compiled_bounce", lambda *a: seen.append(a) or handle(*a))
            pcmm.simulate(scene)
        finally:
            mp.undo()
    assert len(seen) >= 5
    for cfg, tr, plan, t, q, v, got in seen:
        _, q_new, v_new, v_after, _, moved, residual = got
        assert q_new[0] == 0.3 + t * (1.5 + t * -0.2)  # Horner's sums, exactly (f' has the coefficients 1.5, -0.4)
        assert v_new[0] == 1.5 + t * -0.4
        assert q_new[1] == q[1] and v_new[1] == v_after[1]  # the free coordinate kept
        assert not moved and residual == abs(v_after[0] - v_new[0])


def _planted(monkeypatch, plant, after: int = 2):
    """From the ``after``-th compiled bounce on, ``plant(got, t, q, v, e, solve)`` gives what the call
    returns instead (a planted defect in the compiled bounce the run goes on with)."""
    real = transitions.solve_bounce
    calls = []

    def planted(plan, t, q, v, e):
        calls.append(t)
        if len(calls) < after:
            return real(plan, t, q, v, e)
        return plant(real, plan, t, q, v, e)
    monkeypatch.setattr(transitions, "solve_bounce", planted)
    return calls


def test_a_compiled_bounce_with_a_wrong_restitution_is_caught(tmp_path, monkeypatch):
    """A compiled bounce solved with 0.9 e while the stop's e is 0.85 stops the run at that bounce,
    naming Newton's law, the stop and the instant."""
    scene = pcmm.load_scene(builders.pendulum(tmp_path, 0.85, qs=-0.3, t_end=3.0))
    calls = _planted(monkeypatch, lambda solve, plan, t, q, v, e: solve(plan, t, q, v, 0.9 * e), after=3)
    with pytest.raises(SimulationError) as err:
        pcmm.simulate(scene)
    text = str(err.value)
    assert "restitution law" in text and "'stop'" in text and f"t = {calls[2]:.9g} s" in text and "e = 0.85" in text


def test_a_compiled_bounce_that_creates_energy_is_caught(tmp_path, monkeypatch):
    """The energy check runs on the compiled call's kinetic energies: one after the impact 1.5 times the
    one before (no drive to supply it) stops the run at that bounce."""
    scene = pcmm.load_scene(builders.pendulum(tmp_path, 0.85, qs=-0.3, t_end=3.0))

    def more_energy(solve, plan, t, q, v, e):
        got = list(solve(plan, t, q, v, e))
        P, vb, va, ke0, ke1, work = got[4]
        got[4] = (P, vb, va, ke0, 1.5 * ke0, work)
        return tuple(got)
    calls = _planted(monkeypatch, more_energy, after=3)
    with pytest.raises(SimulationError) as err:
        pcmm.simulate(scene)
    text = str(err.value)
    assert "would create energy" in text and "'stop'" in text and f"t = {calls[2]:.9g} s" in text


def test_a_compiled_bounce_that_breaks_a_drive_is_caught(monkeypatch):
    """three_bar_cycle's crank O1 is driven (O1' = pi): a compiled bounce whose velocity after the impulse
    leaves it at pi + 1e-3 (its residual, as the call measures it, 1e-3) is handed to the Python entry,
    which stops the run naming the drive's row, by 1e-3 rad/s."""
    scene = pcmm.load_scene(builders.EXAMPLES / "three_bar_cycle.toml")

    def crank_off(solve, plan, t, q, v, e):
        numbers, q_new, v_new, v_after, scalars, moved, residual = solve(plan, t, q, v, e)
        v_after = v_after.copy()
        v_after[0] += 1e-3
        return numbers, q_new, v_new, v_after, scalars, moved, abs(v_after[0] - v_new[0])
    calls = _planted(monkeypatch, crank_off, after=5)
    with pytest.raises(SimulationError) as err:
        pcmm.simulate(scene, pcmm.RunOptions(t_end=1.0))
    text = str(err.value)
    assert "'O1.drive' (the drive of joint O1) by" in text and f"t = {calls[4]:.9g} s" in text
    by = float(text.split("'O1.drive' (the drive of joint O1) by ")[1].split()[0])
    assert by == pytest.approx(1e-3, rel=1e-9)


def test_a_compiled_projection_off_its_drive_is_refused(monkeypatch):
    """A compiled bounce whose drive law is planted 1e-3 off in f' (its projection writes a wrong crank
    rate) is refused where it is compared with the Python route, at each stop's first bounce: the state
    it enters differs.  Every bounce then takes the Python route, and the run is that route's."""
    scene = pcmm.load_scene(builders.EXAMPLES / "three_bar_cycle.toml")
    options = pcmm.RunOptions(t_end=1.5)
    args = records.bounce_plan_args

    def off(plan, imp, projection):
        out = args(plan, imp, projection)
        wrong = tuple((c[0] + 1e-3,) + tuple(c[1:]) for c in projection[2])
        return None if out is None else out[:-1] + (wrong,)
    monkeypatch.setattr(records, "bounce_plan_args", off)
    taken = []
    handle = transitions._compiled_bounce
    monkeypatch.setattr(transitions, "_compiled_bounce", lambda *a: taken.append(a[3]) or handle(*a))
    records.COMPILED_BOUNCE_REFUSED.clear()
    planted = pcmm.simulate(scene, options)
    assert taken == [] and len(records.COMPILED_BOUNCE_REFUSED) >= 2
    assert set(records.COMPILED_BOUNCE_REFUSED.values()) == {"the state it enters differs from the Python route's"}
    monkeypatch.setattr(transitions, "compiled_bounce", lambda cfg, tr: None)
    assert _events(planted) == _events(pcmm.simulate(scene, options))


def test_a_compiled_bounce_whose_numbers_differ_is_refused(tmp_path, monkeypatch):
    """The compiled bounce is compared with the Python route at the stop's first bounce: a layout whose
    momentum point is one ulp off (planted) makes a record number differ, so it is refused for good,
    with the reason, every bounce takes the Python route, and the run is that route's."""
    scene = pcmm.load_scene(builders.pendulum(tmp_path, 0.85, qs=-0.3, t_end=3.0))
    args = records.bounce_plan_args

    def off(plan, imp, projection):
        out = list(args(plan, imp, projection))
        o0, o1 = out[4]
        out[4] = (math.nextafter(o0, math.inf), o1)
        return tuple(out)
    monkeypatch.setattr(records, "bounce_plan_args", off)
    taken = []
    handle = transitions._compiled_bounce
    monkeypatch.setattr(transitions, "_compiled_bounce", lambda *a: taken.append(a[3]) or handle(*a))
    records.COMPILED_BOUNCE_REFUSED.clear()
    traj = pcmm.simulate(scene)
    assert taken == []
    (why,) = records.COMPILED_BOUNCE_REFUSED.values()
    assert why.startswith("its record's numbers differ from the Python route's (number ")
    monkeypatch.setattr(transitions, "compiled_bounce", lambda cfg, tr: None)
    assert _events(traj) == _events(pcmm.simulate(scene))


def test_without_the_compiled_extension_no_bounce_is_compiled(tmp_path, monkeypatch):
    """PCMM_COMPILED=0: the impulse is the Python solve's, so no compiled bounce is built or taken."""
    monkeypatch.setenv("PCMM_COMPILED", "0")
    scene = pcmm.load_scene(builders.pendulum(tmp_path, 0.85, qs=-0.3, t_end=3.0))
    taken = []
    handle = transitions._compiled_bounce
    monkeypatch.setattr(transitions, "_compiled_bounce", lambda *a: taken.append(a[3]) or handle(*a))
    traj = pcmm.simulate(scene)
    assert len(traj.events) > 80 and taken == []
