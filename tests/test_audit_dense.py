"""The flight-energy audit reads each flight step's dense output as the integrator took it
(pcmm.ode.integrators.Segment.dense: pcmm's DOP853 keeps the step's stages, the compiled loop the
step's contd8 coefficients, the step that held an event the interpolant its location used) instead
of taking the step again.  The audit is a check: keeping those must not move the run (the same
events, states and counts, to the bit), and its figures must be those of the steps taken again
(two routes to the same 7th-order interpolant: round-off apart)."""
from __future__ import annotations

import numpy as np
import pytest
from builders import pendulum

import pcmm
from pcmm.ode import dop853
from pcmm.run import loop


def _run(path, monkeypatch, keep: bool):
    """The run, its flights keeping their steps' dense outputs (the default) or not (the audit then
    takes every step again, as before)."""
    if not keep:
        real = loop._integrate
        monkeypatch.setattr(loop, "_integrate", lambda *a, keep_dense=False: real(*a, keep_dense=False))
    try:
        return pcmm.simulate(pcmm.load_scene(path))
    finally:
        monkeypatch.undo()


@pytest.mark.parametrize("method", ["DOP853F", "DOP853"])  # the compiled loop (Fortran without it); pcmm's DOP853
def test_kept_dense_outputs_leave_the_run_alone_and_give_the_audit_of_the_steps_taken_again(tmp_path, monkeypatch,
                                                                                             method):
    """A spring pendulum (k = 3 N m/rad) bouncing on a stop with e = 0.5: the spring does work in
    every flight, so the audit's quadrature of its power is not trivially zero."""
    path = pendulum(tmp_path, e=0.5, k=3.0, rest_angle=-2.0, merge=False, t_end=1.4, spring_configurations=["c1"],
                    solver={"method": method})
    kept, again = _run(path, monkeypatch, True), _run(path, monkeypatch, False)
    assert len(kept.events) >= 4
    assert [e["t"] for e in kept.events] == [e["t"] for e in again.events]
    for a, b in zip(kept.segments, again.segments, strict=True):
        assert a.t.tobytes() == b.t.tobytes() and a.q.tobytes() == b.q.tobytes() and a.v.tobytes() == b.v.tobytes()
    for key in ("steps", "rhs_evals", "constraint_drift_max"):
        assert kept.stats[key] == again.stats[key], key
    (m,), (n,) = kept.stats["macro_impacts"], again.stats["macro_impacts"]
    assert m["flights"] == n["flights"] == len(kept.events)  # the last flight ends at t_end
    assert 0 < m["flight_energy_residual_max"] < 1e-9 and 0 < n["flight_energy_residual_max"] < 1e-9
    # the same balance from the two routes: 2.950e-12 against 2.970e-12 J (DOP853F, compiled), 3.408e-11
    # against 3.372e-11 J (DOP853: the step that held an event read on the interpolant its location used,
    # not on a step re-taken to the event), with ~0.5 J of kinetic energy at each rebound
    assert m["flight_energy_residual_max"] == pytest.approx(n["flight_energy_residual_max"], rel=0.05)


def test_kept_stages_give_dop853s_dense_output_to_the_bit():
    """pcmm's DOP853 hands out an accepted step's stages (AcceptedStages); the interpolant formed
    from them later, with the same right-hand side, is the solver's own dense output of that step,
    bit for bit, and agrees with the closed form of x'' = -9 x to the tolerance."""
    def rhs(t, y):
        return np.array([y[1], -9.0 * y[0]])
    solver = dop853.DOP853(rhs, 0.0, np.array([1.0, 0.0]), 2.0, rtol=1e-10, atol=1e-12)
    n = 0
    while solver.status == "running":
        assert solver.step() is None
        stages = solver.accepted_stages()
        later = stages.dense_output(rhs)
        own = solver.dense_output()
        ts = np.linspace(solver.t_old, solver.t, 7)
        assert later(ts).tobytes() == own(ts).tobytes()
        np.testing.assert_allclose(later(ts), [np.cos(3 * ts), -3 * np.sin(3 * ts)], rtol=0, atol=1e-9)
        n += 1
    assert n > 10
