"""Cases the compiled impulse (pcmm/model/_impulse.hpp) accepts that tests/test_compiled_impulse.py
does not reach: a prismatic joint stop (its row carries the parent's turn, ``w_a z x r``), a
prismatic joint cut, a point contact against the root (the frame: no Jacobian, no load), the cut
joint not the struck one, a stop of the joint on the root, restitution 0 and 1.  Each is compared with the Python solve by the
cut system (:func:`pcmm.events.impulse.solve_impulse_python`, a second algorithm) at drawn states
to 1e-12 of its scale, and each obeys Newton's law (Eq. 21)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from builders import Bar, base_doc, chain_urdf, stop, write_scene
from test_compiled_impulse import _assert_same, _both, _newton

import pcmm
from pcmm.model import compiled
from pcmm.model.mechanism import Mechanism

pytestmark = pytest.mark.skipif(not compiled.enabled() or not hasattr(compiled._tree_dynamics, "ImpulsePlan"),
                                reason="the compiled impulse is not built here")

SLANT = (math.cos(0.4), math.sin(0.4), 0.0)  # a prismatic axis off the link's x axis


def _cfg(folder, bars, contact, cut, drive):
    """The chain's one configuration, a stop transition with ``contact`` and ``cut``; ``drive``: J1 driven."""
    n = len(bars)
    tr = stop("hit", "c", 0.5, {"type": "coordinate", "measure": {"joint": contact.get("joint", "J2")}, "value": 0.3,
                                "direction": "decreasing"}, contact, cut=cut)
    more = {"transitions": [tr]}
    if drive:
        more["drives"] = [{"joint": "J1", "coefficients": [0.0, 1.3]}]
    doc = base_doc("chain", "c", {"c": "chain.urdf"}, {f"J{i}": 0.0 for i in range(1, n + 1)},
                   {f"J{i}": 0.0 for i in range(1, n + 1)}, g=0.0, **more)
    scene = pcmm.load_scene(write_scene(folder, doc, {"chain.urdf": chain_urdf(bars)}))
    return Mechanism(scene)["c"], scene.transitions[0]


PRISMATIC_MIDDLE = [Bar(0.5, 1.3), Bar(0.4, 0.7, joint="prismatic", axis=SLANT), Bar(0.35, 0.45)]
CASES = {
    # J2 prismatic (slanted axis), stopped and cut: its row is axis . (v_b - v_a - w_a z x r)
    "prismatic stop": (PRISMATIC_MIDDLE, {"joint": "J2"}, ["J2"]),
    # the same stop, the revolute J3 cut instead of the struck joint
    "prismatic stop, another joint cut": (PRISMATIC_MIDDLE, {"joint": "J2"}, ["J3"]),
    # link3's tip against link1, the prismatic J2 cut (its forbidden motions: across the axis, the turn)
    "point contact, prismatic cut": (PRISMATIC_MIDDLE, {"a": "link1", "point_a": [0.3, 0.1], "b": "link3",
                                                        "point_b": [0.35, 0.0], "normal": [0.0, 1.0]}, ["J2"]),
    # link2's tip against the frame (the root): a has no Jacobian and takes no load
    "point contact on the root": ([Bar(0.5, 1.3), Bar(0.4, 0.7), Bar(0.3, 0.4)],
                                  {"a": "frame", "point_a": [0.2, -0.6], "b": "link2", "point_b": [0.4, 0.0],
                                   "normal": [math.sin(0.3), math.cos(0.3)]}, ["J2"]),
    # a revolute stop of J1, whose parent is the root (its couple's reaction on the frame is not
    # loaded), J1 cut; without a drive (J1's drive would leave no motion along the stop's row)
    "revolute stop on the root's joint": ([Bar(0.5, 1.3), Bar(0.4, 0.7), Bar(0.3, 0.4)], {"joint": "J1", "arm": 0.2},
                                          ["J1"]),
}


@pytest.mark.parametrize("e", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("drive", [False, True])
@pytest.mark.parametrize("case", sorted(CASES))
def test_prismatic_stops_root_contacts_and_other_cuts_are_the_python_solve(tmp_path, case, drive, e):
    bars, contact, cut = CASES[case]
    if drive and contact.get("joint") == "J1":
        pytest.skip("a drive on the stopped joint: no impulse along the stop's row (the Python solve's error)")
    cfg, tr = _cfg(tmp_path, bars, contact, cut, drive)
    rng = np.random.default_rng(7)
    solved = 0
    for _ in range(40):
        q = rng.uniform(-math.pi, math.pi, len(bars))
        q[1] = rng.uniform(0.1, 0.4) if bars[1].joint == "prismatic" else q[1]
        v = rng.uniform(-2.0, 2.0, len(bars))
        a, b = _both(cfg, 0.2, q, v, tr.contact, e, cut)
        if b.vn_before >= 0:  # separating: no impact to compare
            continue
        _assert_same(a, b)
        _newton(a, e)
        _newton(b, e)
        solved += 1
    assert solved >= 10
