"""What made the second new user (task h-newcomer2) stumble while writing the four-bar and the leg
of tests/test_newcomer2_mechanisms.py, each now said where the user looks."""
from __future__ import annotations

import math
import re

import pytest

import pcmm
import pcmm.cli
from pcmm.scene.load import CUT_JOINT_KEYS
from pcmm.scene.urdf import undrawn_links
from test_newcomer2_mechanisms import FOURBAR_TOML, FOURBAR_URDF, LEG_URDF, leg_scene


def _without_visuals(urdf: str) -> str:
    return re.sub(r"<visual>.*?</visual>", "", urdf)


def test_check_names_the_links_the_drawing_cannot_show(tmp_path, capsys):
    """The leg's URDF written without <visual>s ran and checked clean, and its drawing showed the hip
    pin, a knee circle and the foot pin, but no thigh and no shank (the legend listed both). `pcmm
    check` now names the file and both links and gives a box along each bar to paste: thigh from its
    origin to the knee (0.4 m), shank to twice its centre of mass (0.4 m, no child joint)."""
    leg_scene(tmp_path, 60.0, 60.0, -0.7)
    (tmp_path / "leg.urdf").write_text(_without_visuals(LEG_URDF))
    assert pcmm.cli.main(["check", str(tmp_path / "leg.toml")]) == 0
    out = capsys.readouterr().out
    bar = '<visual><origin xyz="0.2 0 0" rpy="0 0 0"/><geometry><box size="0.4 0.012 0.012"/></geometry></visual>'
    assert ("leg.urdf: links 'thigh', 'shank' have no <box> or <sphere> <visual>: the drawing and the video show "
            "only their joints") in out
    assert f'in <link name="thigh">: {bar}' in out and f'in <link name="shank">: {bar}' in out
    # pasted, the suggestion is drawn, and the note goes
    text = _without_visuals(LEG_URDF)
    for link in ("thigh", "shank"):
        text = text.replace(f'<link name="{link}">', f'<link name="{link}">{bar}')
    (tmp_path / "leg.urdf").write_text(text)
    assert undrawn_links(tmp_path / "leg.urdf") == []
    assert pcmm.cli.main(["check", str(tmp_path / "leg.toml")]) == 0
    assert "<visual>" not in capsys.readouterr().out


def test_a_point_mass_gets_a_sphere_and_a_bent_bar_points_at_its_child(tmp_path):
    """A link whose centre of mass is on its joint and that carries no joint is a point: a sphere.
    A link whose child joint is off its x axis gets a bar turned towards that joint."""
    urdf = ('<?xml version="1.0"?><robot name="r"><link name="frame"/>'
            '<joint name="j1" type="revolute"><parent link="frame"/><child link="bent"/><axis xyz="0 0 1"/>'
            '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
            '<link name="bent"><inertial><origin xyz="0.1 0 0"/><mass value="1"/>'
            '<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>'
            '<joint name="j2" type="revolute"><parent link="bent"/><child link="point"/><origin xyz="0.3 0.4 0"/>'
            '<axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
            '<link name="point"><inertial><mass value="1"/>'
            '<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial></link></robot>')
    path = tmp_path / "r.urdf"
    path.write_text(urdf)
    out = dict(undrawn_links(path))
    assert out["bent"] == ('<visual><origin xyz="0.15 0.2 0" rpy="0 0 0.927295"/>'
                           '<geometry><box size="0.5 0.012 0.012"/></geometry></visual>')
    assert out["point"] == '<visual><geometry><sphere radius="0.02"/></geometry></visual>'


def test_the_cut_joint_series_are_named_as_the_scene_reference_says(tmp_path):
    """The scene reference said a cut joint's constraint force is the series "NAME.x, NAME.y";
    `traj.series("constraint_forces", "foot.x")` then failed (the rows are foot.fx, foot.fy).
    The reference now gives the names a run has, and which body the force acts on."""
    doc = next(k.doc for k in CUT_JOINT_KEYS if k.name == "name")
    assert "NAME.fx, NAME.fy (revolute" in doc and "NAME.fn, NAME.mz (prismatic" in doc and "on link b" in doc
    (tmp_path / "fourbar.urdf").write_text(FOURBAR_URDF)
    (tmp_path / "fourbar.toml").write_text(FOURBAR_TOML)
    traj = pcmm.simulate(pcmm.load_scene(tmp_path / "fourbar.toml"), pcmm.RunOptions(t_end=0.05))
    fx, fy = (traj.series("constraint_forces", f"J4.{c}") for c in ("fx", "fy"))
    assert len(fx) == len(traj.t) and fy[0] > 0  # the frame holds the rocker up at J4


