"""The differential oracle (tests/oracle.py) over every shipped example and the scenes the tests build.

Each case runs a scene (a short ``t_end`` where its run is long), recomputes every recorded
series at sampled instants of every segment from ``(t, q, v)`` and the scene's data alone
(an independent Pinocchio model, force elements, constraint rows and KKT solve), checks every
event, and checks the same on the run resampled at ``dt``.  The prefix cases run each scene to
two ``t_end`` values and require the common part of every series, of its ``dt`` resampling and
of its CSV to agree.  ``docs/oracle.md`` says what is checked and how to add a scene.
"""
from __future__ import annotations

import math

import builders
import numpy as np
import oracle
import pinocchio as pin
import pytest
from builders import EXAMPLES

import pcmm
from pcmm.errors import SimulationError
from pcmm.model.mechanism import Mechanism

#: every shipped example: (t_end, dt of the resampled check), short where the run is long
EXAMPLE_RUNS = {
    "three_bar.toml": (0.4, 0.01),  # the latch at 0.167 s and the locked stretch after it
    "three_bar_stop.toml": (0.5, 0.01),  # the stop, its bounces and the merge
    "andrews.toml": (0.03, 0.001),  # the seven-body loop, the whole run
    "double_folded.toml": (3.2, 0.1),  # the driven loop, the slider's stop (3.0 s), bounces, merge (3.16 s)
    "double_folded_cycle.toml": (3.3, 0.1),  # the same with unmerge (its release: the xfail case below)
    "three_bar_cycle.toml": (1.3, 0.05),  # merges, the fold, and the first release
    "rimless_wheel.toml": (2.5, 0.05),  # two strikes, each a pin anchored where the spoke lands
    "compass_gait.toml": (1.6, 0.05),  # two heel strikes
}


def _findings(path, t_end=None, dt=None, **options):
    """The oracle's findings on the run (a run that stops keeps its partial trajectory); the
    comparisons it made are checked to cover what the run has (a check that never ran cannot fail)."""
    scene = pcmm.load_scene(path)
    try:
        traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=t_end, **options) if t_end else pcmm.RunOptions(**options))
    except SimulationError as exc:
        if exc.partial is None or not exc.partial.segments:
            raise
        traj = exc.partial
    o = oracle.Oracle(scene)
    found = o.check(traj, samples=4)
    _covered(traj, o.counts)
    if dt is not None:
        found += oracle.Oracle(scene).check(traj.resampled(dt), samples=4)
    return traj, found


def _covered(traj, counts):
    need = {"x,y of", "theta of", "omega of", "kinetic energy", "potential energy"}
    if any(s.force_names for s in traj.segments):
        need.add("force element")
    labels = {lab for s in traj.segments for lab in s.constraint_labels}
    if labels:
        need.add("constraint force")
    if any(not lab.endswith(".hold") for lab in labels):  # a cut joint's or a drive's rows
        need |= {"residual", "residual rate"}
    if len(traj.segments) > 1:
        need |= {"segments meet", "jumps"}
    if any(e.get("impact") and e.get("law", "impulse") == "impulse" for e in traj.events):
        need |= {"momentum not conserved", "kinetic_energy_after", "kinetic_energy_before"}
    missing = need - set(counts)
    assert not missing, f"the oracle made no comparison of: {sorted(missing)}"


def _show(found) -> str:
    seen, lines = set(), []
    for f in found:
        if f.what not in seen:
            seen.add(f.what)
            lines.append(str(f))
    return f"{len(found)} disagreements, {len(lines)} kinds:\n" + "\n".join(lines[:20])


@pytest.mark.parametrize("name", sorted(EXAMPLE_RUNS))
def test_every_example_agrees_with_the_oracle(name):
    assert sorted(p.name for p in EXAMPLES.glob("*.toml")) == sorted(EXAMPLE_RUNS), \
        "a new example: give it a t_end and dt in EXAMPLE_RUNS"
    t_end, dt = EXAMPLE_RUNS[name]
    traj, found = _findings(EXAMPLES / name, t_end, dt)
    assert len(traj.segments) >= 1
    assert not found, _show(found)


