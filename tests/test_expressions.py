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


# ---- issue 22, item 6: hostile expressions are field messages, in linear time -----------------------
@pytest.mark.parametrize("text, position, words", [
    ("sin(1e999)", 5, "the number '1e999' is not finite"),  # was a raw ValueError (math domain error)
    ("cos(1e300 * 1e300)", 11, "result of '*' is not finite"),  # 1e600 overflows at the '*'
    ("2 * 1e308", 3, "result of '*' is not finite"),  # 2e308 > 1.797e308, the largest double
    ("1e308 + 1e308", 7, "result of '+' is not finite"),
    ("1 / 1e-320", 3, "result of '/' is not finite"),  # 1e320 > largest double
    ("(" * 170 + "1" + ")" * 170, 65, "nested more than 64 levels"),  # was a RecursionError
    ("-" * 2000 + "1", 65, "nested more than 64 levels"),
    ("2**" * 2000 + "2", 193, "nested more than 64 levels"),  # the 65th exponent starts at 3*64 + 1
])
def test_hostile_expressions_name_the_position(text, position, words):
    with pytest.raises(ExpressionError) as info:
        evaluate(text)
    assert info.value.position == position and words in info.value.reason
    assert len(str(info.value)) < 400  # a long expression is quoted around the fault, not whole


def test_nesting_limit_is_exact():
    """64 levels evaluate (each '(' adds one level below the top one); one more is refused."""
    assert evaluate("(" * 63 + "7" + ")" * 63) == 7.0
    assert evaluate("-" * 63 + "7") == -7.0  # 63 signs: odd, so negative
    with pytest.raises(ExpressionError, match="nested more than 64"):
        evaluate("(" * 64 + "7" + ")" * 64)


def test_deep_caller_stack_still_gives_a_field_message():
    """Near the interpreter's recursion limit even 20 levels overflow the stack: the parser's
    RecursionError becomes the same ExpressionError, not a traceback."""
    import sys

    def at_depth(n):
        return at_depth(n - 1) if n else evaluate("(" * 20 + "1" + ")" * 20)
    limit = sys.getrecursionlimit()
    here = len(__import__("inspect").stack(0))
    sys.setrecursionlimit(here + 60)
    try:
        with pytest.raises(ExpressionError, match="nested more than"):
            at_depth(10)
    finally:
        sys.setrecursionlimit(limit)


def test_evaluation_time_is_linear_in_length():
    """A 1 MB expression took 24 s (the tokenizer sliced the rest of the text at every token:
    quadratic).  Eight times the length must cost about eight times the time: the ratio of the
    best of three timings at 50 kB and 400 kB is below 24 (quadratic gives 64).  The timings are
    this thread's CPU time, not the wall clock: on a loaded machine a wall-clock timing counts the
    time spent waiting for a core, which may fall on the long text and not on the short one."""
    import time

    def best(n):
        text = "1 + " * (n // 4) + "1"
        times = []
        for _ in range(3):
            t0 = time.thread_time()
            assert evaluate(text) == n // 4 + 1
            times.append(time.thread_time() - t0)
        return min(times)
    small, large = best(50_000), best(400_000)
    assert large / small < 24, (small, large)


def test_hostile_expression_in_a_scene_is_a_field_message(tmp_path):
    """On a pendulum of this suite: the spring's stiffness "sin(1e999)" and a rest angle nested
    170 levels deep are each named by file and field, with the position."""
    from builders import pendulum
    path = pendulum(tmp_path, 0.5, k=2.0)
    deep = "(" * 170 + "0" + ")" * 170
    path.write_text(path.read_text().replace("k = 2.0", 'k = "sin(1e999)"').replace(
        "rest = 0.0", f'rest = "{deep}"'))
    with pytest.raises(SceneError) as info:
        pcmm.load_scene(path)
    probs = info.value.problems
    assert any(f"{path}: forces[0] (spring).k: = 'sin(1e999)': at position 5: the number '1e999' is not finite"
               in p for p in probs), probs
    assert any(f"{path}: forces[0] (spring).rest: = " in p and "at position 65: nested more than 64" in p
               for p in probs), probs
