"""The run loop's own promises (issue 22): a segment's series depend on that segment alone,
every switch leaves the target configuration's constraints satisfied (or stops the run and
says which one), and the flight-energy audit can fail.

Expectations come from independent routes: a KKT solve ``[[M, -A^T], [A, 0]]`` assembled here
from Pinocchio's ``crba`` / ``nle`` / frame Jacobians on the URDF text (not from pcmm's
configurations), and the same run taken to two different ``t_end``.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from scipy.optimize import fsolve

import builders
import pcmm

G = builders.G

# ---- a five-bar whose joint J3 is locked (a four-bar) until its holding moment crosses a value
FIVE = dict(L=(0.1, 0.15, 0.15, 0.12), masses=(0.6, 0.65, 0.65, 0.4), D=(0.25, 0.0), q12=(1.3, -0.6), c=0.01)


def _five_bar_closure(q12, guess=(-1.0, -1.0)):
    """(J1, J2, J3, J4) with the chain's tip on D (the cut joint E), solved here."""
    L, D = FIVE["L"], FIVE["D"]

    def tip(q):
        x = y = a = 0.0
        for length, qi in zip(L, q):
            a += qi
            x, y = x + length * math.cos(a), y + length * math.sin(a)
        return np.array([x, y])
    z = fsolve(lambda z: tip([*q12, *z]) - D, guess, xtol=1e-14)
    return [*q12, float(z[0]), float(z[1])]


def five_bar_released(folder: Path, t_end: float, threshold: float = 0.0) -> Path:
    """Four bars J1..J4 from the origin, the last one's tip pinned to the frame at D by the cut
    joint E; 'locked' is 'open' with J3 locked at its initial value.  The run starts locked
    under gravity, with a damper -c J1' on J1, and 'let go' frees J3 when its holding moment
    drops through ``threshold``."""
    L, m = FIVE["L"], FIVE["masses"]
    q = _five_bar_closure(FIVE["q12"])
    urdf = builders.chain_urdf([builders.Bar(length, mass) for length, mass in zip(L, m)])
    cut = [{"name": "E", "type": "revolute", "a": "frame", "point_a": list(FIVE["D"]), "b": "link4",
            "point_b": [L[3], 0.0]}]
    doc = builders.scene_doc(
        {"locked": {"from": "open", "lock": {"J3": q[2]}}, "open": {"urdf": "fb.urdf", "cut_joints": cut}},
        {"J1": q[0], "J2": q[1], "J4": q[3]}, {"J1": 0.0, "J2": 0.0, "J4": 0.0}, t_end=t_end, initial="locked",
        forces=[{"name": "damper", "type": "linear", "on": {"joint": "J1"}, "measure": {"joint": "J1"},
                 "c": FIVE["c"]}],
        transitions=[{"name": "let go", "type": "release", "from": "locked", "to": "open",
                      "guard": {"type": "reaction", "of": "J3", "value": threshold, "direction": "decreasing"}}])
    return builders.write_scene(folder, doc, {"fb.urdf": urdf})


def kkt_five_bar(urdf: str, q_full, v_full, locked: int | None):
    """Independent KKT solve on the open five-bar: rows = the tip of link 4 at D (x, y) and, if
    ``locked``, that joint's coordinate.  ``M a + h = tau + A^T lam``, ``A a = -Adot v``, with
    the damper's ``tau_1 = -c v_1``.  Returns lam
    (E.fx, E.fy[, hold])."""
    model = pin.buildModelFromXML(urdf)
    model.gravity.linear[:] = [0.0, -G, 0.0]
    tip = model.addFrame(pin.Frame("tip", model.getJointId("J4"), model.getFrameId("link4"),
                                   pin.SE3(np.eye(3), np.array([FIVE["L"][3], 0.0, 0.0])), pin.FrameType.OP_FRAME))
    data = model.createData()
    q, v = np.asarray(q_full, float), np.asarray(v_full, float)
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    h = pin.nle(model, data, q, v)
    pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    A = pin.getFrameJacobian(model, data, tip, pin.LOCAL_WORLD_ALIGNED)[:2]
    gamma = pin.getFrameClassicalAcceleration(model, data, tip, pin.LOCAL_WORLD_ALIGNED).linear[:2]
    assert np.allclose(data.oMf[tip].translation[:2], FIVE["D"], atol=1e-10)  # the state is assembled
    if locked is not None:
        e = np.zeros((1, model.nv))
        e[0, locked] = 1.0
        A, gamma = np.vstack([A, e]), np.append(gamma, 0.0)
    k = A.shape[0]
    K = np.block([[M, -A.T], [A, np.zeros((k, k))]])
    tau = np.zeros(model.nv)
    tau[0] = -FIVE["c"] * v[0]
    return np.linalg.solve(K, np.concatenate([tau - h, -gamma]))[model.nv:]


