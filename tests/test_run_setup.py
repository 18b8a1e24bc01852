"""What every run sets up again (its views, its configurations' force elements and coordinates)
is done once per process where it is a pure function of the scene: a later run must see exactly
what a first run saw, and nothing one run changes may leak into the next."""
from __future__ import annotations

from builders import Bar, chain_urdf
from pcmm.results.trajectory import urdf_joints


def test_urdf_joints_parsed_once_each_call_its_own_copy():
    text = chain_urdf([Bar(0.5, 1.0), Bar(0.4, 2.0, joint="prismatic", axis=(1.0, 0.0, 0.0))])
    expected = {"J1": {"type": "revolute", "parent": "frame", "child": "link1"},
                "J2": {"type": "prismatic", "parent": "link1", "child": "link2"}}
    first = urdf_joints(text)
    assert first == expected
    first["J1"]["type"] = "changed by a reader"
    del first["J2"]
    again = urdf_joints(text)
    assert again == expected
    assert again is not first and again["J1"] is not first["J1"]