#: the scenes tests/builders.py builds, with numbers that make their events happen within t_end
BUILT = {
    "ball": lambda d: builders.ball(d, 0.5, h=0.3, t_end=0.8),
    "ball_hunt_crossley": lambda d: builders.ball(d, 0.8, h=0.3, t_end=0.6, merge=False, law="hunt_crossley",
                                                  stiffness=1e7, exponent=1.5),
    "pendulum": lambda d: builders.pendulum(d, 0.5, q0=0.3, t_end=1.2),
    "spring_pendulum": lambda d: builders.spring_pendulum(d, 3.0, 0.1, t_end=0.5),
    "two_link": lambda d: builders.two_link(d, 0.6, 1.0, 0.7, t_end=0.4),
    "two_free_bodies": lambda d: builders.two_free_bodies(d, 0.8, 1.0, 2.0, 0.01, 0.03),
    "two_balls": lambda d: builders.two_balls(d, 0.5, 0.8),
    "flat_bar": lambda d: builders.flat_bar(d, 0.5, t_end=0.35),
    "slider_crank_slider_driven": lambda d: builders.slider_crank_slider_driven(d, [0.35, 0.02, -0.01], t_end=0.5),
    "parallelogram": lambda d: builders.parallelogram(d, 0.5, 2.0, t_end=0.5),
    "slider_crank_stop": lambda d: builders.slider_crank_stop(d, 0.5, t_end=1.0),
    "four_bar_rocker_stop": lambda d: builders.four_bar_rocker_stop(d, 0.5, 2.2, torque=5.0, t_end=0.6),
    "four_bar_latch": lambda d: builders.four_bar_latch(d),
}


@pytest.mark.parametrize("name", sorted(BUILT))
def test_every_built_scene_agrees_with_the_oracle(name, tmp_path):
    _, found = _findings(BUILT[name](tmp_path), dt=0.01)
    assert not found, _show(found)


def test_the_copied_example_agrees_with_the_oracle(tmp_path):
    """tests/scene_files.py's copy of Example 1 (the scene the deletion tests run)."""
    from scene_files import copy_example1
    _, found = _findings(copy_example1(tmp_path), 0.25, 0.01)
    assert not found, _show(found)


#: (scene, the shorter t_end, the longer one, dt): each shorter run ends inside a stretch that the
#: longer run goes on through (a locked stretch, a bounce sequence, a driven loop)
PREFIX = [
    ("three_bar.toml", 0.12, 0.3, 0.01),
    ("three_bar.toml", 0.2, 0.35, 0.01),
    ("three_bar_stop.toml", 0.2, 0.4, 0.01),
    ("double_folded.toml", 3.05, 3.2, 0.05),
    ("andrews.toml", 0.01, 0.02, 0.001),
    ("three_bar_cycle.toml", 0.2, 0.35, 0.05),
]


@pytest.mark.parametrize("name, t_short, t_long, dt", PREFIX)
def test_a_shorter_run_is_the_first_part_of_a_longer_one(name, t_short, t_long, dt, tmp_path):
    problems = oracle.check_prefix(EXAMPLES / name, t_short, t_long, dt, tmp_path)
    assert not problems, "\n".join(problems[:20])


#: built scenes whose shorter run ends inside a bounce sequence, a contact-law phase, a locked
#: stretch without a free coordinate (its samples spaced by the time left to t_end)
PREFIX_BUILT = [("flat_bar", 0.25, 0.35), ("ball_hunt_crossley", 0.249, 0.6), ("four_bar_latch", 0.9, 1.2)]


@pytest.mark.parametrize("name, t_short, t_long", PREFIX_BUILT)
def test_a_shorter_run_of_a_built_scene_is_the_first_part_of_a_longer_one(name, t_short, t_long, tmp_path):
    problems = oracle.check_prefix(BUILT[name](tmp_path / "scene"), t_short, t_long, 0.01, tmp_path)
    assert not problems, "\n".join(problems[:20])


