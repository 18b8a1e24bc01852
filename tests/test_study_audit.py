"""Every number a study shows, recomputed by another route (issue 22: no silent wrong number).

A sweep's row is read off a run's summary by :func:`pcmm.studies.job.quantities`.  Here each
column is recomputed without that code, twice:

* **by hand**, from the mechanisms' own derivations (``tests/test_newcomer2_mechanisms.py``: the
  four-bar's loop integrated in its own angles and its 18 x 18 Newton-Euler impulse solve, the
  latched triangle's statics, the leg's Lagrangian and pinned-foot impulse;
  ``tests/reference_rimless_wheel.py``: McGeer's strike ratio and the stance quadrature);
* **from a plain run** of the same scene with the same values, written as a TOML file by text
  (not through :mod:`pcmm.scene.variations`) and reduced here from its own event list and
  segments: impacts are the switches across which a link's angular velocity jumps, the energy
  lost is read off the ``kinetic`` series on both sides of each, a merge is a segment that holds a
  constraint row the previous one lacks.  The study must not change a run: the row's times and
  impulses equal the plain run's bit for bit.

Then: a resumed sweep gives the uninterrupted table; an optimisation's rows are runs too, and its
answer is the best of them; a run resampled at ``dt`` equals, at every resampled instant, a run
stopped there (``t_end``); the run to ``T`` is the first part of the run to ``2 T``.
"""
from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import numpy as np
import pytest

import oracle
import test_newcomer2_mechanisms as nm
from reference_rimless_wheel import RimlessWheel

import pcmm
from pcmm.studies.optimize import optimize, parse_vary
from pcmm.studies.sweep import make_plan, parse_set, sweep

ROOT = Path(__file__).resolve().parents[1]
WHEEL = ROOT / "examples" / "rimless_wheel.toml"
TIMING = ("solve_s", "wall_s")
K_PATH, FLOOR_PATH, RATE_PATH = "forces.arm spring.k", "transitions.foot strike.contact.point_a[1]", "initial.v.hip"
GX_PATH = "scene.gravity[0]"


# ---- the table and the plain run, read here ---------------------------------------------------
def read(path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def number(text: str):
    return None if text == "" else float(text)


def run_sweep(scene_path, sets, out, t_end) -> list[dict]:
    res = sweep(pcmm.load_scene(scene_path), make_plan([parse_set(s) for s in sets]), out,
                pcmm.RunOptions(t_end=t_end), workers=1)
    rows = read(out)
    assert res.status == {"complete": len(rows)}
    return rows


def switches(traj):
    """(event, segment before, segment after) for every event: one segment per stay."""
    segs, events = list(traj.segments), list(traj.events)
    assert len(segs) == len(events) + 1
    for e, after in zip(events, segs[1:]):
        assert after.t[0] == e["t"]
    return list(zip(events, segs[:-1], segs[1:]))


def jumps(before, after) -> bool:
    """Does a link's angular velocity change across the switch (an impulse acted)?"""
    w0 = dict(zip(before.links, before.omega[-1]))
    w1 = dict(zip(after.links, after.omega[0]))
    scale = max(1.0, *(abs(w) for w in w0.values()))
    return any(abs(w1[k] - w0[k]) > 1e-12 * scale for k in w0 if k in w1)


def held_extreme(traj, label: str) -> float:
    """The largest |holding force| of ``label`` along the run: its samples', or the force read again on
    the dense output at the times of ``stats.holding``'s extremes (the peak between two steps: the
    study's column takes those, pcmm.results.peaks) where that is larger."""
    values = [float(np.nanmax(np.abs(traj.series("constraint_forces", label))))]
    ext = traj.stats["holding"][label]
    for t in (ext["t_min"], ext["t_max"]):
        (seg,) = [s for s in traj.segments if s.t[0] <= t <= s.t[-1] and label in s.constraint_labels][:1]
        rec = seg.resampled(np.array([t]))
        values.append(abs(float(rec.constraint_forces[0, rec.constraint_labels.index(label)])))
    return max(values)


def plain_columns(traj) -> dict:
    """The table's columns read off a run's own records, not through its summary."""
    impacts = [(e, b, a) for e, b, a in switches(traj) if jumps(b, a)]
    impulses = [abs(e["impulse"]["normal"]) for e, _, _ in impacts]
    # |P| of the 2-D impulse: its world vector where the contact takes a tangential part, else |P_n|
    sizes = [float(np.hypot(*e["impulse"]["vector"])) if "tangential" in e["impulse"] else abs(e["impulse"]["normal"])
             for e, _, _ in impacts]
    holds = {lab for s in traj.segments for lab in s.constraint_labels if lab.endswith(".hold")}
    held = [held_extreme(traj, lab) for lab in holds]
    stays = [s for s in traj.segments if s.t[-1] > s.t[0]]
    merges = [s.t[0] for prev, s in zip(stays, stays[1:]) if set(s.constraint_labels) - set(prev.constraint_labels)]
    lost = math.fsum(b.kinetic[-1] - a.kinetic[0] for _, b, a in impacts)
    # a drive's impulse P works P f'(t) at the impact (the driven joint's rate does not jump)
    drive_work = math.fsum(p[-1] * b.v[-1][b.coordinates.index(label[:-len(".drive")])]
                           for e, b, _ in impacts for label, p in (e.get("constraint_impulses") or {}).items()
                           if label.endswith(".drive"))
    return {"events": len(traj.events), "impacts": len(impacts),
            "first_impact_t": impacts[0][0]["t"] if impacts else None,
            "first_impulse": impacts[0][0]["impulse"]["normal"] if impacts else None,
            "peak_impulse": max(impulses, default=0.0), "total_impulse": math.fsum(impulses),
            "first_impulse_magnitude": sizes[0] if impacts else None,
            "peak_impulse_magnitude": max(sizes, default=0.0), "total_impulse_magnitude": math.fsum(sizes),
            "kinetic_energy_lost": lost, "energy_dissipated": lost + drive_work,
            "max_holding_force": max(held) if held else None,
            "last_merge_t": float(merges[-1]) if merges else None,
            "configuration_final": traj.segments[-1].configuration, "t_final": float(traj.t[-1])}


def same(row: dict, expected: dict, rel: float, abs_: float = 0.0, where: str = "") -> list[str]:
    bad = []
    for k, v in expected.items():
        cell = row[k]
        if v is None or isinstance(v, str):
            ok = cell == ("" if v is None else v)
        else:
            ok = cell != "" and math.isclose(float(cell), v, rel_tol=rel, abs_tol=abs_)
        if not ok:
            bad.append(f"{where} {k}: table {cell!r}, expected {v!r}")
    return bad


def check_row_is_the_plain_run(row, traj):
    assert row["status"] == "complete" and row["error"] == ""
    # the same event list, the same instants and impulses: bit for bit (the study changes no run)
    exact = {k: v for k, v in plain_columns(traj).items()
             if k not in ("kinetic_energy_lost", "energy_dissipated", "max_holding_force")}
    assert same(row, exact, rel=0.0, where=f"run {row['run']}") == []
    assert same(row, plain_columns(traj), rel=1e-12, abs_=1e-15, where=f"run {row['run']}") == []
    assert 0 < float(row["solve_s"]) <= float(row["wall_s"])


# ---- the four-bar -----------------------------------------------------------------------------
def fourbar_scene(folder: Path, k: float) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "fourbar.urdf").write_text(nm.FOURBAR_URDF)
    text = nm.FOURBAR_TOML.replace("k = 1.0\n", f"k = {k!r}\n")
    assert text.count(f"k = {k!r}\n") == 1
    (folder / "fourbar.toml").write_text(text)
    return folder / "fourbar.toml"


