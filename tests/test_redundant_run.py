"""A run in a configuration whose constraint rows are redundant but consistent (issue 22: no false
failure, no silent wrong number): the motion is solved with a maximal independent set of rows, the
rows dropped are checked at every solve, and the forces the rows leave statically indeterminate are
NaN in the series, never one arbitrary split.

Mechanisms of my own: a four-bar (crank a on A at the origin, coupler b on B, rocker c on D at
(d, 0)) closed by the cut joint C, or by C and its copy C2 (the same points): 4 rows of rank 2 on 3
coordinates, whose left null vectors are (1, 0, -1, 0) and (0, 1, 0, -1) / sqrt 2 by hand (the two
copies' forces can be traded at will; only their sum, C's force in the four-bar closed once, is
determinate). The same mechanism with C2 removed from the scene is the independent route for the
motion, the events and the determinate forces.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import pcmm
from builders import bar_xml, base_doc, joint_xml, link_xml, robot_xml, stop, write_scene

A_, B_, C_, D_ = 0.1, 0.3, 0.25, 0.3


def four_bar(folder: Path, twice: bool, drive=None, torque: float = 1.0, t_end: float = 0.8, e: float = 0.5,
             solver=None) -> Path:
    """The four-bar closed by C (and by its copy C2 when ``twice``), under gravity and a motor torque
    on A (or a ``drive`` on A: its coefficients), whose rocker strikes a stop at D = 1.6 rad (D
    decreasing) with restitution ``e`` and bounces."""
    urdf = robot_xml("fb", link_xml("frame"), joint_xml("A", "revolute", "frame", "crank"), bar_xml("crank", A_, 1.0),
                     joint_xml("B", "revolute", "crank", "coupler", xyz=(A_, 0.0)), bar_xml("coupler", B_, 2.0),
                     joint_xml("D", "revolute", "frame", "rocker", xyz=(D_, 0.0)), bar_xml("rocker", C_, 1.5))
    cut = [{"name": "C", "type": "revolute", "a": "coupler", "point_a": [B_, 0.0], "b": "rocker", "point_b": [C_, 0.0]}]
    if twice:
        cut.append(dict(cut[0], name="C2"))
    ds = 1.6
    tip = (D_ + C_ * math.cos(ds), C_ * math.sin(ds))
    tr = stop("rocker stop", "free", e, {"type": "coordinate", "measure": {"joint": "D"}, "value": ds,
                                         "direction": "decreasing"},
              {"a": "frame", "point_a": list(tip), "b": "rocker", "point_b": [C_, 0.0],
               "normal": [-math.sin(ds), math.cos(ds)]})
    more = {"drives": [{"joint": "A", "coefficients": list(drive)}]} if drive else \
        {"forces": [{"name": "motor", "type": "torque", "on": {"joint": "A"}, "value": torque}]}
    doc = base_doc("four_bar_twice" if twice else "four_bar", "free", {"free": {"urdf": "fb.urdf", "cut_joints": cut}},
                   {"A": 1.0, "B": -0.414358, "D": 1.55465}, {"A": 0.0, "B": 0.0, "D": 0.0}, t_end=t_end,
                   transitions=[tr] if not drive else [], solver=solver, **more)
    doc["initial"]["independent"] = ["A"]
    return write_scene(folder, doc, {"fb.urdf": urdf})


def test_a_cut_joint_given_twice_moves_as_the_four_bar_closed_once(tmp_path):
    """The independent route: the scene with the redundant cut joint removed. Stepped by RK4 at one
    fixed step (so both runs sample the same instants), the samples agree to round-off and the events
    are the same, the rocker's bounce at the same instant to the last bit (before it every sample is
    the same: the rows kept are C's, which the four-bar closed once solves too)."""
    solver = {"method": "RK4", "step": 1e-3}
    once = pcmm.simulate(pcmm.load_scene(four_bar(tmp_path / "once", False, solver=solver)))
    twice = pcmm.simulate(pcmm.load_scene(four_bar(tmp_path / "twice", True, solver=solver)))
    [w] = [w for w in twice.stats["warnings"] if "redundant" in w]
    assert w.startswith("t = 0 s, configuration 'free': its 4 constraint rows (C.fx, C.fy, C2.fx, C2.fy) are of rank "
                        "2 on 3 coordinates: redundant but consistent, so the motion is still determined (1 free "
                        "coordinate). It is solved with C.fx, C.fy; the dropped C2.fx, C2.fy are checked")
    assert not [w for w in once.stats["warnings"] if "redundant" in w]
    assert len(once.events) == len(twice.events) == 1  # the rocker's bounce at D = 1.6
    for a, b in zip(once.events, twice.events):
        assert (a["t"], a["kind"]) == (b["t"], b["kind"])
        assert a["impulse"]["normal"] == pytest.approx(b["impulse"]["normal"], rel=1e-13)
        # the impulse each tree joint carries is determinate (C's and C2's reach the links only through
        # their sum): the four-bar's; the impulses of C and of C2 are not: NaN, written null in a summary
        for j in "ABD":
            assert np.max(np.abs(np.subtract(a["joint_impulses"][j], b["joint_impulses"][j]))) < 1e-12
        assert np.all(np.isnan(b["constraint_impulses"]["C"][:2])) and np.all(np.isnan(b["constraint_impulses"]["C2"][:2]))
        assert np.all(np.isfinite(a["constraint_impulses"]["C"]))
    from pcmm.results.trajectory import dumps_json_finite
    import json
    written = json.loads(dumps_json_finite({"events": list(twice.events)}, "summary"))
    assert written["events"][0]["constraint_impulses"]["C2"] == [None, None, 0.0]
    assert np.array_equal(once.t, twice.t)
    for n in "ABD":
        assert np.max(np.abs(once.series("q", n) - twice.series("q", n))) < 1e-13
        assert np.max(np.abs(once.series("v", n) - twice.series("v", n))) < 1e-12


