"""A planar floating base closed by a cut joint: the loop is solved in pcmm's coordinates.

A URDF ``planar`` joint's velocity is in the body's own frame, ``(x', y') = R(theta) (v_x, v_y)``;
the Newton solve that closes a loop works on the positions, whose derivative is the velocity
Jacobian times ``R(theta)^T`` in those two columns.  A bar on a planar joint pinned to the ground
at its tip by one revolute cut joint is a compound pendulum; these tests hold it to the same
pendulum modelled as a revolute joint, to energy conservation and to the pin's reaction in closed
form (Newton's second law of the centroid).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import pcmm
from builders import G, bar_xml, joint_xml, link_xml, pendulum_urdf, robot_xml, scene_doc, write_scene

L, M = 0.8, 2.0
TIGHT = {"method": "DOP853", "rtol": 1e-12, "atol": 1e-14}  # the same integrator for both models


def pinned_bar(folder: Path, phi0: float, w0: float, t_end: float = 2.0, solver=TIGHT, L: float = L) -> Path:
    """A uniform bar (L, M) on the planar joint ``P`` (its frame's origin at one end, the bar along
    +x), pinned at its other end (L, 0) to the frame's origin by the revolute cut joint ``pin``.
    ``phi0`` is the angle from +x of the pin-to-centroid direction (a revolute pendulum's angle),
    so the bar's own angle is ``phi0 + pi`` and its base sits at ``L (cos phi0, sin phi0)``.  The
    base turns about the pin at ``w0``: its velocity ``w0 L (-sin phi0, cos phi0)`` in world axes
    is ``(0, -w0 L)`` in the bar's own (a planar joint's velocity is body-frame), consistent
    whichever coordinates the loop keeps independent."""
    urdf = robot_xml("pinned", link_xml("frame"), joint_xml("P", "planar", "frame", "bar"), bar_xml("bar", L, M))
    cut = {"name": "pin", "type": "revolute", "a": "frame", "point_a": [0.0, 0.0], "b": "bar", "point_b": [L, 0.0]}
    theta = phi0 + math.pi
    doc = scene_doc({"c": "pinned.urdf"}, {"P": [L * math.cos(phi0), L * math.sin(phi0), theta]},
                    {"P": [0.0, -w0 * L, w0]}, t_end=t_end, cut_joints={"c": [cut]}, solver=solver, name="pinned")
    return write_scene(folder, doc, {"pinned.urdf": urdf})


def revolute_pendulum(folder: Path, phi0: float, w0: float, t_end: float = 2.0, solver=TIGHT, L: float = L) -> Path:
    doc = scene_doc({"c": "pendulum.urdf"}, {"J1": phi0}, {"J1": w0}, t_end=t_end, solver=solver, name="revolute")
    return write_scene(folder, doc, {"pendulum.urdf": pendulum_urdf(L, M)})


# released 69 degrees from the bottom with 3 rad/s: the bar turns through more than 90 degrees,
# where a Newton step with the body-frame Jacobian points away from the solution.  With L = 1.7 m
# the angle's column of the pin's rows outweighs x and y: the loop's partition keeps one of the
# planar joint's x, y independent (whose body-frame velocity column is parallel to the angle's
# at the bottom of the swing), and changes as the bar swings (new segments).
# That partition's block degenerates as the bar swings down (its step sizes shrink before the
# repartition): the two models agree there to the integrators' error, 3e-9, not to round-off.
CASES = [(-math.pi / 2 + 1.2, 3.0, L, 1e-9), (-math.pi / 2 - 0.3, 0.0, L, 1e-9), (0.4, -5.0, L, 1e-9),
         (-math.pi / 2 + 1.0, 0.0, 1.7, 1e-8)]


@pytest.mark.parametrize("phi0, w0, length, tol", CASES)
def test_pinned_planar_bar_moves_as_the_revolute_pendulum(tmp_path, phi0, w0, length, tol):
    a = pcmm.simulate(pcmm.load_scene(pinned_bar(tmp_path / "pinned", phi0, w0, L=length)))
    b = pcmm.simulate(pcmm.load_scene(revolute_pendulum(tmp_path / "revolute", phi0, w0, L=length)))
    assert a.status == b.status == "complete", a.message
    ra, rb = a.resampled(0.01), b.resampled(0.01)
    # the instants k 0.01 s of both (a repartition adds the ends of its segments)
    ka, kb = np.round(ra.t / 0.01), np.round(rb.t / 0.01)
    sa = np.isclose(ra.t, ka * 0.01, rtol=0, atol=1e-12) & np.isin(ka, kb)
    sb = np.isclose(rb.t, kb * 0.01, rtol=0, atol=1e-12) & np.isin(kb, ka)
    _, ia = np.unique(ka[sa], return_index=True)
    _, ib = np.unique(kb[sb], return_index=True)
    assert len(ia) == len(ib) == 201
    pick = lambda traj, sel, idx, q, n: traj.series(q, n)[sel][idx]  # noqa: E731
    # the bar's own angle is the pendulum's plus pi; its centroid is at the same place
    assert np.max(np.abs(pick(ra, sa, ia, "theta", "bar") - math.pi - pick(rb, sb, ib, "theta", "link1"))) < tol
    assert np.max(np.abs(pick(ra, sa, ia, "omega", "bar") - pick(rb, sb, ib, "omega", "link1"))) < tol
    centroid = pick(ra, sa, ia, "xy", "bar") + length / 2 * np.column_stack(
        [np.cos(pick(ra, sa, ia, "theta", "bar")), np.sin(pick(ra, sa, ia, "theta", "bar"))])
    phi = pick(rb, sb, ib, "theta", "link1")
    assert np.max(np.abs(centroid - length / 2 * np.column_stack([np.cos(phi), np.sin(phi)]))) < tol
    assert a.stats["constraint_drift_max"] < 1e-12


def test_pinned_planar_bar_conserves_energy_and_its_pin_force_is_newtons(tmp_path):
    phi0, w0 = -math.pi / 2 + 1.2, 3.0
    traj = pcmm.simulate(pcmm.load_scene(pinned_bar(tmp_path, phi0, w0)))
    # energy by hand at the start: I_pin w^2 / 2 + M g (L/2) sin(phi), I_pin = M L^2 / 3
    e0 = M * L * L / 3 * w0 ** 2 / 2 + M * G * L / 2 * math.sin(phi0)
    energy = traj.series("kinetic") + traj.series("potential")
    assert abs(energy[0] - e0) < 1e-12
    assert np.max(np.abs(energy - e0)) < 1e-9
    # the pin's force on the bar is M (a_c - g), a_c the centroid's acceleration of the pendulum
    phi = traj.series("theta", "bar") - math.pi
    w = traj.series("omega", "bar")
    alpha = -1.5 * G / L * np.cos(phi)  # I_pin alpha = -M g (L/2) cos(phi)
    ax = L / 2 * (-w ** 2 * np.cos(phi) - alpha * np.sin(phi))
    ay = L / 2 * (-w ** 2 * np.sin(phi) + alpha * np.cos(phi))
    fx, fy = traj.series("constraint_forces", "pin.fx"), traj.series("constraint_forces", "pin.fy")
    assert np.max(np.abs(fx - M * ax)) < 1e-8
    assert np.max(np.abs(fy - M * (ay + G))) < 1e-8


def test_planar_joint_velocities_are_reported_in_world_axes(tmp_path):
    """A bar turned a quarter turn (theta = pi/2) sliding at +1 m/s along world x without gravity
    or spin: its body-frame velocity, what ``[initial] v`` takes, is R(pi/2)^T (1, 0) = (0, -1);
    the series, the CSV and the summary report the rates of its coordinates, (1, 0, 0)."""
    import json

    from builders import free_bar_urdf
    from pcmm.cli import main as cli_main
    doc = scene_doc({"free": "bar.urdf"}, {"P": [0.0, 0.0, math.pi / 2]}, {"P": [0.0, -1.0, 0.0]},
                    gravity=(0.0, 0.0), t_end=0.5, name="slide")
    path = write_scene(tmp_path, doc, {"bar.urdf": free_bar_urdf(1.0, 0.5)})
    traj = pcmm.simulate(pcmm.load_scene(path))
    assert np.allclose(traj.series("v", "P.x"), 1.0, rtol=0, atol=1e-12)
    assert np.allclose(traj.series("v", "P.y"), 0.0, rtol=0, atol=1e-12)
    assert np.allclose(traj.series("q", "P.x"), traj.t, rtol=0, atol=1e-12)  # x = 1 m/s t: v is its rate
    csv, summary = tmp_path / "run.csv", tmp_path / "run.json"
    assert cli_main(["run", str(path), "--csv", str(csv), "--summary", str(summary), "--quiet"]) == 0
    header = csv.read_text().splitlines()[0].split(",")
    assert "v_P.x [m/s in world axes]" in header and "v_P.theta [rad/s]" in header
    rows = np.genfromtxt(csv, delimiter=",", skip_header=1, usecols=header.index("v_P.x [m/s in world axes]"))
    assert np.allclose(rows, 1.0, rtol=0, atol=1e-12)
    final = json.loads(summary.read_text())["final"]
    assert final["v"]["P.x"] == pytest.approx(1.0, abs=1e-12)
    assert final["v"]["P.y"] == pytest.approx(0.0, abs=1e-12)
    assert final["q"]["P.x"] == pytest.approx(0.5, abs=1e-12)



def test_a_segment_is_reread_without_touching_the_running_coordinates(tmp_path):
    """The pinned bar with L = 1.7 m changes its loop's partition as it swings.  Re-reading its
    first segment (``restored``, what a trajectory's lazy series do, possibly in another thread)
    gives a reader in that segment's partition, while the coordinates the run integrates keep the
    partition of the segment it is in: unpacking the run's state inside and outside the reading
    gives the same posture, bit for bit."""
    from pcmm.model.mechanism import Mechanism

    path = pinned_bar(tmp_path, -math.pi / 2 + 1.0, 0.0, t_end=2.0, L=1.7)
    scene = pcmm.load_scene(path)
    traj = pcmm.simulate(scene)
    first, later = traj.segments[0], traj.segments[1]
    cfg = Mechanism(scene)["c"]
    rates = lambda q, v: cfg.qdot(q, v)  # noqa: E731 - the recorded v are the rates (world axes)
    to_v = lambda q, qd: cfg.velocity(q, qd)  # noqa: E731
    coords = cfg.coords
    coords.pack(0.0, first.q[0], to_v(first.q[0], first.v[0]))
    frozen, D_first = coords.frozen_state(), coords.D.copy()
    t2, q2 = float(later.t[1]), later.q[1]
    y2 = coords.pack(float(later.t[0]), later.q[0], to_v(later.q[0], later.v[0]))
    assert not np.array_equal(coords.D, D_first)  # the run is in another partition now
    y2 = np.concatenate([q2[coords.I], rates(q2, to_v(q2, later.v[1]))[coords.I]])
    outside = coords.unpack(t2, y2)[0].copy()
    with coords.restored(frozen, first.q[0]) as reader:
        assert np.array_equal(reader.D, D_first)
        y1 = np.concatenate([first.q[3][reader.I], first.v[3][reader.I]])
        np.testing.assert_allclose(reader.unpack(float(first.t[3]), y1)[0], first.q[3], rtol=0, atol=1e-12)
        inside = coords.unpack(t2 + 1e-9, y2)[0]  # the run goes on meanwhile (another instant: no cache)
        assert not np.array_equal(coords.D, D_first)
    np.testing.assert_allclose(inside, outside, rtol=0, atol=1e-6)
    np.testing.assert_allclose(outside, q2, rtol=0, atol=1e-12)