RESAMPLED = {
    "three_bar": lambda d: (EXAMPLES / "three_bar.toml", 0.4, 0.01, {}),
    "double_folded": lambda d: (EXAMPLES / "double_folded.toml", 1.0, 0.05, {}),
    "ball": lambda d: (builders.ball(d, 0.5, h=0.3, t_end=0.8), 0.8, 0.01, {}),
    "spring_pendulum_rk4": lambda d: (builders.spring_pendulum(d, 3.0, 0.1, t_end=2.0), 2.0, 0.05,
                                      {"method": "RK4", "step": 0.02}),
}


@pytest.mark.parametrize("name", sorted(RESAMPLED))
def test_the_dt_resampling_follows_the_solution_between_steps(name, tmp_path):
    """The dense output at dt against a run whose steps are at most dt / 8 (tolerances 100 times
    tighter): the resampling is the solution's, not a polygon of the steps or a step taken wrongly."""
    path, t_end, dt, options = RESAMPLED[name](tmp_path)
    problems = oracle.check_resampled_states(path, t_end, dt, **options)
    assert not problems, "\n".join(problems[:20])


def test_the_command_lines_csv_of_a_shorter_run_is_the_first_part_of_a_longer_ones(tmp_path):
    """pcmm run --dt --csv to t_end 0.12 s (before Example 1's latch) and 0.3 s (after it): every
    row of the shorter CSV is the longer one's, column by column."""
    from pcmm.cli import main
    for name, t_end in (("short", "0.12"), ("long", "0.3")):
        assert main(["run", str(EXAMPLES / "three_bar.toml"), "--t-end", t_end, "--dt", "0.01", "--quiet",
                     "--csv", str(tmp_path / f"{name}.csv")]) == 0
    rows = (tmp_path / "short.csv").read_text().splitlines()
    assert len(rows) == 1 + 13  # header, t = 0 ... 0.12 at 0.01
    problems = oracle.compare_csv(tmp_path / "short.csv", tmp_path / "long.csv")
    assert not problems, "\n".join(problems[:20])


@pytest.mark.parametrize("name, t_end", [("three_bar.toml", 0.3), ("andrews.toml", 0.01)])
def test_a_saved_run_loads_back_as_the_oracle_checked_it(name, t_end, tmp_path):
    """pcmm run --out: the NPZ file holds the series the oracle agrees with, bit for bit."""
    traj = pcmm.simulate(pcmm.load_scene(EXAMPLES / name), pcmm.RunOptions(t_end=t_end))
    back = pcmm.Trajectory.load(traj.save(tmp_path / "run.npz"))
    assert [e["t"] for e in back.events] == [e["t"] for e in traj.events]
    for s, b in zip(traj.segments, back.segments, strict=True):
        for a in ("t", "q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces"):
            np.testing.assert_array_equal(getattr(b, a), getattr(s, a), err_msg=a)
    found = oracle.check_run(EXAMPLES / name, traj=back)
    assert not found, _show(found)


@pytest.mark.parametrize("name, t_end", [
    ("three_bar.toml", 0.3),
    ("three_bar_cycle.toml", 1.25),
    ("double_folded.toml", 3.05),
])
def test_a_switch_without_impulse_names_every_velocity_it_changes(name, t_end):
    """The paper's comparison runs (impact = False): every velocity a switch changes is in the event's
    dropped_velocities with its value before (a joint it locks, or one the target's constraints do
    not let keep its rate) and, for the latter, in changed_velocities (before and after) and a
    warning with the energy; every other one goes on unchanged (the oracle compares each with the
    segments on either side)."""
    traj, found = _findings(EXAMPLES / name, t_end, impact=False)
    assert traj.events and not any(e["impact"] for e in traj.events)
    assert not found, _show(found)
    if name == "double_folded.toml":  # the slider's merge closes the driven loop: B and D change, named
        e = traj.events[-1]
        assert set(e["dropped_velocities"]) == {"E", "B", "D"} and set(e["changed_velocities"]) == {"B", "D"}
        (b0, b1), (d0, d1) = e["changed_velocities"]["B"], e["changed_velocities"]["D"]
        assert abs(b1 - b0) > 0.1 and abs(d1 - d0) > 0.1  # not round-off: the loop needs other rates
        assert [w for w in e["warnings"] if f"changes B' {b0:.6g} -> {b1:.6g}, D' {d0:.6g} -> {d1:.6g}" in w
                and f"from {e['kinetic_energy_before']:.6g} to {e['kinetic_energy_after']:.6g} J" in w]


