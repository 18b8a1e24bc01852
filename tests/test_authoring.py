"""Authoring a new mechanism without silent traps (issue 13, items 2-5 and 7).

Each trap a new user met gets a test that reproduces it and asserts the new message or
behaviour; the diagnostics are checked by the impulse-momentum balance and by quantities
recomputed from the trajectory."""
from __future__ import annotations

import json
import math

import numpy as np
import pinocchio as pin
import pytest

import builders
import pcmm
import pcmm.cli
from builders import EXAMPLES, URDF_DIR, copy_example, example_text
from pcmm.model.assembly import assemble
from pcmm.run.checks import check_scene
from pcmm.model.mechanism import Mechanism
from pcmm.errors import SceneError, SimulationError
from pcmm.events.momentum import balance
from pcmm.scene.template import FOUR_BAR, four_bar_angles, write_template


def cli(argv):
    try:
        return pcmm.cli.main([str(a) for a in argv])
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 1


def problems_of(path):
    return check_scene(pcmm.load_scene(path))


# ---- check time: the pose at the switch ---------------------------------------------------------
def test_merged_urdf_at_the_wrong_pose_fails_at_check(tmp_path, capsys):
    """Trap: a merged URDF at the wrong pose passed `pcmm check` and failed only at the switch."""
    wrong = (URDF_DIR / "three_bar_config2.urdf").read_text().replace(
        'rpy="0 0 3.141592653589793"', 'rpy="0 0 3.14159"')
    path = copy_example(tmp_path, urdf_texts={"three_bar_config2.urdf": wrong})
    report = problems_of(path)
    assert len(report.problems) == 1
    p = report.problems[0]
    assert p.startswith(f"{path}: transitions[0] (O3 latches).to: at the guard value")
    assert "link 'link3'" in p and "three_bar_config2.urdf" in p
    assert f"angle by {math.pi - 3.14159:.3g} rad" in p  # 2.65e-06, the rounding of pi
    # the CLI: check and run both stop before simulating (exit 2, nothing saved)
    assert cli(["check", path]) == 2
    assert cli(["run", path, "--quiet"]) == 2
    assert "link 'link3'" in capsys.readouterr().err
    assert not list(tmp_path.glob("*partial*"))


def test_examples_and_templates_pass_check():
    for name in ("three_bar.toml", "three_bar_stop.toml", "double_folded.toml"):
        report = problems_of(EXAMPLES / name)
        assert report.problems == [] and report.warnings == [], name
        assert len(report.postures) == 1


# ---- check time: contact points and normal ------------------------------------------------------
def test_rounded_point_blames_the_point_not_the_normal(tmp_path):
    """Trap: a six-digit rounded contact point ran to the merge and died with a message blaming
    the normal.  Now check names the point (and how far apart), and so does the run."""
    text = example_text().replace("point_b = [0.0625, 0.0]", "point_b = [0.062501, 0.0]")
    path = copy_example(tmp_path, scene_text=text)
    report = problems_of(path)
    assert len(report.problems) == 1
    p = report.problems[0]
    assert p.startswith(f"{path}: transitions[0] (O3 latches).contact.point_b: the contact points do not meet")
    assert "1e-06 m apart" in p and "the points are at fault, not the normal" in p
    assert "contact.normal" not in p
    with pytest.raises(SimulationError) as info:  # the run (API: no check first) stops at the merge
        pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=0.3))
    text = info.value.text()
    assert "still move" in text and "the points are at fault, not the normal" in text
    assert "contact normal of the transition does not act" not in text


