"""The scene loader refuses what it would otherwise run wrong (task h-loader3).

Each row writes a small mechanism of tests/builders.py (a pendulum on a stop, a torque-driven
slider-crank on a stop, a four-bar with a latch and a timed release), edits one thing in its
TOML document, and asserts that ``pcmm.load_scene`` refuses it with one message naming the file,
the field and the value, and that ``pcmm check`` and ``pcmm run`` say the same on standard
error with the scene-error status 2 and no traceback, writing nothing.  What each input did
before (pcmm at 1544be0) is in its row's comment: a silent run, a misleading message far from the
cause, NaN impulses or a traceback.
"""
from __future__ import annotations

import copy
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import builders
import pcmm
import pcmm.cli
from pcmm.errors import SceneError

ROOT = Path(__file__).resolve().parent.parent
SCENE_ERROR = 2  # pcmm.errors.SceneError.exit_code


# ---- the mechanisms ------------------------------------------------------------------------------
def pendulum(folder: Path) -> Path:
    """A bar on revolute J1 falling onto a frame stop at J1 = -pi/2 (e = 0.5) that merges it into
    'rest'; a spring on J1 while it swings."""
    return builders.pendulum(folder, 0.5, k=1.0, spring_configurations=["c1"])


def bare_pendulum(folder: Path) -> Path:
    """The pendulum with no transition and no force (configurations 'c1' and 'rest')."""
    return builders.pendulum(folder, None)


def slider_crank(folder: Path) -> Path:
    """A torque-driven slider-crank (loop closed by the revolute cut joint C) whose slider strikes a
    stop and merges into 'locked'."""
    return builders.slider_crank_stop(folder, 0.5)


def four_bar(folder: Path) -> Path:
    """A four-bar (chain J1-J2-J3 closed by the cut joint D) that latches at J3 = -1.5 into 'latched'
    (derived: J3 locked) and is let go at t = 0.8 s."""
    return builders.four_bar_latch(folder)


def free_bar(folder: Path) -> Path:
    """A bar (1 kg, 0.5 m) on a URDF planar joint P (x, y, theta) from the frame, falling from y = 1."""
    doc = builders.base_doc("free_bar", "c", {"c": "bar.urdf"}, {"P": [0.0, 1.0, 0.0]}, {"P": [0.0, 0.0, 0.0]})
    return builders.write_scene(folder, doc, {"bar.urdf": builders.free_bar_urdf(1.0, 0.5)})


MECHANISMS = {"pendulum": pendulum, "bare_pendulum": bare_pendulum, "slider_crank": slider_crank,
              "four_bar": four_bar, "free_bar": free_bar}


# ---- the edits -----------------------------------------------------------------------------------
def cut_joint_twice(doc):  # before: valid with a redundancy warning, then NaN impulses at the strike
    cuts = doc["configurations"]["free"]["cut_joints"]
    cuts.append(copy.deepcopy(cuts[0]))


def cut_joint_twice_elsewhere(doc):  # before: "its 4 constraint rows (D.fx, D.fy, D.fx, D.fy) ... violated"
    cuts = doc["configurations"]["open"]["cut_joints"]
    other = copy.deepcopy(cuts[0])
    other["point_a"] = [0.25, 0.0]
    cuts.append(other)


def transition_twice(doc):  # before: accepted, both stops keyed by one name
    doc["transitions"].append(copy.deepcopy(doc["transitions"][0]))


def force_twice(doc):  # before: accepted, one series for two elements
    doc["forces"].append({"name": "spring", "type": "damper", "on": {"joint": "J1"},
                          "measure": {"joint": "J1"}, "c": 0.1, "configurations": ["c1"]})


def joint_cut_twice(doc):  # before: check valid; run: numpy.linalg.LinAlgError traceback (three-bar latch)
    doc["transitions"][0]["cut"] = ["P", "P"]


def independent_twice(doc):  # before: accepted
    doc["initial"]["independent"] = ["J1", "J1"]


def force_in_no_configuration(doc):  # before: [] read as "every configuration": the spring acted in both
    doc["forces"][0]["configurations"] = []


def drive_in_no_configuration(doc):  # before: [] read as every one: "joint is fixed in configuration 'rest'"
    doc["drives"] = [{"joint": "J1", "coefficients": [0.0, 1.0], "configurations": []}]


def force_configuration_twice(doc):  # before: accepted
    doc["forces"][0]["configurations"] = ["c1", "c1"]


