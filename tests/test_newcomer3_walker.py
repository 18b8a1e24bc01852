"""A new user's kneed walker (McGeer 1990, "passive walking with knees"; Hsu Chen 2007), modelled from
README.md and the pages it links alone, checked against an independent numpy model.

The walker (tests/reference_kneed_walker.py): a hip mass of 0.5 kg, thighs of 0.5 m and 0.5 kg,
shanks of 0.5 m and 0.05 kg (rigid bars), on a slope of 0.0504 rad; the scene is written by
tests/kneed_walker_scene.py (a planar base on thigh a, the hip, a knee in each leg; one configuration
per phase and stance leg, derived from the free walker by locking knees). One step:

1. swing (a_swing): leg a's knee locked and its foot pinned, leg b's knee free: 3 DOF;
2. knee strike b (latch, a joint stop on knee_b): the knee locks, e = 0;
3. heel strike b (pin): leg b's foot is pinned where it lands, leg a's foot lifts off.

Checked against the reference, which shares no code with pcmm: the flights against solve_ivp
(DOP853, rtol 1e-11) on Lagrange's equations in absolute angles, to 1e-8; each impact against the KKT
solve M (v+ - v-) = A^T P, A v+ = 0 in floating coordinates, to 1e-10; and the momenta each impact
conserves, computed body by body from the recorded states: the swing leg's about the hip and the whole
walker's about the stance foot at the knee strike; the whole walker's about the new foot and the
trailing leg's about the hip at the heel strike.
"""
from __future__ import annotations

import numpy as np
import pytest

import pcmm
import reference_kneed_walker as kw
from kneed_walker_scene import unlock_on_entry, write_walker

W = kw.Walker()
THETA0 = np.array([0.2, -0.2, -0.2])        # stance leg, swing thigh, swing shank (rad)
OMEGA0 = np.array([-0.9, -0.25, -0.25])      # rad/s: found by a grid search on the reference (test docstring)
SWING_LEG = {3, 4}                           # floating_bodies indices: thigh b, shank b
TRAILING_LEG = {1, 2}                        # thigh a, shank a (the hip mass sits at the hip: no moment)


@pytest.fixture(scope="module")
def step(tmp_path_factory):
    path = write_walker(tmp_path_factory.mktemp("walker"), W, THETA0, OMEGA0, t_end=0.6)
    return pcmm.simulate(pcmm.load_scene(path))


def floating(seg, i):
    """The reference's floating (q, v) from a recorded sample: hip, then thigh a, shank a, thigh b, shank b."""
    col = {name: k for k, name in enumerate(seg.links)}
    order = [col[n] for n in ("thigh_a", "shank_a", "thigh_b", "shank_b")]
    hip = np.asarray(seg.xy[i][col["thigh_a"]])
    v_hip = np.asarray(seg.v[i][:2])                 # base.x', base.y': world axes (docs/planar_joints.md)
    assert seg.coordinates[:2] == ["base.x", "base.y"]
    return (np.concatenate([hip, np.asarray(seg.theta[i])[order]]),
            np.concatenate([v_hip, np.asarray(seg.omega[i])[order]]))


def knee_event(t, y):
    return y[2] - y[1]


knee_event.terminal, knee_event.direction = True, 1


def heel_event(t, y):
    """The swing foot's height above the slope (foot a at the origin), counted with the swing leg ahead."""
    return W.leg * (np.cos(y[0]) - np.cos(y[1])) if y[1] > y[0] else 1.0


heel_event.terminal, heel_event.direction = True, -1


@pytest.fixture(scope="module")
def reference():
    """The whole step by the reference alone, from the scene's initial state."""
    swing = kw.flight(W, W.swing_bodies(), THETA0, OMEGA0, 1.0, events=[knee_event])
    t_knee, y = swing.t_events[0][0], swing.y_events[0][0]
    q, v = kw.floating_state(W, "a", y[:3], y[3:])
    v_knee, _ = kw.impact(W, q, v, [("foot", "a"), ("knee", "a"), ("knee", "b")])
    locked = kw.flight(W, W.locked_bodies(), np.array([q[2], q[4]]), np.array([v_knee[2], v_knee[4]]), 1.0,
                       events=[heel_event])
    return {"swing": swing, "t_knee": t_knee, "locked": locked, "t_heel": t_knee + locked.t_events[0][0]}


