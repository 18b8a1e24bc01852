"""Scene and URDF validation: every user mistake is one located, self-contained message.

Each row mutates the shipped Example 1 scene (or its configuration-1 URDF), written to
tmp_path, and lists text fragments the error must contain: the file, the field path, the
bad value and what is allowed.
"""
from __future__ import annotations

import re

import pytest

import pcmm
import pcmm.cli
from builders import URDF_DIR, copy_example, example_text

SCENE = "three_bar.toml"
STOP = "three_bar_stop.toml"
U1 = "three_bar_config1.urdf"


def _sub(text: str, old: str, new: str, count: int = 1, regex: bool = False) -> str:
    out = re.sub(old, new, text, count=count, flags=re.S) if regex else text.replace(old, new, count)
    assert out != text, f"mutation did not apply: {old!r}"  # a no-op mutation would test nothing
    return out


def write_case(tmp_path, target, old, new, base=SCENE, regex=False):
    """Write the example with one (or several) mutations; return the scene path."""
    scene_text = example_text(base)
    urdf_texts = {}
    muts = [(target, old, new)] if not isinstance(target, list) else target
    for tgt, o, n in muts:
        if tgt == "scene":
            scene_text = _sub(scene_text, o, n, regex=regex)
        else:
            urdf_texts[U1] = _sub(urdf_texts.get(U1, (URDF_DIR / U1).read_text()), o, n, regex=regex)
    return copy_example(tmp_path, base, scene_text=scene_text, urdf_texts=urdf_texts)