def fourbar_by_hand(k: float, traj, monkeypatch) -> dict:
    """The columns of the four-bar with the arm's spring k (e = 0.5): the first strike by the loop's
    own dynamics and Newton-Euler; every strike's impulse and energy lost by Newton-Euler from the
    state before it (Kelvin: the impulse's work is P (u- + u+) / 2, u+ = -e u-); the count of bounces
    from the accumulation speed; the hold at the merge by the latched triangle's statics; the release
    where that hold reaches zero."""
    monkeypatch.setattr(nm, "K_ARM", k)
    t1, th, w = nm.fourbar_strike()
    P1, _, _, u1 = nm.fourbar_impact(th, w)
    n = 1 + math.ceil(math.log2(-u1 / 2e-6))
    strikes = [(e, b) for e, b, a in switches(traj) if e["transition"] == "stop" and jumps(b, a)]
    assert len(strikes) == n
    impulses, lost = [], []
    for i, (e, before) in enumerate(strikes):
        th_i = [before.theta[-1][before.links.index(x)] for x in ("crank", "coupler", "rocker")]
        w_i = [before.omega[-1][before.links.index(x)] for x in ("crank", "coupler", "rocker")]
        e_i = 0.0 if i == n - 1 else nm.E_STOP    # the last strike merges: plastic
        P, _, _, u = nm.fourbar_impact(np.array(th_i), np.array(w_i), e_i)
        impulses.append(P)
        lost.append(-P * (1 - e_i) * u / 2)
    t_merge = strikes[-1][0]["t"]
    th1_stop = nm.brentq(lambda x: nm.q3_of(x) - nm.Q3_STOP, math.radians(90), math.radians(180))
    t_release = math.sqrt((math.radians(140) - th1_stop - nm.dpotential(th1_stop) / k) / 0.5)
    assert t_merge < t_release < 1.2
    return {"events": n + 1, "impacts": n, "first_impact_t": t1, "first_impulse": P1,
            "peak_impulse": max(impulses), "total_impulse": math.fsum(impulses),
            "kinetic_energy_lost": math.fsum(lost), "energy_dissipated": math.fsum(lost),
            "max_holding_force": nm.hold_force(th1_stop, t_merge), "configuration_final": "open", "t_final": 1.2}