@pytest.mark.parametrize("name, t_end", [("three_bar.toml", 0.3), ("three_bar_cycle.toml", 0.4),
                                          ("three_bar_stop.toml", 0.5)])
def test_the_csv_and_the_holding_stats_are_the_series(name, t_end, tmp_path):
    """Every CSV column is its series, sample for sample (empty where a segment lacks the name), in
    the run's steps and resampled at dt; stats["holding"] are the extremes of the hold series."""
    traj = pcmm.simulate(pcmm.load_scene(EXAMPLES / name), pcmm.RunOptions(t_end=t_end))
    problems = oracle.check_records(traj, tmp_path)
    problems += oracle.check_records(traj.resampled(0.01), tmp_path, stats=False)
    assert not problems, "\n".join(problems[:20])


def test_the_oracle_sees_a_wrong_number(tmp_path):
    """The oracle can fail: one recorded holding moment, energy and pose changed by a little
    are each reported at their instant."""
    traj = pcmm.simulate(pcmm.load_scene(EXAMPLES / "three_bar.toml"), pcmm.RunOptions(t_end=0.3))
    seg = traj.segments[1]
    k = seg.constraint_labels.index("O3.hold")
    seg.constraint_forces[3, k] += 1e-3
    seg.kinetic[0] += 1e-6
    seg.xy[-1, 2, 0] += 1e-6
    traj.events[0]["kinetic_energy_after"] += 1e-4
    found = oracle.check_run(EXAMPLES / "three_bar.toml", traj=traj, samples=len(seg.t))
    whats = {f.what for f in found}
    assert "config2: constraint force O3.hold" in whats
    assert "config2: kinetic energy" in whats
    assert "config2: x,y of link2" in whats
    traj.stats["holding"]["O3.hold"]["max"] += 1e-9
    assert any(p.startswith("stats holding O3.hold") for p in oracle.check_records(traj, tmp_path))
    # the kinetic energy after the latch is the event record's too
    assert any(f.what.startswith("event 'O3 latches': kinetic_energy_after") for f in found)
    assert all(math.isclose(f.t, seg.t[3]) or math.isclose(f.t, seg.t[0]) or math.isclose(f.t, seg.t[-1])
               for f in found)


# ---- the mechanisms of the defects the oracle found ---------------------------------------------------------------
def five_bar_latch(folder, release=None, t_end=0.2, torque=0.8):
    """A five-bar (chain J1..J4 of bars 0.1, 0.2, 0.2, 0.15 m from the frame's origin, link 4's tip
    pinned to the frame at (0.3, 0) by the cut joint D: two degrees of freedom), a damped motor on
    J1, gravity; its joint J3 latches at -1.3 rad (a joint stop) into 'latched' (derived by locking
    J3: a four-bar, one degree of freedom, on one of two assemblies), optionally released again."""
    urdf = builders.chain_urdf([builders.Bar(0.1, 0.2), builders.Bar(0.2, 0.3), builders.Bar(0.2, 0.3),
                                builders.Bar(0.15, 0.25)])
    cut = [{"name": "D", "type": "revolute", "a": "frame", "point_a": [0.3, 0.0], "b": "link4", "point_b": [0.15, 0.0]}]
    trs = [{"name": "latch", "type": "latch", "from": "open", "to": "latched", "cut": ["J3"],
            "guard": {"type": "coordinate", "measure": {"joint": "J3"}, "value": -1.3, "direction": "increasing"},
            "contact": {"joint": "J3", "arm": 0.05}}]
    if release is not None:
        trs.append({"name": "let go", "type": "release", "from": "latched", "to": "open", "guard": release})
    doc = builders.scene_doc(
        {"open": {"urdf": "fb.urdf", "cut_joints": cut}, "latched": {"from": "open", "lock": ["J3"]}},
        {"J1": 1.5708, "J2": -0.699, "J3": -1.414, "J4": -1.029}, {"J1": 0.0, "J2": 0.0, "J3": 0.0, "J4": 0.0},
        t_end=t_end, independent=["J1", "J3"],
        forces=[{"name": "motor", "type": "linear", "on": {"joint": "J1"}, "measure": {"joint": "J1"},
                 "value": torque, "c": 0.01}], transitions=trs)
    return builders.write_scene(folder, doc, {"fb.urdf": urdf})


