"""Scene variations by value path (pcmm.scene.variations, Scene.with_values).

A variation must be the scene its edited TOML file would be: the same dataclasses,
the same run, and for a bad value the very same validator messages.  Each edited
file here is made by editing the TOML text, a route independent of the path walker.
"""
from __future__ import annotations

import dataclasses
import re

import pytest

import pcmm
from pcmm.errors import SceneError
from pcmm.scene.variations import parse_scalar, value_text

from builders import EXAMPLES, URDF_DIR

THREE_BAR = EXAMPLES / "three_bar.toml"
STOP = EXAMPLES / "three_bar_stop.toml"
DOUBLE = EXAMPLES / "double_folded.toml"


def edited(tmp_path, scene_file, old, new, name="edited.toml"):
    """A copy of ``scene_file`` with one text edit (URDF paths made absolute)."""
    text = scene_file.read_text()
    assert text.count(old) == 1, old
    text = text.replace(old, new).replace('"../urdf/', f'"{URDF_DIR}/')
    out = tmp_path / name
    out.write_text(text)
    return out


def problems_of(fn):
    with pytest.raises(SceneError) as info:
        fn()
    return info.value.problems


def test_value_changed_and_original_untouched():
    scene = pcmm.load_scene(THREE_BAR)
    var = scene.with_values({"forces.tau1.value": 2.0, "forces.tau3.value": 0.3, "scene.gravity[1]": -9.0})
    assert [f.value for f in var.forces] == [2.0, 0.1625, 0.3]
    assert var.gravity == (0.0, -9.0)
    assert [f.value for f in scene.forces] == [1.955, 0.1625, 0.23]  # a new scene; the original is kept
    assert scene.gravity == (0.0, -9.81)
    assert scene.source["forces"][0]["value"] == 1.955
    # a variation of a variation starts from the varied values
    assert [f.value for f in var.with_values({"forces.tau2.value": 0.0}).forces] == [2.0, 0.0, 0.3]


def test_variation_runs_as_its_edited_file(tmp_path):
    """Same run, bit for bit, as the TOML file with the value edited by hand, and as the
    dataclass edited directly (dataclasses.replace): three routes to one scene."""
    scene = pcmm.load_scene(THREE_BAR)
    var = scene.with_values({"forces.tau3.value": 0.3})
    by_file = pcmm.load_scene(edited(tmp_path, THREE_BAR, "value = 0.23", "value = 0.3"))
    tau3 = dataclasses.replace(scene.forces[2], value=0.3)
    by_replace = dataclasses.replace(scene, forces=scene.forces[:2] + (tau3,))
    assert var.forces == by_file.forces == by_replace.forces
    runs = [pcmm.simulate(s, pcmm.RunOptions(t_end=0.2)) for s in (var, by_file, by_replace)]
    t = [r.events[0]["t"] for r in runs]
    P = [r.events[0]["impulse"]["normal"] for r in runs]
    assert t[0] == t[1] == t[2] and P[0] == P[1] == P[2]
    # and the preload moved the latch: the default scene latches at 0.1672851 s (README, Table 1)
    assert t[0] < 0.1672851 - 1e-3


@pytest.mark.parametrize("scene_file, path, value, old, new", [
    (STOP, "transitions.O3 stop.restitution", 1.5, "restitution = 0.8", "restitution = 1.5"),
    (THREE_BAR, "forces.tau1.c", -1, "c = 0.0196", "c = -1"),
    (THREE_BAR, "scene.t_end", 0, "t_end = 1.0", "t_end = 0"),
    (THREE_BAR, "transitions.O3 latches.restitution", 0.5, 'type = "latch"', 'type = "latch"\nrestitution = 0.5'),
    (THREE_BAR, "forces.tau1.vlaue", 1.0, "value = 1.955", "value = 1.955\nvlaue = 1.0"),
    (THREE_BAR, "initial.q.O4", 0.1, "O3 = 0.0 }\nv", "O3 = 0.0, O4 = 0.1 }\nv"),
    (THREE_BAR, "solver.method", "RK99", 'method = "auto"', 'method = "RK99"'),
    (THREE_BAR, "forces.tau2.measure.between[1]", "link9", 'between = ["link1", "link2"]',
     'between = ["link1", "link9"]'),
])
def test_bad_value_gives_the_validators_own_message(tmp_path, scene_file, path, value, old, new):
    scene = pcmm.load_scene(scene_file)
    by_path = problems_of(lambda: scene.with_values({path: value}))
    file = edited(tmp_path, scene_file, old, new)
    by_file = problems_of(lambda: pcmm.load_scene(file))
    assert by_path == [p.replace(str(file), str(scene_file)) for p in by_file]
    assert by_path  # and there is a message


