"""A release fired the instant its configuration is entered (``guard = { type = "entry" }``).

Mechanism: a two-bar arm in a horizontal plane (no gravity), its elbow J2 folding until it latches at
J2 = LATCH (into 'locked', J2 locked); 'locked' lets the elbow go on entry.  By hand: the free arm's
Lagrange equations to the latch (solve_ivp), the plastic latch keeping the angular momentum about the
shoulder (no moment about J1 in the elbow's impulse), then at the same instant the release with no
impulse: J2 = LATCH, J2' = 0, J1' = omega = p1 / M11(LATCH), kinetic energy p1^2 / (2 M11(LATCH)).
The turning arm's centrifugal load then straightens the elbow (J2'' < 0 at relative rest for
0 < J2 < pi), and the latch never fires again: p1 is kept, so at any J2 the kinetic energy is at least
p1^2 / (2 M11(J2)), above the release's for J2 > LATCH (M11 falls with cos J2), while the elbow's
damper takes energy away.
"""
from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import pcmm
from pcmm.errors import SceneError
from pcmm.run.checks import check_scene

from builders import arm_free_rates, arm_mass_matrix, bar_xml, dump_toml, joint_xml, link_xml, robot_xml, scene_doc, write_scene

L1, L2, M1, M2 = 0.6, 0.35, 1.2, 0.5
LATCH = 0.6     # the elbow angle J2 the latch locks at (increasing)
W2 = 5.0        # the elbow's initial rate, the shoulder at rest
C = 0.01        # the elbow's damper (N m s), in 'free' only

ENTRY = {"type": "entry"}


def latch(guard=None, **more):
    return {"name": "elbow latch", "type": "latch", "from": "free", "to": "locked", "cut": ["J2"],
            "guard": guard or {"type": "coordinate", "measure": {"joint": "J2"}, "value": LATCH,
                               "direction": "increasing"},
            "contact": {"joint": "J2", "arm": L2}, **more}


def release(name="elbow release", source="locked", target="free", guard=ENTRY):
    return {"name": name, "type": "release", "from": source, "to": target, "guard": guard}


def arm(folder: Path, transitions=None, t_end: float = 0.8, configs=None) -> Path:
    urdf = robot_xml("arm", link_xml("frame"), joint_xml("J1", "revolute", "frame", "upper"), bar_xml("upper", L1, M1),
                     joint_xml("J2", "revolute", "upper", "fore", xyz=(L1, 0.0)), bar_xml("fore", L2, M2))
    doc = scene_doc(configs or {"free": "arm.urdf", "locked": {"from": "free", "lock": ["J2"]}},
                    {"J1": 0.0, "J2": 0.0}, {"J1": 0.0, "J2": W2}, gravity=(0.0, 0.0), t_end=t_end,
                    forces=[{"name": "elbow damper", "type": "damper", "on": {"joint": "J2"},
                             "measure": {"joint": "J2"}, "c": C, "configurations": ["free"]}],
                    transitions=[latch(), release()] if transitions is None else transitions,
                    solver={"rtol": 1e-11, "atol": 1e-13})
    return write_scene(folder, doc, {"arm.urdf": urdf})


def _mass(q2):
    """The arm's mass matrix in (J1, J2) (:func:`builders.arm_mass_matrix`, by hand)."""
    return arm_mass_matrix(q2, M1, L1, M2, L2)


def _free(t, y):
    """The free arm's equations of motion (:func:`builders.arm_free_rates`, by hand)."""
    return arm_free_rates(y, M1, L1, M2, L2, c=C)


def by_hand(t_end):
    """(latch time, omega after it, the free motion from the release to t_end)."""
    reach = lambda t, y: y[1] - LATCH  # noqa: E731
    reach.terminal, reach.direction = True, 1
    tol = {"method": "DOP853", "rtol": 1e-12, "atol": 1e-14}
    a = solve_ivp(_free, (0.0, 2.0), [0.0, 0.0, 0.0, W2], events=reach, **tol)
    assert a.t_events[0].size == 1
    t_l, (q1, q2, w1, w2) = a.t_events[0][0], a.y_events[0][0]
    omega = (_mass(q2)[0] @ [w1, w2]) / _mass(LATCH)[0, 0]
    b = solve_ivp(_free, (t_l, t_end), [q1, LATCH, omega, 0.0], dense_output=True, **tol)
    return t_l, omega, b