def held_elbow_arm(folder, spring_value=0.3, spring_k=2.0, phi0=0.4, t_end=0.4):
    """Two bars (shoulder S at the origin, elbow E at link 1's tip) under gravity, starting at rest
    with the elbow locked at phi0 ('locked': E fixed in its URDF) and held there from the start: a
    reaction guard on E releases it into 'free'.  A torsion spring acts on E where E is free
    (``configurations = ["free"]``): while E is locked, the lock carries the spring's moment."""
    L1, L2, m1, m2 = 0.4, 0.3, 1.0, 0.8
    parts = (builders.link_xml("frame"), builders.joint_xml("S", "revolute", "frame", "link1"),
             builders.bar_xml("link1", L1, m1))
    free = builders.robot_xml("arm", *parts, builders.joint_xml("E", "revolute", "link1", "link2", xyz=(L1, 0.0)),
                              builders.bar_xml("link2", L2, m2))
    locked = builders.robot_xml("arm_locked", *parts, builders.joint_xml("E", "fixed", "link1", "link2", xyz=(L1, 0.0),
                                                                         yaw=phi0), builders.bar_xml("link2", L2, m2))
    tr = {"name": "elbow release", "type": "release", "from": "locked", "to": "free",
          "guard": {"type": "reaction", "of": "E", "value": 5.0, "direction": "increasing"}}
    forces = [{"name": "elbow spring", "type": "linear", "on": {"joint": "E"}, "measure": {"joint": "E"},
               "value": spring_value, "k": spring_k, "rest": 0.0, "configurations": ["free"]}]
    doc = builders.base_doc("arm", "locked", {"locked": "locked.urdf", "free": "free.urdf"}, {"S": 0.0}, {"S": 0.0},
                            t_end=t_end, transitions=[tr], forces=forces)
    return builders.write_scene(folder, doc, {"locked.urdf": locked, "free.urdf": free})


def test_the_holding_moment_of_a_latched_loop_is_solved_at_the_recorded_posture(tmp_path):
    traj, found = _findings(five_bar_latch(tmp_path), dt=0.01)
    assert [e["name"] for e in traj.events] == ["latch"]
    assert not found, _show(found)


def test_a_latched_loops_holding_moment_does_not_depend_on_t_end(tmp_path):
    problems = oracle.check_prefix(five_bar_latch(tmp_path / "scene"), 0.15, 0.2, 0.01, tmp_path)
    assert not problems, "\n".join(problems[:20])


def test_a_latched_loop_resampled_holds_at_the_kkt_moment(tmp_path):
    """The same five-bar's holding moment from the dense output agrees with the oracle's KKT solve,
    and with Newton-Euler on the free five-bar (the moment J3 needs for zero relative acceleration),
    checked here by finite differences of the resampled velocities."""
    path = five_bar_latch(tmp_path)
    scene = pcmm.load_scene(path)
    traj = pcmm.simulate(scene)
    seg = traj.segments[1]
    h, tm = 1e-5, 0.12
    r = seg.resampled(np.array([tm - h, tm, tm + h]))
    assert not oracle.Oracle(scene).check(pcmm.Trajectory(scene="", scene_name="", impact=True, segments=[r]), 3,
                                                locks={"J3": -1.3})
    O = oracle.Oracle(scene)
    F = O.model(O.texts["open"])

    def state(i):
        vals = dict(zip(r.coordinates, r.q[i]), J3=-1.3)
        rates = dict(zip(r.coordinates, r.v[i]), J3=0.0)
        return F.state(vals, rates)
    q, v = state(1)
    a = (state(2)[1] - state(0)[1]) / (2 * h)
    M = pin.crba(F.model, F.data, q)
    M = np.triu(M) + np.triu(M, 1).T
    F.kinematics(q, v)
    _, JD, _ = O.cut_rows(scene.configurations["open"].cut_joints[0], F, q, v)
    tau = np.zeros(F.nv)
    tau[F.vslice["J1"].start] = 0.8 - 0.01 * v[F.vslice["J1"].start]
    need = M @ a + pin.nonLinearEffects(F.model, F.data, q, v) - tau - JD.T @ r.constraint_forces[1, :2]
    for j in ("J1", "J2", "J4"):  # the free joints need nothing: the recorded D forces are the loop's
        assert abs(need[F.vslice[j].start]) < 1e-5
    assert r.constraint_forces[1, 2] == pytest.approx(need[F.vslice["J3"].start], rel=1e-5)


