"""examples/three_bar_cycle.toml: a metamorphic working cycle run three times.

Example 1's three bars (Table 1) turned by a constant-speed crank in a vertical plane, with O2 and
O3 limited-rotation joints (spring + pin, the paper's Fig. 5): once per turn each opens (its pin's
holding moment turns tensile: a release) and is slammed shut by its spring (impacts with e = 0.8
that accumulate into a merge).  Every expectation here is derived by hand, not read back from a
field pcmm computed the same way:

* the joint rates of an impact come from the links' absolute angular velocities and the joint's
  two links in the URDF; Newton's law is checked on them;
* each impulse is the jump of angular momentum of the struck body about its joint, whose velocity
  the driven crank keeps (I_J (1 + e) |rate-|);
* the kinetic energy and every body's velocity across a release come from the link poses and
  angular velocities, with Table 1's masses;
* the release instants come from the statics of the rigid arm turning at constant speed: a pin
  lets go when the moment the arm needs at the joint exceeds the spring's preload.
"""
from __future__ import annotations

import math
import tomllib
import xml.etree.ElementTree as ET
from itertools import groupby
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

import pcmm

pytestmark = pytest.mark.slow  # runs the 7.5 s working cycle (531 events)

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "examples" / "three_bar_cycle.toml"
URDF = ROOT / "urdf" / "three_bar_config1.urdf"

# Table 1 of the paper (steel 7800 kg/m^3, 2e-4 m^2) and the scene's stated assumptions.
G = 9.81
L = {"link1": 0.25, "link2": 0.125, "link3": 0.125}
M = {k: 7800 * 2e-4 * v for k, v in L.items()}  # 0.39, 0.195, 0.195 kg
IC = {k: M[k] * L[k] ** 2 / 12 for k in L}
OMEGA = math.pi  # crank speed, rad/s
PIN = {"O2": math.pi / 2, "O3": math.pi}
PRELOAD = {"O2": 0.20, "O3": 0.05}  # spring moment pressing each link onto its pin, N m
E = 0.8
PERIOD = 2 * math.pi / OMEGA


@pytest.fixture(scope="module")
def run():
    return pcmm.simulate(pcmm.load_scene(SCENE))


def test_scene_states_the_assumptions_the_test_uses():
    doc = tomllib.loads(SCENE.read_text())
    assert doc["drives"][0]["coefficients"] == [0.0, "pi"]
    springs = {f["on"]["joint"]: f for f in doc["forces"]}
    assert springs["O2"]["value"] == "0.20 + 0.3*pi/2" and springs["O3"]["value"] == "0.05 + 0.3*pi"
    assert springs["O2"]["k"] == springs["O3"]["k"] == 0.3
    assert {t["restitution"] for t in doc["transitions"]} == {E}
    assert {t["guard"]["value"] for t in doc["transitions"]} == {"pi", "pi/2"}


def _joints():
    """{joint: (parent link, child link)} from the hand-written URDF."""
    root = ET.parse(URDF).getroot()
    return {j.get("name"): (j.find("parent").get("link"), j.find("child").get("link")) for j in root.iter("joint")}


def _kind(ev):
    if ev["transition"] == "release":
        return "release"
    return "merge" if ev["merge"] else "impact"


def _cycles(run):
    """The events of each full cycle: a cycle starts when O2's pin lets go of the folded arm."""
    starts = [i for i, e in enumerate(run.events)
              if e["transition"] == "release" and e["from"] == "folded" and e["name"].startswith("O2 pin")]
    return [run.events[a:b] for a, b in zip(starts, starts[1:])], starts


def _pattern(events):
    """Runs of equal (kind, joint, from, to), with their lengths."""
    key = lambda e: (_kind(e), e["name"][:2], e["from"], e["to"])  # noqa: E731
    return [(k, len(list(g))) for k, g in groupby(events, key)]