@pytest.fixture(scope="module")
def fourbar_table(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fourbar_study")
    scene = fourbar_scene(folder / "base", 1.0)
    return folder, run_sweep(scene, [f"{K_PATH}=0.9,1.1"], folder / "fourbar.csv", 1.2)


@pytest.mark.parametrize("i", [0, 1])
def test_fourbar_sweep_row_by_hand_and_by_plain_run(fourbar_table, i, monkeypatch):
    """Each row of a sweep of the arm's spring (0.9, 1.1 N m/rad) over the four-bar's bounces, merge
    and release: every column by hand (impulses to 1e-7, the merge's hold to 1e-6 relative), and
    every column equal to a plain run of the same scene written with that k."""
    folder, rows = fourbar_table
    row = rows[i]
    k = float(row[K_PATH])
    traj = pcmm.simulate(pcmm.load_scene(fourbar_scene(folder / f"k{i}", k)), pcmm.RunOptions(t_end=1.2))
    check_row_is_the_plain_run(row, traj)
    hand = fourbar_by_hand(k, traj, monkeypatch)
    assert same(row, {x: hand[x] for x in ("events", "impacts", "configuration_final", "t_final")}, 0.0) == []
    assert same(row, {"first_impact_t": hand["first_impact_t"]}, 0.0, 1e-9) == []
    assert same(row, {x: hand[x] for x in ("first_impulse", "peak_impulse", "total_impulse")}, 1e-7) == []
    assert same(row, {x: hand[x] for x in ("kinetic_energy_lost", "energy_dissipated")}, 1e-7) == []
    assert same(row, {"max_holding_force": hand["max_holding_force"]}, 1e-6) == []
    # the merge is the last strike, long before the release
    assert float(row["last_merge_t"]) < 0.5


def test_fourbar_sweep_row_at_the_newcomers_spring(tmp_path, monkeypatch):
    scene = fourbar_scene(tmp_path / "base", 1.0)
    (row,) = run_sweep(scene, [f"{K_PATH}=1.0"], tmp_path / "k1.csv", 1.2)
    traj = pcmm.simulate(pcmm.load_scene(scene), pcmm.RunOptions(t_end=1.2))
    hand = fourbar_by_hand(1.0, traj, monkeypatch)
    assert (row["impacts"], row["events"]) == (str(hand["impacts"]), str(hand["events"])) == ("18", "19")
    assert float(row["last_merge_t"]) < 0.5


# ---- the leg ----------------------------------------------------------------------------------
def leg_by_hand(rate: float, floor: float, t_end: float) -> dict:
    """The leg from 60, 60 deg with the hip (and knee) turning at ``rate``: Lagrange's equations to
    the floor, the pinned impulse P = -J^-T M w-, all of the kinetic energy lost; nothing if the foot
    lands after t_end.  A pin is a cut joint, not a lock: no holding force; it is a merge (a latch)."""
    try:
        t, y = nm.leg_strike(60.0, 60.0, floor, rate)
    except IndexError:  # the foot does not reach the floor in 2 s
        t = math.inf
    if t > t_end:
        return {"events": 0, "impacts": 0, "first_impact_t": None, "first_impulse": None, "peak_impulse": 0.0,
                "total_impulse": 0.0, "first_impulse_magnitude": None, "peak_impulse_magnitude": 0.0,
                "total_impulse_magnitude": 0.0, "kinetic_energy_lost": 0.0, "energy_dissipated": 0.0,
                "max_holding_force": None, "last_merge_t": None, "configuration_final": "swing"}
    P = nm.pin_impulse(*y)
    ke = 0.5 * y[2:] @ nm.leg_mass(y[0], y[1]) @ y[2:]
    return {"events": 1, "impacts": 1, "first_impact_t": t, "first_impulse": P[1], "peak_impulse": P[1],
            "total_impulse": P[1], "first_impulse_magnitude": math.hypot(*P), "peak_impulse_magnitude": math.hypot(*P),
            "total_impulse_magnitude": math.hypot(*P), "kinetic_energy_lost": ke, "energy_dissipated": ke, "max_holding_force": None,
            "last_merge_t": t, "configuration_final": "stance"}


@pytest.fixture(scope="module")
def leg_table(tmp_path_factory):
    folder = tmp_path_factory.mktemp("leg_study")
    scene = nm.leg_scene(folder, 60.0, 60.0, -0.7).path
    return folder, scene, run_sweep(scene, [f"{RATE_PATH}=0,0.5", f"{FLOOR_PATH}=-0.7,-0.72"], folder / "leg.csv", 1.0)


def test_leg_sweep_rows_by_hand_and_by_plain_run(leg_table, tmp_path):
    """Four rows (hip rate 0 or 0.5 rad/s, floor 0.7 or 0.72 m below the hip): the foot lands by
    t = 1 s from rest (at 0.46720 s, 0.47092 s) and not with the hip turning up (at 1.150 s; the lower floor not in 2 s)."""
    _, _, rows = leg_table
    assert len(rows) == 4
    for row in rows:
        rate, floor = float(row[RATE_PATH]), float(row[FLOOR_PATH])
        scene = nm.leg_scene(tmp_path, 60.0, 60.0, floor, rate)
        check_row_is_the_plain_run(row, pcmm.simulate(scene, pcmm.RunOptions(t_end=1.0)))
        hand = leg_by_hand(rate, floor, 1.0)
        assert same(row, {x: hand.pop(x) for x in ("first_impact_t", "last_merge_t")}, 0.0, 1e-9, row["run"]) == []
        assert same(row, hand, 1e-8, 1e-12, row["run"]) == []


def test_leg_sweep_rows_end_at_t_end(leg_table):
    _, _, rows = leg_table
    assert [row["t_final"] for row in rows] == ["1.0"] * 4


def test_resumed_leg_sweep_is_the_uninterrupted_table(leg_table, tmp_path):
    """A sweep of two of the four runs, resumed with the whole plan, runs the other two and gives the
    uninterrupted table's rows (run numbers, values, every quantity but the timings)."""
    _, scene, whole = leg_table
    out = tmp_path / "leg.csv"
    run_sweep(scene, [f"{RATE_PATH}=0", f"{FLOOR_PATH}=-0.7,-0.72"], out, 1.0)
    res = sweep(pcmm.load_scene(scene), make_plan([parse_set(f"{RATE_PATH}=0,0.5"), parse_set(f"{FLOOR_PATH}=-0.7,-0.72")]),
                out, pcmm.RunOptions(t_end=1.0), workers=1, resume=True)
    assert (res.skipped, res.ran) == (2, 2)

    def key(r):
        return {k: v for k, v in r.items() if k not in (*TIMING, "check")}
    resumed = sorted((key(r) for r in read(out)), key=lambda r: int(r["run"]))
    assert resumed == [key(r) for r in whole]


def test_optimize_rows_are_runs_and_the_answer_is_their_best(tmp_path):
    """COBYQA on the leg's floor height (0.65 to 0.75 m), minimising the strike's normal impulse over
    5 runs: every row's impulse is the pinned impulse by hand at its floor, and the answer is the row
    with the least of them. Stopped at 3 runs and resumed to 5, it gives the same table."""
    scene = nm.leg_scene(tmp_path, 60.0, 60.0, -0.7).path
    out = tmp_path / "opt.csv"
    res = optimize(pcmm.load_scene(scene), [parse_vary(f"{FLOOR_PATH}=-0.75:-0.65")], "first_impulse", out,
                   pcmm.RunOptions(t_end=1.0), method="cobyqa", max_evals=5, workers=1)
    rows = read(out)
    assert 3 <= len(rows) <= 5
    for row in rows:
        floor = float(row[FLOOR_PATH])
        hand = leg_by_hand(0.0, floor, 1.0)
        assert same(row, {"first_impulse": hand["first_impulse"], "kinetic_energy_lost": hand["kinetic_energy_lost"]},
                    1e-8, 0.0, row["run"]) == []
        assert same(row, {"first_impact_t": hand["first_impact_t"]}, 0.0, 1e-9, row["run"]) == []
    best = min(rows, key=lambda r: float(r["first_impulse"]))
    assert (res.run, res.value) == (int(best["run"]), float(best["first_impulse"]))
    assert res.x == {FLOOR_PATH: float(best[FLOOR_PATH])}
    # stopped after 3 runs and resumed to 5, the optimisation replays the 3 and gives the same table
    short = tmp_path / "short.csv"
    optimize(pcmm.load_scene(scene), [parse_vary(f"{FLOOR_PATH}=-0.75:-0.65")], "first_impulse", short,
             pcmm.RunOptions(t_end=1.0), method="cobyqa", max_evals=3, workers=1)
    again = optimize(pcmm.load_scene(scene), [parse_vary(f"{FLOOR_PATH}=-0.75:-0.65")], "first_impulse", short,
                     pcmm.RunOptions(t_end=1.0), method="cobyqa", max_evals=5, workers=1, resume=True)
    assert again.replayed == 3 and (again.run, again.value) == (res.run, res.value)

    def key(r):
        return {k: v for k, v in r.items() if k not in (*TIMING, "check")}
    assert [key(r) for r in read(short)] == [key(r) for r in rows]


# ---- the rimless wheel ------------------------------------------------------------------------
def wheel_scene(folder: Path, gx: float) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    text = WHEEL.read_text()
    text = re.sub(r'urdf = "[./]*urdf/', f'urdf = "{(ROOT / "urdf").as_posix()}/', text)
    text = text.replace('gravity = ["9.81*sin(0.2)",', f"gravity = [{gx!r},", 1)
    assert f"gravity = [{gx!r}," in text
    (folder / "wheel.toml").write_text(text)
    return folder / "wheel.toml"


def wheel_by_hand(gx: float, t_end: float) -> dict:
    """McGeer's wheel on the slope whose gravity is (gx, -9.81 cos 0.2): its slope angle
    atan(gx / gy) and g = |(gx, gy)|; from phi = -alpha at 1.5 rad/s, each stance by quadrature and
    each strike by Eq. (2); each strike's impulse by the free hub's KKT solve."""
    gy = -9.81 * math.cos(0.2)
    wheel = RimlessWheel(gamma=math.atan2(gx, -gy), g=math.hypot(gx, gy))
    strikes = [s for s in wheel.strikes(1.5, n=4) if s[0] <= t_end]
    impulses = [wheel.strike_impulse(wm)["P"][1] for _, wm, _ in strikes]
    sizes = [math.hypot(*wheel.strike_impulse(wm)["P"]) for _, wm, _ in strikes]
    lost = math.fsum(wheel.J * (wm ** 2 - wp ** 2) / 2 for _, wm, wp in strikes)
    return {"events": len(strikes), "impacts": len(strikes), "first_impact_t": strikes[0][0],
            "first_impulse": impulses[0], "peak_impulse": max(impulses), "total_impulse": math.fsum(impulses),
            "first_impulse_magnitude": sizes[0], "peak_impulse_magnitude": max(sizes),
            "total_impulse_magnitude": math.fsum(sizes),
            "kinetic_energy_lost": lost, "energy_dissipated": lost, "max_holding_force": None,
            "last_merge_t": strikes[-1][0], "configuration_final": f"spoke{len(strikes)}", "t_final": t_end}


def test_rimless_wheel_sweep_rows_by_hand_and_by_plain_run(tmp_path):
    """Two slopes (gravity along the slope 9.81 sin 0.18 and 9.81 sin 0.25 m/s^2), each run to
    2.5 s: two strikes (0.7551 s, 1.7756 s) or three (0.6674, 1.4007, 2.1566 s), every column by McGeer's closed form and the stance quadrature."""
    base = wheel_scene(tmp_path / "base", 9.81 * math.sin(0.2))
    values = (9.81 * math.sin(0.18), 9.81 * math.sin(0.25))
    rows = run_sweep(base, [f"{GX_PATH}={values[0]!r},{values[1]!r}"], tmp_path / "wheel.csv", 2.5)
    for row, gx in zip(rows, values):
        assert float(row[GX_PATH]) == gx
        traj = pcmm.simulate(pcmm.load_scene(wheel_scene(tmp_path / row["run"], gx)), pcmm.RunOptions(t_end=2.5))
        check_row_is_the_plain_run(row, traj)
        hand = wheel_by_hand(gx, 2.5)
        assert same(row, {x: hand.pop(x) for x in ("events", "impacts", "configuration_final", "t_final",
                                                   "max_holding_force")}, 0.0, 0.0, row["run"]) == []
        assert same(row, {x: hand.pop(x) for x in ("first_impact_t", "last_merge_t")}, 0.0, 1e-8, row["run"]) == []
        assert same(row, hand, 1e-8, 0.0, row["run"]) == []


# ---- the working cycle ------------------------------------------------------------------------
def test_working_cycle_sweep_rows_are_the_plain_runs(tmp_path):
    """Two preloads of the working cycle's O2 spring, to 1.5 s (about 135 impacts each: O2's and
    O3's bounces, the drive's impulses doing work): every column equals the plain run's own record,
    the energy dissipated being the energy lost plus each drive impulse's work P f'(t)."""
    text = re.sub(r'urdf = "[./]*urdf/', f'urdf = "{(ROOT / "urdf").as_posix()}/',
                  (ROOT / "examples" / "three_bar_cycle.toml").read_text())
    head, tail = text.split('name = "spring O2"', 1)

    def scene(v, folder):
        folder.mkdir()
        (folder / "cycle.toml").write_text(head + 'name = "spring O2"' + re.sub(r"\nvalue = [^\n]*", f"\nvalue = {v!r}",
                                                                                 tail, count=1))
        return folder / "cycle.toml"
    rows = run_sweep(scene(0.671, tmp_path / "base"), ["forces.spring O2.value=0.671,0.7"], tmp_path / "c.csv", 1.5)
    drives = 0
    for row, v in zip(rows, (0.671, 0.7)):
        traj = pcmm.simulate(pcmm.load_scene(scene(v, tmp_path / row["run"])), pcmm.RunOptions(t_end=1.5))
        check_row_is_the_plain_run(row, traj)
        assert int(row["impacts"]) > 100 and row["max_holding_force"] != ""
        drives += float(row["energy_dissipated"]) != float(row["kinetic_energy_lost"])
    assert drives == 2   # the drive's work was counted, not assumed zero


# ---- resampling -------------------------------------------------------------------------------
SERIES = ("q", "v", "theta", "omega", "kinetic", "potential", "constraint_forces")


def close(a, b, rel) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = max(1.0, float(np.nanmax(np.abs(a))) if a.size else 1.0)
    return a.shape == b.shape and bool(np.all(np.isnan(a) == np.isnan(b))) and \
        (a.size == 0 or float(np.nanmax(np.abs(a - b))) <= rel * scale)


def check_resampled(traj, dt, stops, scene_path, rel=1e-7):
    """The run resampled at dt: each segment's samples lie inside it, its end samples are the
    recorded ends (a sample never interpolates across an impulse), a sample at a recorded step is
    that step, and at each instant of ``stops`` the resampled state (the last sample there) is the
    last state of a run stopped there (t_end)."""
    r = traj.resampled(dt)
    assert len(r.segments) == len(traj.segments)
    for s, rs in zip(traj.segments, r.segments):
        assert rs.t[0] == s.t[0] and rs.t[-1] == s.t[-1] and np.all(np.diff(rs.t) > 0)
        common, i, j = np.intersect1d(s.t, rs.t, return_indices=True)
        for name in SERIES:
            # the ends to round-off (a loop's dependent coordinates are solved again there: 9e-14 rad/s)
            assert close(getattr(s, name)[[0, -1]], getattr(rs, name)[[0, -1]], 1e-12), (s.configuration, s.t[0], name)
            assert close(getattr(s, name)[i], getattr(rs, name)[j], 1e-12), (s.configuration, s.t[0], name)
    for stop in stops:
        k = int(np.nonzero(np.isclose(r.t, stop, rtol=0, atol=1e-12))[0][-1])
        direct = pcmm.simulate(pcmm.load_scene(scene_path), pcmm.RunOptions(t_end=float(r.t[k])))
        last = direct.segments[-1]
        seg_index = int(np.searchsorted(np.cumsum([len(s.t) for s in r.segments]), k, side="right"))
        rs = r.segments[seg_index]
        at = k - sum(len(s.t) for s in r.segments[:seg_index])
        assert (last.configuration, len(direct.events), float(direct.t[-1])) == (rs.configuration, sum(
            e["t"] <= r.t[k] for e in traj.events), float(r.t[k])), stop
        for name in SERIES:
            assert close(getattr(last, name)[-1], getattr(rs, name)[at], rel), (stop, name)
    return r


def test_leg_resampled_is_the_run_stopped_at_each_instant(tmp_path):
    """The leg resampled at 10 ms: before the strike, the strike's instant (the swing's last sample
    and the stance's first: the hand's rates before it, zero after it), and in the pinned stance;
    the --dt CSV has both rows at the strike's instant."""
    scene = nm.leg_scene(tmp_path, 60.0, 60.0, -0.7)
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=1.0))
    t_hand, y = nm.leg_strike(60.0, 60.0, -0.7)
    r = check_resampled(traj, 0.01, (0.1, 0.46, 0.47, 0.6, 1.0), scene.path)
    r.to_csv(tmp_path / "leg.csv")
    rows = [x for x in read(tmp_path / "leg.csv") if float(x["t [s]"]) == traj.events[0]["t"]]
    assert [x["configuration"] for x in rows] == ["swing", "stance"]
    assert [float(rows[0][f"omega_{b} [rad/s]"]) for b in ("thigh", "shank")] == pytest.approx(list(y[2:]), abs=1e-7)
    assert [float(rows[1][f"omega_{b} [rad/s]"]) for b in ("thigh", "shank")] == [0.0, 0.0]
    assert traj.events[0]["t"] == pytest.approx(t_hand, abs=1e-9)


