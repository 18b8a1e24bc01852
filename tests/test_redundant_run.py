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
