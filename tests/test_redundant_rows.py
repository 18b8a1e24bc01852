"""Redundant constraint rows in a configuration the run enters (issue 22: no silent wrong number).

A slider-crank of my own (crank a = 0.1 m on A, rod b = 0.3 m on B, slider on the prismatic P, the
cut joint C closing the rod's tip on the slider) turned by a motor torque; the slider strikes a
stop at the x it has for the crank angle -1 rad and merges into 'held', derived by locking P. In
'held' a drive on A (listed for 'held' only) makes 3 rows (C.fx, C.fy and the drive) on the 2
coordinates A, B.

By hand, at A = -1, phi = asin(-a sin A / b) (the rod's angle), B = phi - A: the rows' Jacobian is
[[d(tip)/dA, d(tip)/dB], [1, 0]], of rank 2 (the C block's determinant is a b sin B != 0), so one
row is redundant, and its left null vector is y ~ (cos phi, sin phi, a sin B) (C's rows being
slider minus rod tip): the rod's axial
force, which the drive's moment (a sin B per newton) and the lock can trade at will, is statically
indeterminate. With a constant drive the rows are consistent (nothing moves); with a drive that
turns A they are not (no motion satisfies them).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import pcmm
from builders import bar_xml, base_doc, joint_xml, link_xml, robot_xml, solid_xml, stop, write_scene
from pcmm.model.mechanism import Mechanism
from pcmm.run.checks import check_scene, redundant_rows

A_, B_, TH0, TH_STOP = 0.1, 0.3, -2.0, -1.0


def slider_x(th):
    return A_ * math.cos(th) + math.sqrt(B_ ** 2 - (A_ * math.sin(th)) ** 2)


def jammed_press(folder: Path, drive=None, lock=("P",), reference=False, t_end=1.0) -> Path:
    """``reference``: a configuration 'ref' on the URDF and cut joint of 'free' with the drive too, on
    which the hold of 'held' is solved (pcmm.events.holding: the held joint free, the same drives)."""
    urdf = robot_xml("sc", link_xml("frame"), joint_xml("A", "revolute", "frame", "crank"), bar_xml("crank", A_, 0.5),
                     joint_xml("B", "revolute", "crank", "rod", xyz=(A_, 0.0)), bar_xml("rod", B_, 0.8),
                     joint_xml("P", "prismatic", "frame", "slider", axis=(1, 0, 0)), solid_xml("slider", 2.0, 1e-3))
    cut = [{"name": "C", "type": "revolute", "a": "rod", "point_a": [B_, 0.0], "b": "slider", "point_b": [0.0, 0.0]}]
    xs = slider_x(TH_STOP)
    tr = stop("stop", "free", 0.0, {"type": "coordinate", "measure": {"joint": "P"}, "value": xs,
                                    "direction": "increasing"},
              {"a": "frame", "point_a": [xs, 0.0], "b": "slider", "point_b": [0.0, 0.0], "normal": [-1.0, 0.0]},
              merge_to="held", cut=["P"], unmerge=False)
    more = {"drives": [{"joint": "A", "coefficients": list(drive),
                        "configurations": ["held", "ref"] if reference else ["held"]}]} if drive else {}
    configs = {"free": {"urdf": "sc.urdf", "cut_joints": cut}, "held": {"from": "free", "lock": list(lock)}}
    if reference:
        configs["ref"] = {"urdf": "sc.urdf", "cut_joints": cut}
    phi = math.asin(-A_ * math.sin(TH0) / B_)
    doc = base_doc("jammed", "free", configs,
                   {"A": TH0, "B": phi - TH0, "P": slider_x(TH0)}, {"A": 0.0, "B": 0.0, "P": 0.0}, t_end=t_end,
                   transitions=[tr], forces=[{"name": "motor", "type": "torque", "on": {"joint": "A"}, "value": 0.5,
                                              "configurations": ["free"]}], **more)
    doc["initial"]["independent"] = ["A"]
    return write_scene(folder, doc, {"sc.urdf": urdf})


def test_consistent_redundant_rows_are_a_warning_naming_the_indeterminate_forces(tmp_path):
    path = jammed_press(tmp_path, drive=[TH_STOP])
    scene = pcmm.load_scene(path)
    report = check_scene(scene)
    assert report.problems == []
    [w] = [w for w in report.warnings if "redundant" in w]
    assert w.startswith(f"{path}: transitions[0] (stop).merge_to: configuration 'held' has 3 constraint rows "
                        "(C.fx, C.fy, drives[0] ('A')) of rank 2 on 2 coordinates: 1 redundant but consistent")
    assert "the forces of C.fx, C.fy, drives[0] ('A'), the holding force 'stop.hold' are not" in w
    assert "pcmm reports no arbitrary split" in w

    # the null vector by hand: C's rows are p_b - p_a = slider - rod tip, so their Jacobian is
    # -d(tip)/d(A, B); y^T R = 0 along B gives (y1, y2) ~ (cos phi, sin phi), the rod's axis, and
    # along A then y3 = +a sin B
    mech = Mechanism(scene)
    held = mech.enter("held", mech["free"], report.postures["stop"])
    q = np.zeros(held.nv)
    phi = math.asin(-A_ * math.sin(TH_STOP) / B_)
    q[held.joint_slice["A"].start], q[held.joint_slice["B"].start] = TH_STOP, phi - TH_STOP
    found = redundant_rows(scene, held, q)
    assert (found.rank, found.nv, found.null.shape) == (2, 2, (3, 1))
    y = np.array([math.cos(phi), math.sin(phi), A_ * math.sin(phi - TH_STOP)])
    y /= np.linalg.norm(y)
    assert abs(abs(float(found.null[:, 0] @ y)) - 1.0) < 1e-12  # the same line: cos(angle) = 1
    assert found.consistent


def test_the_run_goes_on_at_rest_and_reports_no_split(tmp_path):
    """The run enters 'held' (3 rows of rank 2 on A, B) and goes on: the motion is determined (the
    crank held by its drive at -1, the rod by the loop: at rest, A = -1 and B = phi - A by hand),
    solved with a maximal independent set of the rows, the dropped one named once in the warnings
    with the time; every row's force is moved by the null vector (cos phi, sin phi, a sin B), so
    all three constraint_forces series are NaN, and so is the stop's hold (solved on 'ref', with P
    free and the drive: 4 rows of rank 3, the null vector non-zero on the hold's row too)."""
    run = pcmm.simulate(pcmm.load_scene(jammed_press(tmp_path, drive=[TH_STOP], reference=True, t_end=0.6)))
    [(t_merge, to)] = [(e["t"], e["to"]) for e in run.events]
    assert to == "held" and t_merge == pytest.approx(0.2833, abs=1e-4)
    [w] = [w for w in run.stats["warnings"] if "redundant" in w]
    assert w.startswith(f"t = {t_merge:.9g} s, configuration 'held': its 3 constraint rows (C.fx, C.fy, A.drive) are "
                        "of rank 2 on 2 coordinates: redundant but consistent")
    assert "the dropped C.fx is checked at every solve" in w and "C.fx, C.fy, A.drive are statically indeterminate" in w
    [h] = [w for w in run.stats["warnings"] if "holding force" in w]
    assert h.startswith(f"t = {t_merge:.9g} s, configuration 'held': the holding force stop.hold is statically "
                        "indeterminate")
    after = run.t > t_merge
    phi = math.asin(-A_ * math.sin(TH_STOP) / B_)
    assert run.t[-1] == pytest.approx(0.6) and np.count_nonzero(after) >= 2
    assert np.max(np.abs(run.series("q", "A")[after] - TH_STOP)) < 1e-12
    assert np.max(np.abs(run.series("q", "B")[after] - (phi - TH_STOP))) < 1e-12
    assert np.max(np.abs(run.series("v", "A")[after])) < 1e-12 and np.max(np.abs(run.series("v", "B")[after])) < 1e-12
    for label in ("C.fx", "C.fy", "A.drive", "stop.hold"):
        assert np.all(np.isnan(run.series("constraint_forces", label)[after])), label
    for label in ("C.fx", "C.fy"):  # in 'free' (no drive, no hold) C is determinate: finite
        assert np.all(np.isfinite(run.series("constraint_forces", label)[run.t < t_merge]))
    # the summary's extremes of the hold: none (it used to read min = inf, max = -inf, and the summary
    # JSON was refused as "overflowed"); the indeterminate samples counted
    held = run.stats["holding"]["stop.hold"]
    assert held["min"] is None and held["max"] is None and held["indeterminate_samples"] == len(run.segments[-1].t)