def test_fourbar_resampled_is_the_run_stopped_at_each_instant(tmp_path):
    """The four-bar resampled at 10 ms, and runs stopped at 50 ms (before any strike), 120 ms (just
    after the first), 300 ms (between bounces), 460 ms (just after the merge), 0.8 s (latched),
    1.2 s (released)."""
    scene = fourbar_scene(tmp_path, 1.0)
    traj = pcmm.simulate(pcmm.load_scene(scene), pcmm.RunOptions(t_end=1.2))
    check_resampled(traj, 0.01, (0.05, 0.12, 0.3, 0.46, 0.8, 1.2), scene)


def test_fourbar_run_stopped_after_the_release(tmp_path):
    scene = fourbar_scene(tmp_path, 1.0)
    traj = pcmm.simulate(pcmm.load_scene(scene), pcmm.RunOptions(t_end=1.2))
    check_resampled(traj, 0.01, (1.15,), scene)


# ---- t_end invariance -------------------------------------------------------------------------
@pytest.mark.parametrize("case", ["leg", "fourbar before its release"])
def test_run_to_t_is_the_first_part_of_the_run_to_2t(case, tmp_path):
    """oracle.check_prefix: the same events, the same samples (or the longer run's dense output at
    the shorter run's step times), the same 10 ms resampling and CSV rows."""
    if case == "leg":
        scene, t = nm.leg_scene(tmp_path, 60.0, 60.0, -0.7).path, 0.6
    else:
        scene, t = fourbar_scene(tmp_path, 1.0), 0.6
    assert oracle.check_prefix(scene, t, 2 * t, 0.01, tmp_path) == []