def test_the_step_is_a_knee_strike_then_a_heel_strike(step, reference):
    kinds = [(e["name"], e["from"], e["to"]) for e in step.events]
    assert kinds == [("knee strike b", "a_swing", "a_locked"), ("heel strike b", "a_locked", "b_strike")]
    assert step.events[0]["t"] == pytest.approx(reference["t_knee"], abs=1e-9)
    assert step.events[1]["t"] == pytest.approx(reference["t_heel"], abs=1e-9)
    assert reference["t_knee"] == pytest.approx(0.48234161, abs=1e-8)
    assert reference["t_heel"] == pytest.approx(0.52881967, abs=1e-8)


def test_swing_and_locked_flights_follow_the_own_ode(step, reference):
    swing, locked = step.segments[0], step.segments[1]
    worst = 0.0
    for i, t in enumerate(swing.t):
        q, _ = floating(swing, i)
        th = reference["swing"].sol(t)[:3]
        qr, _ = kw.floating_state(W, "a", th, np.zeros(3))
        worst = max(worst, np.max(np.abs(q - qr)))
    for i, t in enumerate(locked.t):
        q, _ = floating(locked, i)
        th = reference["locked"].sol(t - reference["t_knee"])[:2]
        qr, _ = kw.floating_state(W, "a", th, np.zeros(2))
        worst = max(worst, np.max(np.abs(q - qr)))
    assert len(swing.t) > 10 and worst < 1e-8


def _impact_case(step, k, rows):
    before, after = step.segments[k], step.segments[k + 1]
    q, v = floating(before, -1)
    q2, v2 = floating(after, 0)
    assert np.max(np.abs(q2 - q)) < 1e-12                  # an impact moves nothing
    v_ref, P = kw.impact(W, q, v, rows)
    return q, v, v2, v_ref, P


def test_knee_strike_against_the_kkt_solve_and_the_momenta(step):
    q, v, v2, v_ref, P = _impact_case(step, 0, [("foot", "a"), ("knee", "a"), ("knee", "b")])
    assert np.max(np.abs(v2 - v_ref)) < 1e-10
    assert v2[5] - v2[4] == pytest.approx(0.0, abs=1e-12)  # the knee is locked: shank b turns with thigh b
    hip, foot = q[:2], kw.foot_position(W, q, "a")
    for which, about in ((SWING_LEG, hip), (None, foot)):
        h0, h1 = (kw.angular_momentum(W, q, u, about, which) for u in (v, v2))
        assert h1 == pytest.approx(h0, abs=1e-12)
    ev = step.events[0]
    assert ev["kinetic_energy_before"] == pytest.approx(kw.kinetic(W, q, v), abs=1e-12)
    assert ev["kinetic_energy_after"] == pytest.approx(kw.kinetic(W, q, v_ref), abs=1e-12)
    assert ev["kinetic_energy_after"] < ev["kinetic_energy_before"]
    # the knee's moment impulse on shank b (the last row): pcmm reports it as the joint stop's moment
    assert abs(ev["impulse"]["moment"]) == pytest.approx(abs(P[-1]), rel=1e-9)


def test_heel_strike_against_the_kkt_solve_and_the_momenta(step):
    q, v, v2, v_ref, P = _impact_case(step, 1, [("foot", "b"), ("knee", "a"), ("knee", "b")])
    assert np.max(np.abs(v2 - v_ref)) < 1e-10
    ev = step.events[1]
    new_foot, old_foot, hip = kw.foot_position(W, q, "b"), kw.foot_position(W, q, "a"), q[:2]
    assert new_foot[1] == pytest.approx(0.0, abs=1e-10) and ev["anchor"]["foot_b"] == pytest.approx(new_foot, abs=1e-10)
    for which, about in ((None, new_foot), (TRAILING_LEG, hip)):
        h0, h1 = (kw.angular_momentum(W, q, u, about, which) for u in (v, v2))
        assert h1 == pytest.approx(h0, abs=1e-12)
    # the old foot lifts off without an impulse: its normal velocity after, by the reference
    u_old = kw.jacobian(W.foot("a"), q, 6, True) @ v_ref
    assert u_old[1] > 0.0
    assert ev["released"]["foot_a"]["normal_velocity_after"] == pytest.approx(u_old[1], abs=1e-10)
    assert ev["released"]["foot_a"]["impulse"] == 0.0
    assert ev["impulse"]["normal"] == pytest.approx(P[1], abs=1e-10)
    assert ev["impulse"]["tangential"] == pytest.approx(P[0], abs=1e-10)