def test_a_lock_held_from_the_start_carries_its_joints_spring(tmp_path):
    """The elbow lock adopted at the start carries the elbow spring (f = 0.3 - 2 phi = -0.5 N m on
    link 2), though the scene lists it only where E is free (Holds.adopt's lock is the release's,
    whose source is 'locked'). By hand at t = 0 (at rest, S = 0, phi0 = 0.4): the welded arm turns
    about S with alpha = M_g / I_S; link 2's moments about E give the lock's moment
    lam = I_E alpha + m2 (L2/2) L1 alpha cos(phi0) - f + m2 g (L2/2) cos(phi0) = 0.14799 N m
    (-0.352 N m without the spring's moment)."""
    traj, found = _findings(held_elbow_arm(tmp_path))
    assert not found, _show(found)
    L1, L2, m1, m2, g, phi = 0.4, 0.3, 1.0, 0.8, builders.G, 0.4
    f = 0.3 - 2.0 * phi
    c2 = (L1 + L2 / 2 * math.cos(phi), L2 / 2 * math.sin(phi))
    alpha = -(m1 * g * L1 / 2 + m2 * g * c2[0]) / (m1 * L1 ** 2 / 3 + m2 * L2 ** 2 / 12 + m2 * (c2[0] ** 2 + c2[1] ** 2))
    lam = m2 * L2 ** 2 / 3 * alpha + m2 * L2 / 2 * L1 * alpha * math.cos(phi) - f + m2 * g * L2 / 2 * math.cos(phi)
    seg = traj.segments[0]
    assert seg.constraint_forces[0, seg.constraint_labels.index("E.hold")] == pytest.approx(lam, rel=1e-9)


def test_a_lock_held_from_the_start_without_a_spring_agrees(tmp_path):
    """The same arm without the spring: the oracle agrees (the defect above is the carried element)."""
    traj, found = _findings(held_elbow_arm(tmp_path, spring_value=0.0, spring_k=0.0))
    assert traj.segments[0].constraint_labels == ["E.hold"]
    assert not found, _show(found)


COARSE = {
    "andrews": lambda d: (EXAMPLES / "andrews.toml", 0.03),
    # a Grashof crank-rocker (no singular posture on its way) turned fast by a constant torque
    "crank_rocker": lambda d: (builders.four_bar_rocker_stop(d, 0.5, -5.0, torque=3.0, t_end=0.65, g=0.0), 0.65),
}


@pytest.mark.parametrize("name", sorted(COARSE))
def test_a_fast_loop_resampled_at_a_coarse_dt(name, tmp_path):
    """Resampling re-steps the dense output of the step holding each instant, solving the loop at
    that step's start first: warm-started from the segment's start (Andrews' crank beta turns 2.18 rad
    in 0.01 s) the Newton solve failed ('the loop cannot be closed at t = 0.00994615 s', a step
    time) even with every step time in the grid.  Each solve now starts from the accepted step
    before it (PartitionedCoordinates._follow).  The oracle checks the resampled series; resampled
    at its own step times, the segment gives back the series the run derived, sample for sample."""
    path, t_end = COARSE[name](tmp_path)
    traj, found = _findings(path, t_end, 0.01)
    assert not found, _show(found)
    seg = traj.segments[0]
    again = seg.resampled(np.union1d(np.arange(0.0, seg.t[-1], 0.01), seg.t))
    at_steps = np.searchsorted(again.t, seg.t)
    np.testing.assert_allclose(again.q[at_steps], seg.q, atol=1e-9)
    np.testing.assert_allclose(again.constraint_forces[at_steps], seg.constraint_forces, rtol=1e-7, atol=1e-9)