def test_fourbar_run_through_its_release_is_the_first_part_of_a_longer_run(tmp_path):
    scene = fourbar_scene(tmp_path, 1.0)
    assert oracle.check_prefix(scene, 1.2, 2.4, 0.01, tmp_path) == []


# ---- a partial run, and the pool --------------------------------------------------------------
def test_partial_row_is_the_partial_run_and_pool_rows_are_the_in_process_rows(leg_table, tmp_path):
    """A floor 0.6 m down: by hand the strike comes at t = 0.44995870 s and would need mu >= 0.648526;
    the run stops there. Its row is ``partial`` with that message, ends at that instant, and its
    columns are the partial run's (no event: the strike was refused). On the local pool (two worker
    processes) the same two runs give the rows of this process, bit for bit but for the timings."""
    _, scene, whole = leg_table
    t_hand, y = nm.leg_strike(60.0, 60.0, -0.6)
    plan = make_plan([parse_set(f"{FLOOR_PATH}=-0.6,-0.7")])
    sweep(pcmm.load_scene(scene), plan, tmp_path / "p.csv", pcmm.RunOptions(t_end=1.0), workers=1)
    sweep(pcmm.load_scene(scene), plan, tmp_path / "pool.csv", pcmm.RunOptions(t_end=1.0), workers=2)
    partial, complete = read(tmp_path / "p.csv")
    with pytest.raises(pcmm.SimulationError) as err:
        pcmm.simulate(nm.leg_scene(tmp_path, 60.0, 60.0, -0.6), pcmm.RunOptions(t_end=1.0))
    assert partial["status"] == "partial" and f"t = {t_hand:.9f} s" in partial["error"] and "friction >= 0.648526" in partial["error"]
    assert float(partial["t_final"]) == pytest.approx(t_hand, abs=1e-9)
    assert same(partial, plain_columns(err.value.partial), 0.0) == []
    assert partial["events"] == "0" and partial["configuration_final"] == "swing"

    def key(r):
        return {k: v for k, v in r.items() if k not in (*TIMING, "check")}
    assert [key(r) for r in read(tmp_path / "pool.csv")] == [key(partial), key(complete)]
    # the complete run is the uninterrupted leg table's run at the same floor, bit for bit
    twin = next(r for r in whole if r[FLOOR_PATH] == "-0.7" and r[RATE_PATH] == "0")
    assert {k: v for k, v in key(complete).items() if k not in ("run", RATE_PATH)} == \
        {k: v for k, v in key(twin).items() if k not in ("run", RATE_PATH)}