def joint_driven_twice(doc):  # before: "the constraints are singular at t = 0 s ... the cut joints are redundant"
    doc["drives"] = [{"joint": "J1", "coefficients": [0.0, 1.0], "configurations": ["c1"]},
                     {"joint": "J1", "coefficients": [0.0, 2.0], "configurations": ["c1"]}]


def spring_between_one_link(doc):  # before: accepted; the spring measured 0 at all times
    doc["forces"][0]["measure"] = {"between": ["link1", "link1"]}
    doc["forces"][0]["on"] = {"link": "link1"}


def guard_between_one_link(doc):  # before: a warning "no posture reaching it", then a guard that never fires
    doc["transitions"][0]["guard"] = {"type": "coordinate", "measure": {"between": ["link2", "link2"]},
                                      "value": 0.5, "direction": "increasing"}
    doc["transitions"][0]["contact"] = {"joint": "J3"}


def when_between_one_link(doc):  # before: accepted, the region test constant
    doc["transitions"][0]["guard"]["when"] = {"measure": {"between": ["link1", "link1"]}, "above": 0.0}


def branch_between_one_link(doc):  # before: "no assembly has angle link3 - link3 > 0 (... 0, 0, 0 ...)"
    doc["initial"]["branch"] = {"between": ["link3", "link3"], "sign": "+"}


def torque_on_frame(doc):  # before: accepted; a torque conjugate to the frame's angle does nothing
    doc["forces"] = [{"name": "motor", "type": "torque", "on": {"link": "frame"}, "value": 2.0}]


def cut_joint_on_one_link(doc):  # before: "at t = 0 s its 2 constraint rows (D.fx, D.fy) are of rank 1 ..."
    doc["configurations"]["open"]["cut_joints"][0]["a"] = "link3"


def cut_joint_named_as_joint(doc):  # before: accepted; a transition's cut = ["J2"] read as the cut joint
    doc["configurations"]["open"]["cut_joints"][0]["name"] = "J2"


def latch_to_itself(doc):  # before: check valid; run: "more than 10000 events by t = ... (last: 'latch')"
    doc["transitions"][0]["to"] = "open"


def stop_merging_into_itself(doc):  # before: accepted; the "merge" left the bar free on the stop
    doc["transitions"][0]["merge_to"] = "c1"


def start_on_a_coordinate_guard(doc):  # before: accepted and ignored (start is a periodic time guard's)
    doc["transitions"][0]["guard"]["start"] = 0.3


def start_with_at(doc):  # before: accepted and ignored (a time guard with at fires at at)
    doc["transitions"][1]["guard"]["start"] = 0.3


def angle_of_no_vector(doc):  # before: accepted as 0 (math.atan2(0.0, 0.0); of -0.0, -0.0 it is -pi)
    doc["initial"]["q"]["J1"] = "atan2(0, 1 - 1)"


def stop_named_as_another_joint(doc):  # before: accepted; its hold 'A.hold' read as joint A's, and a
    doc["transitions"][0]["name"] = "A"   # reaction guard of = "A" was told A "moves freely"


def push_on_a_planar_joint(doc):  # before: accepted as a force along P.x alone (x = t^2/2 at 1 N, 1 kg)
    doc["forces"] = [{"name": "push", "type": "torque", "on": {"joint": "P"}, "value": 1.0}]


def drive_of_a_planar_joint(doc):  # before: accepted as a drive of P.x alone (x = t), y and theta free
    doc["drives"] = [{"joint": "P", "coefficients": [0.0, 1.0]}]


def reaction_on_a_stop_that_never_merges(doc):  # before: accepted; the guard could never fire
    bump = copy.deepcopy(doc["transitions"][0])
    bump["name"] = "bump"
    del bump["merge_to"]
    doc["transitions"].append(bump)
    doc["transitions"].append({"name": "lift", "type": "release", "from": "rest", "to": "c1",
                               "guard": {"type": "reaction", "of": "bump", "value": 0.0, "direction": "decreasing"}})


def branch_of_a_tree(doc):  # before: accepted and ignored (a tree has one assembly: q as given)
    doc["initial"]["branch"] = {"joint": "J1", "sign": "-"}


def accumulation_on_a_latch(doc):  # before: accepted and ignored (a latch has no bounces)
    doc["transitions"][0]["accumulation_speed"] = 0.01


def reaction_on_a_name_of_two(doc):  # before: read as cut joint C: "the cut joint needs contact = { normal }"
    doc["transitions"][0]["name"] = "C"
    doc["transitions"].append({"name": "let go", "type": "release", "from": "locked", "to": "free",
                               "guard": {"type": "reaction", "of": "C", "value": 0.0, "direction": "decreasing"}})