@pytest.mark.parametrize("path, words", [
    ("forces.tua1.value", ["'forces.tua1.value'", "no element named 'tua1' in forces", "closest: 'tau1'"]),
    ("forcs.tau1.value", ["no key 'forcs' in the scene", "closest: 'forces'", "'transitions'"]),
    ("scene.gravity[2]", ["scene.gravity[2] is out of range", "2 elements"]),
    ("forces.tau1.value.x", ["forces[0].value is a value (1.955)"]),
    ("transitions.O3 latch.guard.value", ["no element named 'O3 latch'", "closest: 'O3 latches'"]),
    ("forces[x].value", ["must be an index such as [0]"]),
    ("solver.", ["ends with '.'"]),
])
def test_bad_path_names_the_path_and_the_closest_keys(path, words):
    scene = pcmm.load_scene(THREE_BAR)
    text = "\n".join(problems_of(lambda: scene.with_values({path: 1.0})))
    assert text.startswith(str(THREE_BAR))
    for w in words:
        assert w in text


def test_paths_reach_arrays_by_name_index_and_drive_joint():
    scene = pcmm.load_scene(DOUBLE)
    var = scene.with_values({
        "drives.A.coefficients[1]": 0.7,  # [[drives]] go by their joint
        "configurations.config1.cut_joints.C.point_a[0]": 0.2,  # cut joints by name (same value: loop closes)
        "transitions[0].restitution": 0.5,  # any array by index
        "forces.spring D.k": 0.5,  # a name with a space
    })
    assert var.drives[0].coefficients[1] == 0.7
    assert var.transitions[0].restitution == 0.5 and scene.transitions[0].restitution == 0.8
    assert var.forces[0].k == 0.5
    assert var.configurations["config1"].cut_joints[0].point_a == (0.2, 0.0)


def test_duplicate_names_must_be_indexed(tmp_path):
    import tomllib
    from pcmm.scene.variations import set_values
    file = edited(tmp_path, THREE_BAR, 'name = "tau2"', 'name = "tau1"')
    # the loader refuses two force elements of one name (tests/test_loader_refusals.py); the path
    # walker, which edits the TOML data before any validation, still cannot pick one of them
    raw = tomllib.loads(file.read_text())
    text = "\n".join(problems_of(lambda: set_values(raw, {"forces.tau1.value": 1.0}, file)))
    assert "several elements of forces are named 'tau1'" in text and "forces[0]" in text
    assert set_values(raw, {"forces[1].value": 1.0}, file)["forces"][1]["value"] == 1.0


def test_scene_not_from_toml_has_no_values_to_vary():
    scene = dataclasses.replace(pcmm.load_scene(THREE_BAR), source=None)
    assert "not loaded from TOML" in problems_of(lambda: scene.with_values({"scene.t_end": 1.0}))[0]


def test_command_line_values_are_read_as_toml():
    assert parse_scalar("0.5") == 0.5 and type(parse_scalar("2")) is int
    assert parse_scalar("true") is True and parse_scalar("DOP853") == "DOP853"
    assert parse_scalar('"a b"') == "a b" and parse_scalar("1e-3") == 1e-3
    # the text of a value is its identity on resume: floats round-trip exactly
    for x in (0.1, 1 / 3, 2.0, -1e-300, 1.955):
        assert float(value_text(x)) == x
    assert value_text(True) == "true" and value_text(3) == "3"
    assert re.fullmatch(r"0\.30000000000000004", value_text(0.1 + 0.2))