def test_inconsistent_rows_are_a_problem_naming_them(tmp_path):
    """A drive turning A at 1 rad/s where the lock and the loop fix A: y's drive component times the
    rate, a sin B / |y| != 0, so no motion satisfies the rows: an error before the run, not a stop at
    the merge 0.283 s into it."""
    report = check_scene(pcmm.load_scene(jammed_press(tmp_path, drive=[TH_STOP, 1.0])))
    [p] = report.problems
    assert "transitions[0] (stop).merge_to: configuration 'held' has 3 constraint rows (C.fx, C.fy, drives[0] ('A')) " \
           "of rank 2 on 2 coordinates, and its drives ask a motion the others forbid" in p


def test_locking_two_joints_of_the_loop_is_redundant_without_a_drive(tmp_path):
    """Locking A and P leaves the rod (B) pinned at both ends: 2 rows on 1 coordinate, rank 1, consistent
    (no drive); the rod's axial force is indeterminate, so both C rows are named."""
    report = check_scene(pcmm.load_scene(jammed_press(tmp_path, lock=("P", "A"))))
    [w] = [w for w in report.warnings if "redundant" in w]
    assert "configuration 'held' has 2 constraint rows (C.fx, C.fy) of rank 1 on 1 coordinates: 1 redundant but " \
           "consistent" in w


