"""One rule for "no impulse along the contact's normal" in the Python and the compiled impulse solve
(pcmm.events.impulse_compiled.NO_IMPULSE, handed to pcmm/model/_impulse.hpp's plan): J W_eff J^T at most
1e-14 of the contact's reach, the largest inverse mass its relative motion meets in the tree without
constraint rows.  Before, the rule was a fraction of tr(W_eff), which the tree's other inertias set:
it refused a well-defined impulse on a link carrying a light pinned link.

The mechanism: a stop on J1 of a two-link chain whose second link hangs on J2 by its centroid, with
a tiny inertia I2.  The stop's denominator is 1 / (I1 + m2 l^2) while tr(W_eff) grows as 1 / I2.
Closed form (a frictionless pin at link 2's centroid passes no moment to it): w1 -> -e w1, the link's
absolute rate w1 + w2 is kept, the stop's moment is (1 + e) |w1| (I1 + m2 l^2).

Still refused, by both solves: a contact whose row lies in the span of the constraint rows (a stop on
a driven joint: J W_eff J^T = 0 but for round-off) and a point contact whose normal is orthogonal to
the motion of its points (a pendulum's tip struck along the bar: J = 0 but for round-off)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from builders import Bar, base_doc, chain_urdf, stop, write_scene

import pcmm
from pcmm.errors import SimulationError
from pcmm.events import impulse_compiled
from pcmm.events.impulse import _plan, solve_impulse, solve_impulse_python
from pcmm.events.impulse_compiled import NO_IMPULSE
from pcmm.model import compiled
from pcmm.model.mechanism import Mechanism

needs_extension = pytest.mark.skipif(not compiled.enabled() or not hasattr(compiled._tree_dynamics, "ImpulsePlan"),
                                     reason=f"the compiled impulse is not here: {compiled.why_not()}")

I1_J = 0.05 + 2.0 * 0.25 ** 2 + 1.0 * 0.5 ** 2  # link 1 about J1, with link 2's mass at J2
E = 0.5
Q, V = np.array([-0.2, 0.1]), np.array([-1.0, 0.3])


def _stop(tmp_path, I2):
    urdf = chain_urdf([Bar(0.5, 2.0, com=(0.25, 0.0), izz=0.05), Bar(0.1, 1.0, com=(0.0, 0.0), izz=I2)])
    tr = stop("hit", "c", E, {"type": "coordinate", "measure": {"joint": "J1"}, "value": -0.2,
                              "direction": "decreasing"}, {"joint": "J1"})
    doc = base_doc("threshold", "c", {"c": "c.urdf"}, {"J1": 0.0, "J2": 0.0}, {"J1": -1.0, "J2": 0.3}, g=0.0,
                   t_end=0.3, transitions=[tr])
    scene = pcmm.load_scene(write_scene(tmp_path, doc, {"c.urdf": urdf}))
    return Mechanism(scene)["c"], scene.transitions[0].contact


def _ratio(I2):
    """J W_eff J^T / tr(W_eff) of the stop, by hand: W = M^-1 with M = [[I1_J + I2, I2], [I2, I2]]."""
    W = np.linalg.inv(np.array([[I1_J + I2, I2], [I2, I2]]))
    return W[0, 0] / np.trace(W)


def _assert_closed_form(v_after, P):
    np.testing.assert_allclose(v_after[0], -E * V[0], rtol=1e-12)
    np.testing.assert_allclose(v_after.sum(), V.sum(), rtol=1e-9)
    np.testing.assert_allclose(P, (1 + E) * abs(V[0]) * I1_J, rtol=1e-12)


@needs_extension
def test_a_ratio_between_the_old_thresholds_is_the_compiled_solve(tmp_path, monkeypatch):
    """I2 = 1e-12: the ratio is 2.4e-12, between 1e-14 and the compiled solve's old 1e-10.  The compiled
    plan solves it (before: None, the Python solve ran) and agrees with the closed form and the Python solve."""
    monkeypatch.setenv(compiled.ENV, "1")
    I2 = 1e-12
    assert 1e-14 < _ratio(I2) < 1e-10
    cfg, contact = _stop(tmp_path, I2)
    plan = _plan(cfg, contact, ())
    fast = impulse_compiled.compiled_impulse(cfg, plan)
    assert fast is not None, impulse_compiled.reason(cfg, plan)
    got = fast.plan.solve(Q, V, E)
    assert got is not None  # before: handed to the Python solve
    _assert_closed_form(got[0], got[1][0])
    out = solve_impulse(cfg, 0.0, Q, V, contact, E, ())  # the first impact: checked against the Python solve
    assert fast.checked and impulse_compiled.reasons(cfg) == {"joint stop J1 (cut none)": "compiled"}
    _assert_closed_form(out.v_after, out.P)


@needs_extension
@pytest.mark.parametrize("I2", [1e-16, 1e-20])
def test_a_stop_on_a_link_carrying_a_light_pinned_link_takes_its_impulse(tmp_path, monkeypatch, I2):
    """The ratio J W_eff J^T / tr(W_eff) is I2 / I1_J (3e-16, 3e-20), below the old 1e-14: both solves
    refused the stop ("cannot take an impulse along its normal").  Its reach is the stop's own 1 / I1_J:
    both solve it, to the closed form."""
    monkeypatch.setenv(compiled.ENV, "1")
    assert _ratio(I2) < NO_IMPULSE / 10  # what the old rule compared with NO_IMPULSE
    cfg, contact = _stop(tmp_path, I2)
    plan = _plan(cfg, contact, ())
    fast = impulse_compiled.compiled_impulse(cfg, plan)
    assert fast is not None, impulse_compiled.reason(cfg, plan)
    got = fast.plan.solve(Q, V, E)
    assert got is not None  # before: None (handed to the Python solve, which refused)
    _assert_closed_form(got[0], got[1][0])
    python = solve_impulse_python(cfg, 0.0, Q, V, contact, E, ())
    _assert_closed_form(python.v_after, python.P)
    out = solve_impulse(cfg, 0.0, Q, V, contact, E, ())  # the first impact: checked against the Python solve
    assert fast.checked and impulse_compiled.reasons(cfg) == {"joint stop J1 (cut none)": "compiled"}
    _assert_closed_form(out.v_after, out.P)


@pytest.mark.parametrize("route", ["compiled", "python"])
def test_a_run_through_the_light_links_stop(tmp_path, monkeypatch, route):
    """The whole run, I2 = 1e-16, no gravity: link 1 turns at -1 rad/s from J1 = 0 into the stop at
    -0.2 rad (t = 0.2 s) and leaves it at e = 0.5 rad/s; the stop's moment 1.5 * I1_J.  Before: the
    run stopped at the stop with "cannot take an impulse along its normal"."""
    monkeypatch.setenv(compiled.ENV, "1" if route == "compiled" else "0")
    compiled.forget_trees()
    _stop(tmp_path, 1e-16)  # writes the scene
    run = pcmm.simulate(pcmm.load_scene(tmp_path / "scene.toml"))
    assert run.status == "complete" and len(run.events) == 1
    ev = run.events[0]
    assert ev["t"] == pytest.approx(0.2, abs=1e-9)
    assert ev["impulse"]["normal"] == pytest.approx((1 + E) * 1.0 * I1_J, rel=1e-9)
    assert ev["v_after"]["J1"] == pytest.approx(E * 1.0, rel=1e-9)
    assert ev["v_after"]["J1"] + ev["v_after"]["J2"] == pytest.approx(-1.0 + 0.3, rel=1e-9)


def _driven_stop(tmp_path):
    """The chain of :func:`_stop` (I2 = 0.01) with J1 driven at -1 rad/s and the stop on J1."""
    urdf = chain_urdf([Bar(0.5, 2.0, com=(0.25, 0.0), izz=0.05), Bar(0.1, 1.0, com=(0.0, 0.0), izz=0.01)])
    tr = stop("hit", "c", E, {"type": "coordinate", "measure": {"joint": "J1"}, "value": -0.2,
                              "direction": "decreasing"}, {"joint": "J1"})
    doc = base_doc("driven", "c", {"c": "c.urdf"}, {"J1": 0.0, "J2": 0.0}, {"J1": -1.0, "J2": 0.3}, g=0.0,
                   t_end=0.3, transitions=[tr], drives=[{"joint": "J1", "coefficients": [0.0, -1.0]}])
    scene = pcmm.load_scene(write_scene(tmp_path, doc, {"c.urdf": urdf}))
    return Mechanism(scene)["c"], scene.transitions[0].contact


def _radial_contact(tmp_path):
    """A pendulum (bar of 0.6 m on J1) whose tip meets a point of the frame with the normal along the
    bar: the tip moves across the normal, J = n . (w x r) = 0 but for round-off (the angle 0.3 rad
    makes it round-off, not an exact zero)."""
    L, qs = 0.6, 0.3
    tip = [L * math.cos(qs), L * math.sin(qs)]
    tr = stop("hit", "c", E, {"type": "coordinate", "measure": {"joint": "J1"}, "value": qs,
                              "direction": "decreasing"},
              {"a": "frame", "point_a": tip, "b": "link1", "point_b": [L, 0.0],
               "normal": [math.cos(qs), math.sin(qs)]})
    doc = base_doc("radial", "c", {"c": "p.urdf"}, {"J1": 0.5}, {"J1": -1.0}, g=0.0, t_end=0.3, transitions=[tr])
    scene = pcmm.load_scene(write_scene(tmp_path, doc, {"p.urdf": chain_urdf([Bar(L, 1.5)])}))
    return Mechanism(scene)["c"], scene.transitions[0].contact, np.array([qs])


@needs_extension
@pytest.mark.parametrize("case", ["driven joint's stop", "normal along the bar"])
def test_a_contact_without_an_impulse_along_its_normal_is_refused_by_both_solves(tmp_path, monkeypatch, case):
    """The denominator is round-off, far below 1e-14 of the contact's reach (checked here by hand: the
    driven stop's J W_eff J^T is 0, the radial contact's row is 0): the compiled plan hands it back (None)
    and the Python solve says the contact takes no impulse along its normal."""
    monkeypatch.setenv(compiled.ENV, "1")
    if case == "driven joint's stop":
        cfg, contact = _driven_stop(tmp_path)
        q, v = Q, np.array([-1.0, 0.3])
    else:
        cfg, contact, q = _radial_contact(tmp_path)
        v = np.array([-1.0])
    fast = impulse_compiled.compiled_impulse(cfg, _plan(cfg, contact, ()))
    assert fast is not None, impulse_compiled.reason(cfg, _plan(cfg, contact, ()))
    assert fast.plan.solve(q, v, E) is None
    with pytest.raises(SimulationError, match="cannot take an impulse along its normal"):
        solve_impulse_python(cfg, 0.0, q, v, contact, E, ())