# ---- the series the holding column is read from -----------------------------------------------
@pytest.mark.parametrize("case", ["fourbar k = 0.9", "leg"])
def test_the_oracle_recomputes_the_series_a_row_reads(case, tmp_path):
    """max_holding_force is the extreme of the recorded hold series and the energies come from the
    kinetic series: the differential oracle (tests/oracle.py: its own Pinocchio model, one KKT solve
    per sample) recomputes them, in the steps and resampled at 10 ms, at the switches (momentum,
    energies) too."""
    if case == "leg":
        scene, t_end = nm.leg_scene(tmp_path, 60.0, 60.0, -0.7).path, 1.0
    else:
        scene, t_end = fourbar_scene(tmp_path, 0.9), 1.2
    traj = pcmm.simulate(pcmm.load_scene(scene), pcmm.RunOptions(t_end=t_end))
    o = oracle.Oracle(pcmm.load_scene(scene))
    found = o.check(traj, samples=6) + oracle.Oracle(pcmm.load_scene(scene)).check(traj.resampled(0.01), samples=6)
    assert found == []
    assert {"constraint force", "kinetic energy", "momentum not conserved", "kinetic_energy_after"} <= set(o.counts)


# ---- a collision resolved by a continuous contact law -----------------------------------------
def hunt_crossley_phase(e: float, h: float, k: float = 1e7, n: float = 1.5, m: float = 1.0, g: float = 9.81):
    """A point mass dropped from h onto the floor through a Hunt-Crossley contact,
    m y'' = -m g + k d^n (1 + D d' / v-), d = -y, D = 3 (1 - e) / 2, integrated here from first
    contact (y = 0, y' = -v-, v- = sqrt(2 g h)) to the gap reopening (y = 0 again). Returns
    (speed after, energy the damping dissipates: the integral of k d^n D d'^2 / v-, duration)."""
    from scipy.integrate import solve_ivp
    v0, D = math.sqrt(2 * g * h), 1.5 * (1 - e)

    def rhs(t, s):
        y, yd, _ = s
        d, dd = max(-y, 0.0), -yd
        force = max(k * d ** n * (1 + D * dd / v0), 0.0)
        return [yd, -g + force / m, k * d ** n * D * dd * dd / v0]

    def reopens(t, s):
        return s[0]
    reopens.terminal, reopens.direction = True, 1
    sol = solve_ivp(rhs, (0, 0.1), [-1e-300, -v0, 0.0], events=reopens, rtol=1e-12, atol=1e-15, method="DOP853",
                    first_step=1e-9)
    return sol.y_events[0][0][1], sol.y_events[0][0][2], sol.t_events[0][0]