def test_the_determinate_force_is_reported_and_the_indeterminate_ones_are_nan(tmp_path):
    """The four-bar closed twice, its crank driven at 3 rad/s: 5 rows (C.fx, C.fy, C2.fx, C2.fy,
    A.drive) of rank 3 on 3 coordinates. By hand the copies' rows are equal, so the left null
    vectors are (1, 0, -1, 0, 0) / sqrt 2 and (0, 1, 0, -1, 0) / sqrt 2: the drive's moment is
    determinate, C's and C2's forces are not (only their sum, C's force in the four-bar closed
    once). So A.drive is reported, and equals the KKT solve on the reduced rows (the four-bar
    closed once: its own A.drive series) to round-off; C's and C2's are NaN; and the reported
    moment with the four-bar's C force (on C, none on C2: one split) balances the full rows,
    M a + h - Q = R^T lam, to round-off."""
    import pinocchio as pin
    from pcmm.model.mechanism import Mechanism
    from pcmm.model.rows import left_null
    solver = {"method": "RK4", "step": 1e-3}
    once = pcmm.simulate(pcmm.load_scene(four_bar(tmp_path / "once", False, drive=[1.0, 3.0], solver=solver, t_end=0.3)))
    scene = pcmm.load_scene(four_bar(tmp_path / "twice", True, drive=[1.0, 3.0], solver=solver, t_end=0.3))
    twice = pcmm.simulate(scene)
    assert np.array_equal(once.t, twice.t)
    moment = twice.series("constraint_forces", "A.drive")
    assert np.all(np.isfinite(moment)) and np.max(np.abs(moment)) > 0.1
    assert np.max(np.abs(moment - once.series("constraint_forces", "A.drive"))) < 1e-12
    for label in ("C.fx", "C.fy", "C2.fx", "C2.fy"):
        assert np.all(np.isnan(twice.series("constraint_forces", label)))
    # the balance of the full rows at a few samples, from the recorded state alone
    cfg = Mechanism(scene)["free"]
    for i in (0, len(twice.t) // 2, len(twice.t) - 1):
        q = np.array([twice.series("q", n)[i] for n in ("A", "B", "D")])
        v = np.array([twice.series("v", n)[i] for n in ("A", "B", "D")])
        R, bias = cfg.coords.rows(twice.t[i], q, v)
        assert R.shape == (5, 3) and np.linalg.matrix_rank(R) == 3
        Y = left_null(R)
        hand = np.array([[1, 0, -1, 0, 0], [0, 1, 0, -1, 0]], float).T / math.sqrt(2)
        assert Y.shape == (5, 2) and np.max(np.abs(Y @ (Y.T @ hand) - hand)) < 1e-12  # the same plane
        lam = np.array([once.series("constraint_forces", "C.fx")[i], once.series("constraint_forces", "C.fy")[i],
                        0.0, 0.0, moment[i]])
        a = np.linalg.lstsq(R, -bias, rcond=None)[0]  # the crank's a = 0 and the loop's: R a + bias = 0
        h = pin.rnea(cfg.model, cfg.data, cfg.to_pin(q), v, a)
        assert np.max(np.abs(R @ a + bias)) < 1e-9
        assert np.max(np.abs(h - cfg.forces.generalized(q, v) - R.T @ lam)) < 1e-9


def test_the_flight_between_two_bounces_is_audited_as_in_the_four_bar_closed_once(tmp_path):
    """e = 0.8: the rocker bounces twice at its stop, and the flight between is audited (the work of
    the motor torque against the change of kinetic plus gravity energy, pcmm.run.audit), which solves
    the constraint rows' multipliers: on the rows kept (one split; the power of any split of
    consistent rows is the same). The same impacts and the same audit as the four-bar closed once."""
    solver = {"method": "RK4", "step": 1e-3}
    once = pcmm.simulate(pcmm.load_scene(four_bar(tmp_path / "once", False, e=0.8, t_end=1.5, solver=solver)))
    twice = pcmm.simulate(pcmm.load_scene(four_bar(tmp_path / "twice", True, e=0.8, t_end=1.5, solver=solver)))
    assert [e["t"] for e in once.events] == [e["t"] for e in twice.events] and len(once.events) == 2
    [a], [b] = once.stats["macro_impacts"], twice.stats["macro_impacts"]
    assert (a["impacts"], a["flights"], a["flights_resolved"]) == (b["impacts"], b["flights"], b["flights_resolved"]) == (2, 2, 2)
    assert math.isfinite(b["flight_energy_residual_max"])
    assert abs(a["flight_energy_residual_max"] - b["flight_energy_residual_max"]) < 1e-12