def test_independent_rows_are_not_flagged(tmp_path):
    """Without the drive, 'held' has the 2 rows of C on A, B: rank 2 = nv, a determinate structure;
    the hold solved on 'free' adds the stop's row on P: 3 rows of rank 3."""
    report = check_scene(pcmm.load_scene(jammed_press(tmp_path)))
    assert report.problems == [] and not [w for w in report.warnings if "redundant" in w]


def test_the_split_is_not_unique_which_is_why_no_run_reports_one(tmp_path):
    """On 'free' with the holding rows of 'held' (C, the drive on A, the stop's normal on P; as
    pcmm.events.holding solves a hold), at rest at the merge posture, R^T lam = h - Q has a line of
    solutions: the KKT solve's and the minimum-norm one (numpy's lstsq) both balance gravity to
    round-off and differ by a multiple of the null vector y of R, which is non-zero on all four rows
    (here the hold on P: 0.555 N in the minimum-norm split, -4.0 N in the KKT solve's own choice).
    So the run must not report one, and it does not: the hold and the rows' forces are NaN in its series
    (test_the_run_goes_on_at_rest_and_reports_no_split)."""
    import pinocchio as pin
    from pcmm.events.contact import contact_row
    from pcmm.model.rows import constrained_accelerations
    scene = pcmm.load_scene(jammed_press(tmp_path, drive=[TH_STOP]))
    q = check_scene(scene).postures["stop"]
    free = Mechanism(scene)["free"]
    zero = np.zeros(free.nv)
    Jc, bc = free.coords.rows(0.3, q, zero)
    drive = np.zeros(free.nv)
    drive[free.joint_slice["A"].start] = 1.0
    Jn, bn = contact_row(free, q, zero, scene.transitions[0].contact)
    R, bias = np.vstack([Jc, drive, Jn]), np.concatenate([bc, [0.0, bn]])
    assert np.linalg.matrix_rank(R) == 3 and R.shape == (4, 3)
    a, lam_kkt = constrained_accelerations(free, q, zero, R, bias)
    h = pin.rnea(free.model, free.data, free.to_pin(q), zero, zero)  # gravity at rest
    rhs = h - free.forces.generalized(q, zero)
    lam_min = np.linalg.lstsq(R.T, rhs, rcond=None)[0]
    assert np.max(np.abs(a)) < 1e-12
    assert np.max(np.abs(R.T @ lam_kkt - rhs)) < 1e-12 and np.max(np.abs(R.T @ lam_min - rhs)) < 1e-12
    y = np.linalg.svd(R.T)[2][-1]  # the left null vector of R
    d = lam_kkt - lam_min
    assert np.linalg.norm(d) > 0.1 and np.linalg.norm(d - (d @ y) * y) < 1e-12 * np.linalg.norm(d) + 1e-13
    assert np.min(np.abs(y)) > 0.05  # every row's force moves along the line
    # the hold: 0.5547 N in the minimum-norm split, -4.0 N (tensile) in the KKT solve's on this machine,
    # whichever split its factorization of the singular system lands on (not pinned here)
    assert lam_min[3] == pytest.approx(0.5547, abs=1e-4) and abs(lam_kkt[3] - lam_min[3]) > 1.0