def unnamed_force(doc):  # before: accepted; a series named ""
    doc["forces"][0]["name"] = ""


def unnamed_transition(doc):  # before: accepted; events named ""
    doc["transitions"][0]["name"] = ""


def unnamed_cut_joint(doc):  # before: accepted; constraint forces ".fx", ".fy"
    doc["configurations"]["open"]["cut_joints"][0]["name"] = " "


# (mechanism, edit, fragments of the one message: the field and the value, and why)
ROWS = [
    pytest.param("slider_crank", cut_joint_twice,
                 ["configurations.free.cut_joints[1] (C).name: = 'C': already the name of "
                  "configurations.free.cut_joints[0] (C)", "distinct names"], id="cut-joint-name-twice"),
    pytest.param("four_bar", cut_joint_twice_elsewhere,
                 ["configurations.open.cut_joints[1] (D).name: = 'D': already the name of "
                  "configurations.open.cut_joints[0] (D)"], id="cut-joint-name-twice-other-point"),
    pytest.param("pendulum", transition_twice,
                 ["transitions[1] (stop).name: = 'stop': already the name of transitions[0] (stop)",
                  "each transition needs its own name"], id="transition-name-twice"),
    pytest.param("pendulum", force_twice,
                 ["forces[1] (spring).name: = 'spring': already the name of forces[0] (spring)",
                  "overwrite the first's series"], id="force-name-twice"),
    pytest.param("slider_crank", joint_cut_twice,
                 ["transitions[0] (stop).cut: = ['P', 'P']: names P more than once"], id="joint-cut-twice"),
    pytest.param("four_bar", independent_twice,
                 ["initial.independent: = ['J1', 'J1']: names J1 more than once"], id="independent-twice"),
    pytest.param("pendulum", force_in_no_configuration,
                 ["forces[0] (spring).configurations: = []: an empty list names no configuration",
                  "leave configurations out for every configuration"], id="force-configurations-empty"),
    pytest.param("bare_pendulum", drive_in_no_configuration,
                 ["drives[0].configurations: = []: an empty list names no configuration"],
                 id="drive-configurations-empty"),
    pytest.param("pendulum", force_configuration_twice,
                 ["forces[0] (spring).configurations: = ['c1', 'c1']: names c1 more than once"],
                 id="force-configuration-twice"),
    pytest.param("bare_pendulum", joint_driven_twice,
                 ["drives[1].joint: = 'J1': already driven by drives[0] in configuration 'c1'"],
                 id="joint-driven-twice"),
    pytest.param("pendulum", spring_between_one_link,
                 ["forces[0] (spring).measure.between: = ['link1', 'link1']: names 'link1' twice",
                  "0 at all times"], id="spring-between-one-link"),
    pytest.param("four_bar", guard_between_one_link,
                 ["transitions[0] (latch).guard.measure.between: = ['link2', 'link2']: names 'link2' twice"],
                 id="guard-between-one-link"),
    pytest.param("pendulum", when_between_one_link,
                 ["transitions[0] (stop).guard.when.measure.between: = ['link1', 'link1']: names 'link1' twice"],
                 id="when-between-one-link"),
    pytest.param("four_bar", branch_between_one_link,
                 ["initial.branch.between: = ['link3', 'link3']: names 'link3' twice"], id="branch-between-one-link"),
    pytest.param("bare_pendulum", torque_on_frame,
                 ["forces[0] (motor).on.link: = 'frame': the frame (the root of p.urdf) does not move",
                  "does nothing"], id="torque-on-frame"),
    pytest.param("four_bar", cut_joint_on_one_link,
                 ["configurations.open.cut_joints[0] (D).b: = 'link3': a and b are the same link",
                  "closes no loop"], id="cut-joint-a-is-b"),
    pytest.param("four_bar", cut_joint_named_as_joint,
                 ["configurations.open.cut_joints[0] (J2).name: = 'J2': also a joint of fb.urdf"],
                 id="cut-joint-named-as-urdf-joint"),
    pytest.param("four_bar", latch_to_itself,
                 ["transitions[0] (latch).to: = 'open': the configuration the latch is watched in (from)"],
                 id="latch-to-its-own-configuration"),
    pytest.param("pendulum", stop_merging_into_itself,
                 ["transitions[0] (stop).merge_to: = 'c1': the configuration the stop is watched in (from)"],
                 id="stop-merging-into-its-own-configuration"),
    pytest.param("pendulum", start_on_a_coordinate_guard,
                 ["transitions[0] (stop).guard.start: not used by a coordinate guard"], id="start-on-a-coordinate-guard"),
    pytest.param("four_bar", start_with_at,
                 ["transitions[1] (let go).guard.start: only used with every"], id="start-with-at"),
    pytest.param("pendulum", angle_of_no_vector,
                 ["initial.q.J1: = 'atan2(0, 1 - 1)': at position 1: atan2(0, 0): the zero vector has no angle"],
                 id="atan2-of-zero"),
    pytest.param("slider_crank", stop_named_as_another_joint,
                 ["transitions[0] (A).name: = 'A': also a joint of free.urdf, which this stop's merge does not lock "
                  "(it locks P)"], id="stop-named-as-a-joint-it-does-not-lock"),
    pytest.param("free_bar", push_on_a_planar_joint,
                 ["forces[0] (push).on.joint: = 'P': a planar joint has three coordinates (x, y, theta)",
                  "it was read as P.x alone"], id="force-on-a-planar-joint"),
    pytest.param("free_bar", drive_of_a_planar_joint,
                 ["drives[0].joint: = 'P': a planar joint has three coordinates (x, y, theta)",
                  "a drive prescribes one coordinate"], id="drive-of-a-planar-joint"),
    pytest.param("pendulum", reaction_on_a_stop_that_never_merges,
                 ["transitions[2] (lift).guard.of: = 'bump': a stop without merge_to never merges"],
                 id="reaction-on-a-stop-that-never-merges"),
    pytest.param("pendulum", branch_of_a_tree,
                 ["initial.branch: configuration 'c1' has no loop (no cut_joints)"], id="branch-of-a-tree"),
    pytest.param("four_bar", accumulation_on_a_latch,
                 ["transitions[0] (latch).accumulation_speed: not used by a latch"], id="accumulation-on-a-latch"),
    pytest.param("slider_crank", reaction_on_a_name_of_two,
                 ["transitions[1] (let go).guard.of: = 'C': names both a cut joint of 'locked' and a stop transition"],
                 id="reaction-on-a-cut-joint-and-stop-of-one-name"),
    pytest.param("pendulum", unnamed_force,
                 ["forces[0].name: = '': must not be empty"], id="force-without-name"),
    pytest.param("pendulum", unnamed_transition,
                 ["transitions[0].name: = '': must not be empty"], id="transition-without-name"),
    pytest.param("four_bar", unnamed_cut_joint,
                 ["configurations.open.cut_joints[0] ( ).name: = ' ': must not be empty"], id="cut-joint-without-name"),
]


