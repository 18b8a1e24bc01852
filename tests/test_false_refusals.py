"""Valid scenes that pcmm refused, and messages that blamed the wrong thing (issue 22, "no false
failure"; met by a newcomer modelling a pawl and a press, task h-faults).

The mechanism of most tests is a lever of my own (tests/builders.py: lever_on_wall): a uniform bar
(m = 0.4 kg, L = 0.25 m, I_O = m L^2 / 3) on a pivot, released at rest, whose tip strikes a vertical
frame wall x = L cos(theta_s) at theta_s = -40 deg. The wall's normal (1, 0) is 50 deg off the tip's
path (0.643, 0.766), so every number below is derived by hand along that oblique normal."""
from __future__ import annotations

import math

import pytest

import builders
import pcmm
from builders import G, copy_example, example_text
from pcmm.run.checks import check_scene

M, L = 0.4, 0.25
I_O = M * L ** 2 / 3
THETA_S = math.radians(-40.0)
E = 0.5


def check(path):
    return check_scene(pcmm.load_scene(path))


def omega_at_wall(q0: float) -> float:
    """|theta'| at the wall from rest at q0: I_O w^2 / 2 = m g (L/2) (sin q0 - sin theta_s)."""
    return math.sqrt(2 * M * G * (L / 2) * (math.sin(q0) - math.sin(THETA_S)) / I_O)


# ---- 1. an oblique normal on a one-coordinate pair ----------------------------------------------
@pytest.mark.parametrize("q0", [0.0, -0.2, -0.5, -0.65])
def test_oblique_wall_with_friction_passes_check_from_any_start(tmp_path, q0):
    """With friction the normal is the wall's: it fixes the friction cone and Routh's process, so
    an oblique wall is no fault. The newcomer's pawl was refused from -0.9 rad only (its guard
    posture was found from there, not from 0): the answer must not depend on the start."""
    report = check(builders.lever_on_wall(tmp_path, THETA_S, q0, friction=0.3))
    assert report.problems == []
    assert not [w for w in report.warnings if "contact.normal" in w]
    assert report.postures["tip strikes wall"][0] == pytest.approx(THETA_S, abs=1e-12)


def test_oblique_frictionless_wall_is_a_warning_and_its_impulse_is_the_walls(tmp_path):
    """Frictionless, the normal's angle alpha = 50 deg changes no velocity: Newton's law along n
    gives theta'+ = -e theta'-. The normal row is J_n = n . dx_tip/dtheta = L sin 40 deg, so the
    wall's impulse is P_n = I_O (1 + e) w / (L sin 40 deg), 1/cos 50 deg = 1.556 times the
    I_O (1 + e) w / L an impulse along the tip's path would take: a warning (55.6 % larger), not
    a refusal, and the run reports exactly that P_n."""
    path = builders.lever_on_wall(tmp_path, THETA_S, -0.3)
    report = check(path)
    assert report.problems == []
    [w] = [w for w in report.warnings if "contact.normal" in w]
    assert "is 50 deg off" in w and "55.6 % larger" in w and "Right for a frictionless wall" in w
    run = pcmm.simulate(pcmm.load_scene(path))
    first = run.events[0]
    w_minus = omega_at_wall(-0.3)
    p_wall = I_O * (1 + E) * w_minus / (L * math.sin(-THETA_S))
    assert first["impulse"]["normal"] == pytest.approx(p_wall, rel=1e-9)
    assert first["impulse"]["normal"] == pytest.approx(I_O * (1 + E) * w_minus / L / math.cos(math.radians(50)),
                                                       rel=1e-9)
    assert first["normal_velocity"]["after"] == pytest.approx(-E * first["normal_velocity"]["before"], rel=1e-9)


def test_oblique_frictional_normal_between_two_moving_links_passes(tmp_path):
    """The three-bar latch's normal tilted by atan 0.3 stays an error frictionless (the contact is
    joint O3's own stop: tests/test_authoring.py), but with friction it is a surface, accepted."""
    text = example_text().replace("normal = [0.0, 1.0]", "normal = [0.3, 1.0], friction = 0.5")
    assert "friction = 0.5" in text
    report = check(copy_example(tmp_path, scene_text=text))
    assert report.problems == []


# ---- 2. the guard's posture from a start where the guard is stationary ------------------------------
@pytest.mark.parametrize("q0", [0.0, -0.1, -0.6])
def test_guard_posture_found_where_the_gap_is_stationary(tmp_path, q0):
    """Level (q0 = 0) the tip's gap L cos q - L cos theta_s has zero slope: Newton made no step and
    check warned "no posture reaches it ... may never fire" of a guard that fires; from -0.1 rad it
    landed a turn away. The posture is theta_s = -40 deg (the nearer of +-40 deg, the lower from
    level), where the run's first strike indeed comes."""
    path = builders.lever_on_wall(tmp_path, THETA_S, q0, friction=0.3)
    report = check(path)
    assert report.problems == [] and report.warnings == []
    assert report.postures["tip strikes wall"][0] == pytest.approx(THETA_S, abs=1e-12)