@pytest.mark.parametrize("compiled", ["1", "0"])
def test_a_latch_released_on_entry_is_two_events_at_one_instant(tmp_path, monkeypatch, compiled):
    monkeypatch.setenv("PCMM_COMPILED", compiled)
    t_end = 0.8
    t_l, omega, free = by_hand(t_end)
    traj = pcmm.simulate(pcmm.load_scene(arm(tmp_path, t_end=t_end)))
    assert all(v.startswith("compiled" if compiled == "1" else "python")
               for v in traj.stats["evaluations"].values()), traj.stats["evaluations"]
    assert [(e["name"], e["from"], e["to"]) for e in traj.events] == [
        ("elbow latch", "free", "locked"), ("elbow release", "locked", "free")]
    lat, rel = traj.events
    assert lat["t"] == pytest.approx(t_l, abs=1e-8)
    # the release: the latch's own instant, after it; no impulse; the state continuous
    assert rel["t"] == lat["t"] and rel["cause"] == "entry" and rel["impact"] is False
    assert rel["impulse"]["normal"] == 0.0 and rel["velocity_jump_max"] < 1e-12
    ke = 0.5 * _mass(LATCH)[0, 0] * omega ** 2
    assert lat["kinetic_energy_after"] == pytest.approx(ke, rel=1e-9)
    assert rel["kinetic_energy_before"] == pytest.approx(ke, rel=1e-9)
    assert rel["kinetic_energy_after"] == pytest.approx(rel["kinetic_energy_before"], rel=1e-14)
    assert rel["freed"]["J2"] == pytest.approx(LATCH, abs=1e-9)
    assert rel["v_after"]["J1"] == pytest.approx(omega, abs=1e-9)
    assert rel["v_after"]["J2"] == pytest.approx(0.0, abs=1e-9)
    # nothing integrated in 'locked': one sample there, at the latch's instant
    locked = [s for s in traj.segments if s.configuration == "locked"]
    assert [(s.t.size, float(s.t[0])) for s in locked] == [(1, lat["t"])]
    # and the free arm straightens from the latch on, as by hand
    q2 = traj.series("q", "J2")
    after = traj.t > lat["t"]
    assert np.all(q2[after] < LATCH)
    assert np.allclose(q2[after], free.sol(traj.t[after])[1], rtol=0, atol=1e-7)
    assert np.allclose(traj.series("v", "J1")[after], free.sol(traj.t[after])[2], rtol=0, atol=1e-7)
    assert free.sol(np.linspace(t_l, t_end, 20001)[1:])[1].max() < LATCH


def test_a_timer_at_the_latch_s_instant_could_not_do_it(tmp_path):
    """The entry guard against its hack: a time guard every 1e-9 s fires up to 1e-9 s after the latch,
    the arm turning rigidly meanwhile; the entry guard at the latch itself, and the motion after them the
    same to that interval's effect (far below 1e-7)."""
    t_l, _, _ = by_hand(0.8)
    timed = pcmm.simulate(pcmm.load_scene(arm(tmp_path / "timer", [latch(), release(guard={"type": "time", "every": 1e-9})])))
    entry = pcmm.simulate(pcmm.load_scene(arm(tmp_path / "entry")))
    assert timed.events[1]["cause"] == "time" and entry.events[1]["cause"] == "entry"
    assert 0.0 < timed.events[1]["t"] - timed.events[0]["t"] <= 1e-9  # the first k * 1e-9 after the latch
    assert entry.events[1]["t"] == entry.events[0]["t"] == pytest.approx(t_l, abs=1e-8)
    assert abs(timed.series("q", "J2")[-1] - entry.series("q", "J2")[-1]) < 1e-7


def test_pcmm_check_accepts_it(tmp_path):
    report = check_scene(pcmm.load_scene(arm(tmp_path)))
    assert report.problems == []
    assert not any("elbow release" in w for w in report.warnings), report.warnings


def _refused(tmp_path, transitions, configs=None) -> str:
    with pytest.raises(SceneError) as info:
        pcmm.load_scene(arm(tmp_path, transitions, configs=configs))
    return str(info.value)


def test_an_entry_guard_on_a_latch_is_refused(tmp_path):
    text = _refused(tmp_path, [latch(guard=ENTRY), release()])
    assert "transitions[0] (elbow latch).guard.type: = 'entry': only a release fires the instant" in text