def test_holding_moment_is_the_kkt_multiplier_of_its_own_segment(tmp_path):
    """Issue 22.1: the lock's holding moment J3.hold of the locked stretch, computed when read
    after the run ended released, is the KKT multiplier of the lock row at the segment's own
    recorded state, at every sampled instant; at the release it equals the guard's value."""
    traj = pcmm.simulate(pcmm.load_scene(five_bar_released(tmp_path, t_end=0.6)))
    (ev,) = [e for e in traj.events if e["name"] == "let go"]
    assert traj.segments[-1].configuration == "open"
    seg = traj.segments[0]
    assert seg.configuration == "locked" and seg.t[-1] == pytest.approx(ev["t"], abs=0)
    j3 = _five_bar_closure(FIVE["q12"])[2]
    urdf = (tmp_path / "fb.urdf").read_text()
    hold = seg.constraint_forces[:, seg.constraint_labels.index("J3.hold")]
    cut = [seg.constraint_labels.index("E.fx"), seg.constraint_labels.index("E.fy")]
    checked = 0
    for i in np.unique(np.linspace(0, len(seg.t) - 1, 12).astype(int)):
        q, v = seg.q[i], seg.v[i]  # (J1, J2, J4)
        lam = kkt_five_bar(urdf, [q[0], q[1], j3, q[2]], [v[0], v[1], 0.0, v[2]], locked=2)
        scale = max(1.0, float(np.max(np.abs(lam))))
        assert hold[i] == pytest.approx(lam[2], abs=1e-9 * scale), f"t = {seg.t[i]}"
        np.testing.assert_allclose(seg.constraint_forces[i, cut], lam[:2], atol=1e-9 * scale)
        checked += 1
    assert checked >= 10
    assert hold[-1] == pytest.approx(0.0, abs=1e-7)  # the guard fired where the moment crossed 0
    # stats.holding's extremes are the moment's between the samples too (pcmm.results.peaks): beyond
    # the samples' (the minimum by 9.4e-3 N m: a sharp dip between steps 2 ms apart), beyond every
    # value of a 1e-5 s resampling on the dense output, the extreme of a 1e-8 s one around its time,
    # and each the KKT multiplier at the dense output's state at its own time
    ext = traj.stats["holding"]["J3.hold"]
    assert ext["min"] < hold.min() - 9e-3 and ext["max"] >= hold.max()
    fine = traj.resampled(1e-5).series("constraint_forces", "J3.hold")
    assert ext["min"] <= np.nanmin(fine) + 1e-12 and ext["max"] >= np.nanmax(fine) - 1e-12
    for value, t, pick in ((ext["min"], ext["t_min"], np.min), (ext["max"], ext["t_max"], np.max)):
        near = np.clip(t + np.linspace(-1e-6, 1e-6, 201), seg.t[0], seg.t[-1])
        local = seg.resampled(np.unique(near)).constraint_forces[:, seg.constraint_labels.index("J3.hold")]
        assert value == pytest.approx(pick(local), abs=1e-9)
        at = seg.resampled(np.array([t]))
        q, v = at.q[0], at.v[0]
        lam = kkt_five_bar(urdf, [q[0], q[1], j3, q[2]], [v[0], v[1], 0.0, v[2]], locked=2)
        assert value == pytest.approx(lam[2], abs=1e-9 * max(1.0, float(np.max(np.abs(lam)))))


