"""The integrator contract (pcmm/integrators.py), checked for every method of the registry on
an oscillator with a closed-form solution, x'' = -w^2 x, x(t) = cos(w t):

* the state at t_bound (closed form);
* an event located on the method's dense output (first crossing of cos(w t) = c: t = acos(c)/w);
* a grazing event, in and out of the guard inside one step (found, at the closed-form time);
* an exception raised in the right-hand side (Ctrl-C, a pcmm error, a loop's repartition)
  ends the integration at once, as that exception, carrying the steps taken before it;
* too many steps, and a right-hand side that turns non-finite, end with a message naming the
  setting to change.

The Fortran DOP853 calls back into Python; an exception raised in a call-back does not stop the
Fortran code by itself (f2py keeps it until the integration ends), so these cases guard it.
"""
from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

import pcmm
from builders import EXAMPLES
from pcmm.model.mechanism import Mechanism
from pcmm.errors import Repartition, SimulationError
from pcmm.events.guards import make_guard
from pcmm.ode.integrators import INTEGRATORS
from pcmm.run.loop import initial_state

W = 3.0  # rad/s


def options(**kw):
    base = dict(rtol=1e-10, atol=1e-12, max_step=np.inf, step=1e-3, event_tol=1e-14, max_steps=10**6)
    return SimpleNamespace(**{**base, **kw})


def oscillator(t, y):
    return np.array([y[1], -W * W * y[0]])


def exact(t):
    return np.array([math.cos(W * t), -W * math.sin(W * t)])


# method: bound on |error| of the state at t = 2 s and of an event time, at rtol 1e-10 (RK4: h = 1e-3 s)
BOUND = {"DOP853": 1e-9, "DOP853F": 1e-9, "RK45": 1e-8, "RK23": 1e-7, "Radau": 1e-7, "BDF": 1e-5,
         "LSODA": 1e-6, "RK4": 1e-9}


def test_every_method_has_a_bound():
    assert set(BOUND) == set(INTEGRATORS)


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_state_at_t_bound_matches_the_closed_form(name):
    seg = INTEGRATORS[name].integrate(oscillator, 0.0, exact(0.0), 2.0, [], options())
    assert seg.status == 0 and seg.event is None, seg.message
    assert seg.t[0] == 0.0 and seg.t[-1] == pytest.approx(2.0, abs=1e-12)
    assert np.all(np.diff(seg.t) > 0)
    assert np.max(np.abs(seg.y[:, -1] - exact(2.0))) < BOUND[name] * W
    assert seg.nfev >= seg.nsteps


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_t_bound_is_reached_whatever_its_rounding(name):
    """Free fall from random (t0, t_bound): every run ends at t_bound exactly with status 0
    (Hairer's code lands its last step an ulp short of t_bound for some pairs: 2 of these 300)."""
    rng = np.random.default_rng(1)
    n = 300 if name == "DOP853F" else 20

    def fall(t, y):
        return np.array([y[1], -9.81])
    for _ in range(n):
        t0 = rng.uniform(0, 1)
        t_bound = t0 + rng.uniform(0.01, 5)
        seg = INTEGRATORS[name].integrate(fall, t0, np.array([0.0, 1.0]), t_bound, [],
                                          options(rtol=1e-8, atol=1e-10, step=0.01))
        assert seg.status == 0 and seg.t[-1] == t_bound, (t0, t_bound, seg.message)
        tau = t_bound - t0
        assert seg.y[0, -1] == pytest.approx(tau - 9.81 * tau * tau / 2, abs=1e-8)


def guard(value, direction, rate_from_state=False):
    """x - value; with ``rate_from_state`` it also gives its rate x' = y[1], as pcmm's guards do
    (the graze test then needs no derivative from the method)."""
    def g(t, y):
        return y[0] - value
    g.terminal, g.direction = True, direction
    if rate_from_state:
        g.rate = lambda t, y, f: y[1]
        g.rate_from_state = True
    return g


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_event_is_located_at_the_closed_form_time(name):
    c = 0.3
    seg = INTEGRATORS[name].integrate(oscillator, 0.0, exact(0.0), 2.0, [guard(c, -1)], options())
    assert seg.status == 1 and seg.event == 0
    assert abs(seg.t[-1] - math.acos(c) / W) < BOUND[name]
    assert abs(seg.y[0, -1] - c) < BOUND[name] * W