# ---- (a) three cycles, the expected sequence --------------------------------------------------------
def test_three_full_cycles_through_three_configurations(run):
    configs = [c for c, _ in groupby(s.configuration for s in run.segments)]
    # the start: both joints slightly open fall onto their pins (O2 first, then O3)
    assert configs[:3] == ["open", "O2_locked", "folded"]
    cycle = ["O3_locked", "folded", "O2_locked", "folded"]
    assert configs[3:] == cycle * 3 + ["O3_locked"]
    assert configs.count("folded") >= 3 + 1  # configuration 1 returns to at least three times
    cycles, _ = _cycles(run)
    assert len(cycles) == 3
    for events in cycles:
        pattern = _pattern(events)
        assert [k for k, _ in pattern] == [
            ("release", "O2", "folded", "O3_locked"), ("impact", "O2", "O3_locked", "O3_locked"),
            ("merge", "O2", "O3_locked", "folded"),
            ("release", "O3", "folded", "O2_locked"), ("impact", "O3", "O2_locked", "O2_locked"),
            ("merge", "O3", "O2_locked", "folded")]
        # each macro-impact: the flights between bounces are short, so a link returns to its pin about as
        # fast as it left, and the rebounds fall geometrically, e^k rate-; the k-th impact is made
        # plastic once e^k rate- drops below the accumulation speed 1e-6 rad/s
        for bounces, merge in ((1, 2), (4, 5)):
            first = next(e for e in events if _kind(e) == "impact" and e["name"][:2] == pattern[bounces][0][1])
            expected = math.log(1e-6 / abs(first["normal_velocity"]["before"])) / math.log(E)
            assert pattern[bounces][1] + pattern[merge][1] == pytest.approx(expected, abs=1.0)
        assert all(e["cause"] == "tensile holding force" for e in events if e["transition"] == "release")


# ---- (b) Newton's restitution law at every impact, and the impulse by hand -----------------------------
def test_every_impact_obeys_newtons_law_from_the_link_velocities(run):
    joints = _joints()
    impacts = [e for e in run.events if e["impact"]]
    assert len(impacts) > 300
    worst = 0.0
    for ev in impacts:
        joint = ev["name"][:2]
        parent, child = joints[joint]
        # the pin sits where the joint's coordinate increases to (the guard's value, direction
        # increasing): the gap is pin - q, and the relative normal velocity is -(joint rate)
        before = -(ev["omega_before"][child] - ev["omega_before"][parent])
        after = -(ev["omega_after"][child] - ev["omega_after"][parent])
        assert before < 0  # the link approaches its pin
        expected = 0.0 if ev["merge"] else -E * before  # the last impact of a macro-impact is plastic
        # the link omegas are near pi rad/s and the last rates near 1e-6 rad/s: their difference
        # carries the omegas' round-off, a few eps * pi, on top of the law's 1e-9
        round_off = 8 * np.finfo(float).eps * max(abs(w) for w in ev["omega_before"].values())
        assert abs(after - expected) <= 1e-9 * abs(before) + round_off
        # the same law on the joint's own rate, the event's generalized velocity (no cancellation)
        rate_before, rate_after = -ev["v_before"][joint], -ev["v_after"][joint]
        assert rate_before == pytest.approx(before, rel=1e-9, abs=round_off)
        expected = 0.0 if ev["merge"] else -E * rate_before
        worst = max(worst, abs(rate_after - expected))
        assert abs(rate_after - expected) <= 1e-9 * abs(rate_before) + round_off
    # measured: at most 2e-15 rad/s, on the last bounces (rates near 1e-6 rad/s beside omegas of pi)
    print(f"Newton's law: worst |rate+ + e rate-| = {worst:.1e} rad/s over {len(impacts)} impacts")


def test_event_velocities_are_the_runs(run):
    """The omegas the impacts are checked on are those of the trajectory either side."""
    for i, ev in enumerate(run.events):
        a, b = run.segments[i], run.segments[i + 1]
        assert b.t[0] == ev["t"] == a.t[-1]
        for k, link in enumerate(a.links):
            assert ev["omega_before"][link] == pytest.approx(a.omega[-1, k], abs=1e-12)
        for k, link in enumerate(b.links):
            assert ev["omega_after"][link] == pytest.approx(b.omega[0, k], abs=1e-12)


