"""Two mechanisms a new user wrote from the README and the docs alone (task h-newcomer), each run
as a user runs it and checked against numbers derived by hand.

* A slider-crank press: the crank driven at constant speed, the connecting rod closing the loop on
  the slider by a cut joint, and a ram riding ahead of the slider on a cushion spring. The ram
  strikes a stop (e = 0.3), its bounces accumulate into a merge with the frame (a derived
  configuration locking the ram's joint), and it is released when the cushion's pull turns the
  holding force tensile.
* A pawl: a pendulum whose tip strikes a frame wall with Coulomb friction (mu = 0.4, e = 0.5),
  bounces, and seats (a derived configuration locking the pivot).

(A press whose slider itself strikes the stop cannot work: with the crank driven the loop has no
free coordinate, so no impulse can change a velocity; pcmm stops at the strike. The ram on its
spring is the freedom an impact needs.)

The pawl's wall is oblique to the tip's path (30°). `pcmm check` and `pcmm run` refuse such a
contact ("normal ... 30 deg off the direction in which joint 'pivot' moves the contact point") when
they find the guard's posture, which from this horizontal start they do not (the gap is stationary
there); the hand calculation below says the wall's normal is the right one. These tests run through
`pcmm.simulate`, which makes no such check.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import pcmm

G = 9.81
LIMIT = '<limit lower="-1e6" upper="1e6" effort="1e6" velocity="1e6"/>'


def _joint(name, jtype, parent, child, x=0.0, axis="0 0 1"):
    return (f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{x!r} 0 0" rpy="0 0 0"/><axis xyz="{axis}"/>{LIMIT}</joint>')


def _link(name, m, cx, izz):
    return (f'<link name="{name}"><inertial><origin xyz="{cx!r} 0 0" rpy="0 0 0"/><mass value="{m!r}"/>'
            f'<inertia ixx="1e-6" ixy="0" ixz="0" iyy="{izz!r}" iyz="0" izz="{izz!r}"/></inertial></link>')


def _robot(name, *parts):
    return f'<?xml version="1.0"?><robot name="{name}"><link name="frame"/>{"".join(parts)}</robot>'


# ---- the press ----------------------------------------------------------------------------------
R, L = 0.1, 0.3                      # crank radius, rod length (m)
OMEGA, THETA0 = 2 * math.pi, 1.25 * math.pi   # crank speed (rad/s), crank angle at t = 0
K, REST, M_RAM = 2000.0, 0.05, 0.5   # cushion stiffness (N/m), rest length (m), ram mass (kg)
X_STOP, E_PRESS = 0.44, 0.3          # the stop's place (m), restitution

PRESS_URDF = _robot(
    "press",
    _joint("crank", "revolute", "frame", "crank"), _link("crank", 0.5, 0.05, 0.5 * R ** 2 / 12),
    _joint("pin", "revolute", "crank", "rod", x=R), _link("rod", 0.6, 0.15, 0.6 * L ** 2 / 12),
    _joint("slide", "prismatic", "frame", "slider", axis="1 0 0"), _link("slider", 1.0, 0.0, 1e-4),
    _joint("ram", "prismatic", "frame", "ram", axis="1 0 0"), _link("ram", M_RAM, 0.0, 1e-4))

PRESS_TOML = f"""
[scene]
name = "press"
description = "driven slider-crank; a ram on a cushion ahead of the slider strikes a stop, merges, is released"
gravity = [0.0, -9.81]
t_end = 0.5
initial_configuration = "free"

[configurations.free]
urdf = "press.urdf"
cut_joints = [
  {{ name = "wrist", type = "revolute", a = "rod", point_a = [{L}, 0.0], b = "slider", point_b = [0.0, 0.0] }},
]

[configurations.held]
from = "free"
lock = ["ram"]

[initial]   # the ram at the cushion's rest length ahead of the slider, at rest
q = {{ crank = "1.25*pi", pin = 2.6, slide = 0.22, ram = "0.1*cos(1.25*pi) + sqrt(0.09 - 0.01*sin(1.25*pi)**2) + 0.05" }}
v = {{ crank = "2*pi", ram = 0.0 }}
independent = ["crank", "ram"]

[[forces]]
name = "cushion"
type = "point_spring"
a = "slider"
point_a = [0.0, 0.0]
b = "ram"
point_b = [0.0, 0.0]
k = {K}
rest = {REST}

[[drives]]
joint = "crank"
coefficients = ["1.25*pi", "2*pi"]

[[transitions]]
name = "ram hits stop"
type = "stop"
from = "free"
merge_to = "held"
restitution = {E_PRESS}
cut = []
guard = {{ type = "gap", value = 0.0, direction = "decreasing" }}
contact = {{ a = "frame", point_a = [{X_STOP}, 0.0], b = "ram", point_b = [0.0, 0.0], normal = [-1.0, 0.0] }}