def planted_foot(folder, vx=1.0, h=0.2, L=0.6, m=1.0, t_end=0.4):
    """A uniform bar (m, L) on a URDF planar joint, upright (its frame at its centre, its foot at
    (0, -L/2)), moving at vx and dropped from h: its foot strikes the floor at x = vx sqrt(2 h / g),
    where a latch plants it into 'pinned' (a revolute cut joint F holds the foot there).  The
    contact's one normal cannot stop the foot's sliding: only F's two rows can."""
    urdf = builders.robot_xml("bar", builders.link_xml("frame"), builders.joint_xml("P", "planar", "frame", "bar"),
                              builders.solid_xml("bar", m, m * L * L / 12))
    x_hit = vx * math.sqrt(2 * h / builders.G)
    foot = {"a": "frame", "point_a": [x_hit, 0.0], "b": "bar", "point_b": [0.0, -L / 2]}
    tr = {"name": "plant", "type": "latch", "from": "flying", "to": "pinned", "cut": [],
          "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"}, "contact": {**foot, "normal": [0.0, 1.0]}}
    doc = builders.base_doc("planted_foot", "flying",
                            {"flying": "bar.urdf", "pinned": {"urdf": "bar.urdf",
                                                              "cut_joints": [{"name": "F", "type": "revolute", **foot}]}},
                            {"P": [0.0, h + L / 2, 0.0]}, {"P": [vx, 0.0, 0.0]}, t_end=t_end, transitions=[tr])
    return builders.write_scene(folder, doc, {"bar.urdf": urdf})


def test_a_latch_whose_normal_cannot_pin_a_foot_stops_naming_the_cut_joint(tmp_path):
    """The plant's impulse acts along the contact normal only, so it cannot stop the foot sliding
    at vx = 1 m/s along the floor; entering 'pinned' would need F's tangential row to jump by
    1 m/s. The run stops and names F's row and the velocity left (issue 22 item 2), instead of
    projecting the velocity silently (which lost 0.5 J and the momentum about the foot)."""
    with pytest.raises(SimulationError) as err:
        pcmm.simulate(pcmm.load_scene(planted_foot(tmp_path)))
    text = str(err.value)
    assert "'F.fx' (cut joint F) by 1 m/s" in text
    assert "P.x' = 1 where the constraints need P.x' = 0" in text


def pinned_planar_bar(folder, L=0.5, m=1.0, q0=0.8, pivot=(0.2, 0.1), at=0.4, t_end=1.0):
    """A uniform bar on a URDF planar joint (x, y, theta), pinned to the frame at ``pivot`` by a
    revolute cut joint through its point (at, 0): a compound pendulum (one degree of freedom),
    started at rest at theta = -q0."""
    urdf = builders.robot_xml("pp", builders.link_xml("frame"), builders.joint_xml("P", "planar", "frame", "bar"),
                              builders.bar_xml("bar", L, m))
    cut = [{"name": "pivot", "type": "revolute", "a": "frame", "point_a": list(pivot), "b": "bar",
            "point_b": [at, 0.0]}]
    x0 = [pivot[0] - at * math.cos(-q0), pivot[1] - at * math.sin(-q0), -q0]
    doc = builders.base_doc("pinned_planar_bar", "c", {"c": {"urdf": "pp.urdf", "cut_joints": cut}}, {"P": x0},
                            {"P": [0.0, 0.0, 0.0]}, t_end=t_end)
    return builders.write_scene(folder, doc, {"pp.urdf": urdf})


def test_a_planar_bar_pinned_at_its_frames_origin_agrees(tmp_path):
    traj = pcmm.simulate(pcmm.load_scene(pinned_planar_bar(tmp_path, pivot=(0.0, 0.0), at=0.0)))
    assert traj.t[-1] == 1.0
    found = oracle.check_run(tmp_path / "scene.toml", traj=traj)
    assert not found, _show(found)


