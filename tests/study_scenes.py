"""Scenes of the study tests whose optimum is known in closed form."""
from __future__ import annotations

import math
from pathlib import Path

from builders import bar_xml, base_doc, joint_xml, link_xml, robot_xml, stop, write_scene

L, M = 0.6, 1.5
I_PIVOT = M * L ** 2 / 3  # a uniform bar about its end
SWING = math.pi / 2  # from q = 0 to the stop at q = pi/2


def torque_to_stop(folder: Path, e: float = 0.5, torque: float = 1.0, t_end: float = 1.2) -> Path:
    """A uniform bar (M, L) on the revolute J1, no gravity, turned from rest at q = 0 by a
    constant torque ``forces.drive.value`` onto a stop at q = pi/2 (contact at the tip, restitution
    e).  By hand: it strikes at t = sqrt(2 I SWING / torque) with omega = sqrt(2 torque SWING / I),
    and the normal impulse (1 + e) I omega / L = (1 + e) sqrt(2 torque SWING I) / L is the run's
    largest (every later strike is slower by the factor e)."""
    qs = SWING
    urdfs = {"p.urdf": robot_xml("pend", link_xml("frame"), joint_xml("J1", "revolute", "frame", "link1"),
                                 bar_xml("link1", L, M)),
             "rest.urdf": robot_xml("pend_rest", link_xml("frame"), joint_xml("J1", "fixed", "frame", "link1", yaw=qs),
                                    bar_xml("link1", L, M))}
    tr = stop("stop", "c1", e, {"type": "coordinate", "measure": {"joint": "J1"}, "value": qs,
                                "direction": "increasing"},
              {"a": "frame", "point_a": [L * math.cos(qs), L * math.sin(qs)], "b": "link1", "point_b": [L, 0.0],
               "normal": [math.sin(qs), -math.cos(qs)]}, merge_to="rest")
    forces = [{"name": "drive", "type": "linear", "on": {"link": "link1"}, "measure": {"link": "link1"},
               "value": torque}]
    doc = base_doc("torque_to_stop", "c1", {"c1": "p.urdf", "rest": "rest.urdf"}, {"J1": 0.0}, {"J1": 0.0}, g=0.0,
                   t_end=t_end, transitions=[tr], forces=forces)
    return write_scene(folder, doc, urdfs)


def strike(torque: float, e: float = 0.5) -> tuple[float, float]:
    """(time of the strike, its normal impulse) by hand."""
    return math.sqrt(2 * I_PIVOT * SWING / torque), (1 + e) * math.sqrt(2 * torque * SWING * I_PIVOT) / L