def test_the_newcomers_press_is_not_over_constrained(tmp_path):
    """The newcomer's press ('held' locks the ram, which rides on its cushion ahead of the slider, not
    the slider itself): the hold is solved on 'free' with C (2 rows), the drive on the crank and the
    stop's normal on the ram. The ram's column is non-zero in the stop's row alone, so the rank is
    1 + the rank of the driven slider-crank's 3 rows on crank, pin, slide (3 off its dead centres):
    4 rows of rank 4 on 4 coordinates, a unique hold (the cushion's push, as
    tests/test_newcomer_mechanisms.py checks to 1e-8 N). No warning."""
    import test_newcomer_mechanisms as newcomer
    (tmp_path / "press.urdf").write_text(newcomer.PRESS_URDF)
    (tmp_path / "press.toml").write_text(newcomer.PRESS_TOML)
    report = check_scene(pcmm.load_scene(tmp_path / "press.toml"))
    assert report.problems == [] and report.warnings == []


def test_a_constant_drive_holding_the_crank_elsewhere_is_a_problem(tmp_path):
    """The drive holds A at -0.8 rad while the lock of P at the stop's x and the loop put A at -1
    (the rows' null vector has a sin B on the drive's row, so y . (f - q) = a sin B (0.2) / |y| != 0):
    no posture satisfies them, an error; at -1 (test above) a warning."""
    report = check_scene(pcmm.load_scene(jammed_press(tmp_path, drive=[TH_STOP + 0.2])))
    [p] = report.problems
    assert "configuration 'held' has 3 constraint rows (C.fx, C.fy, drives[0] ('A')) of rank 2 on 2 coordinates, " \
           "and its drives ask a posture the others forbid: no posture satisfies C.fx, C.fy, drives[0] ('A')" in p
    # a turn away is the same posture: consistent
    report = check_scene(pcmm.load_scene(jammed_press(tmp_path / "turn", drive=[TH_STOP + 2 * math.pi])))
    assert report.problems == [] and [w for w in report.warnings if "redundant but consistent" in w]