def test_wrong_but_approaching_normal_is_caught_with_its_angle(tmp_path):
    """Trap: a wrong normal that still approaches was accepted and changed the impulse.
    The check names the angle it is off, and the impulse factor it would cause, which the
    run with that normal indeed shows (P grows by 1/cos of the angle, velocities unchanged)."""
    nx = 0.3
    text = example_text().replace("normal = [0.0, 1.0]", f"normal = [{nx}, 1.0]")
    path = copy_example(tmp_path, scene_text=text)
    report = problems_of(path)
    assert len(report.problems) == 1
    p = report.problems[0]
    off = math.degrees(math.atan(nx))  # 16.6992 deg
    assert p.startswith(f"{path}: transitions[0] (O3 latches).contact.normal: normal [0.3, 1]")
    assert f"is {off:.6g} deg off" in p and "perpendicular to the lever" in p
    factor = 1 / math.cos(math.atan(nx))
    assert f"{100 * (factor - 1):.3g} % too large" in p
    good = pcmm.simulate(pcmm.load_scene(EXAMPLES / "three_bar.toml"), pcmm.RunOptions(t_end=0.2))
    bad = pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=0.2))
    assert bad.events[0]["impulse"]["normal"] == pytest.approx(factor * good.events[0]["impulse"]["normal"], rel=1e-9)
    assert bad.events[0]["omega_after"] == pytest.approx(good.events[0]["omega_after"], rel=1e-9)


def test_normal_pointing_from_b_to_a_is_named(tmp_path):
    text = example_text().replace("normal = [0.0, 1.0]", "normal = [0.0, -1.0]")
    report = problems_of(copy_example(tmp_path, scene_text=text))
    assert len(report.problems) == 1
    assert "contact.normal: normal [0, -1] points from 'link3' to 'link2'" in report.problems[0]
    assert "flip its sign" in report.problems[0]


def test_guard_value_off_the_latch_names_points_and_pose(tmp_path):
    text = example_text().replace("value = 3.141592653589793", 'value = "170 deg"')
    report = problems_of(copy_example(tmp_path, scene_text=text))
    fields = sorted(p.split(": ")[1].split(".")[-1] for p in report.problems)
    assert fields == ["point_b", "to"]


def test_guard_value_outside_joint_limits_warns(tmp_path):
    limited = (URDF_DIR / "three_bar_config1.urdf").read_text().replace(
        '<limit lower="-1e6" upper="1e6" effort="1e6" velocity="1e6"/>\n  </joint>\n  <link name="link3">',
        '<limit lower="-3" upper="3" effort="1e6" velocity="1e6"/>\n  </joint>\n  <link name="link3">')
    assert limited.count('lower="-3"') == 1
    path = copy_example(tmp_path, urdf_texts={"three_bar_config1.urdf": limited})
    report = problems_of(path)
    assert report.problems == []
    assert len(report.warnings) == 1
    w = report.warnings[0]
    assert "transitions[0] (O3 latches).guard.value" in w and "joint 'O3' is at 3.14159265" in w
    assert "outside its URDF limits [-3, 3]" in w


def test_unreachable_loop_guard_warns(tmp_path):
    """The four-bar's coupler-rocker angle stays within [-138, -76] deg (closed form): a latch
    at -60 deg can never fire. pcmm cannot prove that (it says none was found from its starts)."""
    write_template("fb", tmp_path, closed=True)
    path = tmp_path / "fb.toml"
    path.write_text(path.read_text().replace('value = "-90 deg"', 'value = "-60 deg"'))
    report = problems_of(path)
    assert any("guard.value: = -1.04719755" in w and "no posture closing the loop with the guard there was found" in w
               and "the guard never fires" in w for w in report.warnings)


# ---- closed-loop assembly ------------------------------------------------------------------------
def _four_bar(tmp_path, q: str, branch: str | None = '{ between = ["coupler", "rocker"], sign = "-" }'):
    write_template("fb", tmp_path, closed=True, force=True)
    path = tmp_path / "fb.toml"
    text = path.read_text()
    start = text.index("q = { J1")
    text = text[:start] + q + text[text.index("\n", start):]
    text = text.replace('branch = { between = ["coupler", "rocker"], sign = "-" }',
                        f"branch = {branch}" if branch else "")
    path.write_text(text)
    return path