def test_a_planar_bar_pinned_off_its_frames_origin_swings(tmp_path):
    traj = pcmm.simulate(pcmm.load_scene(pinned_planar_bar(tmp_path)))
    found = oracle.check_run(tmp_path / "scene.toml", traj=traj)
    assert not found, _show(found)


def test_the_merged_stretch_of_example2s_cycle_holds_what_the_kkt_solve_gives():
    _, found = _findings(EXAMPLES / "double_folded_cycle.toml", 6.3)
    assert not found, _show(found)


def test_the_potential_energy_is_continuous_where_the_posture_is():
    # the O2 lock (0.185 s), the O3 merge into folded (1.022 s) and the O2 release (1.199 s)
    traj = pcmm.simulate(pcmm.load_scene(EXAMPLES / "three_bar_cycle.toml"), pcmm.RunOptions(t_end=1.25))
    switches = [(a, b) for a, b in zip(traj.segments, traj.segments[1:]) if a.configuration != b.configuration]
    assert [(a.configuration, b.configuration) for a, b in switches] == [
        ("open", "O2_locked"), ("O2_locked", "folded"), ("folded", "O3_locked")]
    for a, b in switches:
        np.testing.assert_allclose(a.xy[-1], b.xy[0], atol=1e-9)  # the posture does not move
        assert b.potential[0] == pytest.approx(a.potential[-1], abs=1e-9), (a.configuration, b.configuration)
    # the O2 lock keeps 'spring O2' (f = value - k x, k = 0.3 N m/rad, rest 0) at the value O2 locked at:
    # 0.3 x^2 / 2 = 0.370 J over what the locked configuration's own elements (gravity, 'spring O3') store
    a, b = next((a, b) for a, b in switches if b.configuration == "O2_locked")
    x = a.q[-1, a.coordinates.index("O2")]
    mech = Mechanism(pcmm.load_scene(EXAMPLES / "three_bar_cycle.toml"))
    locked = mech.enter("O2_locked", mech["open"], a.q[-1])
    for i in (0, len(b.t) // 2, -1):
        assert b.potential[i] - locked.potential_energy(b.q[i]) == pytest.approx(0.5 * 0.3 * x * x, rel=1e-12)
    assert 0.5 * 0.3 * x * x == pytest.approx(0.370, abs=1e-3)


def block_on_cut_joint(folder, kind, incline=math.pi / 6, t_end=0.5):
    """A block on a URDF planar joint (x, y, theta) with a bar hung on it by the revolute R, held to
    the frame by a ``kind`` cut joint S at the block's origin: prismatic along an incline (the block
    slides, the bar swings: two degrees of freedom) or weld (the bar swings alone)."""
    urdf = builders.robot_xml("blk", builders.link_xml("frame"), builders.joint_xml("P", "planar", "frame", "blk"),
                              builders.solid_xml("blk", 2.0, 0.01), builders.joint_xml("R", "revolute", "blk", "arm"),
                              builders.bar_xml("arm", 0.3, 0.5))
    extra = {"axis": [math.cos(incline), math.sin(incline)], "angle": 0.0} if kind == "prismatic" else {"angle": 0.0}
    cut = [{"name": "S", "type": kind, "a": "frame", "point_a": [0.0, 0.0], "b": "blk", "point_b": [0.0, 0.0], **extra}]
    doc = builders.base_doc("block", "c", {"c": {"urdf": "b.urdf", "cut_joints": cut}}, {"P": [0.0, 0.0, 0.0], "R": -1.0},
                            {"P": [0.0, 0.0, 0.0], "R": 0.0}, t_end=t_end)
    return builders.write_scene(folder, doc, {"b.urdf": urdf})


@pytest.mark.parametrize("kind", ["prismatic", "weld"])
def test_prismatic_and_weld_cut_joints_agree_with_the_oracle(kind, tmp_path):
    traj, found = _findings(block_on_cut_joint(tmp_path, kind), dt=0.05)
    assert traj.segments[0].constraint_labels == (["S.fn", "S.mz"] if kind == "prismatic" else ["S.fx", "S.fy", "S.mz"])
    assert not found, _show(found)
