"""Configurations derived by locking joints (``from = NAME, lock = [...]``) and ``pcmm derive``.

The references are independent of the derivation code: the shipped hand-written merged URDFs
(Example 1's config2, Example 2's config2), Pinocchio's forward kinematics of the *base* model
at the locked joint's value, and the run of a URDF that ``pcmm derive`` wrote, used as a
hand-written configuration.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import builders
import pcmm
import pcmm.cli
from builders import EXAMPLES, URDF_DIR, Bar, chain_urdf, copy_example, dump_toml, example_text, scene_doc
from pcmm.model.mechanism import Mechanism
from pcmm.errors import SceneError, SimulationError
from pcmm.run.loop import RunOptions, simulate
from pcmm.scene.urdf import read_urdf

HAND_CONFIG2 = 'urdf = "three_bar_config2.urdf"'  # as copy_example writes it
DERIVED_CONFIG2 = 'from = "config1"\nlock = ["O3"]'


def three_bar(tmp_path, config2=DERIVED_CONFIG2, extra="", name="three_bar.toml"):
    text = example_text("three_bar.toml").replace(HAND_CONFIG2, config2) + extra
    return copy_example(tmp_path, name, scene_text=text)


def assert_same_run(a, b, tol=1e-10):
    """Same events (times, kinds, configurations, velocities) and the same final state."""
    assert [(e["name"], e["transition"], e["from"], e["to"]) for e in a.events] == \
        [(e["name"], e["transition"], e["from"], e["to"]) for e in b.events]
    for ea, eb in zip(a.events, b.events):
        assert ea["t"] == pytest.approx(eb["t"], abs=tol)
        assert ea["impulse"]["normal"] == pytest.approx(eb["impulse"]["normal"], abs=tol)
        for key in ("v_before", "v_after"):
            for j, val in ea[key].items():
                assert val == pytest.approx(eb[key][j], abs=tol)
    sa, sb = a.segments[-1], b.segments[-1]
    assert sa.configuration == sb.configuration and sa.coordinates == sb.coordinates
    assert sa.t[-1] == pytest.approx(sb.t[-1], abs=tol)
    np.testing.assert_allclose(sa.q[-1], sb.q[-1], atol=tol, rtol=0)
    np.testing.assert_allclose(sa.v[-1], sb.v[-1], atol=tol, rtol=0)
    np.testing.assert_allclose(sa.theta[-1], sb.theta[-1], atol=tol, rtol=0)


# ---- the locked model is the base model at the joint's value ----------------------------------
def _lock_scene(tmp_path, lock_toml):
    """A frame-slider-bar-bar chain: J1 prismatic along (3, 4) with its origin turned by 0.5 rad,
    J2 revolute with its origin turned by 0.3 rad, J3 revolute; config 'locked' locks some."""
    urdf = chain_urdf([Bar(0.4, 1.0, joint="prismatic", axis=(3.0, 4.0, 0.0), yaw=0.5),
                       Bar(0.3, 0.5, yaw=0.3), Bar(0.2, 0.25)], first_xyz=(0.1, -0.2))
    (tmp_path / "chain.urdf").write_text(urdf)
    path = tmp_path / "lock.toml"
    zero = {"J1": 0.0, "J2": 0.0, "J3": 0.0}
    path.write_text(dump_toml(scene_doc({"base": "chain.urdf"}, zero, zero))
                    + f'[configurations.locked]\nfrom = "base"\n{lock_toml}\n')
    return pcmm.load_scene(path)


@pytest.mark.parametrize("lock, q_base", [
    ("lock = { J1 = 0.37 }", (0.37, 0.8, -1.1)),
    ("lock = { J2 = -2.2 }", (0.15, -2.2, 0.6)),
    ("lock = { J1 = -0.05, J3 = 2.9 }", (-0.05, 1.3, 2.9)),
], ids=["prismatic", "revolute", "both"])
def test_locked_model_places_every_link_as_the_base_model_does(tmp_path, lock, q_base):
    scene = _lock_scene(tmp_path, lock)
    mech = Mechanism(scene)
    base, locked = mech["base"], mech["locked"]
    q_base = np.array(q_base)
    q_locked = np.array([q_base[base.joint_slice[j].start] for j in locked.joint_names])
    assert locked.nv == base.nv - (len(lock.split("=")) - 2)
    a, b = locked.link_poses(q_locked), base.link_poses(q_base)
    np.testing.assert_allclose(a[:, :2], b[:, :2], atol=1e-14, rtol=0)
    dtheta = a[:, 2] - b[:, 2]  # a link angle's constant part is read modulo 2 pi (as for any URDF)
    np.testing.assert_allclose(dtheta - 2 * np.pi * np.round(dtheta / (2 * np.pi)), 0.0, atol=1e-14)
    # the mass matrix of the locked model is the base one's restricted to the free joints
    keep = [base.joint_slice[j].start for j in locked.joint_names]
    M = base.mass_matrix(q_base)
    np.testing.assert_allclose(locked.mass_matrix(q_locked), M[np.ix_(keep, keep)], atol=1e-14)


def test_values_at_entry_are_read_from_the_source_and_cached_by_value(tmp_path):
    scene = pcmm.load_scene(three_bar(tmp_path))
    mech = Mechanism(scene)
    c1 = mech["config1"]
    q = np.array([0.4, -0.7, 3.0])
    c2 = mech.enter("config2", c1, q)
    assert dict(c2.spec.derivation.values) == {"O3": 3.0}
    np.testing.assert_allclose(c2.link_poses(q[:2]), c1.link_poses(q), atol=1e-14, rtol=0)
    assert mech.enter("config2", c1, q + [0, 0, 1e-14]) is c2  # the same lock, reached again
    c2b = mech.enter("config2", c1, np.array([0.4, -0.7, math.pi]))  # merged elsewhere: a new model
    assert c2b is not c2 and mech["config2"] is c2b
    assert mech.derived == {"config2": [{"O3": 3.0}, {"O3": math.pi}]}


def test_value_of_a_joint_the_source_lacks_comes_from_the_links_poses(tmp_path):
    """config3 locks O2 of config2 (itself config1 with O3 locked): entered from the hand-written
    config2 URDF, where O3 is a fixed joint at pi, O3's value is read from links 2 and 3."""
    extra = ('\n[configurations.hand2]\nurdf = "three_bar_config2.urdf"\n'
             '[configurations.config3]\nfrom = "config2"\nlock = ["O2"]\n')
    scene = pcmm.load_scene(three_bar(tmp_path, extra=extra))
    assert scene.configurations["config3"].derivation.lock == ("O3", "O2")
    mech = Mechanism(scene)
    hand2 = mech["hand2"]
    q = np.array([0.3, -1.2])
    c3 = mech.enter("config3", hand2, q)
    values = dict(c3.spec.derivation.values)
    assert values["O2"] == -1.2 and values["O3"] == pytest.approx(math.pi, abs=1e-15)
    np.testing.assert_allclose(c3.link_poses(q[:1]), hand2.link_poses(q), atol=1e-14, rtol=0)