def test_rough_guess_is_not_solved_to_an_angle_far_away(tmp_path):
    """Trap: a rough guess was solved silently to an angle 4 pi away (Newton alone landed
    180 rad away, before each Newton update took whole turns off the dependent angles); the
    assembled angles are within pi of the guess, with a warning that the posture moved, and
    they close the loop."""
    guess = 'q = { J1 = "90 deg", J2 = 0.094573, J3 = 3.60370957 }'
    path = _four_bar(tmp_path, guess, branch=None)
    scene = pcmm.load_scene(path)
    cfg = Mechanism(scene)["open"]
    raw, _ = cfg.coords.project(0.0, np.array([math.pi / 2, 0.094573, 3.60370957]), np.zeros(3), [0])
    assert np.max(np.abs(raw[1:] - [0.094573, 3.60370957])) <= math.pi  # the trap, closed: whole turns are taken off every Newton update (partitioned._nearest_turns)
    q, _, notes = assemble(scene, cfg)
    assert np.all(np.abs(q[1:] - [0.094573, 3.60370957]) <= math.pi)
    note = next(n for n in notes if "assembled away from the given values" in n)
    cut = cfg.spec.cut_joints[0]  # the hint names two links of this scene's loop, not placeholders
    assert f'branch = {{ between = ["{cut.a}", "{cut.b}"], sign = "+" }}' in note
    # the mirrored branch of the closed form: J3 of the other circle intersection is -J3 + ...;
    # whichever it is, it closes the loop
    assert cfg.coords.residual(0.0, q) < 1e-12


def test_branch_picks_the_assembly(tmp_path):
    """branch = sign of the coupler-rocker angle: "-" is the closed form's elbow-up assembly,
    "+" its mirror image about the line A-D (J3 -> -J3 on the mirrored triangle)."""
    j2, j3 = four_bar_angles(math.pi / 2)
    guess = 'q = { J1 = "90 deg", J2 = "10 deg", J3 = "40 deg" }'  # nearer the mirrored branch
    path = _four_bar(tmp_path, guess)
    scene = pcmm.load_scene(path)
    q, _, notes = assemble(scene, Mechanism(scene)["open"])
    assert q[1] == pytest.approx(j2, abs=1e-10) and q[2] == pytest.approx(j3, abs=1e-10)
    note = next(n for n in notes if "assembled away" in n)
    # a branch is given: the hint is about the given values (within pi), not to give a branch
    assert "fix the branch" not in note and "each angle is assembled within pi of its given value" in note
    plus = pcmm.load_scene(_four_bar(tmp_path, guess, branch='{ between = ["coupler", "rocker"], sign = "+" }'))
    qp, _, _ = assemble(plus, Mechanism(plus)["open"])
    assert qp[2] == pytest.approx(-j3, abs=1e-9)  # the mirrored triangle B'CD: the angle at B flips sign
    assert Mechanism(plus)["open"].coords.residual(0.0, qp) < 1e-12


def test_other_branch_nearer_the_guess_is_named(tmp_path):
    guess = 'q = { J1 = "90 deg", J2 = "10 deg", J3 = "40 deg" }'
    scene = pcmm.load_scene(_four_bar(tmp_path, guess, branch=None))
    _, _, notes = assemble(scene, Mechanism(scene)["open"])
    # without a branch, Newton from this guess may land on either; when it lands away from the
    # nearer one, the warning names it
    q_plain, _ = Mechanism(scene)["open"].coords.project(
        0.0, np.array([math.pi / 2, math.radians(10), math.radians(40)]), np.zeros(3), [0])
    if abs(math.remainder(q_plain[2] - math.radians(40), 2 * math.pi)) > 0.05:
        assert any("the loop was assembled away" in n for n in notes)


def test_singular_start_asks_for_approximate_values(tmp_path):
    path = _four_bar(tmp_path, 'q = { J1 = "90 deg", J2 = "0 deg", J3 = "0 deg" }', branch=None)
    scene = pcmm.load_scene(path)
    with pytest.raises(SimulationError, match="give approximate assembly values"):
        assemble(scene, Mechanism(scene)["open"])


def test_branch_with_no_assembly_is_a_scene_error(tmp_path):
    path = _four_bar(tmp_path, 'q = { J1 = "90 deg", J2 = "-71 deg", J3 = "-104 deg" }',
                     branch='{ link = "frame", sign = "+" }')
    scene = pcmm.load_scene(path)
    with pytest.raises(SceneError, match=r"initial.branch: no assembly has angle of frame > 0"):
        assemble(scene, Mechanism(scene)["open"])


def test_bad_branch_sign_is_named(tmp_path):
    path = _four_bar(tmp_path, 'q = { J1 = "90 deg", J2 = "-71 deg", J3 = "-104 deg" }',
                     branch='{ between = ["coupler", "rocker"], sign = "up" }')
    with pytest.raises(SceneError, match=r"initial.branch.sign: = 'up': must be"):
        pcmm.load_scene(path)


