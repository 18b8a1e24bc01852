"""`[initial] independent` names a planar joint's coordinate ("P.theta"), as the series do
(issue 24, docs/design_24.md section 7).

A uniform rod (L = 1) on a planar joint P with its lower end A pinned on the floor at entry leans at
theta = 1.2 rad; [initial] v gives P the world rates (0, 0, w), which the pin does not allow (A would
move).  By hand, with G - A = (L/2)(cos theta, sin theta), the pin makes G's velocity
omega (-(L/2) sin theta, (L/2) cos theta), one freedom:

* keeping theta' (independent = ["P.theta"]): omega = w, G moves at w (-(L/2) sin, (L/2) cos);
* keeping y' = 0 (independent = ["P.y"]): omega (L/2) cos theta = 0, so omega = 0;
* keeping x' = 0 (independent = ["P.x"]): likewise omega = 0.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import pcmm
from builders import free_bar_urdf
from pcmm.errors import SceneError

L, TH, W = 1.0, 1.2, 2.5


def pinned_rod(make_scene, independent):
    foot = {"name": "foot", "type": "revolute", "a": "frame", "point_a": "entry", "b": "bar",
            "point_b": [-L / 2, 0.0], "contact": {"normal": [0.0, 1.0], "friction": "stick"}}
    return make_scene({"rod.urdf": free_bar_urdf(1.0, L)},
                      configurations={"pinned": {"urdf": "rod.urdf", "cut_joints": [foot]}},
                      q0={"P": [0.5 * L * math.cos(TH), 0.5 * L * math.sin(TH), TH]}, v0={"P": [0.0, 0.0, W]},
                      independent=independent, gravity=(0.0, 0.0), t_end=1e-3)


@pytest.mark.parametrize("kept, omega", [("P.theta", W), ("P.y", 0.0), ("P.x", 0.0)])
def test_the_named_coordinate_keeps_its_rate(make_scene, kept, omega):
    traj = pcmm.simulate(pcmm.load_scene(pinned_rod(make_scene, [kept])))
    rates = {c: float(traj.series("v", c)[0]) for c in ("P.x", "P.y", "P.theta")}  # world rates
    assert rates["P.theta"] == pytest.approx(omega, abs=1e-12)
    np.testing.assert_allclose([rates["P.x"], rates["P.y"]],
                               [-omega * L / 2 * math.sin(TH), omega * L / 2 * math.cos(TH)], atol=1e-12)


def test_a_coordinate_name_that_is_not_one_is_refused(make_scene):
    with pytest.raises(SceneError, match=r"initial.independent: = 'P.z': only a planar joint's coordinates.*"
                                         r"\.x, \.y, \.theta"):
        pcmm.load_scene(pinned_rod(make_scene, ["P.z"]))
    with pytest.raises(SceneError, match=r"initial.independent.*'Q.theta'"):
        pcmm.load_scene(pinned_rod(make_scene, ["Q.theta"]))
