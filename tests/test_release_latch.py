"""A latch let go at its value is one release (issue 22, h-release2: every guard kind).

A timed release frees a latched joint exactly at the latch's value.  The latch's coordinate guard
then sits at its value at the segment's first instant; read plain, round-off there (the compiled
loop's solve reads it +2.2e-16 past the value where the Python one reads 0.0) could be taken for a
crossing and latch the joint again at once.  It is not, by two readings (docs/limits.md, "Grazing
and resting"): a latch always has a contact (the scene loader requires one), so
:func:`pcmm.run.loop._pending` reads its normal speed at the release, lists it ``leaving`` where the
loads pull the joint away, and the segment watches it re-armed (:func:`pcmm.events.guards.left_at_value`);
and even read plain, a state the release leaves *at or past* the value, moving back out, is no sign
change in the guard's direction: the scans need the value below it first.  Where the loads push the
joint into the latch it latches again at once, with no impulse (the physics: h-release's rule).

Two mechanisms of our own: a two-bar arm on a tree (its elbow angle an entry of the state, exact),
checked against the arm's equations of motion written out by hand; and a four-bar whose latch is on
the loop's dependent joint (read through the closure solve, where the round-off is).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import pcmm
import pcmm.run.loop as loop

from builders import Bar, bar_xml, chain_urdf, joint_xml, link_xml, robot_xml, scene_doc, write_scene

# ---- a two-bar arm in a horizontal plane, its elbow latched and let go by a timer ------------------
L1, L2, M1, M2 = 0.5, 0.4, 1.0, 0.6
LATCH = 0.5          # the elbow angle J2 the latch locks at (increasing)
K, C = 0.3, 0.02     # the elbow's spring (rest at J2 = 0) and damper, in 'free' only
W2 = 4.0             # the elbow's initial rate (the shoulder at rest)
T_RELEASE = 0.4


def arm(folder: Path, t_end: float = 1.0, contact: str = "joint") -> Path:
    """Upper arm on J1 (the frame), forearm on J2 at its tip; no gravity.  The elbow opens against its
    spring, latches at J2 = LATCH (into 'locked', J2 locked; a joint stop or the forearm's tip against
    a point of the upper arm) and a timer lets it go at T_RELEASE."""
    urdf = robot_xml("arm", link_xml("frame"), joint_xml("J1", "revolute", "frame", "upper"), bar_xml("upper", L1, M1),
                     joint_xml("J2", "revolute", "upper", "fore", xyz=(L1, 0.0)), bar_xml("fore", L2, M2))
    if contact == "joint":
        where = {"joint": "J2", "arm": L2}
    else:  # the forearm's tip strikes the upper arm's point where that tip is at the latch
        where = {"a": "upper", "point_a": [L1 + L2 * math.cos(LATCH), L2 * math.sin(LATCH)], "b": "fore",
                 "point_b": [L2, 0.0], "normal": [math.sin(LATCH), -math.cos(LATCH)]}
    doc = scene_doc({"free": "arm.urdf", "locked": {"from": "free", "lock": ["J2"]}},
                    {"J1": 0.0, "J2": 0.0}, {"J1": 0.0, "J2": W2}, gravity=(0.0, 0.0), t_end=t_end,
                    forces=[{"name": "elbow spring", "type": "linear", "on": {"joint": "J2"},
                             "measure": {"joint": "J2"}, "value": 0.0, "k": K, "c": C, "configurations": ["free"]}],
                    transitions=[{"name": "elbow latch", "type": "latch", "from": "free", "to": "locked", "cut": ["J2"],
                                  "guard": {"type": "coordinate", "measure": {"joint": "J2"}, "value": LATCH,
                                            "direction": "increasing"},
                                  "contact": where},
                                 {"name": "elbow release", "type": "release", "from": "locked", "to": "free",
                                  "guard": {"type": "time", "at": T_RELEASE}}])
    return write_scene(folder, doc, {"arm.urdf": urdf})


def _mass(q2):
    """The arm's mass matrix in (J1, J2) (J1 absolute, J2 relative), bars' centroids at mid-length."""
    I1, I2 = M1 * L1 * L1 / 12, M2 * L2 * L2 / 12
    c = math.cos(q2)
    m22 = I2 + M2 * (L2 / 2) ** 2
    m12 = m22 + M2 * L1 * (L2 / 2) * c
    m11 = I1 + M1 * (L1 / 2) ** 2 + I2 + M2 * (L1 * L1 + (L2 / 2) ** 2 + L1 * L2 * c)
    return np.array([[m11, m12], [m12, m22]])


def _free(t, y):
    """The free arm's equations of motion (Lagrange, by hand): M q'' + c(q, q') = (0, -K q2 - C q2')."""
    q1, q2, w1, w2 = y
    h = M2 * L1 * (L2 / 2) * math.sin(q2)
    rhs = np.array([h * (2 * w1 * w2 + w2 * w2), -h * w1 * w1 - K * q2 - C * w2])
    return [w1, w2, *np.linalg.solve(_mass(q2), rhs)]


def by_hand(t_end: float):
    """(latch time, the locked arm's rate, the state at t_end): the free arm to the latch (an event of
    solve_ivp), the plastic latch keeping the angular momentum about the pivot (the first row of
    M q': no moment about J1 in the latch's impulse), rigid rotation to T_RELEASE, free again."""
    reach = lambda t, y: y[1] - LATCH  # noqa: E731
    reach.terminal, reach.direction = True, 1
    tol = dict(method="DOP853", rtol=1e-12, atol=1e-14)
    a = solve_ivp(_free, (0.0, 1.0), [0.0, 0.0, 0.0, W2], events=reach, **tol)
    t_l, (q1, q2, w1, w2) = a.t_events[0][0], a.y_events[0][0]
    momentum = _mass(q2)[0] @ [w1, w2]
    omega = momentum / _mass(LATCH)[0, 0]
    b = solve_ivp(_free, (T_RELEASE, t_end), [q1 + omega * (T_RELEASE - t_l), LATCH, omega, 0.0],
                  dense_output=True, **tol)
    return t_l, omega, b


@pytest.mark.parametrize("compiled", ["1", "0"])
@pytest.mark.parametrize("contact", ["joint", "point"])
def test_an_elbow_latch_let_go_by_a_timer_is_one_release(tmp_path, monkeypatch, compiled, contact):
    """Latched at t_l (by hand: the free arm's equations to J2 = LATCH), the arm turns rigidly at the
    rate the latch's angular momentum gives; the timer lets the elbow go at T_RELEASE with J2 at the
    latch's value and at rest relative to the upper arm, and the spring (with the turning arm's
    centrifugal load) pulls it back: no latch after the release.  Not ever: no moment acts about J1,
    so the angular momentum p1 (M q')_1 is kept, and at any J2 the kinetic energy is at least
    p1^2 / (2 M11(J2)) (the least over J2' at that p1), which at J2 = LATCH is the release's (J2' = 0
    there); with the spring's energy the same there, coming back needs at least the release's energy,
    while the damper has taken some away since: one latch and one release whatever t_end, compiled
    and Python."""
    monkeypatch.setenv("PCMM_COMPILED", compiled)
    t_l, omega, free = by_hand(1.5)
    for t_end in (1.0, 1.5):
        traj = pcmm.simulate(pcmm.load_scene(arm(tmp_path / f"{contact}{t_end}", t_end, contact)))
        assert all(v.startswith("compiled" if compiled == "1" else "python")
                   for v in traj.stats["evaluations"].values()), traj.stats["evaluations"]
        assert [e["transition"] for e in traj.events] == ["latch", "release"]
        latch, release = traj.events
        assert latch["t"] == pytest.approx(t_l, abs=1e-8)
        assert release["t"] == T_RELEASE and release["cause"] == "time"
        q2, w1 = traj.series("q", "J2"), traj.series("v", "J1")
        locked = (traj.t > latch["t"]) & (traj.t <= T_RELEASE)
        assert np.allclose(w1[locked], omega, rtol=0, atol=1e-9)
        after = traj.t > T_RELEASE
        assert np.all(q2[after] < LATCH)
        assert np.allclose(q2[after], free.sol(traj.t[after])[1], rtol=0, atol=1e-7)
    # by hand the elbow never comes back to the latch: its largest angle after the release is LATCH itself
    ts = np.linspace(T_RELEASE, 1.5, 20001)[1:]
    assert free.sol(ts)[1].max() < LATCH