# ---- momenta and impulses ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def four_bar_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("fourbar")
    write_template("fb", d, closed=True)
    return pcmm.simulate(pcmm.load_scene(d / "fb.toml"), pcmm.RunOptions(t_end=0.1))


@pytest.fixture(scope="module")
def example_runs(shipped_run):
    return {"three_bar": shipped_run("three_bar.toml", t_end=0.2)[1],
            "double_folded": shipped_run("double_folded.toml", t_end=3.2)[1]}


def test_impulse_momentum_balance_at_every_event(example_runs, four_bar_run):
    """The summary's momenta change by exactly the reported external impulses (1e-12), at every
    event of both examples (1 latch; 46 bounces and the merge) and at the four-bar's latch."""
    counts = {}
    for name, run in {**example_runs, "four_bar": four_bar_run}.items():
        events = json.loads(json.dumps(list(run.events)))  # as the summary JSON holds them
        counts[name] = len(events)
        for ev in events:
            dL, dH = balance(ev)
            assert np.max(np.abs(dL)) < 1e-12 and abs(dH) < 1e-12, (name, ev["t"], dL, dH)
    assert counts == {"three_bar": 1, "double_folded": 47, "four_bar": 1}  # 46 bounces, then the merge
    ev = example_runs["three_bar"].events[0]
    # Example 1: only O1 is external, at the momentum point: angular momentum about O1 is conserved
    assert set(ev["external_impulses"]) == {"joint O1"} and ev["momentum"]["about"] == [0.0, 0.0]
    assert ev["momentum"]["angular_after"] == pytest.approx(0.0950244, abs=1e-7)  # README table
    fb = four_bar_run.events[0]
    assert set(fb["external_impulses"]) == {"joint J1", "cut joint J4"}
    # a locked triangle: nothing moves after the latch (round-off of an impulse of 4.7 N s)
    assert fb["momentum"]["linear_after"] == pytest.approx([0.0, 0.0], abs=1e-13)
    assert fb["kinetic_energy_after"] < 1e-25


def test_momentum_point_is_settable(tmp_path, example_runs):
    text = example_text().replace('initial_configuration = "config1"',
                                  'initial_configuration = "config1"\nmomentum_point = ["0.25", "0.0"]')
    run = pcmm.simulate(pcmm.load_scene(copy_example(tmp_path, scene_text=text)), pcmm.RunOptions(t_end=0.2))
    ev, ref = run.events[0], example_runs["three_bar"].events[0]
    L = np.array(ref["momentum"]["linear_before"])
    assert ev["momentum"]["about"] == [0.25, 0.0]
    # H_O' = H_O - (O' - O) x L
    assert ev["momentum"]["angular_before"] == pytest.approx(
        ref["momentum"]["angular_before"] - 0.25 * L[1], abs=1e-14)
    dL, dH = balance(ev)
    assert abs(dH) < 1e-12


def test_constraint_impulse_sign_by_the_plate_momentum(example_runs):
    """constraint_impulses["C"] is the impulse on link b (the plate, link3) from link a, at point_b.
    With the joint impulse of D (on the plate from the slider), it is all that acts on the plate:
    the plate's own momentum changes by their sum (linear) and moment (about its D pivot)."""
    run = example_runs["double_folded"]
    ev = run.events[0]
    scene = pcmm.load_scene(EXAMPLES / "double_folded.toml")
    cfg = Mechanism(scene)["config1"]
    seg = run.segments[0]
    q = seg.q[-1]
    names = cfg.joint_names
    vb = np.array([ev["v_before"][n] for n in names])
    va = np.array([ev["v_after"][n] for n in names])

    def plate(v):
        pin.forwardKinematics(cfg.model, cfg.data, cfg.to_pin(q), v)
        jid = cfg.joint_id["D"]
        h = cfg.data.oMi[jid].act(cfg.model.inertias[jid] * cfg.data.v[jid])
        return np.asarray(h.linear[:2]), float(h.angular[2]), cfg.data.oMi[jid].translation[:2].copy()
    (Lb, Hb, pD), (La, Ha, _) = plate(vb), plate(va)
    C = np.array(ev["constraint_impulses"]["C"])
    D = np.array(ev["joint_impulses"]["D"])
    cfg.kinematics(q)
    pC = cfg.point_position(cfg.point("link3", (0.09, 0.0)))
    np.testing.assert_allclose(La - Lb, C[:2] + D[:2], atol=1e-13)
    arm = lambda r, f: r[0] * f[1] - r[1] * f[0]  # noqa: E731
    assert (Ha - Hb) == pytest.approx(arm(pC, C) + C[2] + arm(pD, D) + D[2], abs=1e-13)