# (id, base scene, target, old, new, fragments)
ROWS = [
    pytest.param(SCENE, "scene", "rtol = 1e-10", "rtoll = 1e-10",
                 [SCENE, "solver.rtoll", "unknown key", "did you mean 'rtol'?", "allowed keys", "atol"],
                 id="unknown-key-suggests"),
    pytest.param(SCENE, "scene", "initial_configuration =", "initial_configuraton =",
                 [SCENE, "scene.initial_configuraton", "did you mean 'initial_configuration'?",
                  "scene.initial_configuration", "missing"], id="misspelt-key-is-also-missing"),
    pytest.param(SCENE, "scene", "t_end = 1.0\n", "", [SCENE, "scene.t_end", "missing", "end time"],
                 id="missing-field"),
    pytest.param(SCENE, "scene", "t_end = 1.0", 't_end = true', [SCENE, "scene.t_end", "True", "must be a number"],
                 id="wrong-type-number"),  # a string is an expression now (tests/test_expressions.py)
    pytest.param(SCENE, "scene", "t_end = 1.0", 't_end = "1.0 s"', [SCENE, "scene.t_end", "'1.0 s'", "position 5"],
                 id="bad-expression"),
    pytest.param(SCENE, "scene", "gravity = [0.0, -9.81]", 'gravity = "down"',
                 [SCENE, "scene.gravity", "'down'", "must be a list"], id="wrong-type-list"),
    pytest.param(SCENE, "scene", "gravity = [0.0, -9.81]", "gravity = [0.0, -9.81, 0.0]",
                 [SCENE, "scene.gravity", "list of 2 finite numbers"], id="gravity-3d"),
    pytest.param(SCENE, "scene", "t_end = 1.0", "t_end = -1.0", [SCENE, "scene.t_end", "-1.0", "must be > 0"],
                 id="negative-t-end"),
    pytest.param(SCENE, "scene", 'method = "auto"', 'method = "RK99"',
                 [SCENE, "solver.method", "'RK99'", "must be one of", "DOP853", "RK45"], id="unknown-method"),
    pytest.param(SCENE, "scene", 'type = "latch"', 'type = "latchh"',
                 [SCENE, "transitions[0] (O3 latches).type", "'latchh'", "'latch'", "'stop'"], id="unknown-transition-type"),
    pytest.param(STOP, "scene", "restitution = 0.8", "restitution = 1.5",
                 [STOP, "transitions[0] (O3 stop).restitution", "1.5", "[0, 1]"], id="restitution-above-1"),
    pytest.param(STOP, "scene", "restitution = 0.8", "restitution = -0.1",
                 [STOP, "transitions[0] (O3 stop).restitution", "-0.1", "[0, 1]"], id="restitution-negative"),
    pytest.param(STOP, "scene", "restitution = 0.8", 'restitution = "0.5 - 1"',  # computed, then range-checked
                 [STOP, "transitions[0] (O3 stop).restitution", "-0.5", "[0, 1]"], id="restitution-string"),
    pytest.param(STOP, "scene", "restitution = 0.8\n", "",
                 [STOP, "transitions[0] (O3 stop).restitution", "missing", "[0, 1]"], id="restitution-missing"),
    pytest.param(SCENE, "scene", "cut = [\"O3\"]", "cut = [\"O3\"]\nrestitution = 0.5",
                 [SCENE, "transitions[0] (O3 latches).restitution", "not used by a latch"], id="restitution-on-latch"),
    pytest.param(SCENE, "scene", "value = 1.955", "value = nan",
                 [SCENE, "forces[0] (tau1).value", "nan", "finite"], id="force-value-nan"),
    pytest.param(SCENE, "scene", "k = 0.0161", 'k = "soft"',
                 [SCENE, "forces[1] (tau2).k", "'soft'", "unknown name 'soft'"], id="force-k-string"),
    pytest.param(SCENE, "scene", "O3 = 0.0 }\nv", "O4 = 0.0 }\nv",
                 [SCENE, "initial.q.O4", "'O4'", "no joint of that name", U1, "did you mean 'O3'?",
                  "joint 'O3'", "has no value"], id="unknown-joint-initial"),
    pytest.param(SCENE, "scene", 'cut = ["O3"]', 'cut = ["O4"]',
                 [SCENE, "transitions[0] (O3 latches).cut", "'O4'", "no joint of that name", U1,
                  "did you mean 'O3'?"], id="unknown-cut-joint"),
    pytest.param(SCENE, "scene", 'b = "link3"', 'b = "link4"',
                 [SCENE, "transitions[0] (O3 latches).contact.b", "'link4'", "no link of that name",
                  "did you mean 'link3'?"], id="unknown-contact-link"),
    pytest.param(SCENE, "scene", 'on = { link = "link1" }', 'on = { link = "lnk1" }',
                 [SCENE, "forces[0] (tau1).on.link", "'lnk1'", "did you mean 'link1'?", "config1", "config2"],
                 id="unknown-force-link"),
    pytest.param(SCENE, "scene", 'to = "config2"', 'to = "config3"',
                 [SCENE, "transitions[0] (O3 latches).to", "'config3'", "no such configuration", "config1, config2"],
                 id="unknown-configuration"),
    pytest.param(SCENE, "scene", U1, "nope.urdf",
                 [SCENE, "configurations.config1.urdf", "nope.urdf", "URDF file not found"], id="missing-urdf"),
    pytest.param(SCENE, "urdf", "</robot>", "", [SCENE, "configurations.config1.urdf", U1, "malformed URDF XML"],
                 id="malformed-xml"),
    pytest.param(SCENE, "urdf", r'(<link name="link2">.*?)<inertial>.*?</inertial>', r"\1",
                 [U1, "link 'link2'", "has no <inertial>"], id="link-without-inertial"),
    pytest.param(SCENE, "urdf", '<mass value="0.195"/>', '<mass value="-0.195"/>',
                 [U1, "link 'link2'", "'-0.195'", "mass must be a finite number > 0"], id="negative-mass"),
    pytest.param(SCENE, "urdf", '<mass value="0.195"/>', '<mass value="0"/>',
                 [U1, "link 'link2'", "'0'", "mass must be a finite number > 0"], id="zero-mass"),
    pytest.param(SCENE, "urdf", '<mass value="0.39"/>', '<mass value="nan"/>',
                 [U1, "link 'link1'", "'nan'", "mass must be a finite number > 0"], id="nan-mass"),
    pytest.param(SCENE, "urdf", 'izz="0.00025390625"', 'izz="-0.001"',
                 [U1, "link 'link2'", "not positive definite"], id="inertia-not-positive-definite"),
    pytest.param(SCENE, "urdf", 'iyy="0.00203775"', 'iyy="0.02"',
                 [U1, "link 'link1'", "triangle inequality"], id="inertia-impossible"),
    pytest.param(SCENE, "urdf", r'(<joint name="O2".*?)<axis xyz="0 0 1"/>', r'\1<axis xyz="1 0 0"/>',
                 [U1, "joint 'O2'", "(1.0, 0.0, 0.0)", "not normal to the xy plane", "(0 0 1)"], id="axis-not-z"),
    pytest.param(SCENE, "urdf", r'(<joint name="O1".*?)<axis xyz="0 0 1"/>', r'\1<axis xyz="0 0 -1"/>',
                 [U1, "joint 'O1'", "(0.0, 0.0, -1.0)", "use (0 0 1)"], id="axis-minus-z"),
    pytest.param(SCENE, "urdf", 'type="revolute"', 'type="continuous"',
                 [U1, "joint 'O1'", "'continuous'", "allowed: revolute, prismatic, planar, fixed"],
                 id="continuous-joint"),
    pytest.param(SCENE, "scene", "t_end = 1.0", "t_end = = 1.0", [SCENE, "not valid TOML", "line"],
                 id="invalid-toml"),
]