def test_derived_urdf_equals_the_hand_written_one(tmp_path):
    """Example 1's shipped config2 is config1 with O3 fixed at pi: the generated URDF has the
    same joints (types, parents, origins) and links."""
    scene = pcmm.load_scene(three_bar(tmp_path, config2='from = "config1"\nlock = { O3 = 3.141592653589793 }'))
    out = tmp_path / "derived.urdf"
    out.write_text(scene.configurations["config2"].xml)
    derived, hand = read_urdf(out), read_urdf(URDF_DIR / "three_bar_config2.urdf")
    assert derived.links == hand.links and derived.root == hand.root
    for name, j in hand.joints.items():
        d = derived.joints[name]
        assert (d.type, d.parent, d.child) == (j.type, j.parent, j.child)
        np.testing.assert_allclose(d.xyz, j.xyz, atol=1e-15)
        np.testing.assert_allclose(d.rpy, j.rpy, atol=1e-15)


# ---- runs ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def example1_hand(shipped_run):
    return shipped_run("three_bar.toml")[1]


def test_example1_derived_config2_gives_the_shipped_run(tmp_path, example1_hand):
    traj = simulate(pcmm.load_scene(three_bar(tmp_path)))
    assert len(traj.events) == 1 and traj.events[0]["to"] == "config2"
    assert_same_run(traj, example1_hand)
    assert traj.stats["derived_configurations"]["config2"][0]["O3"] == pytest.approx(math.pi, abs=1e-12)


