"""The guard's posture that `pcmm check` judges is the one the run reaches (issue 22: no false
finding, no false clean bill; pcmm/run/checks.py: path_posture).

The check solves for a posture where a guard meets its value and reports what is wrong there. The
nearest solution to the start can lie where the run never goes: the other crossing of a pendulum's
circle with a wall (above the start, while the lever swings down), or the other assembly of a
four-bar's crank for the rocker's stop angle (where the rocker passes the value the other way, so
the guard does not fire). For a configuration whose loops leave one freedom, the check now follows
that path from the start, in the direction the mechanism moves (its initial velocity, else its loads
at rest), as far as its energy carries it (then back the other way), and says which posture it used.

Mechanisms: tests/builders.py's lever on a wall (a uniform bar, m = 0.4 kg, L = 0.25 m, I_O = m L^2/3,
whose tip meets the vertical wall x = L cos 40 deg at theta = +-40 deg) and four-bar with a rocker stop.
"""
from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

import builders
import pcmm
from pcmm.run.checks import check_scene

M, L, G = 0.4, 0.25, builders.G
I_O = M * L ** 2 / 3
THETA_S = math.radians(-40.0)


def lever(tmp_path, q0, w0=0.0, friction=None):
    path = builders.lever_on_wall(tmp_path, THETA_S, q0, friction=friction)
    doc = tomllib.loads(path.read_text())
    doc["initial"]["v"] = {"J1": w0}
    path.write_text(builders.dump_toml(doc))
    return path


def test_lever_released_above_level_is_judged_where_it_strikes(tmp_path):
    """Released at rest at +0.1 rad, the lever swings down (gravity's moment -m g (L/2) cos 0.1 < 0)
    and strikes at -40 deg. The nearest solution, +40 deg (0.598 rad away against 0.798), was judged
    before: the frictionless wall's warning then gave the tip's direction there, (-0.643, 0.766), and
    told the user to write normal = (0.643, -0.766), which at the real strike is 80 deg off the path.
    At -40 deg the tip moves along (-sin theta_s, cos theta_s) = (0.643, 0.766) (by hand), which the
    warning must name, and the posture it used with it."""
    report = check_scene(pcmm.load_scene(lever(tmp_path, 0.1)))
    assert report.postures["tip strikes wall"][0] == pytest.approx(THETA_S, abs=1e-12)
    [w] = report.warnings
    u = f"[{-math.sin(THETA_S):.9g}, {math.cos(THETA_S):.9g}]"
    assert f"is 50 deg off the direction {u} in which joint 'J1' moves the contact point" in w
    assert f"write normal = {u}" in w
    assert w.endswith("[at the guard's posture reached along the path from the initial posture (J1 = 0.1), "
                      "released at rest, in the direction its loads push it, after 0.8 of path: J1 = -0.698132]")


# the speed upwards from level that just carries the tip to the wall at +40 deg: I_O w^2 / 2 = m g (L/2) sin 40 deg
W_UP = math.sqrt(2 * M * G * (L / 2) * math.sin(-THETA_S) / I_O)   # 8.703 rad/s


@pytest.mark.parametrize("w0, theta", [(0.95 * W_UP, THETA_S), (1.05 * W_UP, -THETA_S)])
def test_an_upward_start_strikes_above_only_with_the_energy_to_get_there(tmp_path, w0, theta):
    """From level, thrown upwards at w0: below W_UP = 8.703 rad/s (energy, by hand) the lever turns
    back before the wall's upper crossing and strikes the lower one on the way down; above it, it
    strikes the upper one on the way up. The check judges the posture the run's first strike has."""
    path = lever(tmp_path, 0.0, w0, friction=0.3)
    report = check_scene(pcmm.load_scene(path))
    assert report.problems == [] and report.warnings == []
    assert report.postures["tip strikes wall"][0] == pytest.approx(theta, abs=1e-12)
    assert ("after the motion turns back" in report.reach["tip strikes wall"]) == (theta < 0)
    x, y = pcmm.simulate(pcmm.load_scene(path)).events[0]["contact_point"]  # the tip (L cos, L sin) at the strike
    assert math.atan2(y, x) == pytest.approx(theta, abs=1e-8)