def test_an_entry_guard_with_other_keys_is_refused(tmp_path):
    text = _refused(tmp_path, [latch(), release(guard={"type": "entry", "at": 0.1})])
    assert "transitions[1] (elbow release).guard.at: not used by an entry guard" in text


def test_two_entry_guards_from_one_configuration_are_refused(tmp_path):
    configs = {"free": "arm.urdf", "locked": {"from": "free", "lock": ["J2"]}, "also": "arm.urdf"}
    text = _refused(tmp_path, [latch(), release(), release("second", target="also")], configs)
    assert ("transitions[2] (second).guard.type: = 'entry': transitions[1] (elbow release) already leaves "
            "'locked' the instant it is entered") in text


def test_a_cycle_of_entry_guards_is_refused_naming_it(tmp_path):
    configs = {"free": "arm.urdf", "locked": {"from": "free", "lock": ["J2"]}, "a": "arm.urdf", "b": "arm.urdf"}
    text = _refused(tmp_path, [latch(), release(), release("a to b", "a", "b"), release("b to a", "b", "a")], configs)
    assert "the releases fired on entry form a cycle, 'a' (a to b) -> 'b' (b to a) -> 'a'" in text
    assert "'locked'" not in text.split("form a cycle")[1]  # the release out of 'locked' is no part of it


def test_pcmm_check_follows_an_entry_release_to_the_configuration_it_frees(tmp_path):
    """The kneed walker (tests/kneed_walker_scene.py): its heel strike enters 'b_strike', which its
    unlock leaves on entry for 'b_swing', at the strike's posture.  pcmm check follows the release there,
    so the second step's guards (b_swing's knee strike, b_locked's heel strike) are judged too; a timer
    fixes no posture, and with it they were not."""
    import reference_kneed_walker as kw
    from kneed_walker_scene import unlock_on_entry, write_walker

    theta, omega = np.array([0.2, -0.2, -0.2]), np.array([-0.9, -0.25, -0.25])
    judged = {}
    for name, unlock in (("entry", unlock_on_entry), ("timer", lambda stance: {"type": "time", "every": 1e-12})):
        report = check_scene(pcmm.load_scene(write_walker(tmp_path / name, kw.Walker(), theta, omega, release=unlock)))
        assert report.problems == []
        judged[name] = set(report.reach)
    assert judged["entry"] == {"knee strike b", "heel strike b", "knee strike a", "heel strike a"}
    assert judged["timer"] == {"knee strike b", "heel strike b"}


def test_a_run_that_starts_in_the_configuration_releases_at_t_0(tmp_path):
    """The run enters its initial configuration at t = 0: a release on entry fires there, with the
    kinetic energy of the rigid arm, M11(LATCH) w1^2 / 2, and the elbow straightens after it."""
    path = arm(tmp_path)
    doc = tomllib.loads(path.read_text())
    doc["scene"]["initial_configuration"] = "locked"
    doc["configurations"]["locked"]["lock"] = {"J2": LATCH}
    doc["initial"] = {"q": {"J1": 0.0}, "v": {"J1": 2.0}}
    path.write_text(dump_toml(doc))
    traj = pcmm.simulate(pcmm.load_scene(path))
    [ev] = traj.events
    assert (ev["name"], ev["t"], ev["cause"], ev["to"]) == ("elbow release", 0.0, "entry", "free")
    assert ev["kinetic_energy_after"] == pytest.approx(0.5 * _mass(LATCH)[0, 0] * 4.0, rel=1e-12)
    assert traj.series("q", "J2")[-1] < LATCH


def test_a_release_on_entry_into_a_latch_pushed_closed_stops_the_run_naming_both(tmp_path):
    """Not a cycle of entry guards (the loader cannot see it): a motor pushes the freed elbow straight
    back into its latch, which closes at once with no impulse, and the release fires again on entry.
    The run's zero-time-cycle check stops it after 64 switches, naming the latch and the release."""
    path = arm(tmp_path)
    doc = tomllib.loads(path.read_text())
    doc["forces"].append({"name": "push", "type": "torque", "on": {"joint": "J2"}, "value": 1.0,
                          "configurations": ["free"]})
    path.write_text(dump_toml(doc))
    with pytest.raises(pcmm.errors.SimulationError) as info:
        pcmm.simulate(pcmm.load_scene(path))
    text = str(info.value)
    assert "switched configuration 64 times without time passing: 'elbow latch' (free -> locked), " \
           "'elbow release' (locked -> free) keep firing" in text
