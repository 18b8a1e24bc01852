"""Property-based tests of the loop solves: random four-bars and five-bars, never a failure.

Hypothesis draws crank-rocker four-bars (Grashof, the crank the shortest link) and five-bars with
two short cranks and long couplers, every one with its transmission angles bounded away from 0
and pi over a whole crank turn, so the constraint Jacobian is well conditioned everywhere.  Constant
torques spin the cranks up from rest without gravity, through every extreme of the coupler and
rocker angles; each run is saved (``--out``) and written at a fixed rate on the dense output
(``--csv --dt``).  Nothing may fail, and every sample, saved or resampled, holds the conservation
of energy exactly: the kinetic energy is the motors' work, ``tau_1 dA + tau_2 dE``.
"""
from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import pcmm
from builders import bar_xml, joint_xml, link_xml, robot_xml, scene_doc, write_scene
from pcmm.cli import main as cli_main

T_END, DT = 0.3, 0.01
COS_MAX = 0.9  # |cos| of every transmission angle over a turn: 26 to 154 degrees
PROPERTY = settings(max_examples=3, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.filter_too_much])


def _meet(p, r1, o, r2, sign=+1.0):
    """The intersection of the circles (p, r1) and (o, r2) on the side ``sign`` of p -> o."""
    p, o = np.asarray(p, float), np.asarray(o, float)
    d = np.linalg.norm(o - p)
    along = (d * d + r1 * r1 - r2 * r2) / (2 * d)
    h = math.sqrt(r1 * r1 - along * along)
    u = (o - p) / d
    return p + along * u + sign * h * np.array([-u[1], u[0]])


def _transmission_cos(l1, l2, gap):
    """cos of the angle between two links l1, l2 whose far ends are ``gap`` apart."""
    return (l1 * l1 + l2 * l2 - gap * gap) / (2 * l1 * l2)


def _run_and_check(path: Path, torques: dict[str, float]):
    folder = path.parent
    out, csv = folder / "run.npz", folder / "run.csv"
    assert cli_main(["run", str(path), "--out", str(out), "--csv", str(csv), "--dt", str(DT), "--quiet"]) == 0
    saved = pcmm.Trajectory.load(out)
    assert saved.status == "complete" and saved.t[-1] == T_END
    header = csv.read_text().splitlines()[0].split(",")
    rows = np.genfromtxt(csv, delimiter=",", skip_header=1)
    assert len(rows) == round(T_END / DT) + 1
    for t, q, kinetic in ((saved.t, lambda j: saved.series("q", j), saved.series("kinetic")),
                          (rows[:, 0], lambda j: rows[:, header.index(f"q_{j} [rad]")],
                           rows[:, header.index("kinetic_energy [J]")])):
        work = sum(tau * (q(j) - q(j)[0]) for j, tau in torques.items())
        assert np.all(np.isfinite(kinetic))
        assert np.max(np.abs(kinetic - work)) < 1e-7 * max(1.0, float(np.max(np.abs(work))))
    return saved


@st.composite
def four_bars(draw):
    a = draw(st.floats(0.04, 0.12))
    b, c, d = (draw(st.floats(0.22, 0.45)) for _ in range(3))
    # the transmission angle (coupler against rocker) at the crank's two dead positions
    assume(all(abs(_transmission_cos(b, c, gap)) < COS_MAX for gap in (d - a, d + a)))
    return a, b, c, d, draw(st.floats(2.0, 8.0)), draw(st.floats(0.0, 2 * math.pi))