@pytest.mark.parametrize("e", [0.5, 0.8])
def test_energy_dissipated_by_a_continuous_contact_law(e, tmp_path):
    """A ball dropped from 0.3 m onto a Hunt-Crossley floor (k = 1e7 N/m^1.5): by hand the damping
    dissipates 0.9126 J of its 2.943 J at e = 0.8 (its rebound speed 2.0151 m/s), which is also the
    mechanical energy the run loses across the contact (the ball leaves the floor where it met it).
    The row said energy_dissipated 0.0: a contact phase's event has no impulse's energy_dissipated,
    and the table summed only the impulses'."""
    import builders
    scene = builders.ball(tmp_path, e, h=0.3, t_end=0.4, merge=False, law="hunt_crossley", stiffness=1e7, exponent=1.5)
    (row,) = run_sweep(scene, ["transitions.floor.restitution=" + repr(e)], tmp_path / "hc.csv", 0.4)
    v_after, lost, duration = hunt_crossley_phase(e, 0.3)
    assert row["impacts"] == "1" and lost > 0.3
    # the contact's impulse: the floor's force integrated, m (v+ + v-) + m g (duration)
    assert float(row["first_impulse"]) == pytest.approx(v_after + math.sqrt(2 * 9.81 * 0.3) + 9.81 * duration, rel=1e-6)
    assert float(row["energy_dissipated"]) == pytest.approx(lost, rel=1e-6)
    assert float(row["kinetic_energy_lost"]) == pytest.approx(0.5 * (2 * 9.81 * 0.3 - v_after ** 2), rel=1e-6)


def test_a_contact_phase_without_its_record_is_unknown_not_zero(tmp_path):
    """quantities() given a summary alone cannot know a contact phase's dissipation: the cell is
    empty (None), never the sum of the other impacts'."""
    import builders
    from pcmm.results.summary import summary
    from pcmm.studies.job import contact_phase_losses, quantities
    scene = pcmm.load_scene(builders.ball(tmp_path, 0.8, h=0.3, t_end=0.4, merge=False, law="hunt_crossley",
                                          stiffness=1e7, exponent=1.5))
    traj = pcmm.simulate(scene)
    summ = summary(traj, scene.initial_configuration)
    assert quantities(summ)["energy_dissipated"] is None
    (loss,) = contact_phase_losses(traj).values()
    assert quantities(summ, contact_phase_losses(traj))["energy_dissipated"] == loss == pytest.approx(
        hunt_crossley_phase(0.8, 0.3)[1], rel=1e-6)


# ---- resampled samples against the hand's own dense solution ----------------------------------
def test_every_resampled_sample_is_the_hands_solution(tmp_path):
    """At every 5 ms sample of the --dt resampling, the angles and rates are the hand's: the leg's
    swing by its own Lagrangian (DOP853 dense output) up to the strike and at rest after it; the
    four-bar's loop by its own KKT integration up to the first strike, and from rest at the
    release (t = sqrt((140 deg - th1* - V'(th1*)/k) / 0.5)) to the end, across the release's events."""
    from scipy.integrate import solve_ivp
    leg = pcmm.simulate(nm.leg_scene(tmp_path, 60.0, 60.0, -0.7), pcmm.RunOptions(t_end=1.0))
    t_strike, y_strike = nm.leg_strike(60.0, 60.0, -0.7)
    r = leg.resampled(0.005)
    a = math.radians(60.0)

    def leg_rhs(t, y):
        a1, a2, w1, w2 = y
        s = math.sin(a1 - a2)
        f = np.array([-nm.M2 * nm.L1 * nm.L2 / 2 * s * w2 ** 2, nm.M2 * nm.L1 * nm.L2 / 2 * s * w1 ** 2]) - nm.leg_gravity(a1, a2)
        return [w1, w2, *np.linalg.solve(nm.leg_mass(a1, a2), f)]
    swing = solve_ivp(leg_rhs, (0, t_strike), [a, 2 * a, 0.0, 0.0], rtol=1e-12, atol=1e-13, method="DOP853",
                      dense_output=True).sol
    names = ("thigh", "shank")
    got = np.column_stack([r.series("theta", x) for x in names] + [r.series("omega", x) for x in names])
    config = r.configuration_at()
    before = np.array([c == "swing" for c in config])
    want = np.array([swing(t) if b else [*y_strike[:2], 0.0, 0.0] for t, b in zip(r.t, before)])
    assert before.sum() > 90 and (~before).sum() > 100
    assert np.max(np.abs(got[:, :2] - want[:, :2])) < 1e-8
    assert np.max(np.abs(got[:, 2:] - want[:, 2:])) < 1e-7

    fb = pcmm.simulate(pcmm.load_scene(fourbar_scene(tmp_path / "fb", 1.0)), pcmm.RunOptions(t_end=1.2))
    r = fb.resampled(0.005)
    t1, _, _ = nm.fourbar_strike()
    th1_stop = nm.brentq(lambda x: nm.q3_of(x) - nm.Q3_STOP, math.radians(90), math.radians(180))
    t_release = math.sqrt((math.radians(140) - th1_stop - nm.dpotential(th1_stop) / nm.K_ARM) / 0.5)
    start = solve_ivp(nm.loop_rhs, (0, t1), nm.at_rest(math.pi / 2), rtol=1e-12, atol=1e-13, method="DOP853",
                      dense_output=True).sol
    end = solve_ivp(nm.loop_rhs, (t_release, 1.2), nm.at_rest(th1_stop), rtol=1e-12, atol=1e-13, method="DOP853",
                    dense_output=True).sol
    links = ("crank", "coupler", "rocker")
    got = np.column_stack([r.series("theta", x) for x in links] + [r.series("omega", x) for x in links])
    early, late = r.t <= t1 - 1e-9, r.t >= t_release + 1e-9
    assert early.sum() > 20 and late.sum() > 15
    for mask, sol in ((early, start), (late, end)):
        want = np.array([sol(t) for t in r.t[mask]])
        assert np.max(np.abs(got[mask, :3] - want[:, :3])) < 1e-8
        assert np.max(np.abs(got[mask, 3:] - want[:, 3:])) < 1e-7


