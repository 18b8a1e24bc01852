"""Defects found reviewing the changes since 57f9a16 (h-review3), one test per defect.

Mechanism: the two-bar arm of tests/test_entry_guard.py (shoulder J1, elbow J2, 'locked' derived by
locking J2); the loader's cases put one table at fault before the one a cross-check refuses.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import pcmm
from pcmm.errors import SceneError

from builders import bar_xml, joint_xml, link_xml, robot_xml, scene_doc, write_scene
from test_entry_guard import latch, release


def _arm_urdf() -> str:
    return robot_xml("arm", link_xml("frame"), joint_xml("J1", "revolute", "frame", "upper"),
                     bar_xml("upper", 0.6, 1.2), joint_xml("J2", "revolute", "upper", "fore", xyz=(0.6, 0.0)),
                     bar_xml("fore", 0.35, 0.5))


def _problems(folder, configs=None, **tables) -> list[str]:
    doc = scene_doc(configs or {"free": "arm.urdf", "locked": {"from": "free", "lock": ["J2"]}},
                    {"J1": 0.0, "J2": 0.0}, {"J1": 0.0, "J2": 1.0}, gravity=(0.0, 0.0), t_end=0.1, **tables)
    with pytest.raises(SceneError) as info:
        pcmm.load_scene(write_scene(folder, doc, {"arm.urdf": _arm_urdf()}))
    return [p.split("scene.toml: ", 1)[1] for p in info.value.problems]


# -- a cross-check's message names the table at fault by its place in the file, not by its place
#    among the tables that were built (a table at fault before it is not built)

def test_an_entry_guard_refusal_names_the_transitions_at_their_place_in_the_file(tmp_path):
    configs = {"free": "arm.urdf", "locked": {"from": "free", "lock": ["J2"]}, "also": "arm.urdf"}
    broken = {"name": "broken", "type": "release", "to": "free", "guard": {"type": "time", "at": 0.1}}  # no from
    problems = _problems(tmp_path, configs, transitions=[broken, latch(), release(), release("second", target="also")])
    assert problems[0].startswith("transitions[0] (broken).from: missing")
    assert problems[1].startswith("transitions[3] (second).guard.type: = 'entry': transitions[2] (elbow release) "
                                  "already leaves 'locked'"), problems


def test_a_transition_cross_check_names_its_place_in_the_file(tmp_path):
    broken = {"name": "broken", "type": "release", "to": "free", "guard": {"type": "time", "at": 0.1}}
    wrong = release("to nowhere", target="nowhere", guard={"type": "time", "at": 0.05})
    problems = _problems(tmp_path, transitions=[broken, latch(), wrong])
    assert any(p.startswith("transitions[2] (to nowhere).to: = 'nowhere': no such configuration") for p in problems), \
        problems


def test_a_force_cross_check_names_its_place_in_the_file(tmp_path):
    broken = {"name": "broken", "type": "torque", "value": 1.0}  # no on
    spring = {"name": "elbow spring", "type": "spring", "on": {"joint": "J9"}, "measure": {"joint": "J2"},
              "k": 2.0}
    problems = _problems(tmp_path, forces=[broken, spring])
    assert problems[0].startswith("forces[0] (broken).on: missing")
    assert any(p.startswith("forces[1] (elbow spring).on.joint") for p in problems), problems


def test_a_drive_cross_check_names_its_place_in_the_file(tmp_path):
    broken = {"joint": "J1"}  # no coefficients
    problems = _problems(tmp_path, drives=[broken, {"joint": "J9", "coefficients": [0.0, 1.0]}])
    assert problems[0].startswith("drives[0].coefficients: missing")
    assert any(p.startswith("drives[1].joint") for p in problems), problems


# -- a table from before the impulse magnitude columns: the warning counts the rows it keeps

def test_an_older_table_s_warning_counts_only_the_rows_it_keeps(tmp_path):
    """Of an older table's two rows, one altered: the upgrade warning says 1 row keeps the new columns
    empty (it said 2, counting the row dropped as altered, which its own line reports)."""
    from pcmm.studies.sweep import make_plan, parse_set, sweep
    from pcmm.studies.table import checksum
    from test_audit3_pins import read_csv, write_block

    path = write_block(tmp_path / "base")
    out = tmp_path / "t.csv"
    plan = make_plan([parse_set("scene.gravity[1]=-9.81,-6.0")])
    sweep(pcmm.load_scene(path), plan, out, pcmm.RunOptions(t_end=0.5), workers=1)
    rows = read_csv(out)
    new_cols = ("first_impulse_magnitude", "peak_impulse_magnitude", "total_impulse_magnitude")
    old_header = [c for c in rows[0] if c not in new_cols]
    lines = [",".join(old_header)]
    for k, row in enumerate(rows):
        cells = [row[c] for c in old_header[:-1]]
        check = checksum(cells)
        if k == 1:
            cells[-1] += "0"  # altered after its checksum
        lines.append(",".join([*cells, check]))
    out.write_text("\n".join(lines) + "\n")
    res = sweep(pcmm.load_scene(path), plan, out, pcmm.RunOptions(t_end=0.5), workers=1, resume=True)
    assert res.ran == 1  # the altered row's run, again
    assert res.dropped[0].startswith("written before the columns first_impulse_magnitude, peak_impulse_magnitude, "
                                     "total_impulse_magnitude: its 1 rows keep them empty"), res.dropped
    assert res.dropped[1].startswith("line 3 (run "), res.dropped


# -- a spring whose measure runs against its coordinate, in two configurations: said once

def test_a_reversed_measure_is_refused_once_not_once_per_configuration(tmp_path):
    """between = [fore, upper] is -J2: the refusal names forces[0].measure once, though the spring acts in
    'free' and 'also' (the guard meant to say it once compared the message without its file prefix, so
    it never matched and the same line came twice)."""
    spring = {"name": "elbow spring", "type": "spring", "on": {"joint": "J2"},
              "measure": {"between": ["fore", "upper"]}, "k": 2.0, "configurations": ["free", "also"]}
    problems = _problems(tmp_path, {"free": "arm.urdf", "also": "arm.urdf"}, forces=[spring])
    assert [p.split(":")[0] for p in problems] == ["forces[0] (elbow spring).measure"], problems
    assert "so its stiffness drives that coordinate away from rest and feeds energy in" in problems[0], problems


# -- pcmm check judges a release on entry's target as it judges any other transition's

def _arm_urdf_elbow_at(x: float) -> str:
    return robot_xml("arm", link_xml("frame"), joint_xml("J1", "revolute", "frame", "upper"),
                     bar_xml("upper", 0.6, 1.2), joint_xml("J2", "revolute", "upper", "fore", xyz=(x, 0.0)),
                     bar_xml("fore", 0.35, 0.5))


def test_pcmm_check_finds_a_release_on_entry_into_a_urdf_that_places_the_links_elsewhere(tmp_path):
    """'locked' is left on entry for 'other', whose URDF has the elbow 0.1 m nearer the shoulder: the
    forearm would jump 0.1 m at the switch (the run stops there, naming the link).  pcmm check judged
    a coordinate or gap guard's target for that, but followed an entry release's target unjudged."""
    from pcmm.run.checks import check_scene
    from test_entry_guard import ENTRY

    doc = scene_doc({"free": "arm.urdf", "locked": {"from": "free", "lock": ["J2"]}, "other": "other.urdf"},
                    {"J1": 0.0, "J2": 0.0}, {"J1": 0.0, "J2": 5.0}, gravity=(0.0, 0.0), t_end=0.3,
                    transitions=[latch(), release(target="other", guard=ENTRY)])
    path = write_scene(tmp_path, doc, {"arm.urdf": _arm_urdf(), "other.urdf": _arm_urdf_elbow_at(0.5)})
    scene = pcmm.load_scene(path)
    report = check_scene(scene)
    found = [p for p in report.problems if p.split(": ", 1)[1].startswith("transitions[1] (elbow release).to:")]
    assert found and "fore" in found[0], report.problems
    # the run agrees: it stops at the switch, naming the link that would move
    with pytest.raises(pcmm.errors.SimulationError) as info:
        pcmm.simulate(scene)
    assert "fore" in str(info.value) and "'locked' -> 'other'" in str(info.value)


# -- a reaction guard left past its value by a bounce, not by the entry

def test_a_hold_that_a_bounce_leaves_past_a_release_s_value_is_said_as_the_bounce(tmp_path):
    """The arm of tests/test_entry_guard.py latches its elbow (into 'locked', omega by hand), then its
    shoulder bounces at a joint stop (e = 0.5: omega -> -omega / 2).  With the elbow locked and no load
    the elbow's holding moment is the forearm's centripetal one, M2 (L2/2) L1 sin(LATCH) omega^2 (by
    hand: the elbow point's acceleration L1 omega^2 towards the shoulder, about J2), so the bounce
    drops it to a quarter at once.  A release watching it decrease through a value between the two is
    past it after the bounce without a crossing: the warning said "where the configuration is entered"
    (it was entered 0.33 s earlier, by the latch) and advised an entry guard, which would let the elbow
    go at the latch instead."""
    from test_entry_guard import L1, L2, LATCH, M2, arm, by_hand
    from builders import stop

    e = 0.5
    _, omega, _ = by_hand(0.2)
    held = M2 * (L2 / 2) * L1 * math.sin(LATCH) * omega ** 2  # N m, before the bounce
    value = 0.6 * held
    shoulder = stop("shoulder stop", "locked", e, {"type": "coordinate", "measure": {"joint": "J1"}, "value": 0.3,
                                                   "direction": "increasing"}, {"joint": "J1", "arm": L1})
    let_go = release("elbow let go", guard={"type": "reaction", "of": "J2", "value": value, "direction": "decreasing"})
    traj = pcmm.simulate(pcmm.load_scene(arm(tmp_path, [latch(), shoulder, let_go], t_end=0.7)))
    assert [ev["name"] for ev in traj.events] == ["elbow latch", "shoulder stop"]  # the release never fires
    hold = traj.series("constraint_forces", "J2.hold")
    hold = hold[~np.isnan(hold)]  # (held in 'locked' only)
    assert abs(hold[0]) == pytest.approx(held, rel=1e-9) and abs(hold[-1]) == pytest.approx(e * e * held, rel=1e-9)
    (said,) = [w for w in traj.stats["warnings"] if "'elbow let go'" in w]
    t_bounce = traj.events[1]["t"]
    assert said.startswith(f"t = {t_bounce:.9g} s, configuration 'locked': the release 'elbow let go' watches the "
                           f"holding force of 'J2' cross {value:.9g} decreasing, but the bounce at 'shoulder stop' left it "
                           f"{value - e * e * held:.6g} past that value"), said
    assert "entered" not in said and "type = \"entry\"" not in said