@pytest.mark.parametrize("base,target,old,new,fragments", ROWS)
def test_scene_error_names_file_field_value(tmp_path, base, target, old, new, fragments):
    path = write_case(tmp_path, target, old, new, base=base, regex=old.startswith("("))
    with pytest.raises((pcmm.SceneError, pcmm.ModelError)) as info:
        pcmm.load_scene(path)
    text = info.value.text()
    for frag in fragments:
        assert frag in text, f"{frag!r} not in:\n{text}"
    assert "Traceback" not in text


# ---- several problems at once --------------------------------------------------------------------
TWO = [
    pytest.param([("scene", "rtol = 1e-10", "rtoll = 1e-10"), ("scene", "t_end = 1.0", "t_end = -1.0")],
                 ["solver.rtoll", "scene.t_end"], id="two-scene-keys"),
    pytest.param([("scene", "t_end = 1.0", "t_end = -1.0"), ("urdf", '<mass value="0.195"/>', '<mass value="-0.195"/>')],
                 ["scene.t_end", "link 'link2'"], id="scene-and-urdf"),
    pytest.param([("urdf", '<mass value="0.39"/>', '<mass value="0"/>'),
                  ("urdf", 'izz="0.00025390625"', 'izz="-0.001"')],
                 ["link 'link1'", "link 'link2'"], id="two-urdf-problems"),
    pytest.param([("scene", 'b = "link3"', 'b = "link4"'), ("scene", 'cut = ["O3"]', 'cut = ["O4"]')],
                 ["contact.b", "'link4'", ".cut", "'O4'"], id="two-names"),
    pytest.param([("scene", "t_end = 1.0", "t_end = -1.0"), ("scene", 'b = "link3"', 'b = "link4"')],
                 ["scene.t_end", "contact.b", "'link4'"], id="value-and-name"),
]


@pytest.mark.parametrize("mutations,fragments", TWO)
def test_all_problems_reported_at_once(tmp_path, mutations, fragments):
    path = write_case(tmp_path, mutations, None, None)
    with pytest.raises((pcmm.SceneError, pcmm.ModelError)) as info:
        pcmm.load_scene(path)
    err = info.value
    assert len(err.problems) >= 2
    text = err.text()
    assert text.startswith(f"{len(err.problems)} problems:")
    for frag in fragments:
        assert frag in text, f"{frag!r} not in:\n{text}"