def test_a_segments_series_do_not_depend_on_what_comes_after_it(tmp_path):
    """Issue 22.1: the same run to t_end = 0.05 s (ends locked) and 0.6 s (ends released): the
    common part of every series agrees (the locked stretch's holding moment included)."""
    short = pcmm.simulate(pcmm.load_scene(five_bar_released(tmp_path / "a", t_end=0.05)))
    long = pcmm.simulate(pcmm.load_scene(five_bar_released(tmp_path / "b", t_end=0.6)))
    assert long.segments[-1].configuration == "open" and short.segments[-1].configuration == "locked"
    a, b = short.segments[0], long.segments[0]
    common, ia, ib = np.intersect1d(a.t, b.t, return_indices=True)
    assert common.size >= 3 and common[0] == 0.0
    assert a.constraint_labels == b.constraint_labels
    for name in ("q", "v", "constraint_forces", "kinetic", "potential"):
        np.testing.assert_allclose(getattr(a, name)[ia], getattr(b, name)[ib], rtol=1e-12, atol=1e-12,
                                   err_msg=name)


# ---- a hold read after the run re-entered its reference configuration at other locked values ------
ARM = dict(L=(0.4, 0.3, 0.25), m=(1.0, 0.8, 0.5), J3=0.3, elbow=0.4, wrist=-0.6)


def arm_relocked(folder: Path, t_end: float = 1.2) -> Path:
    """A hanging three-bar arm J1-J2-J3 that starts with J2 = 0, J3 = 0.3 locked ('start'); at
    0.05 s J2 is freed into 'A' (the arm with J3 locked at entry); the elbow latches at J2 = 0.4
    into 'B' (J2 and J3 locked), whose holding moment J2.hold is solved in 'A' (the configuration
    with J2 free); at 0.5 s both are freed ('free'), and the wrist latches at J3 = -0.6 into 'A'
    again: a model of 'A' built for J3 = -0.6, which ``mechanism['A']`` is from then on."""
    urdf = builders.chain_urdf([builders.Bar(length, mass) for length, mass in zip(ARM["L"], ARM["m"])])

    def latch(name, source, joint, value, direction):
        return {"name": name, "type": "latch", "from": source, "to": "B" if joint == "J2" else "A", "cut": [joint],
                "guard": {"type": "coordinate", "measure": {"joint": joint}, "value": value, "direction": direction},
                "contact": {"joint": joint, "arm": 0.05}}
    doc = builders.scene_doc(
        {"start": {"from": "free", "lock": {"J2": 0.0, "J3": ARM["J3"]}}, "free": "arm.urdf",
         "A": {"from": "free", "lock": ["J3"]}, "B": {"from": "free", "lock": ["J2", "J3"]}},
        {"J1": 0.0}, {"J1": 0.0}, t_end=t_end, initial="start",
        transitions=[{"name": "unlock", "type": "release", "from": "start", "to": "A", "guard": {"type": "time", "at": 0.05}},
                     latch("elbow", "A", "J2", ARM["elbow"], "increasing"),
                     {"name": "let go", "type": "release", "from": "B", "to": "free", "guard": {"type": "time", "at": 0.5}},
                     latch("wrist", "free", "J3", ARM["wrist"], "decreasing")])
    return builders.write_scene(folder, doc, {"arm.urdf": urdf})


def kkt_locked_arm(urdf: str, q1: float, v1: float) -> float:
    """Independent KKT solve on the free arm with J2 and J3 locked at (elbow, J3) and J1 at (q1, v1):
    the multiplier of J2's row, ``M a + h = A^T lam``, ``A a = 0``, ``A`` the rows of J2 and J3."""
    model = pin.buildModelFromXML(urdf)
    model.gravity.linear[:] = [0.0, -G, 0.0]
    data = model.createData()
    q, v = np.array([q1, ARM["elbow"], ARM["J3"]]), np.array([v1, 0.0, 0.0])
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    K = np.block([[M, -A.T], [A, np.zeros((2, 2))]])
    return float(np.linalg.solve(K, np.concatenate([-pin.nle(model, data, q, v), np.zeros(2)]))[3])