def test_holding_rows_alone_redundant_say_the_reported_split_is_one_of_many(tmp_path):
    """A cart on the prismatic X carrying a bar on the revolute J2, level (J2 = 0), whose tip strikes
    a wall x = 0.5 along its normal (1, 0); the merge locks J2, and in 'held' a constant drive holds X.
    'held' alone has 1 row (the drive) on 1 coordinate: independent, the run goes on. Its hold is
    solved on 'free' with the drive's row e_X and the stop's normal row, which at J2 = 0 is
    n . d(tip)/d(X, J2) = (1, -L sin 0) = (1, 0) = e_X (by hand): 2 rows of rank 1, the wall's force and
    the drive's force trade at will. The check says any split would be one of many. (The run itself
    reports none here: no configuration has J2 free with the drive, so its hold cannot be solved: NaN,
    and the run's warnings say so; reading the series used to raise, and so did every read of a
    run's stats where a pinned foot's stance forces share the segment: tests/test_newcomer3_walker.py.)"""
    urdf = robot_xml("cart", link_xml("frame"), joint_xml("X", "prismatic", "frame", "cart", axis=(1, 0, 0)),
                     solid_xml("cart", 1.0, 1e-3), joint_xml("J2", "revolute", "cart", "bar"), bar_xml("bar", 0.3, 0.5))
    tr = stop("tip hits wall", "free", 0.0, {"type": "gap", "value": 0.0, "direction": "decreasing"},
              {"a": "frame", "point_a": [0.5, 0.0], "b": "bar", "point_b": [0.3, 0.0], "normal": [-1.0, 0.0]},
              merge_to="held", unmerge=False)
    doc = base_doc("cart", "free", {"free": "cart.urdf", "held": {"from": "free", "lock": ["J2"]}},
                   {"X": 0.0, "J2": 0.0}, {"X": 1.0, "J2": 0.0}, g=0.0, t_end=1.0, transitions=[tr],
                   drives=[{"joint": "X", "coefficients": [0.2], "configurations": ["held"]}])
    path = write_scene(tmp_path, doc, {"cart.urdf": urdf})
    report = check_scene(pcmm.load_scene(path))
    run = pcmm.simulate(pcmm.load_scene(path))
    assert [(e["t"], e["to"]) for e in run.events] == [(pytest.approx(0.2, abs=1e-9), "held")]  # x + 0.3 = 0.5 at 1 m/s
    assert np.all(np.isnan(run.series("constraint_forces", "tip hits wall.hold")[run.t > 0.2]))
    [note] = [w for w in run.stats["warnings"] if "tip hits wall.hold cannot be solved here" in w]
    assert "configuration 'held'" in note and "plus J2 free, its drives and its cut joints (none)" in note
    [w] = [w for w in report.warnings if "redundant" in w]
    assert "configuration 'free' has 2 constraint rows (drives[0] ('X'), 'tip hits wall.hold') of rank 1 on 2 " \
           "coordinates: 1 redundant but consistent" in w
    assert "any split would be one of many, so it reports those it leaves indeterminate as NaN" in w


def test_a_guard_on_the_indeterminate_hold_is_refused_at_check_and_at_run(tmp_path):
    """The same press with unmerge = true: the merge would be undone where its hold turns tensile, but
    the hold is statically indeterminate (the null vector is non-zero on its row: the sign of the
    hold depends on the split, -4.0 N in one, 0.555 N in another), so no guard can read it without
    the parts' compliance: `pcmm check` refuses it (the field: the stop's unmerge), and so does the
    run when it enters 'held' (before this, the guard read NaN, never fired, and said nothing)."""
    path = jammed_press(tmp_path, drive=[TH_STOP], reference=True, t_end=0.6)
    path.write_text(path.read_text().replace("unmerge = false", "unmerge = true"))
    report = check_scene(pcmm.load_scene(path))
    [p] = report.problems
    assert p.startswith(f"{path}: transitions[0] (stop).unmerge: = true (the stop's): the merge is undone where its "
                        "holding force 'stop.hold' turns tensile, which the redundant rows leave statically indeterminate")
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(pcmm.load_scene(path))
    text = info.value.text()
    assert "configuration 'held': a guard reads the holding force of 'stop', which the constraint rows leave " \
           "statically indeterminate" in text and "t = 0.2832989" in text


def test_a_drive_that_turns_inconsistent_stops_the_run_naming_the_dropped_row(tmp_path):
    """The drive on A, f(t) = -1 + (t - t_m)^3 with t_m the merge's instant: at t_m it holds the crank
    where the lock and the loop put it, at rest (consistent: the run enters 'held' and goes on), then
    turns it, which the loop and the lock forbid. The row dropped at entry (C.fx) is checked at every
    solve: its residual leaves round-off within a few steps and the run stops naming it and the time
    (its velocity residual 3 (t - t_m)^2 a sin B / ... reaches 1e-9 after about 2e-5 s)."""
    first = pcmm.simulate(pcmm.load_scene(jammed_press(tmp_path / "first", drive=[TH_STOP], reference=True, t_end=0.4)))
    tm = first.events[0]["t"]
    cubic = [TH_STOP - tm ** 3, 3 * tm ** 2, -3 * tm, 1.0]  # -1 + (t - tm)^3, expanded
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(pcmm.load_scene(jammed_press(tmp_path / "cubic", drive=cubic, reference=True, t_end=0.4)))
    text = info.value.text()
    assert "configuration 'held': at t = " in text and "its redundant rows, dropped at t = " in text
    assert "are violated: C.fx (residual" in text and "max_step" not in text  # not blamed on a Newton solve
    t_stop = float(text.split("configuration 'held': at t = ")[1].split(" s")[0])
    assert tm < t_stop < tm + 0.01