def test_a_key_given_twice_is_named_with_its_lines(tmp_path):
    """A second `contact = { ... }` pasted into the leg's cut joint read "not valid TOML: Cannot mutate
    immutable namespace ('contact',) (at line 14, column 190)", and a key repeated in a table "Cannot
    overwrite a value (at end of document)": neither named the key's line (tomllib's words). The
    message now names the key (or the table) and the line(s)."""
    leg_scene(tmp_path, 60.0, 60.0, -0.7)
    text = (tmp_path / "leg.toml").read_text()
    path = tmp_path / "leg.toml"
    lines = text.splitlines()
    number = next(i for i, line in enumerate(lines, 1) if 'point_a = "entry"' in line)
    path.write_text(text.replace('point_a = "entry"', 'point_a = "entry", contact = { normal = [0.0, 1.0] }'))
    with pytest.raises(pcmm.SceneError) as err:
        pcmm.load_scene(path)
    assert f"the key 'contact' is given twice in one inline table {{ ... }} on line {number}" in str(err.value)
    # a key repeated in a table: tomllib says "at end of document"
    t_end = next(i for i, line in enumerate(lines, 1) if line.startswith("t_end"))
    path.write_text(text.replace("t_end = 1.0\n", "t_end = 1.0\nt_end = 2.0\n"))
    with pytest.raises(pcmm.SceneError) as err:
        pcmm.load_scene(path)
    assert f"the key 't_end' is given twice in [scene], on lines {t_end} and {t_end + 1}" in str(err.value)
    # a table declared twice
    path.write_text(text + "\n[scene]\ngravity = [0.0, -9.81]\n")
    with pytest.raises(pcmm.SceneError) as err:
        pcmm.load_scene(path)
    scene_line = next(i for i, line in enumerate(lines, 1) if line == "[scene]")
    assert f"the table [scene] is declared twice, on lines {scene_line} and {len(lines) + 2}" in str(err.value)


def test_a_link_welded_to_a_moving_link_is_named_too(tmp_path):
    """The tutorial's latched arm without its boxes: the forearm hangs on a `fixed` elbow but moves
    with the upper arm, so it is named too; a link welded to the frame is not (it never moves)."""
    urdf = ('<?xml version="1.0"?><robot name="r"><link name="frame"/>'
            '<joint name="base" type="fixed"><parent link="frame"/><child link="plate"/></joint>'
            '<link name="plate"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/>'
            '</inertial></link>'
            '<joint name="shoulder" type="revolute"><parent link="plate"/><child link="upper"/><axis xyz="0 0 1"/>'
            '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
            '<link name="upper"><inertial><origin xyz="0.15 0 0"/><mass value="0.6"/>'
            '<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>'
            '<joint name="elbow" type="fixed"><parent link="upper"/><child link="fore"/><origin xyz="0.3 0 0"/></joint>'
            '<link name="fore"><inertial><origin xyz="0.1 0 0"/><mass value="0.4"/>'
            '<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link></robot>')
    path = tmp_path / "r.urdf"
    path.write_text(urdf)
    out = dict(undrawn_links(path))
    assert sorted(out) == ["fore", "upper"]
    assert '<box size="0.3 0.012 0.012"/>' in out["upper"] and '<box size="0.2 0.012 0.012"/>' in out["fore"]


def test_a_pin_judged_with_two_frictions_is_named(tmp_path, capsys):
    """The leg's friction is written twice: on the strike (`transitions[0].contact.friction`) and on
    the cut joint that holds the foot (`configurations.stance.cut_joints[0].contact.friction`). Written
    0.6 and 0.3, the scene checked clean and the run stopped right after the strike: "would slip: its
    force needs friction >= 0.346292 ... the cut joint has mu = 0.3" (by hand, the stance needs
    |F_t| / F_n = 8.0803 / 23.3338 = 0.3463). `pcmm check` (and `pcmm run`) now warn, naming both
    fields and values; the same mu on both says nothing."""
    leg_scene(tmp_path, 60.0, 60.0, -0.7)
    path = tmp_path / "leg.toml"
    text = path.read_text()
    held = "contact = { normal = [0.0, 1.0], friction = 0.6 } }"
    assert held in text
    path.write_text(text.replace(held, held.replace("0.6", "0.3")))
    assert pcmm.cli.main(["check", str(path)]) == 0
    err = capsys.readouterr().err
    assert (f"pcmm: warning: {path}: transitions[0] (foot strike).contact.friction: = 0.6, but the cut joint "
            "'foot' of 'stance' that holds the point after the strike has friction = 0.3") in err
    path.write_text(text.replace(held, held.replace("0.6", '"stick"')))
    assert pcmm.cli.main(["check", str(path)]) == 0
    assert 'friction = "stick"' in capsys.readouterr().err
    path.write_text(text)
    assert pcmm.cli.main(["check", str(path)]) == 0
    assert "friction" not in capsys.readouterr().err