# ---- the comparison run without impact ---------------------------------------------------------------
def test_no_impact_record_matches_the_trajectory():
    """Trap: a 0-DOF target (Example 2's locked slider with the driven crank) reported velocities
    the trajectory does not have."""
    run = pcmm.simulate(pcmm.load_scene(EXAMPLES / "double_folded.toml"), pcmm.RunOptions(impact=False, t_end=3.1))
    ev = run.events[0]
    after = run.segments[1]
    assert after.configuration == "config2"
    for i, name in enumerate(after.coordinates):
        assert ev["v_after"][name] == pytest.approx(after.v[0, i], abs=1e-12)
    assert ev["kinetic_energy_after"] == pytest.approx(after.kinetic[0], rel=1e-12)
    assert ev["kinetic_energy_change"] == pytest.approx(ev["kinetic_energy_after"] - ev["kinetic_energy_before"],
                                                        abs=1e-18)
    # the energy falls; the one warning names the kept rates the merged loop changes (B, D)
    assert ev["kinetic_energy_change"] < 0 and len(ev["warnings"]) == 1 and "raises" not in ev["warnings"][0]
    assert set(ev["changed_velocities"]) == {"B", "D"}
    for link, w in ev["omega_after"].items():
        assert w == pytest.approx(after.omega[0, after.links.index(link)], abs=1e-12)


def test_no_impact_switch_that_raises_energy_warns():
    from pcmm.events.records import event_record
    from pcmm.events.impulse import no_impulse
    scene = pcmm.load_scene(EXAMPLES / "three_bar.toml")
    cfg = Mechanism(scene)["config1"]
    q, v = np.array([0.3, -0.2, 2.0]), np.array([1.0, -1.0, 2.0])
    imp = no_impulse(cfg, q, v, 1.5 * v, scene.transitions[0].contact)
    ev = event_record(cfg, scene.transitions[0], 0.1, "config2", True, imp, q=q)
    assert ev["kinetic_energy_change"] == pytest.approx(1.25 * ev["kinetic_energy_before"], rel=1e-12)
    assert len(ev["warnings"]) == 1 and "raises the kinetic energy" in ev["warnings"][0]


# ---- runs that end without the expected event --------------------------------------------------------
def test_closest_approach_when_the_latch_never_fires(tmp_path):
    text = example_text().replace("value = 3.141592653589793", 'value = "-90 deg"').replace(
        'direction = "increasing"', 'direction = "decreasing"')
    path = copy_example(tmp_path, scene_text=text)
    run = pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=0.5))
    assert run.events == []
    (rec,) = run.stats["closest_approach"]
    rel = run.series("theta", "link3") - run.series("theta", "link2")
    d = np.abs(rel + math.pi / 2)
    i = int(np.argmin(d))  # the angle starts at 0 and opens: its nearest sample to -90 deg is the first
    assert i == 0 and rec["t"] == 0.0 and rec["closest"] == pytest.approx(0.0, abs=1e-15)
    assert rec["distance"] == pytest.approx(math.pi / 2, abs=1e-15) and rec["last_fired"] is None