def test_a_pin_into_a_configuration_with_other_joints_is_refused_at_load(tmp_path):
    """Stumble: the heel strike first went straight into the next swing phase (leg a's knee free).
    `pcmm check` said "valid" and the run stopped only at the strike, 0.53 s in ("a pin keeps the tree
    ..."); the loader now refuses it, naming the transition, both joint lists and the remedy."""
    import tomllib

    from builders import dump_toml

    path = write_walker(tmp_path, W, THETA0, OMEGA0, t_end=0.6)
    doc = tomllib.loads(path.read_text())
    doc["transitions"][1]["to"] = "b_swing"          # heel strike b into leg b's stance with leg a's knee free
    path.write_text(dump_toml(doc))
    with pytest.raises(pcmm.SceneError) as err:
        pcmm.load_scene(path)
    text = str(err.value)
    assert "transitions[1] (heel strike b).to: = 'b_swing'" in text
    assert "['base', 'hip', 'knee_a']" in text and "'a_locked' ['base', 'hip']" in text and "`release`" in text


def test_a_pinned_foot_stays_where_it_struck_across_a_latch_and_a_release(tmp_path, step):
    """Silent-anchor defect: a configuration whose foot is pinned "where it is entered" was anchored
    only by a pin (and a lift-off).  Entered by a latch or a release, it kept the anchor of its
    previous entry, or the origin: the walker's knee strike stopped the run ("link 'thigh_a' ... differs
    by 1 m") as soon as the stance foot was not at the world's origin, and leg a's knee could not be
    unlocked after the heel strike at x = 0.397 m.  Now a pinned foot stays where it struck."""
    shifted = pcmm.simulate(pcmm.load_scene(write_walker(tmp_path / "shifted", W, THETA0, OMEGA0, t_end=0.6,
                                                         foot=(1.0, 0.0))))
    # the same walk, one metre further down the slope: translation changes nothing but x
    assert [e["name"] for e in shifted.events] == [e["name"] for e in step.events]
    for a, b in zip(shifted.events, step.events):
        assert a["t"] == pytest.approx(b["t"], abs=1e-12)
        assert a["kinetic_energy_after"] == pytest.approx(b["kinetic_energy_after"], abs=1e-12)
    assert shifted.events[1]["anchor"]["foot_b"] == pytest.approx(np.add(step.events[1]["anchor"]["foot_b"], [1.0, 0.0]),
                                                                  abs=1e-12)
    # leg a's knee unlocked 0.05 s after the heel strike (a timer): no impulse, foot b stays put
    t_rel = 0.58
    run = pcmm.simulate(pcmm.load_scene(write_walker(
        tmp_path / "release", W, THETA0, OMEGA0, t_end=0.6,
        release=lambda stance: {"type": "time", "at": t_rel})))
    assert [e["name"] for e in run.events] == ["knee strike b", "heel strike b", "knee a unlocks"]
    ev = run.events[2]
    assert ev["t"] == t_rel and ev["kinetic_energy_after"] == pytest.approx(ev["kinetic_energy_before"], rel=1e-12)
    before, after = run.segments[2], run.segments[3]
    assert after.configuration == "b_swing"
    q0, v0 = floating(before, -1)
    q1, v1 = floating(after, 0)
    assert np.max(np.abs(q1 - q0)) < 1e-12 and np.max(np.abs(v1 - v0)) < 1e-12
    anchor = np.asarray(run.events[1]["anchor"]["foot_b"])
    for seg in (before, after):
        for i in range(len(seg.t)):
            q, _ = floating(seg, i)
            assert np.max(np.abs(kw.foot_position(W, q, "b") - anchor)) < 1e-9