def hostile(tmp_path: Path, mechanism: str, edit) -> Path:
    path = MECHANISMS[mechanism](tmp_path)
    doc = tomllib.loads(path.read_text())
    edit(doc)
    path.write_text(builders.dump_toml(doc))
    return path


@pytest.mark.parametrize("mechanism", sorted(MECHANISMS))
def test_the_unedited_mechanisms_load(tmp_path, mechanism):
    """The control: each row's mechanism as built is accepted, so its edit is what is refused."""
    scene = pcmm.load_scene(MECHANISMS[mechanism](tmp_path))
    assert scene.configurations


def test_a_stop_named_as_the_joint_it_locks_loads(tmp_path):
    """The control of the row above: the pendulum's stop named J1, the joint its merge into 'rest'
    locks, names one thing (its hold, J1.hold, is J1's), and loads."""
    path = pendulum(tmp_path)
    doc = tomllib.loads(path.read_text())
    doc["transitions"][0]["name"] = "J1"
    path.write_text(builders.dump_toml(doc))
    assert pcmm.load_scene(path).transitions[0].name == "J1"


@pytest.mark.parametrize("mechanism, edit, fragments", ROWS)
def test_refused_with_one_located_message(tmp_path, capsys, mechanism, edit, fragments):
    path = hostile(tmp_path, mechanism, edit)
    with pytest.raises(SceneError) as info:
        pcmm.load_scene(path)
    problems = info.value.problems
    assert len(problems) == 1, problems  # the cause alone, not its consequences too
    for fragment in fragments:
        assert f"{path}: {fragments[0]}" in problems[0] and fragment in problems[0], problems[0]
    # the command line: the same message, status 2, no traceback, no output file
    summary = tmp_path / "out.json"
    for argv in (["check", str(path)], ["run", str(path), "--quiet", "--summary", str(summary)]):
        assert pcmm.cli.main(argv) == SCENE_ERROR, argv
        out, err = capsys.readouterr()
        assert f"{path}: {fragments[0]}" in err and "Traceback" not in err, err
        assert out == ""
    assert not summary.exists()