def test_pcmm_derive_round_trips(tmp_path, example1_hand, capsys):
    scene = three_bar(tmp_path)
    out = tmp_path / "derived"
    assert pcmm.cli.main(["derive", str(scene), "--out", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    written = out / "config2.urdf"
    assert read_urdf(written).joints["O3"].type == "fixed"
    # the written URDF, used as a hand-written configuration, gives the same run again
    again = three_bar(tmp_path, config2='urdf = "derived/config2.urdf"', name="again.toml")
    assert_same_run(simulate(pcmm.load_scene(again)), example1_hand)
    # no silent overwrite
    assert pcmm.cli.main(["derive", str(scene), "--out", str(out)]) == 2
    assert "exists; pass --force" in capsys.readouterr().err
    assert pcmm.cli.main(["derive", str(scene), "--out", str(out), "--force"]) == 0


def test_pcmm_derive_names_what_the_run_never_reached(tmp_path, capsys):
    scene = three_bar(tmp_path, extra='\n[configurations.fixed3]\nfrom = "config1"\nlock = { O2 = 0.5 }\n')
    scene.write_text(scene.read_text().replace("t_end = 1.0", "t_end = 0.1"))  # the latch is at 0.167 s
    out = tmp_path / "derived"
    assert pcmm.cli.main(["derive", str(scene), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "configuration 'config2': never reached by the run (t = 0 .. 0.1 s); not written" in text
    assert (out / "fixed3.urdf").is_file() and not (out / "config2.urdf").exists()
    assert "O2 = 0.5" in text


def test_example2_derived_config2_gives_the_shipped_events(tmp_path):
    """Example 2's config2 = config1 with the slider's prismatic joint E locked (E is in the loop,
    the cut joint C is inherited): the same impacts and merge as the shipped URDF, to 3.25 s."""
    text = (EXAMPLES / "double_folded.toml").read_text()
    cut = 'cut_joints = [ { name = "C", type = "revolute", a = "link2", point_a = [0.2, 0.0], b = "link3", point_b = [0.09, 0.0] } ]'
    hand = 'urdf = "../urdf/double_folded_config2.urdf"\n' + cut
    assert hand in text
    derived_text = text.replace(hand, 'from = "config1"\nlock = ["E"]').replace("../urdf/", f"{URDF_DIR}/")
    path = tmp_path / "double_folded.toml"
    path.write_text(derived_text)
    scene = pcmm.load_scene(path)
    assert scene.configurations["config2"].cut_joints == scene.configurations["config1"].cut_joints
    opts = RunOptions(t_end=3.25)
    derived = simulate(scene, opts)
    shipped = simulate(pcmm.load_scene(EXAMPLES / "double_folded.toml"), opts)
    assert len(derived.events) > 30 and derived.events[-1]["merge"] and derived.events[-1]["to"] == "config2"
    assert_same_run(derived, shipped, tol=1e-9)
    assert derived.stats["derived_configurations"]["config2"][0]["E"] == pytest.approx(0.3195, abs=1e-12)


def test_a_typo_in_an_inherited_cut_joint_is_reported_once(tmp_path):
    """The derived config2 inherits config1's cut joint C: a misspelt link in it is one problem,
    at config1 where it is written, not a second one at config2 (the same link, the same URDF)."""
    text = (EXAMPLES / "double_folded.toml").read_text()
    cut = 'cut_joints = [ { name = "C", type = "revolute", a = "link2", point_a = [0.2, 0.0], b = "link3", point_b = [0.09, 0.0] } ]'
    hand = 'urdf = "../urdf/double_folded_config2.urdf"\n' + cut
    typo = text.replace(hand, 'from = "config1"\nlock = ["E"]').replace(cut, cut.replace('a = "link2"', 'a = "lnk2"'))
    path = tmp_path / "typo.toml"
    path.write_text(typo.replace("../urdf/", f"{URDF_DIR}/"))
    with pytest.raises(SceneError) as info:
        pcmm.load_scene(path)
    message = str(info.value)
    assert message.count("'lnk2'") == 1, message
    assert "configurations.config1.cut_joints[0].a" in message and "did you mean 'link2'?" in message


def test_check_builds_derived_models_with_the_guard_values(tmp_path, capsys):
    assert pcmm.cli.main(["check", str(three_bar(tmp_path))]) == 0
    out = capsys.readouterr().out
    assert "configuration 'config2': 'config1' with O3 = 3.141592654 locked, 2 coordinates; " \
           "O3 fixed by the guards into it" in out


# ---- bad inputs --------------------------------------------------------------------------------------
BAD = [
    ('urdf = "three_bar_config2.urdf"\nfrom = "config1"\nlock = ["O3"]', ["configurations.config2", "both urdf and from"]),
    ('from = "config9"\nlock = ["O3"]', ["configurations.config2.from", "'config9'", "no such configuration",
                                        "config1"]),
    ('from = "config1"\nlock = ["O4"]', ["configurations.config2.lock", "'O4'", "no joint of that name",
                                        "did you mean", "O1, O2, O3"]),
    ('from = "config1"\nlock = []', ["configurations.config2.lock", "is empty"]),
    ('from = "config1"\nlock = ["O3", "O3"]', ["configurations.config2.lock", "more than once"]),
    ('from = "config1"\nlock = { O3 = "pi +" }', ["configurations.config2.lock.O3", "'pi +'", "ends too early"]),
    ('from = "config1"\nlock = { O3 = [3.14] }', ["configurations.config2.lock.O3", "[3.14]", "finite number"]),
    ('from = "config1"\nlock = "O3"', ["configurations.config2.lock", "'O3'", "a list or a table"]),
    ('from = "config1"', ["configurations.config2.lock", "missing"]),
    ('lock = ["O3"]', ["configurations.config2.from", "missing"]),
    ('from = "config2"\nlock = ["O3"]', ["configurations.config2.from", "config2 -> config2 is a cycle"]),
    ("", ["configurations.config2.urdf", "missing", "from = NAME with lock"]),
]


@pytest.mark.parametrize("config2, fragments", BAD)
def test_bad_derived_configuration_is_named(tmp_path, config2, fragments):
    with pytest.raises(SceneError) as err:
        pcmm.load_scene(three_bar(tmp_path, config2=config2))
    text = str(err.value)
    for frag in ["three_bar.toml"] + fragments:
        assert frag in text


def test_locking_an_already_fixed_or_planar_joint_is_refused(tmp_path, make_scene):
    extra = ('\n[configurations.hand2]\nurdf = "three_bar_config2.urdf"\n'
             '[configurations.c3]\nfrom = "hand2"\nlock = ["O3"]\n'
             '[configurations.c4]\nfrom = "config2"\nlock = ["O3"]\n')
    with pytest.raises(SceneError) as err:
        pcmm.load_scene(three_bar(tmp_path, extra=extra))
    text = str(err.value)
    assert "configurations.c3.lock: = 'O3': joint 'O3' is already fixed in 'hand2'" in text
    assert "configurations.c4.lock: = 'O3': already locked in 'config2'" in text
    from builders import free_bar_urdf
    path = make_scene({"free.urdf": free_bar_urdf(1.0, 0.5)}, q0={"P": [0.0, 0.0, 0.0]}, v0={"P": [0.0, 0.0, 0.0]})
    path.write_text(path.read_text() + '[configurations.held]\nfrom = "c1"\nlock = ["P"]\n')
    with pytest.raises(SceneError, match=r"configurations.held.lock: = 'P': a planar joint has three "
                                         r"coordinates; pcmm locks revolute and prismatic joints only"):
        pcmm.load_scene(path)


def test_a_derived_initial_configuration_needs_values(tmp_path):
    text = example_text("three_bar.toml").replace('initial_configuration = "config1"',
                                                  'initial_configuration = "config2"')
    text = text.replace(HAND_CONFIG2, DERIVED_CONFIG2).replace("O1 = 0.0, O2 = 0.0, O3 = 0.0", "O1 = 0.0, O2 = 0.0")
    with pytest.raises(SceneError, match=r"scene.initial_configuration: = 'config2': the run starts in this "
                                         r"derived configuration.*lock = \{ O3 = value \}"):
        pcmm.load_scene(copy_example(tmp_path, scene_text=text))
    # with the value given, it starts there: theta3 - theta2 = pi throughout
    text = text.replace(DERIVED_CONFIG2, 'from = "config1"\nlock = { O3 = 3.141592653589793 }')
    traj = simulate(pcmm.load_scene(copy_example(tmp_path, scene_text=text)), RunOptions(t_end=0.05))
    s = traj.segments[-1]
    i2, i3 = s.links.index("link2"), s.links.index("link3")
    np.testing.assert_allclose(s.theta[:, i3] - s.theta[:, i2], math.pi, atol=1e-14)
    assert np.ptp(s.theta[:, i2]) > 0.01  # and it moved


def test_a_force_on_a_locked_joint_is_refused_unless_it_lists_configurations(tmp_path):
    force = '\n[[forces]]\nname = "brake"\ntype = "damper"\non = { joint = "O3" }\nmeasure = { joint = "O3" }\nc = 0.01\n'
    with pytest.raises(SceneError) as err:
        pcmm.load_scene(three_bar(tmp_path, extra=force))
    text = str(err.value)
    assert "forces[3] (brake).on.joint: = 'O3': joint is fixed in configuration 'config2'" in text
    assert "applies in every configuration unless it lists configurations" in text
    scene = pcmm.load_scene(three_bar(tmp_path, extra=force + 'configurations = ["config1"]\n'))
    assert [f.name for f in scene.forces_in("config2")] == ["tau1", "tau2", "tau3"]


def test_entering_without_a_source_is_a_clear_error(tmp_path):
    mech = Mechanism(pcmm.load_scene(three_bar(tmp_path)))
    with pytest.raises(SimulationError, match=r"configuration 'config2' locks O3 at the values they have when "
                                              r"the run enters it.*lock = \{ O3 = value \}"):
        mech["config2"]


def test_pcmm_derive_command_line_errors(tmp_path, capsys):
    assert pcmm.cli.main(["derive", str(EXAMPLES / "three_bar.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "three_bar.toml: has no derived configuration" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    scene = three_bar(tmp_path)
    assert pcmm.cli.main(["derive", str(scene), "--out", str(scene)]) == 2
    assert f"{scene}: is a file; --out takes a folder" in capsys.readouterr().err
    assert pcmm.cli.main(["derive", str(scene), "--out", str(scene / "sub")]) == 2
    assert "cannot create the output folder" in capsys.readouterr().err


@pytest.mark.parametrize("measure, value, expected", [
    (("joint", ("O3",)), 2.5, 2.5),
    (("between", ("link2", "link3")), 2.5, 2.5 - 0.25),  # theta3 - theta2 = yaw + q
    (("between", ("link3", "link2")), 2.5, -2.5 - 0.25),
    (("link", ("link3",)), 2.5, None),  # link3 hangs on link2, not on the frame
    (("joint", ("O2",)), 2.5, None),
])
def test_the_guard_value_that_fixes_a_locked_joint(measure, value, expected):
    from pcmm.scene.derive import _fixed_by
    from pcmm.scene.spec import GuardSpec, Measure
    from pcmm.scene.urdf import UrdfJoint
    joint = UrdfJoint("O3", "revolute", "link2", "link3", (0.125, 0.0, 0.0), (0.0, 0.0, 0.25), (0.0, 0.0, 1.0))
    guard = GuardSpec("coordinate", Measure(*measure), value, +1)
    assert _fixed_by(guard, joint, "frame") == expected
    on_frame = UrdfJoint("O1", "revolute", "frame", "link1", (0.0, 0.0, 0.0), (0.0, 0.0, 0.25), (0.0, 0.0, 1.0))
    assert _fixed_by(GuardSpec("coordinate", Measure("link", ("link1",)), value, -1), on_frame, "frame") == value - 0.25


def test_a_base_with_a_bad_urdf_is_reported_once(tmp_path):
    path = three_bar(tmp_path)
    (tmp_path / "three_bar_config1.urdf").write_text("<robot name='x'><link name='frame'/><joint/></robot>")
    with pytest.raises(SceneError) as err:
        pcmm.load_scene(path)
    text = str(err.value)
    assert "configurations.config1.urdf" in text and "configurations.config2.from" not in text


O2_LATCH = """
[[transitions]]
name = "O2 latches"
type = "latch"
from = "config2"
to = "config3"
cut = ["O2"]
guard = { type = "coordinate", measure = { between = ["link1", "link2"] }, value = 0.0, direction = "increasing" }
contact = { a = "link1", point_a = [0.3125, 0.0], b = "link2", point_b = [0.0625, 0.0], normal = [0.0, -1.0] }
"""


def test_a_chain_of_derived_configurations_runs_as_hand_written_urdfs(tmp_path):
    """After O3's latch, O2 latches at theta2 - theta1 = 0 into config3 = config2 with O2 locked:
    O3's value is carried from config2's lock.  The reference writes config3's URDF by hand (the
    shipped config2 with O2 fixed at 0) and declares config2 by its shipped URDF."""
    derived = three_bar(tmp_path, extra='\n[configurations.config3]\nfrom = "config2"\nlock = ["O2"]\n' + O2_LATCH)
    hand_text = (URDF_DIR / "three_bar_config2.urdf").read_text().replace(
        '<joint name="O2" type="revolute">', '<joint name="O2" type="fixed">').replace(
        '<origin xyz="0.25 0 0" rpy="0 0 0.0"/>\n    <axis xyz="0 0 1"/>\n'
        '    <limit lower="-1e6" upper="1e6" effort="1e6" velocity="1e6"/>\n',
        '<origin xyz="0.25 0 0" rpy="0 0 0.0"/>\n')
    assert hand_text.count('type="fixed"') == 2
    (tmp_path / "hand3.urdf").write_text(hand_text)
    hand = three_bar(tmp_path, config2=HAND_CONFIG2, name="hand.toml",
                     extra='\n[configurations.config3]\nurdf = "hand3.urdf"\n' + O2_LATCH)
    a, b = simulate(pcmm.load_scene(derived)), simulate(pcmm.load_scene(hand))
    assert [e["to"] for e in a.events] == ["config2", "config3"]
    assert a.segments[-1].coordinates == ["O1"]
    assert_same_run(a, b, tol=1e-9)
    values = a.stats["derived_configurations"]["config3"][0]
    assert values["O3"] == a.stats["derived_configurations"]["config2"][0]["O3"]
    assert values["O2"] == pytest.approx(0.0, abs=1e-12)


def test_problems_of_a_chain_are_reported_once(tmp_path):
    extra = ('\n[configurations.c3]\nfrom = "c4"\nlock = ["O2"]\n[configurations.c4]\nfrom = "c3"\nlock = ["O1"]\n'
             '[configurations.c5]\nfrom = "config2"\nlock = ["O9"]\n[configurations.c6]\nfrom = "c5"\nlock = ["O1"]\n')
    with pytest.raises(SceneError) as err:
        pcmm.load_scene(three_bar(tmp_path, extra=extra))
    problems = err.value.problems
    assert sum("is a cycle" in p for p in problems) == 1
    assert any("configurations.c3.from: c3 -> c4 -> c3 is a cycle" in p or
               "configurations.c4.from: c4 -> c3 -> c4 is a cycle" in p for p in problems)
    assert sum("'O9': no joint of that name in configuration 'config2'" in p for p in problems) == 1


def test_working_cycle_with_derived_configurations_runs_as_with_hand_written_urdfs(tmp_path):
    """The three-link arm of the working-cycle tests (elbow stop-merge, wrist latch, the elbow
    released when its holding moment turns tensile) needs four URDFs; with three of them derived
    from 'free' (elbow_locked locks E, both_locked locks W of elbow_locked, wrist_locked locks W)
    the run is the same: the release from both_locked enters wrist_locked with W's value carried
    from both_locked's lock."""
    import tomllib

    import builders as xm
    from test_working_cycles import _three_link
    hand = _three_link(tmp_path / "hand")
    doc = tomllib.loads(hand.read_text())
    doc["configurations"] = {"free": {"urdf": "../hand/free.urdf"},
                             "elbow_locked": {"from": "free", "lock": ["E"]},
                             "both_locked": {"from": "elbow_locked", "lock": ["W"]},
                             "wrist_locked": {"from": "free", "lock": ["W"]}}
    derived = builders.write_scene(tmp_path / "derived", doc, {})
    a, b = simulate(pcmm.load_scene(derived)), simulate(pcmm.load_scene(hand))
    assert "wrist_locked" in [e["to"] for e in a.events]
    assert_same_run(a, b, tol=1e-9)
    built = a.stats["derived_configurations"]
    assert built["wrist_locked"][0]["W"] == built["both_locked"][0]["W"] == pytest.approx(0.8, abs=1e-12)
    assert built["elbow_locked"][0]["E"] == pytest.approx(-0.3, abs=1e-12)


@pytest.mark.parametrize("value", [math.pi, math.nextafter(math.pi, 4.0), math.nextafter(math.pi, 3.0)])
def test_a_lock_at_pi_keeps_the_relative_angle_a_spring_measures(tmp_path, value):
    """Example 1's config2 derived with O3 locked one ulp either side of pi (where the latch
    leaves it, by round-off): the link angles continue those of config1 at the lock, so tau3's
    measure theta3 - theta2 is the lock value, not the value 2 pi below it that the child's
    wrapped neutral angle gives when the ulp falls above pi (tau3 then pushed with 0.163 N m
    more: the config3 run of the chain test ended 0.66 rad ahead)."""
    path = three_bar(tmp_path, config2=f'from = "config1"\nlock = {{ O3 = {value!r} }}')
    mech = Mechanism(pcmm.load_scene(path))
    src, cfg = mech["config1"], mech["config2"]
    q1 = src.vector({"O1": 0.4, "O2": -1.3, "O3": value})
    q2 = cfg.vector({"O1": 0.4, "O2": -1.3})
    i2, i3 = cfg.link_index["link2"], cfg.link_index["link3"]
    rel = cfg.link_angles(q2)[i3] - cfg.link_angles(q2)[i2]
    assert rel == pytest.approx(value, abs=1e-15)
    np.testing.assert_allclose(cfg.link_angles(q2), src.link_angles(q1), rtol=0, atol=1e-15)
    # each tau_i acts on link i from the frame (Eq. 44); link3 is welded to link2 in config2
    tau = cfg.forces.generalized(q2, np.zeros(2))
    tau2, tau3 = 0.1625 - 0.0161 * (-1.3), 0.23 - 0.026 * value  # theta2 - theta1 = O2
    assert tau[0] == pytest.approx(1.955 + tau2 + tau3, abs=1e-12)  # O1 turns the whole arm
    assert tau[1] == pytest.approx(tau2 + tau3, abs=1e-12)  # O2 turns link2 and link3


@pytest.mark.parametrize("yaw", [math.pi, -math.pi, math.nextafter(math.pi, 4.0), 3 * math.pi / 2])
def test_a_hand_written_link_keeps_the_angle_its_urdf_writes(tmp_path, yaw):
    """A link welded to its parent at a yaw of +-pi (or 3 pi / 2): its neutral angle is the URDF's
    own (the sum of the joint origins' yaws), not whichever side of +-pi the composed rotation's
    round-off gives, nor the rotation's angle wrapped into (-pi, pi]."""
    urdf = builders.robot_xml("w", builders.link_xml("frame"),
                              builders.joint_xml("O1", "revolute", "frame", "link1"), builders.bar_xml("link1", 0.5, 1.0),
                              builders.joint_xml("W", "fixed", "link1", "link2", xyz=(0.5, 0.0), yaw=yaw),
                              builders.bar_xml("link2", 0.3, 1.0))
    doc = builders.scene_doc({"c": "w.urdf"}, {"O1": 0.0}, {"O1": 0.0})
    cfg = Mechanism(pcmm.load_scene(builders.write_scene(tmp_path, doc, {"w.urdf": urdf})))["c"]
    angle = cfg.link_angles(np.zeros(1))[cfg.link_index["link2"]]
    assert angle == pytest.approx(yaw, abs=1e-15)