def test_scene_file_not_found(tmp_path):
    with pytest.raises(pcmm.SceneError) as info:
        pcmm.load_scene(tmp_path / "absent.toml")
    assert "absent.toml" in info.value.text() and "not found" in info.value.text()



def test_an_inline_table_broken_over_lines_says_so(tmp_path):
    """tomllib's "Invalid initial character for a key part" did not say that TOML 1.0 keeps an
    inline table on one line (a newcomer copied a wrapped cut_joints entry from a page)."""
    path = tmp_path / "wrapped.toml"
    path.write_text('x = [ { a = 1,\n      b = 2 } ]\n')
    with pytest.raises(pcmm.SceneError) as info:
        pcmm.load_scene(path)
    assert "inline table { ... } runs past the end of its line" in info.value.text()
    path.write_text('x = { a = 1 }\ny = "{" = 2\n')  # a brace in a string, a closed table: no hint
    with pytest.raises(pcmm.SceneError) as info:
        pcmm.load_scene(path)
    assert "inline table" not in info.value.text()

# ---- the command line: one message, non-zero status, no traceback ----------------------------------
CLI_ROWS = [
    pytest.param(SCENE, "scene", "rtol = 1e-10", "rtoll = 1e-10", "solver.rtoll", id="unknown-key"),
    pytest.param(SCENE, "urdf", '<mass value="0.195"/>', '<mass value="-0.195"/>', "link 'link2'", id="bad-mass"),
    pytest.param(SCENE, "scene", "t_end = 1.0", "t_end = = 1.0", "not valid TOML", id="invalid-toml"),
    pytest.param(SCENE, "urdf", "</robot>", "", "malformed URDF XML", id="malformed-xml"),
    pytest.param(STOP, "scene", "restitution = 0.8", "restitution = 1.5", "restitution", id="restitution"),
]


@pytest.mark.parametrize("command", ["run", "check"])
@pytest.mark.parametrize("base,target,old,new,fragment", CLI_ROWS)
def test_cli_reports_scene_errors_cleanly(tmp_path, capsys, command, base, target, old, new, fragment):
    path = write_case(tmp_path, target, old, new, base=base)
    argv = [command, str(path)] + (["--quiet"] if command == "run" else [])
    rc = pcmm.cli.main(argv)
    out, err = capsys.readouterr()
    assert rc != 0
    assert err.count("pcmm: error:") == 1 and err.startswith("pcmm: error:")
    assert fragment in err and path.name in err
    assert "Traceback" not in err and "Traceback" not in out
    assert list(tmp_path.glob("*.npz")) == []  # nothing simulated, nothing saved


def test_a_configuration_at_fault_is_reported_once_not_at_every_reference(tmp_path):
    """config2's URDF name has a typo: that is the one problem (with the file it probably meant),
    not also one "no such configuration" for the transition that merges into it."""
    path = copy_example(tmp_path, scene_text=example_text().replace(
        'urdf = "three_bar_config2.urdf"', 'urdf = "three_bar_config_2.urdf"'))
    with pytest.raises(pcmm.SceneError) as err:
        pcmm.load_scene(path)
    assert err.value.problems == [
        f"{path}: configurations.config2.urdf: {tmp_path / 'three_bar_config_2.urdf'}: URDF file not found "
        "(did you mean three_bar_config2.urdf or three_bar_config1.urdf?)"]


def test_a_broken_expression_is_not_also_reported_missing(tmp_path):
    path = copy_example(tmp_path, scene_text=example_text().replace("value = 3.141592653589793", 'value = "180 degs"'))
    assert '"180 degs"' in path.read_text()
    with pytest.raises(pcmm.SceneError) as err:
        pcmm.load_scene(path)
    (problem,) = err.value.problems
    assert "guard.value: = '180 degs': at position 5: unexpected 'degs'" in problem