def test_closest_approach_is_measured_between_long_steps(tmp_path):
    """A bar released at rest 0.6 rad from hanging swings to 0.6 rad on the other side (energy
    conservation: no force but gravity); a stop 0.61 rad out is never reached. The closest approach
    is that turning point, -pi/2 - 0.6, found on the dense output between two long steps, where the
    nearest recorded step alone is far off (asserted, so the refinement is what is tested)."""
    turn = -math.pi / 2 - 0.6
    path = builders.pendulum(tmp_path, 0.5, qs=turn - 0.01, q0=-math.pi / 2 + 0.6, t_end=1.2)
    run = pcmm.simulate(pcmm.load_scene(path))
    assert run.events == []
    (rec,) = run.stats["closest_approach"]
    step_error = float(np.min(np.abs(run.segments[0].q[:, 0] - turn)))
    assert step_error > 1e-6, "the steps land near the turning point: the refinement goes untested"
    assert rec["closest"] == pytest.approx(turn, abs=1e-9)
    assert rec["distance"] == pytest.approx(0.01, abs=1e-9)
    # the half period of the compound pendulum at this amplitude, by quadrature of the energy integral
    from scipy.integrate import quad
    L, g = 0.6, builders.G
    w2 = 1.5 * g / L  # m g (L/2) / (m L^2 / 3)
    half = 2 * quad(lambda x: 1 / math.sqrt(2 * w2 * (math.cos(x) - math.cos(0.6))), 0, 0.6, limit=200)[0]
    assert rec["t"] == pytest.approx(half, abs=1e-6)


def test_cli_says_why_the_run_ended_without_its_event(tmp_path, capsys):
    """The template arm with its motor reversed never latches: the CLI and the summary say how
    close the latch came (the relative angle's largest value, read off the trajectory)."""
    write_template("arm", tmp_path)
    path = tmp_path / "arm.toml"
    path.write_text(path.read_text().replace("value = 0.5", "value = -0.5"))
    S, T = tmp_path / "s.json", tmp_path / "t.npz"
    assert cli(["run", path, "--t-end", "0.3", "--summary", S, "--out", T]) == 0
    captured = capsys.readouterr()
    assert "no configuration transformation before t_end" in captured.out
    assert ("pcmm: warning: guard of 'J3 latches' (angle link3 - link2 increasing to 0.523598776) did not fire: "
            "closest") in captured.err  # a warning: on stderr, where --quiet does not hide it
    rec = json.loads(S.read_text())["closest_approach"][0]
    run = pcmm.Trajectory.load(T)
    rel = run.series("theta", "link3") - run.series("theta", "link2")
    assert rec["closest"] == pytest.approx(rel[int(np.argmin(np.abs(rel - math.pi / 6)))], abs=1e-12)


# ---- templates ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv", [[], ["--links", "2"], ["--links", "5"], ["--closed"]])
def test_new_writes_a_scene_that_checks_and_runs(tmp_path, argv, capsys):
    assert cli(["new", "demo", "--dir", tmp_path, *argv]) == 0
    scene = tmp_path / "demo.toml"
    assert cli(["check", scene]) == 0
    assert "1 transition, 1 force element; poses and contacts consistent at 1 guard value)" in capsys.readouterr().out
    summary = tmp_path / "s.json"
    assert cli(["run", scene, "--t-end", "0.3", "--quiet", "--summary", summary]) == 0
    d = json.loads(summary.read_text())
    assert [e["transition"] for e in d["events"]] == ["latch"] and d["configuration_final"] == "latched"
    assert d["warnings"] == []
    ev = d["events"][0]
    assert abs(ev["normal_velocity"]["after"]) < 1e-12  # the latch's plastic lock
    # the templates' files refuse to be overwritten
    assert cli(["new", "demo", "--dir", tmp_path, *argv]) == 2


def test_new_refuses_bad_arguments(tmp_path, capsys):
    assert cli(["new", "x", "--dir", tmp_path, "--links", "1"]) == 2
    assert cli(["new", "x", "--dir", tmp_path, "--closed", "--links", "4"]) == 2
    assert cli(["new", "../x", "--dir", tmp_path]) == 2
    assert cli(["new", "x", "--dir", tmp_path / "nope"]) == 2
    err = capsys.readouterr().err
    assert "at least 2 links" in err and "four-bar" in err and "folder does not exist" in err


def test_four_bar_template_assembles_on_the_closed_form():
    """The template's initial guess (rounded degrees) assembles onto the closed-form posture."""
    j2, j3 = four_bar_angles(math.pi / 2)
    d, a, b, c = (FOUR_BAR[k] for k in "dabc")
    # independent check of the closed form: the rocker's far end lands on the frame point D
    th1, th2 = math.pi / 2, math.pi / 2 + j2
    th3 = th2 + j3
    x = a * math.cos(th1) + b * math.cos(th2) + c * math.cos(th3)
    y = a * math.sin(th1) + b * math.sin(th2) + c * math.sin(th3)
    assert (x, y) == pytest.approx((d, 0.0), abs=1e-14)


