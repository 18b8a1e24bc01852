"""Numbers that people write (issue 13, item 1): expression strings in scene files.

Every value is checked against the closed form it names; errors must name the file, the field
and the position in the expression; nothing is evaluated as Python."""
from __future__ import annotations

import math

import numpy as np
import pytest

import pcmm
from builders import copy_example, example_text
from pcmm.errors import SceneError
from pcmm.scene.expressions import ExpressionError, evaluate


@pytest.mark.parametrize("text, value", [
    ("pi/2", math.pi / 2), ("0.25*pi", math.pi / 4), ("30 deg", math.pi / 6), ("sqrt(3)/2", 3 ** 0.5 / 2),
    ("-0.1425 + 0.08", -0.0625), ("2**3**2", 512.0), ("-2**2", -4.0), ("(30 + 15) deg", math.pi / 4),
    ("atan2(1, -1)", 3 * math.pi / 4), ("cos(60 deg)", 0.5), ("tan(45 deg)", 1.0), ("sin(pi/6)", 0.5),
    ("e", math.e), ("1.5e-3 * 2", 3e-3), (".5", 0.5), ("2 * -3", -6.0), ("12 / 4 / 3", 1.0),
    ("10 - 4 - 3", 3.0), ("  7  ", 7.0), ("(((1)))", 1.0), ("90 deg deg", math.pi / 2 * math.pi / 180),
])
def test_values(text, value):
    assert evaluate(text) == pytest.approx(value, rel=1e-15, abs=1e-16)


@pytest.mark.parametrize("text, position, words", [
    ("3*pi/", 6, "ends too early"), ("sqr(2)", 1, "did you mean 'sqrt'"), ("2 3", 3, "operator"),
    ("__import__('os')", 12, "unexpected character"), ("__import__", 1, "unknown name"), ("1/0", 2, "division by zero"), ("sqrt(-1)", 1, "negative"),
    ("(1+2", 5, "expected ')'"), ("atan2(1)", 1, "2 arguments"), ("1e999", 1, "not finite"),
    ("pi; 1", 3, "unexpected character"), ("deg", 1, "follows a number"), ("", 1, "empty"),
    ("(-8) ** 0.5", 6, "fractional power"), ("cos 3", 5, "parentheses"), ("x.real", 2, "unexpected character"),
])
def test_errors_name_the_position(text, position, words):
    with pytest.raises(ExpressionError) as info:
        evaluate(text)
    assert info.value.position == position and words in info.value.reason


def _scene(tmp_path, text):
    return copy_example(tmp_path, scene_text=text)


def test_scene_error_names_file_field_and_position(tmp_path):
    text = example_text().replace("value = 3.141592653589793", 'value = "pi +"').replace(
        "c = 0.0196", 'c = "0.0196 * sqr(1)"').replace("O2 = 0.0,", 'O2 = "0 dg",', 1)
    path = _scene(tmp_path, text)
    with pytest.raises(SceneError) as info:
        pcmm.load_scene(path)
    probs = info.value.problems
    assert any(f"{path}: transitions[0] (O3 latches).guard.value: = 'pi +': at position 5:" in p for p in probs)
    assert any("forces[0] (tau1).c: = '0.0196 * sqr(1)': at position 10:" in p and "sqrt" in p for p in probs)
    assert any("initial.q.O2: = '0 dg': at position 3:" in p for p in probs)


def test_expression_in_list_and_name_lists_untouched(tmp_path):
    text = example_text().replace("point_b = [0.0625, 0.0]", 'point_b = ["0.125/2", "0 * pi"]')
    scene = pcmm.load_scene(_scene(tmp_path, text))
    assert scene.transitions[0].contact.point_b == (0.0625, 0.0)
    assert scene.transitions[0].guard.measure.names == ("link2", "link3")  # names stay names
    bad = example_text().replace("point_b = [0.0625, 0.0]", 'point_b = ["0.125/", 0.0]')
    with pytest.raises(SceneError, match=r"contact.point_b: = '0.125/': at position 7"):
        pcmm.load_scene(_scene(tmp_path, bad))


@pytest.mark.parametrize("stop", ["point", "joint"])
def test_pi_and_deg_scene_runs_as_example1(tmp_path, stop):
    """Example 1 written with "pi", "deg" and expressions runs the same to 1e-12; so does it with
    the latch's contact written as a joint stop on O3 at the arm "0.125/2" (issue 13's scene of
    "pi", "deg" and joint stops in one)."""
    text = (example_text().replace("value = 3.141592653589793", 'value = "180 deg"')
            .replace("q = { O1 = 0.0, O2 = 0.0, O3 = 0.0 }", 'q = { O1 = "0 deg", O2 = "0*pi", O3 = "pi - pi" }')
            .replace("value = 1.955", 'value = "1.955"').replace("k = 0.026", 'k = "0.026"')
            .replace("point_a = [0.0625, 0.0]", 'point_a = ["0.125 / 2", "sin(pi) * 0"]'))
    assert '"180 deg"' in text and '"0 deg"' in text
    if stop == "joint":
        line = next(ln for ln in text.splitlines() if ln.startswith("contact = { a = \"link2\""))
        text = text.replace(line, 'contact = { joint = "O3", arm = "0.125/2" }')
        assert 'joint = "O3"' in text and "point_b" not in text
    a = pcmm.simulate(pcmm.load_scene(pcmm_example()), pcmm.RunOptions(t_end=0.3))
    b = pcmm.simulate(pcmm.load_scene(_scene(tmp_path, text)), pcmm.RunOptions(t_end=0.3))
    assert len(a.events) == len(b.events) == 1
    assert abs(a.events[0]["t"] - b.events[0]["t"]) < 1e-12
    np.testing.assert_allclose(b.series("omega", "link3")[-1], a.series("omega", "link3")[-1], atol=1e-12)
    for link in ("link1", "link2", "link3"):
        np.testing.assert_allclose(list(b.events[0]["omega_after"].values()),
                                   list(a.events[0]["omega_after"].values()), atol=1e-12)
        np.testing.assert_allclose(b.series("theta", link)[-1], a.series("theta", link)[-1], atol=1e-12)


def pcmm_example():
    from builders import EXAMPLES
    return EXAMPLES / "three_bar.toml"