[[transitions]]
name = "ram released"
type = "release"
from = "held"
to = "free"
guard = {{ type = "reaction", of = "ram", value = 0.0, direction = "decreasing" }}
"""


def slider_x(theta):
    """The slider's place from the crank angle (the loop's closure): x = r cos θ + √(l² − r² sin² θ)."""
    return R * np.cos(theta) + np.sqrt(L ** 2 - R ** 2 * np.sin(theta) ** 2)


def _write(folder: Path, files: dict[str, str], scene: str) -> Path:
    for name, text in files.items():
        (folder / name).write_text(text)
    return folder / scene


@pytest.fixture(scope="module")
def press_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("press")
    path = _write(folder, {"press.urdf": PRESS_URDF, "press.toml": PRESS_TOML}, "press.toml")
    return pcmm.simulate(pcmm.load_scene(path))


def test_press_first_strike_matches_the_ram_on_its_cushion(press_run):
    """The slider is a known function of time (the drive and the loop): x_c(t) = x(θ0 + ω t). The
    ram, on its cushion, obeys m x'' = k (rest − (x − x_c(t))), integrated here on its own
    (scipy, rtol 1e-12) from rest at the cushion's rest length, up to x = 0.44 m. The first strike
    must come then with that speed, and, the ram being the only free body of a stable impact,
    Newton's law gives v⁺ = −e v⁻ and the impulse P = m (1 + e) |v⁻|."""
    def rhs(t, y):
        return [y[1], K * (REST - (y[0] - slider_x(THETA0 + OMEGA * t))) / M_RAM]

    def strike(t, y):
        return y[0] - X_STOP
    strike.terminal, strike.direction = True, 1
    ref = solve_ivp(rhs, (0, 1), [slider_x(THETA0) + REST, 0.0], method="DOP853", rtol=1e-12, atol=1e-14,
                    events=strike)
    t_ref, v_ref = ref.t_events[0][0], ref.y_events[0][0][1]   # 0.3272354 s, 0.298766 m/s
    first = press_run.events[0]
    assert first["t"] == pytest.approx(t_ref, abs=1e-8)
    assert first["normal_velocity"]["before"] == pytest.approx(-v_ref, rel=1e-7)
    assert first["normal_velocity"]["after"] == pytest.approx(E_PRESS * v_ref, rel=1e-7)
    assert first["impulse"]["normal"] == pytest.approx(M_RAM * (1 + E_PRESS) * v_ref, rel=1e-7)


def test_press_bounces_merge_then_release_where_the_cushion_pulls(press_run):
    """Every bounce keeps v⁺ = −e v⁻; they accumulate into a merge with the frame ('held'). Held,
    the ram is locked at the stop, so the stop's holding force is the cushion's push,
    N = k (rest − (0.44 − x_c(t))): largest, k (rest − 0.04) = 20 N, at the outer dead centre
    (θ = 2π, t = 0.375 s), and zero where the slider has come back to x_c = 0.39 m (θ in (2π, 3π),
    by root finding): the release, with the ram at 0.44 m and at rest, no impulse."""
    events = press_run.events
    strikes = [e for e in events if e["name"] == "ram hits stop"]
    for e in strikes[:-1]:
        assert e["normal_velocity"]["after"] == pytest.approx(-E_PRESS * e["normal_velocity"]["before"], rel=1e-9)
    assert strikes[-1]["merge"] and strikes[-1]["to"] == "held"
    assert len(strikes) == 11  # 0.2988 m/s × 0.3^10 = 1.8e-6 > 1e-6 m/s, the next below: the merge
    release = events[-1]
    assert (release["name"], release["from"], release["to"]) == ("ram released", "held", "free")
    theta = brentq(lambda th: slider_x(th) - (X_STOP - REST), 2 * math.pi, 3 * math.pi)
    assert release["t"] == pytest.approx((theta - THETA0) / OMEGA, abs=1e-9)   # 0.4373003 s
    assert release["freed"]["ram"] == pytest.approx(X_STOP, abs=1e-12)
    held = (press_run.t > strikes[-1]["t"]) & (press_run.t < release["t"])
    hold = press_run.series("constraint_forces", "ram hits stop.hold")[held]
    expected = K * (REST - (X_STOP - slider_x(THETA0 + OMEGA * press_run.t[held])))
    assert np.max(np.abs(hold - expected)) < 1e-8
    assert np.max(expected) <= 20.0 + 1e-12


# ---- the pawl -----------------------------------------------------------------------------------
M_PAWL, L_PAWL = 0.3, 0.2            # a uniform bar on its pivot: I_O = m L²/3 = 0.004 kg m²
I_O = M_PAWL * L_PAWL ** 2 / 3
MU, E_PAWL = 0.4, 0.5
THETA_S = -math.pi / 3               # the tip meets the wall x = L cos θ_s = 0.1 m