ROWS = {"a_swing": [("foot", "a"), ("knee", "a")], "a_locked": [("foot", "a"), ("knee", "a"), ("knee", "b")],
        "b_strike": [("foot", "b"), ("knee", "a"), ("knee", "b")]}


def test_the_knee_holding_moment_is_solved_with_the_stance_foot_that_holds(tmp_path):
    """Silent wrong number: after the heel strike the latched knee b's holding moment ("knee_b.hold") was
    solved in 'a_swing', the configuration with knee b free, whose foot a is pinned instead of foot b:
    -0.028943 N m where the walker, standing on foot b, holds knee b with +0.005860 N m (the other sign:
    a knee stop there would have to pull).  Given a configuration with foot b pinned and both knees free,
    it was solved there, with the locked swing knee a free: +0.009727 N m.  The holds are now solved only
    in a configuration with the same cut joints and exactly the held joints freed; without one they are
    NaN, and the run's warnings say why."""
    run = pcmm.simulate(pcmm.load_scene(write_walker(tmp_path / "refs", W, THETA0, OMEGA0, t_end=0.6,
                                                     hold_references=True)))
    assert run.stats["warnings"] == []
    checked = 0
    for seg in run.segments:
        labels = list(seg.constraint_labels)
        for i in range(len(seg.t)):
            q, v = floating(seg, i)
            _, lam = kw.constrained_dynamics(W, q, v, ROWS[seg.configuration])
            forces = dict(zip(labels, seg.constraint_forces[i]))
            foot = ROWS[seg.configuration][0][1]
            assert forces[f"foot_{foot}.fx"] == pytest.approx(lam[0], abs=1e-9)
            assert forces[f"foot_{foot}.fy"] == pytest.approx(lam[1], abs=1e-9)
            if "knee_b.hold" in forces:     # knee b's row is the last one
                assert forces["knee_b.hold"] == pytest.approx(lam[-1], abs=1e-9)
                checked += 1
    assert checked > 5
    first = dict(zip(run.segments[2].constraint_labels, run.segments[2].constraint_forces[0]))
    assert first["knee_b.hold"] == pytest.approx(0.00586032506, abs=1e-10)
    # without a configuration to solve it in: NaN and a warning, never another mechanism's number
    bare = pcmm.simulate(pcmm.load_scene(write_walker(tmp_path / "bare", W, THETA0, OMEGA0, t_end=0.6)))
    seg = bare.segments[2]
    assert np.all(np.isnan(np.asarray(seg.constraint_forces)[:, list(seg.constraint_labels).index("knee_b.hold")]))
    (note,) = bare.stats["warnings"]
    assert "'b_strike'" in note and "knee_b.hold cannot be solved here" in note and "cut joints (foot_b)" in note
    # a configuration with more joints free (both knees) is not the one to solve it in either
    import tomllib

    from builders import dump_toml

    path = write_walker(tmp_path / "wider", W, THETA0, OMEGA0, t_end=0.6, hold_references=True)
    doc = tomllib.loads(path.read_text())
    del doc["configurations"]["a_knee_free"], doc["configurations"]["b_knee_free"]
    path.write_text(dump_toml(doc))
    seg = pcmm.simulate(pcmm.load_scene(path)).segments[2]
    assert np.all(np.isnan(np.asarray(seg.constraint_forces)[:, list(seg.constraint_labels).index("knee_b.hold")]))


# -- a whole cycle: Chen's (2007) mass distribution, the thigh's centroid 0.325 m below the hip -----------
CHEN = kw.Walker(c_thigh=0.325)


@pytest.fixture(scope="module")
def gait():
    """The period-one gait of the reference's step map (fsolve; the start: the map iterated 25 times
    from Chen's published initial state, rounded), and pcmm's two steps from it."""
    from scipy.optimize import fsolve

    x, info, ok, msg = fsolve(lambda z: kw.step(CHEN, z)[0] - z, [0.25380973, -1.11242228, -0.29885974],
                              xtol=1e-13, full_output=True)
    assert ok == 1, msg
    _, t_knee, t_heel = kw.step(CHEN, x)
    return x, t_knee, t_heel