def test_six_digit_stop_point_is_reported_as_the_point(tmp_path):
    """A stop on the frame at q = -30 deg with the frame's contact point typed to six digits
    (0.519615, -0.3 for 0.6 (cos, sin)(-30 deg)): check blames the point, by its distance, and not
    the normal, which is exact; written as an expression the same scene is clean."""
    path = builders.pendulum(tmp_path, 0.5, qs=-math.pi / 6)
    exact = path.read_text()
    assert "0.5196152422706632" in exact
    path.write_text(exact.replace("0.5196152422706632", "0.519615"))
    report = problems_of(path)
    assert len(report.problems) == 1 and "contact.point_b: the contact points do not meet" in report.problems[0]
    gap = 0.6 * math.cos(math.pi / 6) - 0.519615  # 2.4e-7 m, along the bar, across the normal
    assert f"{gap:.3g} m apart" in report.problems[0] and "normal" not in report.problems[0].split("(")[0]
    path.write_text(exact.replace("0.5196152422706632", '"0.6*cos(-30 deg)"').replace(
        "-0.29999999999999993", '"0.6*sin(-30 deg)"'))
    assert problems_of(path).problems == []


def test_run_time_separating_stop_names_the_flipped_normal(tmp_path):
    """Through the API (no check first), a stop whose normal points from b to a stops at the guard
    with the check's own diagnosis: the normal, flipped."""
    text = example_text("three_bar_stop.toml").replace("normal = [0.0, 1.0]", "normal = [0.0, -1.0]")
    assert "normal = [0.0, -1.0]" in text
    path = copy_example(tmp_path, "three_bar_stop.toml", scene_text=text)
    with pytest.raises(SimulationError) as info:
        pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=0.3))
    msg = info.value.text()
    assert "the contact is separating" in msg
    assert "contact.normal: normal [0, -1] points from 'link3' to 'link2'" in msg and "flip its sign" in msg


def test_driven_joint_keeps_its_drive_value(tmp_path):
    """Example 2 with the coupler's guess 4 pi off: it is assembled 4 pi off too, i.e. the same
    posture within pi of the guess.  With the crank's guess 2 pi off its drive value the drive
    wins (pi at t = 0): a driven angle is never moved by 2 pi k."""
    base = (EXAMPLES / "double_folded.toml").read_text().replace('"../urdf/', f'"{URDF_DIR}/')
    ref_scene = pcmm.load_scene(EXAMPLES / "double_folded.toml")
    q_ref, _, _ = assemble(ref_scene, Mechanism(ref_scene)["config1"])
    for old, new in (("B = -3.459398", 'B = "-3.459398 + 4*pi"'), ("A = 3.141592653589793", 'A = "3*pi"')):
        path = tmp_path / "df.toml"
        path.write_text(base.replace(old, new))
        scene = pcmm.load_scene(path)
        cfg = Mechanism(scene)["config1"]
        q, _, _ = assemble(scene, cfg)
        iA, iB = cfg.joint_slice["A"].start, cfg.joint_slice["B"].start
        assert q[iA] == pytest.approx(math.pi, abs=1e-12)
        assert cfg.coords.residual(0.0, q) < 1e-12
        if new.startswith("B"):
            assert q[iB] == pytest.approx(q_ref[iB] + 4 * math.pi, abs=1e-9)


# ---- [initial] v of a closed loop: the constraints fix the dependent and driven velocities ----------------------------
def _example2_with_v(tmp_path, v: str):
    text = (EXAMPLES / "double_folded.toml").read_text().replace("../urdf/", f"{URDF_DIR}/")
    assert "v = { D = 0.0 }" in text
    path = tmp_path / "v.toml"
    path.write_text(text.replace("v = { D = 0.0 }", v))
    scene = pcmm.load_scene(path)
    return scene, Mechanism(scene)["config1"]