def test_a_holding_moment_read_after_its_reference_was_built_again_is_the_one_of_its_time(tmp_path):
    """J2.hold of the locked stretch in 'B', read when the run is over (after the wrist latch built
    'A' again for J3 = -0.6), is the KKT multiplier of J2's row at the segment's recorded state with
    J3 = 0.3, as it was then; before Holds.applied kept the reference model, it was solved on the
    model of 'A' of the run's end (J3 = -0.6) and was off by up to 1.03 N m."""
    traj = pcmm.simulate(pcmm.load_scene(arm_relocked(tmp_path)))
    assert [e["name"] for e in traj.events] == ["unlock", "elbow", "let go", "wrist"]
    assert traj.stats["derived_configurations"]["A"] == [{"J3": pytest.approx(ARM["J3"], abs=1e-12)},
                                                          {"J3": pytest.approx(ARM["wrist"], abs=1e-9)}]
    (seg,) = [s for s in traj.segments if s.configuration == "B"]
    assert traj.segments[-1].configuration == "A" and seg.constraint_labels == ["J2.hold"]
    urdf = (tmp_path / "arm.urdf").read_text()
    hold = seg.constraint_forces[:, 0]
    for i in range(len(seg.t)):
        lam = kkt_locked_arm(urdf, seg.q[i, 0], seg.v[i, 0])
        assert hold[i] == pytest.approx(lam, abs=1e-9 * max(1.0, abs(lam))), f"t = {seg.t[i]}"
    assert len(seg.t) >= 6 and np.ptp(hold) > 1.0  # a moment that varies, checked at every sample


# ---- issue 22.2: a switch whose target's constraints the impulse does not satisfy -----------------
FOOT = dict(L=0.8, m=2.0, h=0.5, theta=-0.4)


def pinned_foot(folder: Path, t_end: float = 0.6) -> Path:
    """A bar on a planar joint P (centroid at P), tilted by ``theta`` and dropped from rest; its
    lower tip strikes the ground and latches into 'pinned', where the cut joint F pins that tip
    to the ground.  The contact has the single normal (0, 1): its impulse cannot stop the tip's
    sliding, which F's x row forbids."""
    L, m, h, th = FOOT["L"], FOOT["m"], FOOT["h"], FOOT["theta"]
    urdf = builders.robot_xml("foot", builders.link_xml("frame"), builders.joint_xml("P", "planar", "frame", "bar"),
                              builders.solid_xml("bar", m, m * L * L / 12))
    x_tip = L / 2 * math.cos(th)
    contact = {"a": "frame", "point_a": [x_tip, 0.0], "b": "bar", "point_b": [L / 2, 0.0], "normal": [0.0, 1.0]}
    pin_f = [{"name": "F", "type": "revolute", "a": "frame", "point_a": [x_tip, 0.0], "b": "bar",
              "point_b": [L / 2, 0.0]}]
    tr = {"name": "strike", "type": "latch", "from": "flight", "to": "pinned", "cut": [],
          "guard": {"type": "gap", "value": 0.0, "direction": "decreasing"}, "contact": contact}
    doc = builders.base_doc("foot", "flight", {"flight": "foot.urdf", "pinned": {"urdf": "foot.urdf", "cut_joints": pin_f}},
                            {"P": [0.0, h, th]}, {"P": [0.0, 0.0, 0.0]}, t_end=t_end, transitions=[tr])
    return builders.write_scene(folder, doc, {"foot.urdf": urdf})