@pytest.fixture(scope="module")
def cycle(gait, tmp_path_factory):
    x = gait[0]
    path = write_walker(tmp_path_factory.mktemp("cycle"), CHEN, np.array([x[0], -x[0], -x[0]]),
                        np.array([x[1], x[2], x[2]]), t_end=1.3, hold_references=True,
                        release=unlock_on_entry)
    return pcmm.simulate(pcmm.load_scene(path))


def test_a_whole_cycle_against_the_reference_gait(gait, cycle):
    x, t_knee, t_heel = gait
    assert np.max(np.abs(kw.step(CHEN, x)[0] - x)) < 1e-11        # the gait is periodic (the reference's own check)
    assert (t_knee, t_heel) == (pytest.approx(0.50734586, abs=1e-8), pytest.approx(0.63215593, abs=1e-8))
    names = [e["name"] for e in cycle.events]
    assert names == ["knee strike b", "heel strike b", "knee a unlocks", "knee strike a", "heel strike a", "knee b unlocks"]
    times = [e["t"] for e in cycle.events]
    expected = [t_knee, t_heel, t_heel, t_heel + t_knee, 2 * t_heel, 2 * t_heel]
    assert max(abs(a - b) for a, b in zip(times, expected)) < 1e-8
    # the unlocks fire on entering the strike's configuration: at the strike's instant itself, after it
    assert times[2] == times[1] and times[5] == times[4]
    # the unlocks: no impulse, every body's velocity continuous; nothing integrated in the strike's configuration
    for k in (2, 5):
        ev = cycle.events[k]
        assert ev["cause"] == "entry" and ev["kinetic_energy_after"] == pytest.approx(ev["kinetic_energy_before"], rel=1e-12)
    struck = [s for s in cycle.segments if s.configuration in ("b_strike", "a_strike")]
    assert [(s.t.size, s.t[0]) for s in struck] == [(1, times[1]), (1, times[4])]
    # the second step is the first with the legs swapped, one step length further
    start, again = floating(cycle.segments[0], 0), floating(cycle.segments[-1], 0)
    assert cycle.segments[-1].configuration == "a_swing"
    step_length = 2 * CHEN.leg * np.sin(x[0])
    assert np.max(np.abs(again[0] - start[0] - np.array([2 * step_length, 0, 0, 0, 0, 0]))) < 1e-8
    assert np.max(np.abs(again[1] - start[1])) < 1e-8
    mid = floating(cycle.segments[3], 0)                  # b_swing: leg b in stance, leg a's knee free
    assert cycle.segments[3].configuration == "b_swing"
    swap = [0, 1, 4, 5, 2, 3]
    assert np.max(np.abs(mid[0][swap] - start[0] - np.array([step_length, 0, 0, 0, 0, 0]))) < 1e-8
    assert np.max(np.abs(mid[1][swap] - start[1])) < 1e-8


def test_each_heel_strike_of_the_cycle_conserves_the_two_momenta(cycle):
    for k, new, old, trailing in ((1, "b", "a", TRAILING_LEG), (4, "a", "b", SWING_LEG)):
        ev = cycle.events[k]
        seg_before, = [s for s in cycle.segments if s.t[-1] == ev["t"] and s.configuration == ev["from"]]
        seg_after, = [s for s in cycle.segments if s.t[0] == ev["t"] and s.configuration == ev["to"]]
        q, v = floating(seg_before, -1)
        _, v2 = floating(seg_after, 0)
        v_ref, P = kw.impact(CHEN, q, v, [("foot", new), ("knee", "a"), ("knee", "b")])
        assert np.max(np.abs(v2 - v_ref)) < 1e-10
        foot, hip = kw.foot_position(CHEN, q, new), q[:2]
        for which, about in ((None, foot), (trailing, hip)):
            h0, h1 = (kw.angular_momentum(CHEN, q, u, about, which) for u in (v, v2))
            assert h1 == pytest.approx(h0, abs=1e-12)
        assert ev["released"][f"foot_{old}"]["impulse"] == 0.0
        assert ev["released"][f"foot_{old}"]["normal_velocity_after"] > 0.0


