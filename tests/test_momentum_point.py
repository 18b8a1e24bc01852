"""``[scene] momentum_point = "contact"``: each event's angular momentum about its own contact point,
the quantity a strike on a floating mechanism conserves (pcmm.events.momentum).

About a fixed point (the default, or ``[x, y]``) a pin strike's momentum block shows a change: the
frame's impulse at the struck point has a moment there.  About the struck point it has none, so where
the struck point takes the only impulse from the frame, H_O+ = H_O- (checked inside the run:
:func:`pcmm.events.momentum.check_struck_point_momentum`).  By hand, for one body of mass m, inertia
I about its centre of mass c (velocity v_c, rate w): H_O = I w + m (c - O) x v_c.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import builders
import pcmm
import test_double_support as ds
import test_newcomer3_rocking as rock
from builders import EXAMPLES
from pcmm.errors import SceneError, SimulationError
from pcmm.events import pins, records
from pcmm.events.momentum import struck_point_only
from pcmm.model.mechanism import Mechanism


def _contact_scene(scene):
    return scene.with_values({"scene.momentum_point": "contact"})


def _h_by_hand(q, v_joint, p, m, inertia):
    """I w + m (c - p) x v_c of one body on a planar joint (its centre of mass at the joint's origin):
    q = [x, y, theta], v_joint = the joint's body-frame velocity [vx, vy, w]."""
    x, y, th = q
    c, s = math.cos(th), math.sin(th)
    vc = np.array([c * v_joint[0] - s * v_joint[1], s * v_joint[0] + c * v_joint[1]])
    r = np.array([x, y]) - np.asarray(p, float)
    return inertia * v_joint[2] + m * float(r[0] * vc[1] - r[1] * vc[0])


def _strike_states(traj):
    """(event, q at the event) of every event (the segment it ends)."""
    return [(e, np.asarray(seg.q[-1], float)) for e, seg in zip(traj.events, traj.segments)]


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rocking_contact")
    (folder / "block.urdf").write_text(rock.URDF)
    (folder / "rocking.toml").write_text(rock.SCENE)
    return pcmm.load_scene(folder / "rocking.toml")


def test_rocking_block_about_each_struck_corner_is_conserved_and_is_housners(block):
    traj = pcmm.simulate(_contact_scene(block))
    assert len(traj.events) == 7
    w_housner = rock._housner(7)[1]
    i_cm = rock.M * (4 * rock.B ** 2 + 4 * rock.H ** 2) / 12  # 0.0333 kg m^2
    for (e, q), w_hand in zip(_strike_states(traj), w_housner):
        m = e["momentum"]
        assert m["about"] == e["contact_point"]  # the struck corner, on the ground
        assert abs(m["about"][0]) == pytest.approx(2 * rock.B if e["name"] == "left strikes" else 0.0, abs=1e-9)
        assert m["about"][1] == pytest.approx(0.0, abs=1e-12)
        before, after = m["angular_before"], m["angular_after"]
        assert after == pytest.approx(before, rel=1e-12, abs=0)
        # by hand from the event's own state, before and after
        assert before == pytest.approx(_h_by_hand(q, e["v_before"]["base"], m["about"], rock.M, i_cm), rel=1e-12)
        assert after == pytest.approx(_h_by_hand(q, e["v_after"]["base"], m["about"], rock.M, i_cm), rel=1e-12)
        # and by Housner: upright at the strike, c - O = (+-b, h) from the new corner, so H = (I_cm + m (h^2 - b^2)) w
        assert abs(before) == pytest.approx((i_cm + rock.M * (rock.H ** 2 - rock.B ** 2)) * w_hand, rel=1e-8)


def test_rocking_block_about_a_fixed_point_is_unchanged_by_the_option(block):
    """The default (the origin here: no pivot on the frame) and [x, y] give what they gave: H about
    a fixed point changes at a strike by the moment there of the corner's impulse."""
    short = pcmm.RunOptions(t_end=0.5)
    default = pcmm.simulate(block, short).events[0]
    fixed = pcmm.simulate(block.with_values({"scene.momentum_point": [0.5, 0.0]}), short).events[0]
    assert default["momentum"]["about"] == [0.0, 0.0] and fixed["momentum"]["about"] == [0.5, 0.0]
    for e in (default, fixed):
        m = e["momentum"]
        o, p = np.array(m["about"]), np.array(e["contact_point"])
        dL = np.subtract(m["linear_after"], m["linear_before"])  # the corner's impulse, at p
        moment = float((p - o)[0] * dL[1] - (p - o)[1] * dL[0])
        assert abs(moment) > 0.01
        assert m["angular_after"] - m["angular_before"] == pytest.approx(moment, rel=1e-9)


def test_rimless_wheel_about_each_struck_tip_is_conserved_and_is_mcgeers():
    scene = pcmm.load_scene(EXAMPLES / "rimless_wheel.toml")
    traj = pcmm.simulate(_contact_scene(scene), pcmm.RunOptions(t_end=4.0))
    assert len(traj.events) >= 3
    r = 0.55 / 1.05  # (I + m l^2 cos 2 alpha) / (I + m l^2)
    for e, q in _strike_states(traj):
        m = e["momentum"]
        assert m["about"] == e["contact_point"]
        assert m["about"][1] == pytest.approx(0.0, abs=1e-9)  # the tip lands on the slope
        before, after = m["angular_before"], m["angular_after"]
        assert after == pytest.approx(before, rel=1e-12, abs=0)
        assert before == pytest.approx(_h_by_hand(q, e["v_before"]["hub"], m["about"], 1.0, 0.05), rel=1e-12)
        assert after == pytest.approx(_h_by_hand(q, e["v_after"]["hub"], m["about"], 1.0, 0.05), rel=1e-12)
        # the spoke symmetric about the tip's normal: H- = (I + m l^2 cos 2 alpha) w-, H+ = (I + m l^2) w+
        assert e["v_after"]["hub"][2] == pytest.approx(r * e["v_before"]["hub"][2], rel=1e-9)
        assert after == pytest.approx(1.05 * e["v_after"]["hub"][2], rel=1e-9)


def test_a_word_other_than_contact_is_refused_naming_the_field(block):
    with pytest.raises(SceneError, match=r'scene\.momentum_point.*\'contct\'.*"contact"'):
        block.with_values({"scene.momentum_point": "contct"})


def test_a_wrong_strike_impulse_is_caught_by_the_conservation_check(block, monkeypatch):
    """The check can fail: a solve that gives 1 % too much velocity after (still on the target's
    constraints, which are homogeneous) breaks H about the struck corner, and the run says so."""
    right = pins.impact_with_rows

    def too_fast(*args):
        v, lam, redundant = right(*args)
        return 1.01 * v, lam, redundant
    monkeypatch.setattr(pins, "impact_with_rows", too_fast)
    with pytest.raises(SimulationError, match=r"'left strikes'.*angular momentum about the struck point"):
        pcmm.simulate(block, pcmm.RunOptions(t_end=0.5))


def test_a_foot_held_through_the_strike_takes_an_impulse_with_a_moment_about_the_struck_foot(make_scene):
    """test_double_support's walker landing on B with A held (both feet push, 'double'): A's impulse
    P_A has the moment (A - B) x P_A about B, so H about B is not conserved and is not checked there;
    the block shows exactly that change.  Released A (no impulse): conserved about B."""
    held = pcmm.load_scene(ds.walker(make_scene, -0.5, -4.0))
    mech = Mechanism(held)
    assert struck_point_only(mech["single_a"], mech["double"], "foot_b") == \
        "the cut joint 'foot_a' holds a point to the frame through the strike"
    traj = pcmm.simulate(_contact_scene(held))
    q, w1, w2 = ds._strike_state(traj)
    A, _, _, _, B, _, _ = ds._points(q)
    P_A = ds.locked_impulse_at_A(q, w1, w2)
    m = traj.events[0]["momentum"]
    np.testing.assert_allclose(m["about"], B, rtol=0, atol=1e-9)
    change = ds._cross(A - B, P_A)
    assert abs(change) > 0.05
    assert m["angular_after"] - m["angular_before"] == pytest.approx(change, rel=1e-8)

    released = pcmm.load_scene(ds.walker(make_scene, -1.0, 0.0))
    mech = Mechanism(released)
    assert struck_point_only(mech["single_a"], mech["single_b"], "foot_b") is None
    e = pcmm.simulate(_contact_scene(released)).events[0]
    assert e["to"] == "single_b"
    assert e["momentum"]["angular_after"] == pytest.approx(e["momentum"]["angular_before"], rel=1e-12, abs=0)


@pytest.fixture(scope="module")
def kneed_step(tmp_path_factory):
    """docs/kneed_walker.md's step (a knee strike, then a heel strike), momenta about each event's contact."""
    import test_newcomer3_walker as nw
    from kneed_walker_scene import write_walker
    path = write_walker(tmp_path_factory.mktemp("walker_contact"), nw.W, nw.THETA0, nw.OMEGA0, t_end=0.6)
    return _contact_scene(pcmm.load_scene(path)), pcmm.simulate(_contact_scene(pcmm.load_scene(path)))


def test_the_kneed_walker_s_heel_strike_conserves_h_about_the_new_foot(kneed_step):
    """The walker's stumble (docs/kneed_walker.md): about the origin its heel strike reads -1.43987 ->
    -1.17544; about the new foot, as the reference walker computes it (tests/reference_kneed_walker.py)
    from the recorded state, the same value before and after."""
    import reference_kneed_walker as kw
    import test_newcomer3_walker as nw
    _, traj = kneed_step
    heel = traj.events[1]
    assert heel["name"] == "heel strike b"
    q, v, v2, _, _ = nw._impact_case(traj, 1, [("foot", "b"), ("knee", "a"), ("knee", "b")])
    foot = kw.foot_position(nw.W, q, "b")
    m = heel["momentum"]
    np.testing.assert_allclose(m["about"], foot, rtol=0, atol=1e-12)
    assert m["angular_after"] == pytest.approx(m["angular_before"], rel=1e-12, abs=0)
    assert m["angular_before"] == pytest.approx(kw.angular_momentum(nw.W, q, v, foot, None), rel=1e-10)
    assert m["angular_after"] == pytest.approx(kw.angular_momentum(nw.W, q, v2, foot, None), rel=1e-10)
    assert m["angular_before"] == pytest.approx(-1.30237005408214, rel=1e-9)  # docs/kneed_walker.md's figure


def test_a_knee_strike_is_taken_about_the_knee_where_the_stance_foot_s_impulse_has_a_moment(kneed_step):
    """A joint stop (the knee's latch) has no contact point: the record's contact_point, the knee's
    position, is used.  The stance foot (pinned to the frame) takes the only external impulse, dL,
    at the foot: about the knee H changes by exactly its moment (foot - knee) x dL, not zero."""
    import reference_kneed_walker as kw
    import test_newcomer3_walker as nw
    _, traj = kneed_step
    knee = traj.events[0]
    assert knee["name"] == "knee strike b"
    q = nw.floating(traj.segments[0], -1)[0]
    m = knee["momentum"]
    assert m["about"] == knee["contact_point"]
    np.testing.assert_allclose(m["about"], kw.position({4: nw.W.l_thigh}, q, q[:2]), rtol=0, atol=1e-12)  # knee b
    foot = kw.foot_position(nw.W, q, "a")
    r = foot - np.asarray(m["about"])
    dL = np.subtract(m["linear_after"], m["linear_before"])
    moment = float(r[0] * dL[1] - r[1] * dL[0])
    assert abs(moment) > 1e-3
    assert m["angular_after"] - m["angular_before"] == pytest.approx(moment, rel=1e-9)


def test_a_bouncing_pendulum_about_each_contact_point_and_nothing_else_changes(tmp_path):
    """A bar (m, L) on a pivot at the origin bouncing on a stop at its tip (builders.pendulum, e = 0.85):
    about the tip, H = I_cm w + m (c - p) x v_c = m L^2 w / 12 - m L^2 w / 4 = -m L^2 w / 6 (the pivot's
    impulse has a moment there: H+ = -e H-).  The bounces' fast record (its point fixed per stop) is
    refused with the reason, and every other number of every event is the default run's."""
    e, L, m, qs = 0.85, 0.6, 1.5, -0.3
    scene = pcmm.load_scene(builders.pendulum(tmp_path, e, L=L, m=m, qs=qs, t_end=3.0))
    records.BOUNCE_RECORD_REFUSED.clear()
    contact = pcmm.simulate(_contact_scene(scene))
    from pcmm.model import compiled
    # the fast record needs the compiled impulse's momenta: on the Python path (PCMM_COMPILED=0) it is
    # refused for that reason first
    assert records.BOUNCE_RECORD_REFUSED[("c1", "stop")] == (
        'the momenta are taken about each bounce\'s contact point (momentum_point = "contact")' if compiled.enabled()
        else "the impulse was not solved compiled (no momenta at hand)")
    default = pcmm.simulate(scene)
    bounces = [ev for ev in contact.events if ev["transition"] == "stop" and not ev["merge"]]
    assert len(bounces) > 50
    for ev in bounces:
        mom = ev["momentum"]
        np.testing.assert_allclose(mom["about"], [L * math.cos(qs), L * math.sin(qs)], rtol=0, atol=1e-9)
        assert mom["about"] == ev["contact_point"]
        w0, w1 = ev["v_before"]["J1"], ev["v_after"]["J1"]
        assert mom["angular_before"] == pytest.approx(-m * L * L * w0 / 6, rel=1e-12)
        assert mom["angular_after"] == pytest.approx(-m * L * L * w1 / 6, rel=1e-12)
        assert mom["angular_after"] == pytest.approx(-e * mom["angular_before"], rel=1e-9)
    assert len(contact.events) == len(default.events)
    for a, b in zip(contact.events, default.events):
        a, b = dict(a), dict(b)
        assert b["momentum"]["about"] == [0.0, 0.0]  # the pivot
        a.pop("momentum"), b.pop("momentum")
        assert repr(a) == repr(b)


def test_the_check_runs_at_each_heel_strike_and_not_with_a_foot_held(tmp_path, make_scene, monkeypatch):
    """The conservation check runs where it must hold (the kneed walker's heel strike, the default
    momentum point) and not where a held foot takes an impulse (test_double_support's 'double')."""
    import test_newcomer3_walker as nw
    from kneed_walker_scene import write_walker
    checked = []
    real = pins.check_struck_point_momentum

    def counted(cfg, tr, *args):
        checked.append(tr.name)
        return real(cfg, tr, *args)
    monkeypatch.setattr(pins, "check_struck_point_momentum", counted)
    pcmm.simulate(pcmm.load_scene(write_walker(tmp_path / "w", nw.W, nw.THETA0, nw.OMEGA0, t_end=0.6)))
    assert checked == ["heel strike b"]
    checked.clear()
    traj = pcmm.simulate(pcmm.load_scene(ds.walker(make_scene, -0.5, -4.0)))
    assert traj.events[0]["to"] == "double" and checked == []