def test_the_command_line_prints_no_traceback(tmp_path):
    """As a user runs it (``python -m pcmm.cli``): the joint cut twice, which ended a run in
    numpy's LinAlgError traceback, and the cut joint named twice, which ended it in NaN impulses."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    for k, (mechanism, edit, field) in enumerate(
            [("slider_crank", joint_cut_twice, "transitions[0] (stop).cut: = ['P', 'P']"),
             ("slider_crank", cut_joint_twice, "configurations.free.cut_joints[1] (C).name: = 'C'")]):
        path = hostile(tmp_path / str(k), mechanism, edit)
        for argv in (["check", str(path)], ["run", str(path), "--quiet"]):
            p = subprocess.run([sys.executable, "-m", "pcmm.cli", *argv], env=env, capture_output=True, text=True,
                               timeout=120)
            assert p.returncode == SCENE_ERROR, p.stderr
            assert p.stderr.startswith("pcmm: error: ") and field in p.stderr, p.stderr
            assert "Traceback" not in p.stderr and p.stdout == ""



def test_a_latch_into_redundant_rows_is_checked_without_a_traceback(tmp_path, capsys):
    """The four-bar's latch into 'latched' (J3 locked: J1, J2 left, the cut joint D's 2 rows take both)
    with a second cut joint X where J2 already joins link1's tip to link2: 4 rows of rank 2 on 2
    coordinates, X's forces statically indeterminate.  ``pcmm check`` and ``pcmm run`` ended in
    AttributeError ('LatchSpec' object has no attribute 'unmerge': the check of the guards reading
    indeterminate forces asked a latch for a stop's unmerge); now the redundancy is a warning and
    both go on."""
    path = four_bar(tmp_path)
    doc = tomllib.loads(path.read_text())
    doc["configurations"]["latched"]["cut_joints"] = doc["configurations"]["open"]["cut_joints"] + [
        {"name": "X", "type": "revolute", "a": "link1", "point_a": [0.06, 0.0], "b": "link2", "point_b": [0.0, 0.0]}]
    path.write_text(builders.dump_toml(doc))
    for argv in (["check", str(path)], ["run", str(path), "--quiet", "--t-end", "0.5"]):
        assert pcmm.cli.main(argv) == 0, argv
        err = capsys.readouterr().err
        assert "Traceback" not in err
        assert "configuration 'latched' has 4 constraint rows (D.fx, D.fy, X.fx, X.fy) of rank 2 on 2 coordinates" \
            in err and "statically indeterminate" in err, err


# ---- a design study's value paths -------------------------------------------------------------------
def test_two_value_paths_to_one_value_are_refused(tmp_path, capsys):
    """``forces.spring.k`` and ``forces[0].k`` are one value: before, the later path silently won, and
    a sweep's table listed values no run used (Example 1 swept with forces.tau3.value = 0.1, 0.2 and
    forces[2].value = 0.3: two rows, 0.1 and 0.2, with the same final angle of link3 to the last bit)."""
    path = pendulum(tmp_path)
    scene = pcmm.load_scene(path)
    with pytest.raises(SceneError) as info:
        scene.with_values({"forces.spring.k": 2.0, "forces[0].k": 5.0})
    assert info.value.problems == [f"{path}: value paths 'forces.spring.k' and 'forces[0].k' both set "
                                   "forces[0].k: each value may be set by one path only"]
    with pytest.raises(SceneError) as info:  # one inside the other: the list, then one of its numbers
        scene.with_values({"scene.gravity": [0.0, -1.0], "scene.gravity[1]": -2.0})
    assert "value paths 'scene.gravity' and 'scene.gravity[1]' both set scene.gravity[1] (one inside the other)" \
        in info.value.problems[0]
    assert scene.with_values({"forces.spring.k": 2.0, "forces[0].rest": 0.1}).forces[0].k == 2.0  # two values
    # the command line: refused before the first run, no table written, no traceback
    table = tmp_path / "k.csv"
    argv = ["sweep", str(path), "--set", "forces.spring.k=2,3", "--set", "forces[0].k=5", "--out", str(table),
            "--workers", "1", "--quiet"]
    assert pcmm.cli.main(argv) == SCENE_ERROR
    out, err = capsys.readouterr()
    assert "value paths 'forces.spring.k' and 'forces[0].k' both set forces[0].k" in err and "Traceback" not in err
    assert not table.exists()
