"""Diagnoses that name the true cause, time and field (issue 22, item 4), each on a scene of this
file: a fixed-step run that blows up is told its step is unstable (not to flip a normal), a
non-physical velocity is named as such without raw numpy warnings, a huge integer literal is a
field message, ``--quiet`` keeps the warning of a guard that never fired, a revolute guard written
in degrees is warned about at ``check``, and the assembly's other-branch warning prints angles on
the guess's branch."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest

import builders
from pcmm.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]
HANG = -math.pi / 2  # the pendulum builder's angle is from +x: hanging straight down


def cli(argv, capsys):
    rc = cli_main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return rc, out, err


# ---- (e) --quiet does not hide that the only guard never fired ------------------------------------
def test_quiet_still_warns_that_the_guard_never_fired(tmp_path, capsys):
    """A pendulum let go 0.3 rad from hanging swings to 0.3 rad on the other side (energy
    conservation) and never reaches its stop 0.4 rad out: with --quiet the run printed nothing.
    The warning goes to stderr with the closest value (-pi/2 - 0.3, 0.1 short) at the half period
    (the energy integral's quadrature)."""
    from scipy.integrate import quad
    path = builders.pendulum(tmp_path, 0.5, q0=HANG + 0.3, qs=HANG - 0.4, t_end=1.0)
    rc, out, err = cli(["run", path, "--quiet"], capsys)
    assert rc == 0 and out == ""
    w2 = 1.5 * builders.G / 0.6  # m g (L/2) / (m L^2 / 3), the builder's bar of 0.6 m
    half = 2 * quad(lambda x: 1 / math.sqrt(2 * w2 * (math.cos(x) - math.cos(0.3))), 0, 0.3, limit=200)[0]
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        f"pcmm: warning: guard of 'stop' (joint J1 decreasing to {HANG - 0.4:.9g}) did not fire: closest "), err
    closest, t = (float(x) for x in __import__("re").search(r"closest (\S+) at t = (\S+) s", lines[0]).groups())
    assert closest == pytest.approx(HANG - 0.3, abs=1e-6) and t == pytest.approx(half, abs=2e-3)
    assert lines[0].endswith(", 0.1 short")


# ---- (g) the other branch's angles are printed on the guess's turn ----------------------------------
def test_other_branch_warning_prints_angles_near_the_guess(tmp_path):
    """A four-bar (crank 0.1 on A, coupler 0.3, rocker 0.25 on D at (0.3, 0)) guessed at A = 1,
    B = 2, D = -1.7: Newton from one of the grid starts lands 27 turns away (B = -134.192, D =
    167.432 were printed).  The warning must print the other assembly within pi of each guessed
    angle; it must close the loop (the coupler's tip on the rocker's, by the bars' geometry), be
    the other branch (not the assembled posture), and lie nearer the guess than it."""
    import re
    import tomllib
    import pcmm
    from pcmm.model.assembly import assemble
    from pcmm.model.mechanism import Mechanism
    path = builders.four_bar_rocker_stop(tmp_path, 0.5, rocker_stop=1.0)
    doc = tomllib.loads(path.read_text())
    guess = {"A": 1.0, "B": 2.0, "D": -1.7}
    doc["initial"]["q"] = guess
    path.write_text(builders.dump_toml(doc))
    scene = pcmm.load_scene(path)
    q, _, notes = assemble(scene, Mechanism(scene)[scene.initial_configuration])
    (note,) = [n for n in notes if "lies nearer" in n]
    other = {k: float(v) for k, v in re.findall(r"(\w) = (-?[\d.]+(?:e[-+]?\d+)?)", note.split("given values:")[1])}
    assert all(abs(other[j] - guess[j]) <= math.pi for j in "ABD"), note

    def tip_gap(A, B, D, a=0.1, b=0.3, c=0.25, d=0.3):
        coupler = (a * math.cos(A) + b * math.cos(A + B), a * math.sin(A) + b * math.sin(A + B))
        rocker = (d + c * math.cos(D), c * math.sin(D))
        return math.dist(coupler, rocker)
    assert tip_gap(*(other[j] for j in "ABD")) < 1e-5  # 6 printed digits
    assembled = dict(zip("ABD", q))
    assert tip_gap(*(assembled[j] for j in "ABD")) < 1e-12
    wrap = lambda x: (x + math.pi) % (2 * math.pi) - math.pi  # noqa: E731
    assert abs(wrap(other["D"] - assembled["D"])) > 0.1  # the mirrored assembly, not the same posture
    assert max(abs(other[j] - guess[j]) for j in "BD") < max(abs(wrap(assembled[j] - guess[j])) for j in "BD")


# ---- (f) a revolute guard written in degrees ------------------------------------------------------
@pytest.mark.parametrize("qs, warned", [(-50.0, True), (math.radians(-50.0), False), (-2 * math.pi + 0.01, False),
                                        (7.0, True)])
def test_check_warns_of_a_guard_angle_beyond_a_turn(tmp_path, capsys, qs, warned):
    """A stop on a pendulum's revolute joint at -50 (meant in degrees) passed `pcmm check` without a
    word.  Outside [-2 pi, 2 pi] a warning gives the value in radians (math.radians: -0.872665);
    inside, nothing is said."""
    path = builders.pendulum(tmp_path, 0.5, q0=0.3, qs=qs)
    rc, out, err = cli(["check", path], capsys)
    assert rc == 0 and "valid" in out
    if warned:
        assert err == (f"pcmm: warning: {path}: transitions[0] (stop).guard.value: = {qs:g}: an angle (joint J1) of "
                       f"{qs:g} rad, {qs / (2 * math.pi):.3g} turns, outside [-2 pi, 2 pi]; guard values are in "
                       f"radians: if {qs:g} degrees is meant, write value = \"{qs:g} deg\" (= "
                       f"{qs * math.pi / 180:.6g} rad)\n")
    else:
        assert "outside [-2 pi, 2 pi]" not in err


# ---- (d) an integer literal beyond Python's int conversion ----------------------------------------
@pytest.mark.parametrize("old, new, field", [
    ("k = 2.0", "k = " + "7" * 5000, "forces[0].k"),
    ("k = 2.0", "k = 2.0\nc = [0.5, -" + "1_0" * 2500 + "]", "forces[0].c"),
])
def test_huge_integer_literal_is_a_field_message(tmp_path, old, new, field):
    """tomllib refuses an integer of more than 4300 digits with Python's advice to call
    sys.set_int_max_str_digits(), which pcmm passed on.  The message names the line and the field,
    in the words of the schema's check of integers too large for a double (401 digits and up)."""
    import pcmm
    from pcmm.errors import SceneError
    path = builders.pendulum(tmp_path, 0.5, q0=0.3, qs=-1.0, k=2.0)
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    line = 1 + next(i for i, ln in enumerate(path.read_text().splitlines()) if "7777" in ln or "1_01_0" in ln)
    with pytest.raises(SceneError) as info:
        pcmm.load_scene(path)
    digits = 5000
    assert info.value.problems == [f"{path}: line {line}: {field}: = an integer of {digits} digits: beyond the "
                                   "range of a floating-point number (about 1.8e308)"]
    # the same words as for an integer short enough to parse (the schema's own check)
    path.write_text(text.replace(old, "k = 1" + "0" * 400))
    with pytest.raises(SceneError, match=r"forces\[0\]\.k: = an integer of 401 digits: beyond the range"):
        pcmm.load_scene(path)