def four_bar_crank_angles(a, b, c, d, rocker):
    """Both crank angles closing the four-bar at a rocker angle (closed form): the crank tip
    a (cos A, sin A) is at b from the rocker tip R = (d + c cos D, c sin D), so
    R . (cos A, sin A) = (|R|^2 + a^2 - b^2) / (2 a)."""
    R = np.array([d + c * math.cos(rocker), c * math.sin(rocker)])
    k = (R @ R + a * a - b * b) / (2 * a)
    base, half = math.atan2(R[1], R[0]), math.acos(k / np.linalg.norm(R))
    return [(base + s * half) % (2 * math.pi) for s in (1, -1)]


def test_four_bar_rocker_stop_is_judged_on_the_crank_angle_the_run_reaches(tmp_path):
    """tests/builders.py's four-bar (a, b, c, d = 0.1, 0.3, 0.25, 0.3) under a crank torque from A = 1
    rad: the rocker reaches 1.7 rad at two crank angles, 1.501 and 6.275 rad (closed form). Turning
    forward from 1, the crank passes 1.501 with the rocker rising through 1.7 (the decreasing guard
    does not fire) and strikes at 6.275. The nearest solution, 1.501, was judged before."""
    path = builders.four_bar_rocker_stop(tmp_path, 0.5, 1.7, theta0=1.0, rocker0=2.0)
    report = check_scene(pcmm.load_scene(path))
    crank = report.postures["rocker stop"][0]
    low, high = sorted(four_bar_crank_angles(0.1, 0.3, 0.25, 0.3, 1.7))
    assert (low, high) == pytest.approx((1.50148602, 6.27546381), abs=1e-8)
    assert crank % (2 * math.pi) == pytest.approx(high, abs=1e-9)
    assert "reached along the path from the initial posture" in report.reach["rocker stop"]
    run = pcmm.simulate(pcmm.load_scene(path))
    upto = run.t <= run.events[0]["t"]  # the first segment ends at the strike (its last sample)
    assert run.series("q", "A")[upto][-1] % (2 * math.pi) == pytest.approx(high, abs=1e-6)


def test_two_freedoms_say_the_check_could_not_tell(tmp_path):
    """Two bars on two joints (no loop): the posture space has two freedoms, no single path; the
    check keeps the nearest solution and says it could not tell whether the run reaches it."""
    report = check_scene(pcmm.load_scene(builders.two_link(tmp_path, 0.5, 1.0, 1.0)))
    assert "whether the run reaches it pcmm could not tell" in report.reach["hit"]


def driven_slider_crank(tmp_path, coefficients):
    """tests/builders.py's slider-crank whose slider strikes a stop at x(-1 rad), with its crank driven
    by ``coefficients`` instead of its motor (the stop's x is also x(+1 rad): x = a cos + sqrt(b^2 - a^2 sin^2))."""
    path = builders.slider_crank_stop(tmp_path, 0.5, theta0=-2.0, theta_stop=-1.0)
    doc = tomllib.loads(path.read_text())
    del doc["forces"]
    doc["initial"]["v"] = {"A": coefficients[1] if len(coefficients) > 1 else 0.0}
    doc["drives"] = [{"joint": "A", "coefficients": list(coefficients)}]
    path.write_text(builders.dump_toml(doc))
    return path


def test_a_drive_turning_the_crank_away_reaches_the_stop_after_most_of_a_turn(tmp_path):
    """The crank driven at -4 rad/s from -2 rad turns away from -1 rad: the slider first goes back,
    then forward to the stop at the crank's other solution, 1 - 2 pi rad, at t = (-2 - (1 - 2 pi)) / 4
    = 0.8208 s, where the run stops (a driven loop has no freedom to take the impulse). The nearest
    solution, -1 rad, was judged before."""
    path = driven_slider_crank(tmp_path, [-2.0, -4.0])
    report = check_scene(pcmm.load_scene(path))
    assert report.postures["stop"][0] % (2 * math.pi) == pytest.approx(1.0, abs=1e-9)
    assert "in the direction of its initial velocity" in report.reach["stop"]  # the drive's rate
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(pcmm.load_scene(path))
    text = info.value.text()
    assert "cannot take an impulse along its normal" in text
    assert float(text.split("t = ", 1)[1].split(" s", 1)[0]) == pytest.approx((-2.0 - (1.0 - 2 * math.pi)) / 4.0, abs=1e-9)