CYCLE_ROWS = {"a_swing": [("foot", "a"), ("knee", "a")], "b_swing": [("foot", "b"), ("knee", "b")],
              "a_locked": [("foot", "a"), ("knee", "a"), ("knee", "b")], "b_locked": [("foot", "b"), ("knee", "a"), ("knee", "b")],
              "a_strike": [("foot", "a"), ("knee", "a"), ("knee", "b")], "b_strike": [("foot", "b"), ("knee", "a"), ("knee", "b")]}


def test_the_cycle_s_stance_forces_and_knee_holds_against_the_kkt_solve(cycle):
    """Every recorded foot force and knee holding moment of the cycle against the reference's KKT solve.
    The stance knee's moment changes sign during its stance (about -0.07 to +0.06 N m): positive, the
    lock pulls the shank towards extension, which a hyperextension stop cannot; this walker's stance
    knee needs a latch that holds both ways."""
    worst, stance_knee = 0.0, []
    for seg in cycle.segments:
        rows = CYCLE_ROWS[seg.configuration]
        labels = list(seg.constraint_labels)
        for i in range(len(seg.t)):
            q, v = floating(seg, i)
            _, lam = kw.constrained_dynamics(CHEN, q, v, rows)
            forces = dict(zip(labels, seg.constraint_forces[i]))
            leg = rows[0][1]
            worst = max(worst, abs(forces[f"foot_{leg}.fx"] - lam[0]), abs(forces[f"foot_{leg}.fy"] - lam[1]))
            for k, row in enumerate(rows[1:], start=2):   # a foot takes multipliers 0 and 1, each knee one
                label = f"knee_{row[1]}.hold"
                if label in forces:
                    worst = max(worst, abs(forces[label] - lam[k]))
                    if row[1] == leg:
                        stance_knee.append(forces[label])
    assert worst < 1e-9
    assert min(stance_knee) < -0.05 and max(stance_knee) > 0.05