def test_a_joint_stops_accumulation_speed_is_its_joints_rate(tmp_path):
    """The four-bar's stop written as a joint stop (`contact = { joint = "J3", arm = 0.05 }`) instead of
    the point 0.05 m along the rocker: the same first impulse, but 22 impacts to the merge instead of 18.
    The reference said the accumulation speed is in m/s; at a joint stop it is compared with the joint's
    rate, 1/arm = 20 times the point's speed: from u1 = 3.38133 rad/s the halving bounces reach a rebound
    below 1e-6 after 1 + ceil(log2(u1 / 2e-6)) = 22 impacts (18 from the point's 0.16907 m/s). The
    setting's text now says so."""
    from pcmm.scene.settings import SETTINGS
    doc = next(s for s in SETTINGS if s.name == "accumulation_speed").help
    assert "at a joint stop the joint's own rate (rad/s" in doc
    (tmp_path / "fourbar.urdf").write_text(FOURBAR_URDF)
    text = re.sub(r'contact = \{ a = "coupler".*\n', 'contact = { joint = "J3", arm = 0.05 }\n', FOURBAR_TOML)
    (tmp_path / "fourbar.toml").write_text(text.replace("t_end = 1.2", "t_end = 0.5"))
    traj = pcmm.simulate(pcmm.load_scene(tmp_path / "fourbar.toml"))
    impacts = [e for e in traj.events if e["transition"] == "stop"]
    u1 = -impacts[0]["normal_velocity"]["before"]
    assert u1 == pytest.approx(3.38133, abs=1e-5)
    assert impacts[0]["impulse"]["normal"] == pytest.approx(12.85177, abs=1e-5)  # as the point contact's
    assert impacts[-1]["merge"] and len(impacts) == 1 + math.ceil(math.log2(u1 / 2e-6)) == 22


SPRING_TOML = """
[scene]
name = "knee"
gravity = [0.0, 0.0]
t_end = 0.5
initial_configuration = "swing"
[configurations.swing]
urdf = "leg.urdf"
[initial]
q = { hip = 0.0, knee = 0.3 }
v = { hip = 0.0, knee = 0.0 }
[[forces]]
name = "knee spring"
type = "spring"
ON
MEASURE
k = 5.0
"""


def _spring(tmp_path, on: str, measure: str):
    (tmp_path / "leg.urdf").write_text(LEG_URDF)
    path = tmp_path / "knee.toml"
    path.write_text(SPRING_TOML.replace("ON", on).replace("MEASURE", measure))
    return path


def test_a_spring_measured_against_its_joint_is_refused(tmp_path):
    """A knee spring written `on = { joint = "knee" }`, `measure = { between = ["shank", "thigh"] }`
    (the pair reversed) measures minus the knee's coordinate: -k (x - rest) then pushes the knee away
    from rest, a negative spring. It ran without a word: without gravity, from the knee at 0.3 rad at
    rest, the knee wound up to 12.7 rad and kinetic + potential energy rose from 0.225 to 810 J in
    0.5 s (k < 0 itself is refused as an energy source). It is refused now, at the measure, with the
    order to write; the right order conserves that energy (0.225 J = k 0.3^2 / 2)."""
    path = _spring(tmp_path, 'on = { joint = "knee" }', 'measure = { between = ["shank", "thigh"] }')
    with pytest.raises(pcmm.SceneError) as err:
        pcmm.load_scene(path)
    assert (f"{path}: forces[0] (knee spring).measure: = between ['shank', 'thigh'] is theta_thigh - theta_shank, "
            "minus the coordinate the element acts along (on = { joint = 'knee' }: joint 'knee' (thigh -> shank), "
            "whose coordinate is theta_shank - theta_thigh), so its stiffness drives that coordinate away from rest "
            "and feeds energy in, as k < 0 or c < 0 would; write between = ['thigh', 'shank']") in str(err.value)
    path = _spring(tmp_path, 'on = { joint = "knee" }', 'measure = { between = ["thigh", "shank"] }')
    traj = pcmm.simulate(pcmm.load_scene(path))
    energy = traj.series("kinetic") + traj.series("potential")
    assert energy == pytest.approx(0.5 * 5.0 * 0.3 ** 2, abs=1e-9)
    # a torque on a link from the frame, measured from the link to the frame: minus its angle
    path = _spring(tmp_path, 'on = { link = "thigh" }', 'measure = { between = ["thigh", "frame"] }')
    with pytest.raises(pcmm.SceneError, match=r"forces\[0\] \(knee spring\)\.measure: = between \['thigh', 'frame'\]"):
        pcmm.load_scene(path)
    assert pcmm.load_scene(_spring(tmp_path, 'on = { link = "thigh" }', 'measure = { between = ["frame", "thigh"] }'))


def test_measure_sign_reads_welds_links_and_joints():
    """measure_sign on the shipped examples: every element acts along its measure (+1) or, as Example
    1's Eq. 44 torques (on a link, measured between two links), along another coordinate (0); none
    against it."""
    from pathlib import Path
    from pcmm.scene.load import measure_sign
    root = Path(__file__).resolve().parents[1] / "examples"
    signs = {}
    for name in ("three_bar.toml", "three_bar_cycle.toml", "double_folded.toml"):
        scene = pcmm.load_scene(root / name)
        for f in scene.forces:
            signs[(name, f.name)] = {measure_sign(f, scene.configurations[c])
                                     for c in (f.configurations or scene.configurations)}
    assert signs[("three_bar.toml", "tau1")] == {1} and signs[("three_bar.toml", "tau2")] == {0}
    assert signs[("three_bar_cycle.toml", "spring O2")] == {1} and signs[("double_folded.toml", "spring D")] == {1}
