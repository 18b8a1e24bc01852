"""One rule for "no impulse along the contact's normal" in the Python and the compiled impulse solve
(pcmm.events.impulse_compiled.NO_IMPULSE, handed to pcmm/model/_impulse.hpp's plan): J W_eff J^T at most
1e-14 of tr(W_eff).  Before, the compiled solve handed every contact below 1e-10 to the Python solve,
which took it down to 1e-14.

The mechanism: a stop on J1 of a two-link chain whose second link hangs on J2 by its centroid, with
a tiny inertia I2.  The stop's denominator is 1 / (I1 + m2 l^2) while tr(W_eff) grows as 1 / I2, so
I2 sets the ratio.  Closed form (a frictionless pin at link 2's centroid passes no moment to it):
w1 -> -e w1, the link's absolute rate w1 + w2 is kept, the stop's moment is (1 + e) |w1| (I1 + m2 l^2)."""
from __future__ import annotations

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
@pytest.mark.parametrize("factor", [4.0, 0.25])
def test_the_compiled_and_the_python_solve_refuse_on_the_same_side_of_the_rule(tmp_path, monkeypatch, factor):
    """A ratio 4 times NO_IMPULSE: both solve it, to the closed form; 4 times below: the compiled plan
    hands it back (None) and the Python solve says the contact takes no impulse along its normal."""
    monkeypatch.setenv(compiled.ENV, "1")
    I2 = factor * NO_IMPULSE * I1_J  # the ratio is I2 / I1_J to first order
    assert _ratio(I2) == pytest.approx(factor * NO_IMPULSE, rel=1e-6)
    cfg, contact = _stop(tmp_path, I2)
    fast = impulse_compiled.compiled_impulse(cfg, _plan(cfg, contact, ()))
    assert fast is not None
    got = fast.plan.solve(Q, V, E)
    if factor > 1:
        assert got is not None
        _assert_closed_form(got[0], got[1][0])
        python = solve_impulse_python(cfg, 0.0, Q, V, contact, E, ())
        _assert_closed_form(python.v_after, python.P)
    else:
        assert got is None
        with pytest.raises(SimulationError, match="cannot take an impulse along its normal"):
            solve_impulse_python(cfg, 0.0, Q, V, contact, E, ())
