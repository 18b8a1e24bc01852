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

import numpy as np
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
    # the check before the run follows the swing by energy (tests/test_reachable_posture.py): its
    # turning points are the same -pi/2 -+ 0.3, and it says the guard cannot fire
    assert len(lines) == 2 and lines[0].startswith(f"pcmm: warning: {path}: transitions[0] (stop).guard.value: "), err
    assert (f"swings between two turning points where its energy runs out (dampers left out), J1 = {HANG - 0.3:.6g} "
            f"and J1 = {HANG + 0.3:.6g}") in lines[0] and "the guard cannot fire" in lines[0]
    assert lines[1].startswith(
        f"pcmm: warning: guard of 'stop' (joint J1 decreasing to {HANG - 0.4:.9g}) did not fire: closest "), err
    closest, t = (float(x) for x in __import__("re").search(r"closest (\S+) at t = (\S+) s", lines[1]).groups())
    assert closest == pytest.approx(HANG - 0.3, abs=1e-6) and t == pytest.approx(half, abs=2e-3)
    assert lines[1].endswith(", 0.1 short")


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
        first, *rest = err.splitlines()
        assert first == (f"pcmm: warning: {path}: transitions[0] (stop).guard.value: = {qs:g}: an angle (joint J1) of "
                         f"{qs:g} rad, {qs / (2 * math.pi):.3g} turns, outside [-2 pi, 2 pi]; guard values are in "
                         f"radians: if {qs:g} degrees is meant, write value = \"{qs:g} deg\" (= "
                         f"{qs * math.pi / 180:.6g} rad); a guard meant after more than a turn is right as it is")
        # and the swing from 0.3 rad at rest (between 0.3 and -pi - 0.3) never meets it (tests/test_reachable_posture.py)
        [swing] = rest
        assert "J1 = -3.44159 and J1 = 0.3" in swing and "the guard cannot fire" in swing
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


# ---- (a) a fixed step beyond the stability limit is named, before any symptom --------------------------
def _stiff_pendulum(folder, k, step, w0=-5.0, t_end=0.2):
    """The builders' pendulum (bar 0.6 m, 1.5 kg: I = m L^2 / 3 = 0.18 about J1), horizontal, no
    gravity, on a torsion spring k (in 'c1' only), launched at w0 towards a stop at -0.2 rad, RK4."""
    import tomllib
    path = builders.pendulum(folder, 0.5, q0=0.0, w0=w0, qs=-0.2, k=k, g=0.0, t_end=t_end,
                             solver={"method": "RK4", "step": step})
    doc = tomllib.loads(path.read_text())
    doc["forces"][0]["configurations"] = ["c1"]
    path.write_text(builders.dump_toml(doc))
    return path


def test_rk4_beyond_its_stability_limit_is_told_so(tmp_path, capsys):
    """omega = sqrt(k / I) = 3000 rad/s; RK4 amplifies the mode i omega per step by |R(i h omega)| =
    sqrt(1 - y^6/72 + y^8/576) at y = h omega, > 1 beyond y = 2 sqrt 2.  At h = 1e-3 s (y = 3) the
    oscillation of amplitude w0 / omega = 1.7 mrad grew until it reached the stop 0.2 rad away at an
    absurd speed, and the message blamed the contact (or the run merged silently).  The run must
    stop at t = 0 naming solver.step, |lambda| = 3000, the growth per step and the largest stable
    step 2 sqrt 2 / omega; below it (h = 9e-4 s) the run goes on and the amplitude never exceeds
    w0 / omega (RK4 inside its stability region does not amplify)."""
    import numpy as np
    import pcmm
    I, omega = 0.18, 3000.0
    k = I * omega ** 2
    rc, out, err = cli(["run", _stiff_pendulum(tmp_path / "a", k, 1e-3), "--quiet", "--out", tmp_path / "a.npz"], capsys)
    assert rc != 0 and "normal" not in err and "flip" not in err
    y = 3.0
    growth = math.sqrt(1 - y ** 6 / 72 + y ** 8 / 576)
    limit = 2 * math.sqrt(2) / omega
    assert "t = 0 s, configuration 'c1': the fixed-step method RK4 is unstable at solver.step = 0.001 s" in err, err
    assert f"|lambda| = {omega:.4g} 1/s" in err and f"multiplies that mode by {growth:.3g}" in err
    assert f"stable up to {limit:.3g} s" in err and 'solver.method = "DOP853"' in err
    traj = pcmm.simulate(pcmm.load_scene(_stiff_pendulum(tmp_path / "b", k, 9e-4)))
    q = traj.series("q", "J1")
    assert not traj.events and np.max(np.abs(q)) <= 5.0 / omega * (1 + 1e-9)
    assert np.max(np.abs(q)) > 0.5 * 5.0 / omega  # it does swing