@pytest.mark.parametrize("rate_from_state", [False, True], ids=["rate-from-derivative", "rate-from-state"])
@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_a_graze_inside_one_step_is_found(name, rate_from_state):
    """From t0 = -0.4 s the oscillator rises to x = 1 at t = 0 and falls again; the guard
    x = 1 - 1e-6 is above it only for |t| < 4.7e-4 s, far less than one adaptive step."""
    depth = 1e-6
    t0 = -0.4
    seg = INTEGRATORS[name].integrate(oscillator, t0, exact(t0), 1.0, [guard(1 - depth, +1, rate_from_state)],
                                      options())
    assert seg.status == 1 and seg.event == 0, seg.message
    t_in = -math.acos(1 - depth) / W
    slope = W * math.sin(W * abs(t_in))  # the guard's rate where it crosses: small near the tangency
    assert abs(seg.t[-1] - t_in) < BOUND[name] * W / slope


class _Raising:
    """The oscillator, raising ``exc`` at its first call past ``t_raise``; counts later calls."""

    def __init__(self, exc, t_raise):
        self.exc, self.t_raise, self.raised, self.after = exc, t_raise, False, 0

    def __call__(self, t, y):
        if self.raised:
            self.after += 1
        elif t > self.t_raise:
            self.raised = True
            raise self.exc
        return oscillator(t, y)


@pytest.mark.parametrize("exc", [KeyboardInterrupt(), SimulationError("singular loop"), Repartition(0.5)],
                         ids=["ctrl-c", "pcmm-error", "repartition"])
@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_an_exception_in_the_rhs_ends_the_integration_at_once(name, exc):
    fun = _Raising(exc, 0.5)
    with pytest.raises(type(exc)) as info:
        INTEGRATORS[name].integrate(fun, 0.0, exact(0.0), 10.0, [], options())
    assert info.value is exc
    assert fun.after == 0, f"{fun.after} right-hand-side calls after the exception"
    seg = info.value.segment
    assert seg.status == -1 and seg.t.size >= 2 and seg.t[-1] <= 0.5
    assert np.all(np.isfinite(seg.y))
    assert np.max(np.abs(seg.y[:, -1] - exact(seg.t[-1]))) < BOUND[name] * W


def test_fortran_stops_within_a_few_hundred_calls_of_an_exception(monkeypatch):
    """What DOP853F answers after an exception costs nothing, but the Fortran code must stop
    soon: the calls it makes (counted on the way in, before pcmm's own wrapper) stay bounded,
    where f2py alone would have run to t_bound on garbage."""
    from scipy import integrate

    calls = []

    class CountingOde(integrate.ode):
        def __init__(self, f, jac=None):
            super().__init__(lambda t, y: (calls.append(t), f(t, y))[1], jac)
    monkeypatch.setattr("pcmm.ode.integrators.si.ode", CountingOde)
    fun = _Raising(KeyboardInterrupt(), 0.5)
    with pytest.raises(KeyboardInterrupt):
        INTEGRATORS["DOP853F"].integrate(fun, 0.0, exact(0.0), 1e4, [], options())
    before = sum(1 for t in calls if t <= 0.5)
    assert 0 < len(calls) - before < 500, f"{len(calls) - before} calls after the exception"


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_too_many_steps_names_max_steps(name):
    with pytest.raises(SimulationError, match="max_steps") as info:
        INTEGRATORS[name].integrate(oscillator, 0.0, exact(0.0), 100.0, [], options(max_steps=5))
    assert info.value.segment.t[-1] < 100.0


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_a_non_finite_rhs_ends_with_a_message(name):
    def fun(t, y):
        return np.full(2, np.nan) if t > 0.3 else oscillator(t, y)
    try:
        seg = INTEGRATORS[name].integrate(fun, 0.0, exact(0.0), 2.0, [], options())
    except SimulationError as exc:
        seg, msg = exc.segment, str(exc)
    else:
        msg = seg.message  # scipy's steppers report their failure in the segment
    assert seg.status == -1 and 0.0 < seg.t[-1] <= 0.3 + 1e-12
    assert np.all(np.isfinite(seg.y))
    assert any(k in msg for k in ("not finite", "no longer finite", "collapsed", "step size")), msg
    if name in ("DOP853F", "DOP853", "RK45"):  # methods with a checked rhs, or (DOP853F) a diagnosis after failing
        assert "the derivative of the state is not finite at t = " in msg, msg


# ---- guard rates: the graze test's input, checked against the guard's own time derivative ------
# A guard's ``rate`` (read from the state alone) must equal d/dt g(t, y(t)) along the flow,
# here a central difference of the guard along the right-hand side's direction.
def _flow_difference(g, fun, t, y, eps=1e-6):
    f = fun(t, y)
    return (g(t + eps, y + eps * f) - g(t - eps, y - eps * f)) / (2 * eps)