def test_impulses_by_hand(run):
    """The crank is driven, so its speed and the struck joint's velocity do not jump; the impulsive
    reaction at the joint has no moment about it.  The impulse moment is then the jump of angular
    momentum of the struck body about its joint: I_J (rate+ - rate-) = I_J (1 + e) |rate-|, with
    I_J = links 2+3 folded (O3 at pi) about O2, or link 3 about O3."""
    # link 3 folded back on link 2: its centre is L2 - L3/2 from O2
    I_O2 = IC["link2"] + M["link2"] * (L["link2"] / 2) ** 2 + IC["link3"] + M["link3"] * (L["link2"] - L["link3"] / 2) ** 2
    I_O3 = IC["link3"] + M["link3"] * (L["link3"] / 2) ** 2
    checked = 0
    for ev in run.events:
        if not ev["impact"] or ev["from"] not in ("O3_locked", "O2_locked"):
            continue
        joint = ev["name"][:2]
        inertia = I_O2 if joint == "O2" else I_O3
        link = "link2" if joint == "O2" else "link3"
        jump = ev["omega_after"][link] - ev["omega_before"][link]
        assert jump < 0  # the pin turns the struck link back
        for side in ("omega_before", "omega_after"):
            assert ev[side]["link1"] == pytest.approx(OMEGA, rel=1e-14)
        assert ev["impulse"]["moment"] == pytest.approx(-inertia * jump, rel=1e-9)
        assert ev["impulse"]["normal"] == pytest.approx(-inertia * jump / 0.0625, rel=1e-9)  # at the 0.0625 m arm
        checked += 1
    assert checked > 300


# ---- (c) releases: no impulse ---------------------------------------------------------------------
def _bodies(seg, i):
    """Every link's centre position and velocity and its angular velocity, from the link frames'
    poses and angular velocities (the chain O1 -> O2 -> O3, O1 fixed at the origin)."""
    out, v_origin, prev = {}, np.zeros(2), None
    for name in ("link1", "link2", "link3"):
        k = seg.links.index(name)
        th, w, origin = seg.theta[i, k], seg.omega[i, k], seg.xy[i, k]
        if prev is not None:
            w_p, o_p = prev
            v_origin = v_origin + w_p * np.array([-(origin - o_p)[1], (origin - o_p)[0]])
        r = L[name] / 2 * np.array([math.cos(th), math.sin(th)])
        out[name] = (origin + r, v_origin + w * np.array([-r[1], r[0]]), th, w)
        prev = (w, origin)
    return out


def _kinetic(bodies):
    return sum(0.5 * M[n] * v @ v + 0.5 * IC[n] * w * w for n, (_, v, _, w) in bodies.items())


def test_every_release_keeps_every_body_and_the_kinetic_energy(run):
    releases = [i for i, e in enumerate(run.events) if e["transition"] == "release"]
    assert len(releases) == 7
    worst = 0.0
    for i in releases:
        ev = run.events[i]
        assert ev["impact"] is False and ev["impulse"]["normal"] == 0.0
        before, after = _bodies(run.segments[i], -1), _bodies(run.segments[i + 1], 0)
        for name in before:
            (c0, v0, th0, w0), (c1, v1, th1, w1) = before[name], after[name]
            assert np.allclose(c1, c0, rtol=0, atol=1e-12) and th1 == pytest.approx(th0, abs=1e-12)
            assert np.allclose(v1, v0, rtol=0, atol=1e-9) and w1 == pytest.approx(w0, abs=1e-9)
        k0, k1 = _kinetic(before), _kinetic(after)
        worst = max(worst, abs(k1 - k0) / k0)
        assert k1 == pytest.approx(k0, rel=1e-9)
        assert ev["kinetic_energy_before"] == pytest.approx(k0, rel=1e-9)  # pcmm's energy is the same
        (joint, value), = ev["freed"].items()
        assert value == pytest.approx(PIN[joint], abs=1e-9)  # the freed joint starts on its pin, at rest
        assert ev["v_after"][joint] == pytest.approx(0.0, abs=1e-9)
    print(f"releases: worst relative kinetic-energy change {worst:.1e}")