@PROPERTY
@given(four_bars())
def test_random_crank_rockers_save_and_resample(params):
    a, b, c, d, torque, a0 = params
    crank_tip = a * np.array([math.cos(a0), math.sin(a0)])
    joint_c = _meet(crank_tip, b, (d, 0.0), c)
    coupler = math.atan2(*(joint_c - crank_tip)[::-1])
    rocker = math.atan2(*(joint_c - np.array([d, 0.0]))[::-1])
    urdf = robot_xml("four_bar", link_xml("frame"),
                     joint_xml("A", "revolute", "frame", "crank"), bar_xml("crank", a, 0.5),
                     joint_xml("B", "revolute", "crank", "coupler", xyz=(a, 0.0)), bar_xml("coupler", b, 1.0),
                     joint_xml("D", "revolute", "frame", "rocker", xyz=(d, 0.0)), bar_xml("rocker", c, 1.0))
    cut = {"name": "C", "type": "revolute", "a": "coupler", "point_a": [b, 0.0], "b": "rocker", "point_b": [c, 0.0]}
    doc = scene_doc({"open": "fb.urdf"}, {"A": a0, "B": coupler - a0, "D": rocker}, {"A": 0.0},
                    gravity=(0.0, 0.0), t_end=T_END, cut_joints={"open": [cut]}, independent=["A"], name="four_bar",
                    forces=[{"name": "motor", "type": "linear", "on": {"joint": "A"}, "measure": {"joint": "A"},
                             "value": torque}])
    path = write_scene(Path(tempfile.mkdtemp()), doc, {"fb.urdf": urdf})
    saved = _run_and_check(path, {"A": torque})
    # through its extremes: a crank turn or more, and the rocker turns back (its rate changes sign)
    assert saved.series("q", "A")[-1] - a0 > 2 * math.pi
    omega = saved.series("omega", "rocker")
    assert np.any(omega[1:] * omega[:-1] < 0)


@st.composite
def five_bars(draw):
    r1, r4 = draw(st.floats(0.03, 0.08)), draw(st.floats(0.03, 0.08))
    l2, l3, d = draw(st.floats(0.25, 0.4)), draw(st.floats(0.25, 0.4)), draw(st.floats(0.2, 0.35))
    # the couplers' angle over every crank pair: their far ends lie d - r1 - r4 ... d + r1 + r4 apart
    assume(all(abs(_transmission_cos(l2, l3, gap)) < COS_MAX for gap in (d - r1 - r4, d + r1 + r4)))
    torques = draw(st.floats(2.0, 6.0)), draw(st.floats(-6.0, 6.0))
    return r1, r4, l2, l3, d, torques, draw(st.floats(0.0, 2 * math.pi)), draw(st.floats(0.0, 2 * math.pi))


@PROPERTY
@given(five_bars())
def test_random_five_bars_save_and_resample(params):
    r1, r4, l2, l3, d, (t1, t2), a0, e0 = params
    tip1 = r1 * np.array([math.cos(a0), math.sin(a0)])
    tip2 = np.array([d, 0.0]) + r4 * np.array([math.cos(e0), math.sin(e0)])
    joint_c = _meet(tip1, l2, tip2, l3)
    c1 = math.atan2(*(joint_c - tip1)[::-1])
    c2 = math.atan2(*(joint_c - tip2)[::-1])
    urdf = robot_xml("five_bar", link_xml("frame"),
                     joint_xml("A", "revolute", "frame", "crank1"), bar_xml("crank1", r1, 0.4),
                     joint_xml("B", "revolute", "crank1", "coupler1", xyz=(r1, 0.0)), bar_xml("coupler1", l2, 0.9),
                     joint_xml("E", "revolute", "frame", "crank2", xyz=(d, 0.0)), bar_xml("crank2", r4, 0.4),
                     joint_xml("F", "revolute", "crank2", "coupler2", xyz=(r4, 0.0)), bar_xml("coupler2", l3, 0.9))
    cut = {"name": "C", "type": "revolute", "a": "coupler1", "point_a": [l2, 0.0], "b": "coupler2", "point_b": [l3, 0.0]}
    doc = scene_doc({"open": "fb.urdf"}, {"A": a0, "B": c1 - a0, "E": e0, "F": c2 - e0}, {"A": 0.0, "E": 0.0},
                    gravity=(0.0, 0.0), t_end=T_END, cut_joints={"open": [cut]}, independent=["A", "E"],
                    name="five_bar",
                    forces=[{"name": "m1", "type": "linear", "on": {"joint": "A"}, "measure": {"joint": "A"}, "value": t1},
                            {"name": "m2", "type": "linear", "on": {"joint": "E"}, "measure": {"joint": "E"}, "value": t2}])
    path = write_scene(Path(tempfile.mkdtemp()), doc, {"fb.urdf": urdf})
    _run_and_check(path, {"A": t1, "E": t2})