@pytest.mark.parametrize("scene_file,guard_type", [
    ("three_bar_stop.toml", "gap"),  # a mobile contact: the normal turns with link2
    ("double_folded.toml", "coordinate"),  # loop + drive: q' of the dependent joints
    ("double_folded.toml", "gap"),
    ("double_folded.toml", "singular"),  # the loop's partition guard: det of the dependent block
], ids=["mobile-gap", "loop-coordinate", "loop-gap", "loop-singularity"])
def test_guard_rate_is_the_time_derivative_of_the_guard(scene_file, guard_type):
    scene = pcmm.load_scene(EXAMPLES / scene_file)
    cfg = Mechanism(scene)[scene.initial_configuration]
    tr = scene.transitions_from(cfg.name)[0]
    if guard_type == "gap":  # the same contact watched by its gap
        tr = dataclasses.replace(tr, guard=dataclasses.replace(tr.guard, type="gap", value=0.0, measure=None))
    g = cfg.coords.singularity_guard() if guard_type == "singular" else make_guard(cfg, tr)
    assert g.rate_from_state
    rng = np.random.default_rng(7)
    y_start = cfg.coords.pack(0.0, *initial_state(scene, cfg)[:2])
    k = len(y_start) // 2
    for _ in range(5):  # states near the initial one (a loop stays assemblable), brisk rates
        y = y_start + np.concatenate([0.05 * rng.standard_normal(k), 3.0 * rng.standard_normal(k)])
        expected = _flow_difference(g, cfg.coords.rhs, 0.3, y)
        assert g.rate(0.3, y, None) == pytest.approx(expected, rel=1e-6, abs=1e-9)


@pytest.mark.parametrize("g, dg, lo, hi, root, most", [
    # a smooth crossing: quadratic convergence from the secant's estimate
    (lambda t: math.cos(t) - 0.3, lambda t: -math.sin(t), 1.0, 1.5, math.acos(0.3), 4),
    # a steep tanh: Newton from the secant's estimate would overshoot; the bracket keeps it
    (lambda t: math.tanh(40 * (t - 0.3)), lambda t: 40 / math.cosh(40 * (t - 0.3)) ** 2, 0.0, 1.0, 0.3, 8),
    # falling through zero, the bracket given high end first in value
    (lambda t: 1.0 - t * t, lambda t: -2 * t, 0.5, 2.0, 1.0, 6),
])
def test_bracketed_newton_finds_the_crossing_with_few_evaluations(g, dg, lo, hi, root, most):
    """The event root finder on a guard with a rate read from the state: the root to 4 ulp of t,
    in fewer evaluations than scipy's brentq takes for the same bracket and tolerance (8, 11 and
    9 here, its two end-point calls included), and never outside the bracket where Newton's step
    would leave it."""
    from pcmm.ode.integrators import _bracketed_newton
    calls = []

    def counted(t):
        calls.append(t)
        assert lo <= t <= hi
        return g(t)
    x = _bracketed_newton(counted, dg, lo, hi, g(lo), g(hi), xtol=4 * np.finfo(float).eps)
    assert x == pytest.approx(root, abs=1e-14)
    assert len(calls) <= most


def test_a_signal_between_a_samples_time_and_its_state_keeps_the_complete_samples():
    """SIGTERM landed between _Stepper.accept's two appends (a clean-clone CI: a bouncing run's
    partial then failed with 'cannot reshape array of size 12 into shape (3,5)', a traceback
    instead of the partial result).  The sample whose state was not appended is not kept; the
    others are the run's, unchanged."""
    from types import SimpleNamespace
    from pcmm.ode.integrators import _Stepper
    y0 = np.array([1.0, 2.0, 3.0])
    st = _Stepper(lambda t, y: -y, [], SimpleNamespace(max_steps=10), 0.0, y0, -y0, 1.0)
    for k in (1, 2, 3):
        st.ts.append(0.1 * k)
        st.ys.append(y0 * k)
    st.ts.append(0.4)  # the signal: this time's state never appended
    seg = st.segment(None, 7, -1, "stopped")
    np.testing.assert_array_equal(seg.t, [0.0, 0.1, 0.2, 0.30000000000000004])
    np.testing.assert_array_equal(seg.y, np.column_stack([y0, y0, 2 * y0, 3 * y0]))