def initial_held(folder: Path, drive: float, lock_x: float | None = None) -> Path:
    """The press starting in 'held' (P locked at the stop's x, or at ``lock_x``), its crank driven
    at ``drive``: 2 rows (C.fx, C.fy) and the drive on A, B: 3 rows on 2 coordinates."""
    import tomllib
    from builders import dump_toml
    path = jammed_press(folder, drive=[drive], t_end=0.2)
    doc = tomllib.loads(path.read_text())
    doc["scene"]["initial_configuration"] = "held"
    doc["configurations"]["held"]["lock"] = {"P": slider_x(TH_STOP) if lock_x is None else lock_x}
    doc["initial"]["q"] = {"A": drive, "B": doc["initial"]["q"]["B"]}
    doc["initial"]["v"] = {"A": 0.0, "B": 0.0}
    doc["initial"].pop("independent", None)
    doc["transitions"] = []
    path.write_text(dump_toml(doc))
    return path


def test_a_consistent_redundant_initial_configuration_loads_and_runs(tmp_path):
    """Crank driven at -1 and slide locked at the x the loop gives for -1: the loader counted 2
    coordinates less 1 driven for 2 rows and said "no posture satisfies them all" (a false error:
    A = -1, B = phi + 1 does, by hand). Now it loads, assembles there, and stays at rest."""
    run = pcmm.simulate(pcmm.load_scene(initial_held(tmp_path, TH_STOP)))
    phi = math.asin(-A_ * math.sin(TH_STOP) / B_)
    assert abs(run.series("q", "A")[-1] - TH_STOP) < 1e-12 and abs(run.series("q", "B")[-1] - (phi - TH_STOP)) < 1e-12
    assert [w for w in run.stats["warnings"] if "t = 0 s, configuration 'held': its 3 constraint rows" in w]


def test_an_inconsistent_redundant_initial_configuration_is_a_clear_error(tmp_path):
    """The slide locked 1 cm beyond where the loop puts it for the crank's -1: no posture satisfies
    the rows; the assembly says so, naming the row it cannot satisfy and its residual."""
    with pytest.raises(pcmm.PcmmError) as info:
        pcmm.simulate(pcmm.load_scene(initial_held(tmp_path, TH_STOP, lock_x=slider_x(TH_STOP) + 0.01)))
    text = info.value.text()
    assert "configuration 'held': at t = 0 s its 3 constraint rows (C.fx, C.fy, A.drive) are of rank 2 and no " \
           "posture and motion satisfies them all" in text
    # solved with C.fx and the drive (QR's pivoting at the guess): the crank at -1, the rod's tip reaching
    # the slider's x, 1 cm beyond its reach there, leaves the tip off the slide by, by hand,
    # a sin A + sqrt(b^2 - (sqrt(b^2 - a^2 sin^2 A) + 0.01)^2) = -0.0492 m: C.fy's residual
    assert "solved with C.fx, A.drive, the others are violated: C.fy (residual " in text
    residual = float(text.split("(residual ")[1].split(",")[0])
    dx = math.sqrt(B_ ** 2 - (A_ * math.sin(TH_STOP)) ** 2) + 0.01
    hand = A_ * math.sin(TH_STOP) + math.sqrt(B_ ** 2 - dx ** 2)
    assert abs(abs(residual) - abs(hand)) < 1e-3 * abs(hand) and abs(hand) == pytest.approx(0.0492, abs=1e-4)