# ---- (c) a non-physical velocity ----------------------------------------------------------------
def test_faster_than_light_initial_velocity_is_named_without_raw_warnings(tmp_path):
    """w0 = 1e150 rad/s on the 0.6 m bar: its centre of mass (0.3 m out) would move at 3e149 m/s.
    It was "stiff or singular" with numpy's overflow warnings; now one message names initial.v,
    the speed and the cause, and nothing else is printed."""
    path = builders.pendulum(tmp_path, 0.5, q0=0.3, w0=1e150, qs=-1.0, t_end=0.5)
    p = subprocess.run([sys.executable, "-m", "pcmm.cli", "run", str(path), "--quiet"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120,
                       env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
    assert p.returncode != 0 and p.stdout == ""
    assert p.stderr == (f"pcmm: error: {path}: initial.v: the centre of mass of the body on joint 'J1' moves at "
                        f"{0.3 * 1e150:.3g} m/s, faster than light (2.99792e+08 m/s) at t = 0 s: the initial velocities "
                        "are not physical (the largest: J1 = 1e+150); check initial.v and its units (rad/s for a "
                        "revolute joint, m/s for a slider)\n"), p.stderr


def test_speed_of_light_threshold_is_the_fastest_body_point(tmp_path):
    """Just below c at the bar's centre of mass (omega * 0.3 m) nothing is said; just above, the
    centre of mass is named.  A slider's speed is its velocity."""
    import numpy as np
    import pcmm
    from pcmm.model.mechanism import Mechanism
    from pcmm.run.stability import SPEED_OF_LIGHT, unphysical_speed
    scene = pcmm.load_scene(builders.pendulum(tmp_path / "p", 0.5))
    cfg = Mechanism(scene)["c1"]
    q = np.array([0.3])
    assert unphysical_speed(cfg, q, np.array([0.99 * SPEED_OF_LIGHT / 0.3])) is None
    assert unphysical_speed(cfg, q, np.array([1.01 * SPEED_OF_LIGHT / 0.3])).startswith(
        "the centre of mass of the body on joint 'J1' moves at 3.03e+08 m/s, faster than light")
    assert "is not finite" in unphysical_speed(cfg, q, np.array([np.nan]))
    scene = pcmm.load_scene(builders.ball(tmp_path / "b", 0.5))
    cfg = Mechanism(scene)["free"]
    assert unphysical_speed(cfg, np.array([1.0]), np.array([-0.99 * SPEED_OF_LIGHT])) is None
    assert "faster than light" in unphysical_speed(cfg, np.array([1.0]), np.array([-1.01 * SPEED_OF_LIGHT]))


def test_a_blown_up_state_blames_the_integration_not_the_normal(tmp_path):
    """Where a run fails in a state faster than light (an RK4 run that blew up in a stiff contact:
    1.8e37 m/s at the guard), the message that blamed the normal is replaced by the cause, naming
    the time, the speed and solver.step."""
    import numpy as np
    import pcmm
    from pcmm.errors import SimulationError
    from pcmm.model.mechanism import Mechanism
    from pcmm.ode.integrators import INTEGRATORS
    from pcmm.run.stability import blow_up
    scene = pcmm.load_scene(builders.pendulum(tmp_path, 0.5))
    cfg = Mechanism(scene)["c1"]
    exc = SimulationError("t = 2.013 s, transition 'stop': the latch's impulse comes out tensile ...; flip its sign")
    v = np.array([1.8e37 / 0.6])  # the contact point at the bar's tip, 0.6 m out
    text = blow_up(cfg, exc, 2.013, np.array([-1.0]), v, INTEGRATORS["RK4"], 1e-3)
    assert text.startswith("t = 2.013 s, configuration 'c1': the integration blew up: the origin of the body") or \
        text.startswith("t = 2.013 s, configuration 'c1': the integration blew up: the centre of mass of the body")
    assert "9e+36 m/s, faster than light" in text  # the centre of mass, 0.3 m out
    assert "RK4 at solver.step = 0.001 s is beyond its stability limit" in text
    assert blow_up(cfg, exc, 2.013, np.array([-1.0]), np.array([3.0]), INTEGRATORS["RK4"], 1e-3) is None


# ---- a contact law's separation is not a crossing against the guard -----------------------------------
def test_contact_law_bounce_is_no_wrong_direction_warning(tmp_path, capsys):
    """A ball dropped from 0.5 m onto a Hunt-Crossley floor (first contact at sqrt(2 h / g)) leaves
    the floor and is in flight at t_end: the gap crossing 0 upwards at the separation was reported
    as "crossed against the guard's direction; check `direction`".  Now no warning; the guard is
    said to have had its last event at the separation (the event's t_end)."""
    import json
    path = builders.ball(tmp_path, 0.8, h=0.5, law="hunt_crossley", stiffness=1e10, exponent=1.5, merge=False,
                         t_end=0.4)
    S = tmp_path / "s.json"
    rc, out, err = cli(["run", path, "--summary", S], capsys)
    assert rc == 0 and "against the guard's direction" not in out + err and "warning" not in err
    (event,) = json.loads(S.read_text())["events"]
    assert event["t"] == pytest.approx(math.sqrt(2 * 0.5 / builders.G), abs=1e-9)
    assert f"since its last event at t = {event['t_end']:.9g} s" in out


# ---- (b) a failure at a trial step reports where the run stopped --------------------------------------
def test_failure_at_a_trial_step_reports_the_true_stop_time(tmp_path, monkeypatch):
    """A loop's Newton solve that fails at a trial step of the integrator (a long smooth step can
    reach as far as t_end) named that trial time and blamed a singular posture: the run stopped at
    2.013 s, the message said t = 3 s.  Here a four-bar under a constant crank torque fails, by a
    stand-in of that solve, at its first right-hand side call past 0.5 s.  The message must give
    the last accepted step (where the partial run ends) as the time the run stopped, the trial
    time as where the failure came, and the condition number of the loop's constraint Jacobian
    there, which the test computes from the bars' geometry (crank 0.1, coupler 0.3, rocker 0.25,
    ground 0.3)."""
    import re
    import numpy as np
    import pcmm
    from pcmm.errors import SimulationError
    from pcmm.model.constraints import PartitionedCoordinates
    real = PartitionedCoordinates.rhs

    def failing(self, t, y):
        if t > 0.5:
            raise SimulationError(f"configuration '{self.cfg.name}': the loop cannot be closed at t = {t:.6g} s "
                                  "(residual 0.464): the mechanism is at or beyond a singular posture")
        return real(self, t, y)
    monkeypatch.setattr(PartitionedCoordinates, "rhs", failing)
    path = builders.four_bar_rocker_stop(tmp_path, 0.5, rocker_stop=0.2, g=0.0, t_end=3.0)
    with pytest.raises(SimulationError) as info:
        pcmm.simulate(pcmm.load_scene(path))
    traj = info.value.partial
    t_stop = float(traj.t[-1])
    text = info.value.problems[0]
    assert t_stop < 0.5 and text.startswith(
        f"{path}: t = {t_stop:.9g} s, configuration 'free': the run stopped here, at its last accepted step; "
        "there the loop's constraint Jacobian has condition number "), text
    said = float(re.search(r"The failure came at t = (\S+) s", text).group(1))
    assert said > 0.5 and f"the loop cannot be closed at t = {said:.6g} s" in text
    A, B, D = (float(traj.series("q", j)[-1]) for j in "ABD")
    a, b, c = 0.1, 0.3, 0.25
    J = np.array([[-a * math.sin(A) - b * math.sin(A + B), -b * math.sin(A + B), c * math.sin(D)],
                  [a * math.cos(A) + b * math.cos(A + B), b * math.cos(A + B), -c * math.cos(D)]])
    cond = float(re.search(r"condition number (\S+), a regular posture", text).group(1))
    assert cond == pytest.approx(np.linalg.cond(J), rel=5e-3)


def test_a_measure_that_starts_on_its_value_to_round_off_did_not_cross_it():
    """A release maps the state onto the value of a stop guard to round-off, on either side by
    the route that mapped it (1.1e-16 past it under the compiled loop stepping, 0 under Python's):
    leaving from there against the guard's direction is no crossing against it, and a hair past
    the value is not past it.  A real crossing from 1e-9 away still is."""
    from types import SimpleNamespace
    from pcmm.run.approach import _crossed_against, _past
    value = 0.34198728609555523
    tr = SimpleNamespace(guard=SimpleNamespace(value=value, direction=1.0))
    t = np.array([0.9, 0.91, 0.92])
    owner = np.zeros(3, int)
    on = np.array([np.nextafter(value, 1.0), value - 0.01, value - 0.02])
    assert _crossed_against(tr, t, on, owner) is None and not _past(tr, float(on[0]))
    off = np.array([value + 1e-9, value - 0.01, value - 0.02])
    assert _crossed_against(tr, t, off, owner) == pytest.approx(0.9 + 0.01 * 1e-9 / (1e-9 + 0.01), abs=1e-15)
    assert _past(tr, value + 1e-9)


def test_the_closest_approach_of_a_guard_that_fired_reads_the_segments_since_it_last_fired(tmp_path):
    """A stored run of 1e6 bounces ended with 3 GB of memory computing this record: it read every
    segment of the final configuration, all the bounces, before keeping the samples since the
    guard last fired.  It now takes the segments from the end back to that firing: the same
    record as from all of them, from the last segment of a ball's 20 bounces."""
    import pcmm
    from pcmm.model.mechanism import Mechanism
    from pcmm.run import approach
    scene = pcmm.load_scene(builders.ball(tmp_path, 1.0, t_end=18.1, merge=False))
    traj = pcmm.simulate(scene)
    bounces = [e for e in traj.events if e["name"] == "floor"]
    assert len(bounces) >= 15 and len(traj.segments) == len(bounces) + 1
    cfg = Mechanism(scene)["free"]
    tail = approach._segments_in(traj, "free", scene.transitions_from("free"))
    assert [s.t[0] for s in tail] == [s.t[0] for s in traj.segments[-1:]]
    full = approach._segments_in(traj, "free", None)
    assert len(full) == len(traj.segments)
    got = approach.closest_approach(scene, cfg, traj)
    read = []
    real = approach._segments_in
    approach._segments_in = lambda traj, name, watched, *a: (read.append(1), real(traj, name, None))[1]
    try:
        everything = approach.closest_approach(scene, cfg, traj)
    finally:
        approach._segments_in = real
    assert read and got == everything and got[0]["last_fired"] == bounces[-1]["t"]