def _moment_needed(joint, th1):
    """The moment the rigid folded arm, turning at the constant speed OMEGA, needs at the joint on
    its outer part (Newton-Euler about the joint: no angular acceleration, centripetal
    accelerations -OMEGA^2 r)."""
    u = lambda a: np.array([math.cos(a), math.sin(a)])  # noqa: E731
    th2 = th1 + PIN["O2"]
    th3 = th2 + PIN["O3"]
    o2 = L["link1"] * u(th1)
    o3 = o2 + L["link2"] * u(th2)
    centres = {"link2": o2 + L["link2"] / 2 * u(th2), "link3": o3 + L["link3"] / 2 * u(th3)}
    pivot, outer = (o2, ("link2", "link3")) if joint == "O2" else (o3, ("link3",))
    total = 0.0
    for n in outer:
        r, f = centres[n] - pivot, M[n] * (-OMEGA ** 2 * centres[n] - np.array([0.0, -G]))
        total += r[0] * f[1] - r[1] * f[0]
    return total


def test_release_instants_from_the_statics_of_the_rigid_arm(run):
    """A pin holds while the spring's preload exceeds the moment the arm needs at the joint; it lets
    go when that moment rises through the preload: O2 near the bottom of the turn, O3 near the top."""
    releases = [e for e in run.events if e["transition"] == "release"]
    for ev in releases:
        joint = ev["name"][:2]
        lo, hi = (math.pi, 1.5 * math.pi) if joint == "O2" else (0.0, 0.5 * math.pi)
        th_star = brentq(lambda th: _moment_needed(joint, th) - PRELOAD[joint], lo, hi, xtol=1e-15)
        turns = math.floor(OMEGA * ev["t"] / (2 * math.pi))
        t_star = (th_star + 2 * math.pi * turns) / OMEGA
        assert ev["t"] == pytest.approx(t_star, abs=1e-9)
    first = {e["name"][:2]: math.degrees(OMEGA * e["t"]) % 360 for e in releases[1:3]}
    assert first["O2"] == pytest.approx(215.8, abs=0.05) and first["O3"] == pytest.approx(42.0, abs=0.05)


# ---- (d) the cycle repeats ------------------------------------------------------------------------
def test_the_cycle_repeats(run):
    """The folded arm has no free coordinate: its state is a function of the crank angle alone, so
    every cycle leaves it (the O2 release, at a crank angle fixed by the statics above) in the same
    state, whatever the earlier cycles did. The cycle is therefore periodic from the first release on
    (a dead-beat limit cycle): cycle k + 1 repeats cycle k one crank period later, up to round-off at
    the releases and up to the integration error (rtol 1e-10) and the accumulation threshold
    (1e-6 rad/s) of the free phases and their macro-impacts."""
    cycles, starts = _cycles(run)
    start_diff, event_diff = [], []
    for k in range(len(starts) - 1):
        a, b = run.segments[starts[k] + 1], run.segments[starts[k + 1] + 1]
        assert b.t[0] - a.t[0] == pytest.approx(PERIOD, abs=1e-10)
        dq = b.q[0] - a.q[0]
        dq[b.coordinates.index("O1")] -= 2 * math.pi
        start_diff.append(max(np.abs(dq).max(), np.abs(b.v[0] - a.v[0]).max()))
    for c0, c1 in zip(cycles, cycles[1:]):
        assert _pattern(c1) == _pattern(c0)  # the same events, the same number of bounces
        event_diff.append(max(abs(e1["t"] - e0["t"] - PERIOD) for e0, e1 in zip(c0, c1)))
        rates = [abs(e1["normal_velocity"]["before"] - e0["normal_velocity"]["before"]) for e0, e1 in zip(c0, c1)]
        assert max(rates) < 1e-7  # measured 1e-8 rad/s, on the last bounces of a macro-impact
    print("start of cycle k+1 vs k (max |dq|, |dv|):", ", ".join(f"{d:.1e}" for d in start_diff))
    print("events of cycle k+1 vs k, max |dt - 2 s|:", ", ".join(f"{d:.1e}" for d in event_diff))
    assert max(start_diff) < 1e-9
    assert max(event_diff) < 1e-8