def test_given_dependent_velocities_that_the_loop_forbids_are_replaced_and_said(tmp_path):
    """Example 2 as shipped before: B and E given at rest. The loop and the drive (A' = pi/5)
    fix them: B' = -0.363742, E' = 0.0165351 rad/s and m/s, which satisfy Phi_q v + Phi_t = 0."""
    scene, cfg = _example2_with_v(tmp_path, "v = { A = 0.6283185307179586, B = 0.0, D = 0.0, E = 0.0 }")
    q, v, notes = assemble(scene, cfg)
    (note,) = [n for n in notes if "velocities" in n]
    assert "B given 0, now -0.363742" in note and "E given 0, now 0.0165351" in note
    assert "kept as given: D" in note and "A given" not in note  # A's given value is its drive's
    _, Jq, _ = cfg.coords._phi(0.0, q)
    np.testing.assert_allclose(Jq @ v + cfg.coords._phi_t(0.0), 0.0, atol=1e-12)  # an independent check
    assert v[cfg.joint_slice["A"].start] == pytest.approx(math.pi / 5, abs=1e-15)
    # the same state as from the shipped scene, which gives only D's
    scene2, cfg2 = _example2_with_v(tmp_path, "v = { D = 0.0 }")
    q2, v2, notes2 = assemble(scene2, cfg2)
    assert not [n for n in notes2 if "velocit" in n]
    np.testing.assert_allclose(v2, v, rtol=0, atol=1e-15)


def test_an_independent_velocity_left_out_starts_at_rest_and_is_said(tmp_path):
    scene, cfg = _example2_with_v(tmp_path, "v = { A = 0.6283185307179586 }")
    q, v, notes = assemble(scene, cfg)
    assert any("initial.v has no value for D" in n and "starts at rest" in n for n in notes), notes
    assert v[cfg.joint_slice["D"].start] == 0.0


def test_a_tree_still_needs_every_velocity(tmp_path):
    path = copy_example(tmp_path, "three_bar.toml", example_text().replace("v = {", "v = { O9 = 0.0,", 1))
    with pytest.raises(SceneError, match="initial.v.O9"):
        pcmm.load_scene(path)
    text = example_text()
    start = text.index("v = {")
    end = text.index("}", start)
    path = copy_example(tmp_path, "three_bar.toml", text[:start] + "v = { O1 = 0.0 }" + text[end + 1:])
    with pytest.raises(SceneError, match="has no value; give every movable joint"):
        pcmm.load_scene(path)


def test_a_guard_crossed_against_its_direction_says_so(tmp_path):
    """Example 1's latch written `decreasing`: O3's angle goes up through pi at t_p = 0.1672851 s
    (the latch instant of the shipped scene), so the message names that crossing and `direction`,
    not a distance "past it"."""
    text = example_text().replace('value = 3.141592653589793, direction = "increasing"',
                                  'value = 3.141592653589793, direction = "decreasing"')
    assert 'direction = "decreasing"' in text
    traj = pcmm.simulate(copy_example(tmp_path, "three_bar.toml", text), pcmm.RunOptions(t_end=0.3))
    assert traj.events == []
    (rec,) = traj.stats["closest_approach"]
    assert rec["crossed_against"] == pytest.approx(0.16728511518199546, abs=1e-4)  # linear between samples
    from pcmm.run.approach import describe
    assert "crossed 3.14159265 increasing at t = 0.1672" in describe([rec]) and "check `direction`" in describe([rec])


def test_a_timer_the_run_was_not_there_for_says_so(tmp_path):
    """A release from Example 1's latched configuration timed at 0.1 s, before the latch at
    0.167 s: it never fires, and the run says why instead of ending silently locked."""
    text = example_text() + (
        '\n[[transitions]]\nname = "early release"\ntype = "release"\nfrom = "config2"\nto = "config1"\n'
        'guard = { type = "time", at = 0.1 }\n')
    traj = pcmm.simulate(copy_example(tmp_path, "three_bar.toml", text), pcmm.RunOptions(t_end=0.3))
    assert [e["name"] for e in traj.events] == ["O3 latches"]
    (rec,) = traj.stats["closest_approach"]
    from pcmm.run.approach import describe
    message = describe([rec])
    assert message.startswith("time guard of 'early release' (at = 0.1 s) did not fire: the run entered 'config2' "
                              "at t = 0.167285115 s, after it")