def test_a_latch_whose_impulse_cannot_satisfy_a_new_cut_joint_stops_and_says_why(tmp_path):
    """Issue 22.2: the plastic normal impulse at the tip, by hand (r = tip - centroid, I = m L^2/12):
    P = v- / (1/m + r_x^2 / I), the bar spins up by r_x P / I and the tip slides at
    -omega r_y: the cut joint F's x row is left violated by that speed at the strike, which
    happens at t = sqrt(2 d / g) (d the tip's drop).  The run stops there and says so; before,
    the velocity was projected onto the pin silently (kinetic energy 2.4 -> 1.3 J, no word)."""
    L, m, h, th = FOOT["L"], FOOT["m"], FOOT["h"], FOOT["theta"]
    I = m * L * L / 12
    r = np.array([L / 2 * math.cos(th), L / 2 * math.sin(th)])
    d = h + r[1]
    v_minus = math.sqrt(2 * G * d)
    P = v_minus / (1 / m + r[0] ** 2 / I)
    slide = -(r[0] * P / I) * r[1]
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(pcmm.load_scene(pinned_foot(tmp_path)))
    text = str(info.value)
    assert float(re.search(r"t = (\S+) s, latch", text).group(1)) == pytest.approx(math.sqrt(2 * d / G), rel=1e-7)
    assert "latch 'strike' 'flight' -> 'pinned'" in text and "'F.fx' (cut joint F)" in text
    found = float(re.search(r"'F\.fx' \(cut joint F\) by (\S+) m/s", text).group(1))
    assert abs(found) == pytest.approx(abs(slide), rel=1e-5)
    assert "'F.fy'" not in text  # the normal row is what the impulse did satisfy
    assert info.value.partial is not None and info.value.partial.segments[-1].configuration == "flight"


def test_a_latch_in_a_loop_enters_with_its_constraints_at_round_off(tmp_path):
    """Issue 22.2, the normal case: the four-bar's latch (cut joint D kept, J3 locked) enters
    'latched' with exactly the impulse's velocity (no projection moves it) and the cut joint's
    velocity rows hold at round-off, checked here on the URDF with Pinocchio alone."""
    path = builders.four_bar_latch(tmp_path, t_end=0.79)
    traj = pcmm.simulate(pcmm.load_scene(path))
    ev = next(e for e in traj.events if e["name"] == "latch")
    after = next(s for s in traj.segments if s.configuration == "latched")
    assert after.t[0] == ev["t"]
    v_after = ev["v_after"]
    v_full = np.array([v_after["J1"], v_after["J2"], v_after["J3"]])
    scale = max(abs(w) for w in ev["v_before"].values())  # round-off of the pre-impact velocities
    assert scale > 0.1
    assert abs(v_full[2]) < 1e-12 * scale  # J3 stopped by the impulse
    np.testing.assert_allclose(after.v[0], v_full[:2], rtol=0, atol=1e-12 * scale)
    model = pin.buildModelFromXML((tmp_path / "fb.urdf").read_text())
    data = model.createData()
    q3 = next(s for s in traj.segments if s.configuration == "open").q[-1][2]  # J3 where it latched
    q_full = np.array([after.q[0][0], after.q[0][1], q3])
    tip = model.addFrame(pin.Frame("tip", model.getJointId("J3"), model.getFrameId("link3"),
                                   pin.SE3(np.eye(3), np.array([0.12, 0.0, 0.0])), pin.FrameType.OP_FRAME))
    data = model.createData()
    pin.computeJointJacobians(model, data, q_full)
    pin.updateFramePlacements(model, data)
    np.testing.assert_allclose(data.oMf[tip].translation[:2], [0.2, 0.0], atol=1e-9)
    J = pin.getFrameJacobian(model, data, tip, pin.LOCAL_WORLD_ALIGNED)[:2]
    assert np.max(np.abs(J @ v_full)) < 1e-12 * scale


# ---- issue 22.5: the flight-energy audit measures what the integrator did not ---------------------
BALL = dict(e=0.8, h=0.5, m=1.5)