# ---- one more: the free phases against an independent one-degree-of-freedom model ------------------------
def test_free_phases_against_a_pendulum_on_a_turning_pivot(run):
    """While one joint is open, its outer part (links 2+3 folded, or link 3) is a rigid body pinned
    at a point that the driven, rigid inner part carries round a circle at constant speed. About
    that moving pivot O: I_O theta'' = tau_spring + (r_c x m (g - a_O))_z with a_O = -OMEGA^2 O and
    theta = (angle of the inner part) + q.  Integrated with scipy from the release to the pin: the
    first impact's instant and approach rate must be pcmm's."""
    from scipy.integrate import solve_ivp
    u = lambda a: np.array([math.cos(a), math.sin(a)])  # noqa: E731
    k, c = 0.3, 0.01
    bodies = {  # joint: (mass, centre distance from the pivot, inertia about the pivot, pivot(th1), inner angle(th1))
        "O2": (M["link2"] + M["link3"], L["link2"] / 2,
               IC["link2"] + M["link2"] * (L["link2"] / 2) ** 2 + IC["link3"] + M["link3"] * (L["link2"] - L["link3"] / 2) ** 2,
               lambda th1: L["link1"] * u(th1), lambda th1: th1),
        "O3": (M["link3"], L["link3"] / 2, IC["link3"] + M["link3"] * (L["link3"] / 2) ** 2,
               lambda th1: L["link1"] * u(th1) + L["link2"] * u(th1 + PIN["O2"]), lambda th1: th1 + PIN["O2"]),
    }
    (cycle, *_), _ = _cycles(run)
    for release in (e for e in cycle if e["transition"] == "release"):
        joint = release["name"][:2]
        m, d, I_O, pivot, inner = bodies[joint]

        def rhs(t, y, m=m, d=d, I_O=I_O, pivot=pivot, inner=inner, joint=joint):
            q, qd = y
            th1 = OMEGA * t
            r = d * u(inner(th1) + q)
            f = m * (np.array([0.0, -G]) + OMEGA ** 2 * pivot(th1))
            spring = PRELOAD[joint] + k * (PIN[joint] - q) - c * qd
            return [qd, (spring + r[0] * f[1] - r[1] * f[0]) / I_O]

        def hit(t, y, joint=joint):
            return y[0] - PIN[joint]
        hit.direction, hit.terminal = 1.0, True
        sol = solve_ivp(rhs, (release["t"], release["t"] + PERIOD), [PIN[joint] - 1e-13, 0.0], method="DOP853",
                        rtol=1e-12, atol=1e-14, events=hit)
        t_hit, (q_hit, rate_hit) = sol.t_events[0][0], sol.y_events[0][0]
        first = next(e for e in cycle if e["impact"] and e["t"] > release["t"] and e["name"][:2] == joint)
        assert first["t"] == pytest.approx(t_hit, abs=1e-10)
        assert first["v_before"][joint] == pytest.approx(rate_hit, rel=1e-9)
        print(f"{joint}: open {t_hit - release['t']:.6f} s, pin struck at {rate_hit:.6f} rad/s; "
              f"pcmm {first['t'] - t_hit:+.1e} s, {first['v_before'][joint] / rate_hit - 1:+.1e} relative")


# ---- the scene feature the example needed: lock values may be expressions --------------------------------
def _example1_locked_at(tmp_path, value):
    text = (ROOT / "examples" / "three_bar.toml").read_text().replace("../urdf/", f"{ROOT / 'urdf'}/")
    text = text.replace('urdf = "' + str(ROOT / "urdf") + '/three_bar_config2.urdf"',
                        f'from = "config1"\nlock = {{ O3 = {value} }}')
    path = tmp_path / "locked.toml"
    path.write_text(text)
    return pcmm.load_scene(path)


def test_lock_values_take_expressions(tmp_path):
    """lock = { O3 = "pi" } is lock = { O3 = 3.141592653589793 }, and a bad expression names the
    field and the position, as for every scalar of a scene."""
    exact = _example1_locked_at(tmp_path, "3.141592653589793").configurations["config2"].derivation
    expr = _example1_locked_at(tmp_path, '"pi"').configurations["config2"].derivation
    assert dict(expr.values) == dict(exact.values) == {"O3": math.pi}
    with pytest.raises(pcmm.SceneError, match=r"configurations\.config2\.lock\.O3: = 'pi \+': at position 5"):
        _example1_locked_at(tmp_path, '"pi +"')