def test_optimize_on_the_fourbar_answers_the_least_peak_impulse(tmp_path):
    """By hand every k in [0.95, 1.05] merges at about 0.458 s (the 18th strike) and the peak impulse
    is the first strike's, growing with k; so every run meets last_merge_t <= 0.5 and the answer is the
    run of least peak impulse."""
    scene = fourbar_scene(tmp_path, 1.0)
    from pcmm.studies.optimize import parse_constraint
    res = optimize(pcmm.load_scene(scene), [parse_vary(f"{K_PATH}=0.95:1.05")], "peak_impulse", tmp_path / "o.csv",
                   pcmm.RunOptions(t_end=1.2), subject_to=[parse_constraint("last_merge_t<=0.5")], method="cobyqa",
                   max_evals=6, workers=1)
    rows = read(tmp_path / "o.csv")
    assert all(float(r["last_merge_t"]) < 0.5 for r in rows), [(r[K_PATH], r["last_merge_t"]) for r in rows]
    best = min(rows, key=lambda r: float(r["peak_impulse"]))
    assert res.run == int(best["run"])


LEG_HC_TOML = """
[scene]
name = "leg_hc"
gravity = [0.0, -9.81]
t_end = 0.6
initial_configuration = "swing"

[configurations.swing]
urdf = "leg.urdf"

[initial]
q = { hip = "60 deg", knee = "60 deg" }
v = { hip = 0.0, knee = 0.0 }

[[transitions]]
name = "foot"
type = "stop"
from = "swing"
restitution = 0.6
cut = []
law = "hunt_crossley"
stiffness = 1e7
exponent = 1.5
contact = { a = "frame", point_a = [0.0, -0.7], b = "shank", point_b = [0.4, 0.0], normal = [0.0, 1.0] }
guard = { type = "gap", value = 0.0, direction = "decreasing" }
"""


def test_energy_dissipated_by_a_contact_law_is_not_the_kinetic_energy_lost(tmp_path):
    """The leg's foot strikes a Hunt-Crossley floor (e = 0.6, k = 1e7 N/m^1.5): during the 4.5 ms
    contact the leg keeps swinging and gravity works on it, so the energy the contact dissipates is
    not the kinetic energy lost. By hand (the leg's Lagrangian with the floor's force at the foot,
    integrated from the strike to the foot leaving the floor): the damping's work is 11.57064 J, the
    kinetic energy lost 11.44296 J, the contact ends at 0.47173619 s. The row has both."""
    from scipy.integrate import solve_ivp
    (tmp_path / "leg.urdf").write_text(nm.LEG_URDF)
    (tmp_path / "leg.toml").write_text(LEG_HC_TOML)
    (row,) = run_sweep(tmp_path / "leg.toml", ["transitions.foot.restitution=0.6"], tmp_path / "t.csv", 0.6)
    t0, y = nm.leg_strike(60.0, 60.0, -0.7)
    k, n, floor, D = 1e7, 1.5, -0.7, 1.5 * (1 - 0.6)
    v0 = -(nm.foot_jacobian(y[0], y[1]) @ y[2:])[1]

    def rhs(t, s):
        a1, a2, w1, w2, _ = s
        J = nm.foot_jacobian(a1, a2)
        depth, rate = max(floor - nm.L1 * math.sin(a1) - nm.L2 * math.sin(a2), 0.0), -(J @ [w1, w2])[1]
        force = max(k * depth ** n * (1 + D * rate / v0), 0.0)
        sn = math.sin(a1 - a2)
        f = (np.array([-nm.M2 * nm.L1 * nm.L2 / 2 * sn * w2 ** 2, nm.M2 * nm.L1 * nm.L2 / 2 * sn * w1 ** 2])
             - nm.leg_gravity(a1, a2) + J.T @ [0.0, force])
        return [w1, w2, *np.linalg.solve(nm.leg_mass(a1, a2), f), k * depth ** n * D * rate * rate / v0]

    def leaves(t, s):
        return nm.L1 * math.sin(s[0]) + nm.L2 * math.sin(s[1]) - floor
    leaves.terminal, leaves.direction = True, 1
    sol = solve_ivp(rhs, (0, 0.1), [*y, 0.0], events=leaves, rtol=1e-12, atol=1e-15, method="DOP853", first_step=1e-9)
    end = sol.y_events[0][0]

    def kinetic(s):
        return 0.5 * np.array(s[2:4]) @ nm.leg_mass(s[0], s[1]) @ np.array(s[2:4])
    assert end[4] == pytest.approx(11.57064, abs=1e-5) and t0 + sol.t_events[0][0] == pytest.approx(0.47173619, abs=1e-8)
    assert float(row["energy_dissipated"]) == pytest.approx(end[4], rel=1e-8)
    assert float(row["kinetic_energy_lost"]) == pytest.approx(kinetic(y) - kinetic(end), rel=1e-8)
    assert abs(float(row["energy_dissipated"]) - float(row["kinetic_energy_lost"])) > 0.1