def _bouncing_ball(tmp_path, monkeypatch=None, plant=None):
    """A ball dropped from h on a floor with restitution e (builders.ball); ``plant(out)``
    alters the state the run re-enters after each bounce (a planted defect)."""
    from pcmm.events import transitions
    if plant is not None:
        handle = transitions.TRANSITIONS["stop"]

        def planted(ctx, cfg, tr, t, q, v):
            out = handle(ctx, cfg, tr, t, q, v)
            if out.configuration == cfg.name:  # a bounce: a flight follows
                plant(out)
            return out
        monkeypatch.setitem(transitions.TRANSITIONS, "stop", planted)
    path = builders.ball(tmp_path, BALL["e"], h=BALL["h"], mass=BALL["m"], t_end=3.0)
    traj = pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(accumulation_speed=1e-3))
    (macro,) = traj.stats["macro_impacts"]
    assert macro["flights"] >= 5
    return traj, macro


def test_flight_audit_is_at_round_off_on_an_honest_run(tmp_path):
    _, macro = _bouncing_ball(tmp_path)
    assert macro["flight_energy_relative_max"] < 1e-10
    assert macro["flight_energy_residual_max"] < 1e-12


def test_flight_audit_catches_a_wrong_re_entry_velocity(tmp_path, monkeypatch):
    """Re-entering each flight at (1 + 1e-6) x the impulse's velocity puts a relative
    (1 + 1e-6)^2 - 1 = 2e-6 of the rebound energy into every flight, which the audit must
    report (the integrator's own energy balance, started from the re-entered state, sees none)."""
    eps = 1e-6

    def plant(out):
        out.v = out.v * (1 + eps)
    traj, macro = _bouncing_ball(tmp_path, monkeypatch, plant)
    assert macro["flight_energy_relative_max"] == pytest.approx((1 + eps) ** 2 - 1, rel=1e-3)


def test_flight_audit_catches_a_restart_shifted_off_the_impact(tmp_path, monkeypatch):
    """Re-entering each flight 1e-9 m above the impact posture (the old re-arm shift, made
    large enough to stand above round-off) gives every flight m g d of gravity energy that no
    force supplied: the audit's residual is that, J for J."""
    d = 1e-9

    def plant(out):
        out.q = out.q + d
    _, macro = _bouncing_ball(tmp_path, monkeypatch, plant)
    assert macro["flight_energy_residual_max"] == pytest.approx(BALL["m"] * G * d, rel=1e-4)


def test_every_switch_enters_its_configuration_through_the_checked_entry(tmp_path, monkeypatch):
    """Issue 22.2: the constraint check lives in entry.enter, and every transition kind
    reaches the next configuration through it: a latch and a timed release of the four-bar,
    and a ball's bounces and its merge, one checked entry per event (a bounce's is
    entry.enter_bounce: the same checks, into its own configuration)."""
    from pcmm.events import entry, pins, transitions
    calls = []
    real, real_bounce = entry.enter, entry.enter_bounce

    def counting(src, dst, t, *args, **kw):
        entry = real(src, dst, t, *args, **kw)
        calls.append((t, src.name, dst.name, entry.velocity_residual))
        return entry

    def counting_bounce(cfg, t, *args, **kw):
        q, v, residual = real_bounce(cfg, t, *args, **kw)
        calls.append((t, cfg.name, cfg.name, residual))
        return q, v, residual
    for module in (entry, transitions, pins):  # every module that enters a configuration
        monkeypatch.setattr(module, "enter", counting)
        if hasattr(module, "enter_bounce"):
            monkeypatch.setattr(module, "enter_bounce", counting_bounce)
    latch = pcmm.simulate(pcmm.load_scene(builders.four_bar_latch(tmp_path / "fb", t_end=1.0)))
    ball = pcmm.simulate(pcmm.load_scene(builders.ball(tmp_path / "ball", 0.5, h=0.3, t_end=2.0)),
                         pcmm.RunOptions(accumulation_speed=1e-2))
    events = latch.events + ball.events
    assert {e["transition"] for e in events} >= {"latch", "release", "stop"}
    assert [(e["t"], e["from"], e["to"]) for e in events] == [c[:3] for c in calls]
    assert max(c[3] for c in calls) < 1e-12