def test_unreachable_guard_is_not_claimed_unreachable_only_not_found(tmp_path):
    """A wall beyond the tip's reach (x = 1.2 L). The lever released at rest at -0.3 rad swings,
    down, by energy (m g (L/2) sin q constant), between its turning points -0.3 and -pi + 0.3 rad; the
    check follows that path (tests/test_reachable_posture.py) and says the guard is not met between
    them, naming both, and skips the contact checks; before, a Newton solve found no posture and
    said only that it could not tell."""
    path = builders.lever_on_wall(tmp_path, THETA_S, -0.3, friction=0.3)
    path.write_text(path.read_text().replace(repr(L * math.cos(THETA_S)), repr(1.2 * L)))
    report = check(path)
    assert report.problems == []
    [w] = report.warnings
    assert "guard.value: = 0: the path from the initial posture (J1 = -0.3) swings between two turning points" in w
    turns = [float(x) for x in w.split("(dampers left out), J1 = ")[1].split(", and")[0].split(" and J1 = ")]
    assert sorted(turns) == pytest.approx([-math.pi + 0.3, -0.3], abs=1e-5)
    assert "the guard cannot fire unless a force adds energy" in w and "contact and pose checks were skipped" in w


# ---- 3. a driven mechanism with no free coordinate strikes a stop --------------------------------
THETA0, OMEGA, THETA_STOP = -2.0, 4.0, -1.0


def driven_slider_crank(folder):
    """tests/builders.slider_crank_stop with its crank A driven at OMEGA (a [[drives]] row) instead
    of its motor torque: 3 coordinates (A, B, P), the revolute cut joint C takes 2, the drive the
    last. The slider reaches the stop when the crank reaches THETA_STOP, at t = 1/OMEGA = 0.25 s."""
    import tomllib
    path = builders.slider_crank_stop(folder, 0.5, theta0=THETA0, theta_stop=THETA_STOP)
    doc = tomllib.loads(path.read_text())
    del doc["forces"]
    doc["initial"]["v"] = {"A": OMEGA}  # the other rates follow from the loop
    doc["drives"] = [{"joint": "A", "coefficients": [THETA0, OMEGA]}]
    path.write_text(builders.dump_toml(doc))
    return path


def test_check_warns_that_a_driven_loop_has_no_freedom_at_the_strike(tmp_path):
    report = check(driven_slider_crank(tmp_path))
    assert report.problems == []
    [w] = report.warnings
    assert "transitions[0] (stop).contact: at the guard's posture configuration 'free' has no free coordinate" in w
    assert "(3 coordinates; its loops leave 1 and drives[0] ('A') prescribes it)" in w
    assert "the run will stop at the strike" in w and "`torque` force" in w
    # the same loop under a motor torque keeps its crank free: no warning
    assert check(builders.slider_crank_stop(tmp_path / "torque", 0.5, theta0=THETA0, theta_stop=THETA_STOP)).warnings == []


def test_run_names_the_drive_when_no_coordinate_is_free(tmp_path):
    """The run stops at the strike, t = (THETA_STOP - THETA0) / OMEGA, blaming the drive, not the
    contact normal and cut joints (which are right)."""
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(pcmm.load_scene(driven_slider_crank(tmp_path)))
    text = info.value.text()
    t = float(text.split("t = ", 1)[1].split(" s", 1)[0])
    assert t == pytest.approx((THETA_STOP - THETA0) / OMEGA, abs=1e-9)
    assert "cannot take an impulse along its normal" in text
    assert "configuration 'free' has no free coordinate there: its loops and cut joints leave 1 and the drive on 'A'" in text
    assert "check the contact normal and cut joints" not in text


# ---- 4. a pin on a one-freedom pendulum with finite friction -------------------------------------
def test_pin_on_one_freedom_is_refused_as_redundant_not_as_slipping(tmp_path):
    """Pinning the lever's tip adds two rows to one coordinate: the velocity after is unique (the
    lever stops), the impulse's split between the pin and the pivot is not. Along the lever the
    pivot can carry any part of it, so the tip's impulse may be any F with F . u fixed (u the tip's
    path, 50 deg off the normal): with mu = 0.3 (16.7 deg) some F lies in the cone, and the
    minimum-norm split's tan 50 deg = 1.19 says nothing. The motion is determined (the rows are
    consistent: the run enters the pin), but whether the pin lifts off or slips is not: the run
    stops when its guards first read the indeterminate force, as it does with friction = "stick"."""
    for friction in (0.3, "stick"):
        path = builders.lever_on_wall(tmp_path / str(friction), THETA_S, -0.3, friction=friction, kind="pin")
        with pytest.raises(pcmm.SimulationError) as info:
            pcmm.simulate(pcmm.load_scene(path))
        text = info.value.text()
        assert "the point held by cut joint 'tip' is held by compression (and friction) only, but its force is " \
               "statically indeterminate: the rows (tip.fx, tip.fy) are redundant" in text
        assert "would slip" not in text