PAWL_URDF = _robot("pawl", _joint("pivot", "revolute", "frame", "pawl"),
                   _link("pawl", M_PAWL, L_PAWL / 2, M_PAWL * L_PAWL ** 2 / 12))

PAWL_TOML = f"""
[scene]
name = "pawl"
description = "a pawl swings down from the horizontal; its tip strikes a wall with friction and seats"
gravity = [0.0, -9.81]
t_end = 1.0
initial_configuration = "free"

[configurations.free]
urdf = "pawl.urdf"

[configurations.seated]
from = "free"
lock = ["pivot"]

[initial]
q = {{ pivot = 0.0 }}
v = {{ pivot = 0.0 }}

[[transitions]]
name = "tip strikes wall"
type = "stop"
from = "free"
merge_to = "seated"
restitution = {E_PAWL}
cut = []
guard = {{ type = "gap", value = 0.0, direction = "decreasing" }}
contact = {{ a = "frame", point_a = [0.1, "-0.2*sin(pi/3)"], b = "pawl", point_b = [{L_PAWL}, 0.0], normal = [1.0, 0.0], friction = {MU} }}
"""


@pytest.fixture(scope="module")
def pawl_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pawl")
    path = _write(folder, {"pawl.urdf": PAWL_URDF, "pawl.toml": PAWL_TOML}, "pawl.toml")
    return pcmm.simulate(pcmm.load_scene(path))


def test_pawl_strike_by_routh_on_one_freedom(pawl_run):
    """From rest at θ = 0, energy gives ω⁻² = m g (L/2) sin 60° · 2 / I_O at θ_s = −60°. The tip
    r = L (cos θ_s, sin θ_s) moves with ω (−r_y, r_x): along n = (1, 0), J_n = −r_y = L sin 60°;
    along t = (n_y, −n_x) = (0, −1), J_t = −r_x = −0.1. So v_n = J_n ω < 0 and the slip
    v_t = J_t ω > 0 (σ = +1). With one freedom, κ = −J_n/J_t = 1.73 > μ: the tip slides, and the
    slip reverses with ω at the end of compression. The generalized impulse is
    (J_n − σ μ J_t) dP_n: compression (σ = +1) takes P_c = I_O |ω⁻| / (J_n + μ |J_t|), Newton's
    restitution (ω⁺ = −e ω⁻, σ = −1) P_r = I_O e |ω⁻| / (J_n − μ |J_t|); P_t = −μ P_c + μ P_r."""
    omega = math.sqrt(2 * M_PAWL * G * (L_PAWL / 2) * math.sin(-THETA_S) / I_O)
    jn, jt = L_PAWL * math.sin(-THETA_S), -L_PAWL * math.cos(THETA_S)
    p_c = I_O * omega / (jn + MU * abs(jt))
    p_r = I_O * E_PAWL * omega / (jn - MU * abs(jt))
    first = pawl_run.events[0]
    assert first["normal_velocity"]["before"] == pytest.approx(-jn * omega, rel=1e-9)   # -1.95527 m/s
    assert first["normal_velocity"]["after"] == pytest.approx(E_PAWL * jn * omega, rel=1e-9)
    assert first["impulse"]["normal"] == pytest.approx(p_c + p_r, rel=1e-9)            # 0.381285 N s
    assert first["impulse"]["tangential"] == pytest.approx(MU * (p_r - p_c), rel=1e-9)  # -0.0169188 N s
    assert first["friction"]["phases"] == "slide+ -> slide-"
    assert first["kinetic_energy_after"] == pytest.approx(E_PAWL ** 2 * first["kinetic_energy_before"], rel=1e-9)


def test_pawl_seats_and_its_holding_force_balances_gravity(pawl_run):
    """Each bounce returns with e times its speed, so the bounces accumulate and the pawl seats at
    θ_s. Seated, the wall's normal force N balances gravity's moment about the pivot:
    N · L sin 60° = m g (L/2) cos 60°, N = 0.849571 N, and it never turns tensile."""
    strikes = pawl_run.events
    for e in strikes[:-1]:
        assert e["normal_velocity"]["after"] == pytest.approx(-E_PAWL * e["normal_velocity"]["before"], rel=1e-9)
    assert strikes[-1]["merge"] and strikes[-1]["to"] == "seated"
    seated = pawl_run.t > strikes[-1]["t"]
    hold = pawl_run.series("constraint_forces", "tip strikes wall.hold")[seated]
    n = M_PAWL * G * (L_PAWL / 2) * math.cos(THETA_S) / (L_PAWL * math.sin(-THETA_S))
    assert np.max(np.abs(hold - n)) < 1e-9
    assert np.allclose(pawl_run.series("theta", "pawl")[seated], THETA_S, atol=1e-9)