def test_a_release_whose_holding_force_is_past_its_value_at_entry_is_named(tmp_path, capsys):
    """Stumble: the trailing knee's unlock written as a reaction guard (its holding moment, tensile from
    the heel strike on: +0.0271 N m) never fires, since a guard fires on a crossing only; the walker went
    on to t_end with the knee locked and nothing said so.  The run's warnings now name the release, the
    force and how far past it is."""
    run = pcmm.simulate(pcmm.load_scene(write_walker(
        tmp_path, W, THETA0, OMEGA0, t_end=0.7, hold_references=True,
        release=lambda stance: {"type": "reaction", "of": f"knee_{stance}", "value": 0.0, "direction": "increasing"})))
    assert [e["name"] for e in run.events] == ["knee strike b", "heel strike b"]
    (note,) = run.stats["warnings"]
    assert note.startswith("t = 0.528819673 s, configuration 'b_strike': the release 'knee a unlocks' watches")
    # how far past: the reference's holding moment of knee a just after the heel strike
    seg = run.segments[2]
    q, v = floating(seg, 0)
    _, lam = kw.constrained_dynamics(W, q, v, ROWS["b_strike"])
    assert f"already {lam[2]:.6g} past that value" in note and lam[2] == pytest.approx(0.0271241, abs=1e-7)
    assert note.endswith('a release meant at the instant the configuration is entered takes guard = { type = "entry" }')
    # and `pcmm run` prints it (the run's warnings reached only the summary and traj.stats)
    from pcmm.cli import main as cli_main

    capsys.readouterr()
    assert cli_main(["run", str(tmp_path / "kneed_walker.toml"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert f"pcmm: warning: {note}" in err


def test_a_knee_stop_let_go_on_the_stance_leg_keeps_the_stance_foot(tmp_path):
    """The knee strike as a stop (e = 0) that merges and lets go where its holding force turns tensile
    (the default unmerge): after the heel strike knee b is the stance knee, and the lock would have to
    pull its shank straight (+0.00586 N m, the reference's KKT solve), so the merge is let go at once.
    It was let go into 'a_swing', the first configuration with knee b free, whose foot a is pinned
    (the foot that just lifted off): the run stopped ("the velocity after the switch violates the
    constraints of 'a_swing': 'foot_a.fx' ..."). Now into the one with foot b pinned, and the foot stays."""
    import tomllib

    from builders import dump_toml

    path = write_walker(tmp_path, W, THETA0, OMEGA0, t_end=0.6, hold_references=True)
    doc = tomllib.loads(path.read_text())
    knee = doc["transitions"][0]
    knee.update(type="stop", restitution=0.0, merge_to=knee.pop("to"))
    path.write_text(dump_toml(doc))
    run = pcmm.simulate(pcmm.load_scene(path))
    assert [(e["name"], e["to"]) for e in run.events] == [
        ("knee strike b", "a_locked"), ("heel strike b", "b_strike"), ("knee strike b", "b_knee_free")]
    ev = run.events[2]
    assert ev["cause"] == "tensile holding force" and ev["t"] == run.events[1]["t"]
    q, v = floating(run.segments[2], 0)
    _, lam = kw.constrained_dynamics(W, q, v, ROWS["b_strike"])
    assert lam[3] == pytest.approx(0.00586032506, abs=1e-10)       # knee b's lock would pull
    anchor = np.asarray(run.events[1]["anchor"]["foot_b"])
    seg = run.segments[-1]
    assert seg.configuration == "b_knee_free"
    for i in range(len(seg.t)):
        qi, _ = floating(seg, i)
        assert np.max(np.abs(kw.foot_position(W, qi, "b") - anchor)) < 1e-9
    assert floating(seg, -1)[0][5] - floating(seg, -1)[0][4] < -1e-3   # the stance knee buckles


def test_point_mass_segments_and_the_knee_s_cut(tmp_path):
    """Stumble: Chen's walker has point-mass segments (no inertia).  Its knee strike stopped the run with
    "configuration 'a_swing': the mass matrix is not positive definite (a link without mass or
    inertia?)", though 'a_swing''s mass matrix is positive definite: the matrix at fault is the cut
    system's, where cutting knee_b frees shank_b, a point mass with no inertia about its centroid.  The
    message now says so and gives the remedy: for a joint stop, cut = [] (the same run); with it the
    point-mass walker's knee strike matches the reference."""
    points = kw.Walker(c_thigh=0.325, i_thigh=0.0, i_shank=0.0)
    with pytest.raises(pcmm.SimulationError) as err:
        pcmm.simulate(pcmm.load_scene(write_walker(tmp_path / "cut", points, THETA0, OMEGA0, t_end=0.6)))
    text = str(err.value)
    assert "transition 'knee strike b': cutting 'knee_b' (its `cut`) frees 'shank_b'" in text and "cut = []" in text
    run = pcmm.simulate(pcmm.load_scene(write_walker(tmp_path / "nocut", points, THETA0, OMEGA0, t_end=0.6,
                                                     knee_cut=False)))
    swing = kw.flight(points, points.swing_bodies(), THETA0, OMEGA0, 1.0, events=[knee_event])
    assert run.events[0]["name"] == "knee strike b"
    assert run.events[0]["t"] == pytest.approx(swing.t_events[0][0], abs=1e-9)
    q, v = floating(run.segments[0], -1)
    _, v2 = floating(run.segments[1], 0)
    v_ref, _ = kw.impact(points, q, v, [("foot", "a"), ("knee", "a"), ("knee", "b")])
    assert np.max(np.abs(v2 - v_ref)) < 1e-10


def test_the_differential_oracle_finds_nothing(tmp_path, step, cycle):
    """The suite's own second route (tests/oracle.py: its own models, locks and KKT solves) on the step
    and on the cycle.  On main it reported knee_b.hold recorded -0.028943 where it solves 0.005860."""
    import oracle

    path = write_walker(tmp_path / "refs", W, THETA0, OMEGA0, t_end=0.6, hold_references=True)
    assert oracle.check_run(path) == []
    assert oracle.check_run(cycle.scene, traj=cycle) == []