def test_friction_cone_over_every_split_by_hand():
    """n = (0, 1), t = (1, 0), mu = 0.5; the impulse F = (1, 1) (|F_t| / F_n = 1) moved along K:
    along n, F = (1, 1 + s) enters the cone for s >= 1; along t, (1 + s, 1) at s = -1. From
    (1, 0) along (1, 0.1): F_n = 0.1 s > 0 needs s > 0, and then 1 + s > 0.05 s: never. No K: F
    itself, outside with mu = 0.5, on the cone's edge with mu = 1."""
    from pcmm.events.pins import _inside_cone
    import numpy as np
    n, t, F = np.array([0.0, 1.0]), np.array([1.0, 0.0]), np.array([1.0, 1.0])
    assert _inside_cone(F, np.array([[0.0], [1.0]]), n, t, 0.5)
    assert _inside_cone(F, np.array([[1.0], [0.0]]), n, t, 0.5)
    assert not _inside_cone(np.array([1.0, 0.0]), np.array([[1.0], [0.1]]), n, t, 0.5)
    assert not _inside_cone(F, np.zeros((2, 0)), n, t, 0.5)
    assert _inside_cone(F, np.zeros((2, 0)), n, t, 1.0)
    assert _inside_cone(F, np.eye(2), n, t, 0.0)  # any impulse: n itself, mu = 0


# ---- 5. a flipped normal at the start ------------------------------------------------------------
def test_flipped_normal_at_the_start_suggests_flipping_it(tmp_path):
    """Normal (-1, 0): level, the tip is L - L cos 40 deg = 0.0585 m from the wall along -n, so the
    gap reads -0.0585, past its value: the run refuses to start. The bodies are apart, along -n,
    and the message says to flip the normal to [1, 0] (as well as the old advice)."""
    path = builders.lever_on_wall(tmp_path, THETA_S, 0.0, friction=0.3, normal=(-1.0, 0.0))
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(pcmm.load_scene(path))
    text = info.value.text()
    apart = L - L * math.cos(THETA_S)
    assert f"gap is {apart:.3g} past the value 0" in text and "start the bodies apart (initial.q)" in text
    assert f"b's point {apart:.3g} m from a's along -n" in text and "flip contact.normal to [1, 0]" in text


# ---- the newcomer's own pawl: one verdict whatever the start -------------------------------------
@pytest.mark.parametrize("q0", [0.0, -0.1, -0.9])
def test_newcomer_pawl_passes_check_from_every_start(tmp_path, q0):
    """The pawl of tests/test_newcomer_mechanisms.py (its strike checked there against Routh's
    process by hand), started level, a little below, and at -0.9 rad (refused before): check finds
    the strike's posture, theta_s = -60 deg, every time and reports nothing."""
    from test_newcomer_mechanisms import PAWL_TOML, PAWL_URDF, THETA_S as PAWL_THETA_S
    (tmp_path / "pawl.urdf").write_text(PAWL_URDF)
    path = tmp_path / "pawl.toml"
    path.write_text(PAWL_TOML.replace("q = { pivot = 0.0 }", f"q = {{ pivot = {q0!r} }}"))
    assert f"pivot = {q0!r}" in path.read_text()
    report = check(path)
    assert report.problems == [] and report.warnings == []
    assert report.postures["tip strikes wall"][0] == pytest.approx(PAWL_THETA_S, abs=1e-12)


@pytest.mark.parametrize("q0", [0.0, -0.6])
def test_frictionless_wall_verdict_does_not_depend_on_the_start(tmp_path, q0):
    report = check(builders.lever_on_wall(tmp_path, THETA_S, q0))
    assert report.problems == []
    assert [w for w in report.warnings if "contact.normal" in w and "is 50 deg off" in w]


def test_guard_posture_is_the_one_the_run_reaches_even_outside_the_joint_limits(tmp_path):
    """With the pivot limited to [-0.5, 1e6] rad the wall's -40 deg posture (-0.698 rad) lies
    outside the joint's range. Released at rest from level, the lever swings down (gravity's moment
    about the pivot, -m g (L/2) cos 0, is negative) and strikes there, not at +40 deg, which it never
    reaches: check judges -40 deg and warns that it lies outside the limits. (It used to keep +40 deg,
    inside them, and say nothing: a clean bill on a posture the run never reaches.)"""
    path = builders.lever_on_wall(tmp_path, THETA_S, 0.0, friction=0.3)
    urdf = tmp_path / "lever.urdf"
    urdf.write_text(urdf.read_text().replace('lower="-1e6"', 'lower="-0.5"'))
    report = check(path)
    assert report.problems == []
    [w] = report.warnings
    assert "joint 'J1' is at -0.698131701 there, outside its URDF limits [-0.5, 1e+06]" in w
    assert "released at rest, in the direction its loads push it" in w
    assert report.postures["tip strikes wall"][0] == pytest.approx(THETA_S, abs=1e-12)