def test_a_constant_drive_holds_the_path_still(tmp_path):
    """The crank held at -2 rad by a constant drive: the loop's one freedom is held, the slider never
    moves, the guard cannot fire: the check says so and judges nothing."""
    report = check_scene(pcmm.load_scene(driven_slider_crank(tmp_path, [-2.0])))
    assert report.postures == {}
    [w] = report.warnings
    assert "its drives (A) are constant and hold the configuration's one freedom still" in w


def test_a_spinning_lever_meets_an_angle_guard_beyond_a_turn(tmp_path):
    """A coordinate guard is not periodic: a lever thrown up from level at 40 rad/s has the energy to
    go over the top (I_O w^2 / 2 = 0.667 J against m g L/2 = 0.49 J) and spins; it meets J1 = 7 rad
    (more than a turn) on its second turn, where the run's guard fires (its stop on the frame merges
    the lever there)."""
    w0 = 40.0
    assert I_O * w0 ** 2 / 2 > M * G * L / 2
    path = builders.pendulum(tmp_path, 0.5, L=L, m=M, q0=0.0, w0=w0, qs=7.0, direction="increasing")
    report = check_scene(pcmm.load_scene(path))
    assert report.postures["stop"][0] == pytest.approx(7.0, abs=1e-12)
    assert "in the direction of its initial velocity" in report.reach["stop"]
    run = pcmm.simulate(pcmm.load_scene(path))
    before = run.t < run.events[0]["t"]
    assert np.max(run.series("q", "J1")[before]) < 7.0 < np.max(run.series("q", "J1")[before]) + 0.5


HANG = -math.pi / 2
P_L, P_M = 0.6, 1.5   # tests/builders.py's pendulum bar
W_03 = math.sqrt(2 * P_M * G * (P_L / 2) * (1 - math.cos(0.3)) / (P_M * P_L ** 2 / 3))  # swings 0.3 rad from hanging


@pytest.mark.parametrize("q0, w0, qs, direction, how", [
    (HANG + 0.3, 0.0, HANG - 0.2, "increasing", "as the motion turns back"),   # passed falling, fires rising
    (HANG, W_03, HANG - 0.2, "decreasing", "after the motion turns back"),     # up first, then down through it
    (HANG, W_03, HANG - 0.4, "decreasing", None),                              # beyond the swing
])
def test_a_swing_meets_a_rising_or_falling_guard_where_the_run_does(tmp_path, q0, w0, qs, direction, how):
    """A pendulum swinging 0.3 rad either side of hanging (energy, by hand: w0 = 2.21 rad/s from
    hanging, or at rest 0.3 rad out) meets a guard on its angle only in the guard's direction: the
    check follows the swing through its turning points and says when the run's guard fires (the run
    confirms: it fires at qs, or never)."""
    path = builders.pendulum(tmp_path, 0.5, q0=q0, w0=w0, qs=qs, direction=direction, t_end=2.0)
    report = check_scene(pcmm.load_scene(path))
    run = pcmm.simulate(pcmm.load_scene(path))
    if how is None:
        [w] = report.warnings
        assert f"swings between two turning points where its energy runs out (dampers left out), J1 = " \
               f"{HANG + 0.3:.6g} and J1 = {HANG - 0.3:.6g}" in w
        assert run.events == []
        return
    assert report.postures["stop"][0] == pytest.approx(qs, abs=1e-12)
    assert how in report.reach["stop"]
    assert run.events[0]["name"] == "stop"
