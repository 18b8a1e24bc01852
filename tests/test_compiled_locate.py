"""The compiled event locator (pcmm/model/_locate.hpp) against the Python one
(:func:`pcmm.ode.integrators._locate_python`): the same event times to the bit on DOP853's
dense outputs (the compiled loop's ``contd8`` and scipy's ``y_old, F``), for guards linear in
the state (a state entry, a time guard, a tree's joint-angle row), plain and re-armed, on
hypothesis-drawn polynomials including tangent (grazing) roots, near misses and two roots in one
step; and in whole runs, the same events as with the Python locator."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pcmm
from pcmm.events.guards import UNFIRED
from pcmm.model import compiled
from pcmm.ode import integrators
from pcmm.ode.dop853 import DenseStep
from pcmm.ode.integrators import _Contd8, _locate, _locate_python
from pcmm.ode.witness import Guard

from builders import driven_cart_pendulum, pendulum

pytestmark = pytest.mark.skipif(getattr(compiled._tree_dynamics, "locate", None) is None,
                                reason="the extension is not built with _locate.hpp")


@pytest.fixture(autouse=True)
def registered(monkeypatch):
    monkeypatch.setattr(integrators, "COMPILED_LOCATE", [compiled._tree_dynamics.locate, lambda: True])


def _basis(s):
    """contd8's basis at s: y = sum_i c_i b_i(s)."""
    s1 = 1.0 - s
    return np.array([np.ones_like(s), s, s * s1, s * s * s1, (s * s1) ** 2, s ** 3 * s1 ** 2, (s * s1) ** 3,
                     s ** 4 * s1 ** 3])


def _contd8_of(values_at, ny=3, p=0, r=1, rng=None):
    """8 x ny coefficients whose component p is the polynomial ``values_at(s)`` (degree <= 7) and
    whose component r is its derivative in time over a step of size 1 (a consistent rate), the
    other components noise."""
    s = np.linspace(0.0, 1.0, 8)
    B = _basis(s).T
    cont = (rng or np.random.default_rng(0)).normal(size=(8, ny))
    cont[:, p] = np.linalg.solve(B, values_at(s))
    h = 1e-6
    cont[:, r] = np.linalg.solve(B, (values_at(s + h) - values_at(s - h)) / (2 * h))
    return cont


def _guard(direction, rearm=False, target=0.0, ny=3, p=0, r=1):
    """A state-entry guard y[p] - target with rate y[r], as pcmm.events.guards builds it."""
    def raw(t, y):
        return y[p] - target

    def raw_rate(t, y, f):
        return y[r]
    value, rate = raw, raw_rate
    if rearm:
        def value(t, y):
            val = raw(t, y)
            if direction * raw_rate(t, y, None) > 0.0:
                return val
            return -direction * max(-direction * val, UNFIRED)

        def rate(t, y, f):
            rr = raw_rate(t, y, f)
            if direction * rr > 0.0 or -direction * raw(t, y) > UNFIRED:
                return rr
            return 0.0
    c, rr = np.zeros(max(p, r) + 1), np.zeros(max(p, r) + 1)
    c[p], rr[r] = 1.0, 1.0
    return Guard("g", value, direction, rate=rate, rate_from_state=True,
                 linear=(c, 0.0, -target, rr, 0.0, rearm, UNFIRED))


def _both(e, sol, t_a, t_b, tol=1e-12):
    g_a = e(t_a, sol(t_a))
    return _locate(e, sol, t_a, t_b, g_a, tol), _locate_python(e, sol, t_a, t_b, g_a, tol)


def _sols(cont, t_old, h):
    """The two dense outputs of one polynomial: the compiled loop's and scipy's DOP853's (whose step
    size is its ends' difference)."""
    t = t_old + h
    return [_Contd8(t_old, t - t_old, cont), DenseStep(t_old, t, cont[0].copy(), cont[1:].copy())]


def test_the_two_dense_outputs_are_one_polynomial():
    cont = np.random.default_rng(3).normal(size=(8, 4))
    a, b = _sols(cont, 0.7, 0.013)
    ts = np.linspace(0.7, 0.713, 33)
    assert np.array_equal(a(ts), b(ts))


def test_a_simple_root_is_the_python_root_and_the_closed_form():
    cont = _contd8_of(lambda s: s - 0.3)  # y_p = s - 0.3 on [0, 1]: the root at s = 0.3
    for sol in _sols(cont, 0.0, 1.0):
        fast, ref = _both(_guard(+1), sol, 0.0, 1.0)
        assert fast == ref
        assert abs(fast - 0.3) < 1e-12


roots = st.floats(0.02, 0.98)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(a=roots, b=roots, scale=st.floats(0.1, 10.0), direction=st.sampled_from([-1, 0, 1]),
       rearm=st.booleans(), t_old=st.floats(-5.0, 50.0), log_h=st.floats(-8.0, 0.0),
       shape=st.sampled_from(["one", "two", "tangent", "near miss", "graze through", "cubic"]),
       seed=st.integers(0, 2 ** 16))
def test_drawn_polynomials_give_the_python_event_time_to_the_bit(a, b, scale, direction, rearm, t_old, log_h, shape,
                                                                  seed):
    lo, hi = min(a, b), max(a, b)
    shapes = {
        "one": lambda s: scale * (s - a),
        "two": lambda s: scale * (s - lo) * (s - hi),  # two roots in one step
        "tangent": lambda s: -scale * (s - a) ** 2,  # touches zero at a (a graze)
        "near miss": lambda s: -scale * (s - a) ** 2 - 1e-9 * scale,  # comes within 1e-9 and turns back
        "graze through": lambda s: scale * ((s - a) ** 2 * (s - b) - 1e-7),
        "cubic": lambda s: scale * (s - a) * (s - b) * (s - 0.5),
    }
    cont = _contd8_of(shapes[shape], rng=np.random.default_rng(seed))
    h = 10.0 ** log_h
    for sign in (1.0, -1.0):
        c = cont.copy()
        c[:, :2] *= sign
        for sol in _sols(c, t_old, h):
            fast, ref = _both(_guard(direction, rearm), sol, sol.t_old, sol.t_old + sol.h)
            assert fast == ref or (fast is not None and ref is not None and math.isnan(fast) and math.isnan(ref))


def test_a_time_guard_and_a_tree_row():
    """g = t - 0.37 (a time guard) and g = y0 - y1 - 0.1 with rate y2 - y3 (a relative angle on a
    tree's [q, v]): each at the Python locator's time."""
    cont = np.random.default_rng(5).normal(size=(8, 4)) * 0.01
    cont[0] = [0.2, 0.1, 1.0, -1.0]  # y0 - y1 starts at 0.1 and grows at ~2 /s
    sol = _Contd8(0.3, 0.1, cont)
    t_guard = Guard("t", lambda t, y: t - 0.37, 1, rate=lambda t, y, f: 1.0, rate_from_state=True,
                    linear=(np.zeros(0), 1.0, -0.37, np.zeros(0), 1.0, False, UNFIRED))
    fast, ref = _both(t_guard, sol, 0.3, 0.4)
    assert fast == ref and abs(fast - 0.37) < 1e-15
    row = Guard("rel", lambda t, y: np.array([1.0, -1.0]) @ y[:2] - 0.1005, 1,
                rate=lambda t, y, f: np.array([1.0, -1.0]) @ y[2:], rate_from_state=True,
                linear=(np.array([1.0, -1.0, 0.0, 0.0]), 0.0, -0.1005, np.array([0.0, 0.0, 1.0, -1.0]), 0.0, False,
                        UNFIRED))
    fast, ref = _both(row, sol, 0.3, 0.4)
    assert ref is not None and fast == ref


def _events(path, compiled_locate: bool, monkeypatch, t_end=None):
    """The run's events and the number of calls of the compiled locator (the Python one alone where
    ``compiled_locate`` is false: no dense output is handed to the compiled one)."""
    calls = []
    real = compiled._tree_dynamics.locate

    def counted(*args):
        calls.append(1)
        return real(*args)
    monkeypatch.setattr(compiled._tree_dynamics, "locate", counted)  # what the run registers
    monkeypatch.setattr(integrators, "COMPILED_LOCATE", [counted, lambda: True])
    if not compiled_locate:
        monkeypatch.setattr(integrators, "_polynomial", lambda sol: None)
    scene = pcmm.load_scene(path)
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=t_end)) if t_end is not None else pcmm.simulate(scene)
    return [(ev["t"], ev["name"], ev["to"]) for ev in traj.events], len(calls)


@pytest.mark.parametrize("build", ["pendulum", "driven"])
def test_whole_runs_have_the_python_locators_events(tmp_path, monkeypatch, build):
    """A bouncing pendulum (a tree: the compiled loop's contd8, its stop guard re-armed after each
    bounce) and a pendulum on a driven cart (drives: scipy's DOP853 dense output): every event at
    the Python locator's time, to the bit, and the compiled locator did locate them."""
    if build == "pendulum":
        path = pendulum(tmp_path, 0.6, q0=0.0, t_end=1.5)
    else:
        path = driven_cart_pendulum(tmp_path, e=0.6)
    fast, n_fast = _events(path, True, monkeypatch)
    ref, n_ref = _events(path, False, monkeypatch)
    assert n_fast >= 2 and n_ref == 0
    assert len(fast) >= 2
    assert fast == ref


def test_three_bar_cycle_has_the_python_locators_events(monkeypatch):
    """The benchmark scene (drives: the compiled loop with scipy's tableau, its stop guards re-armed
    after each bounce) to 2.5 s: every event at the Python locator's time, to the bit."""
    from builders import EXAMPLES
    path = EXAMPLES / "three_bar_cycle.toml"
    fast, n_fast = _events(path, True, monkeypatch, t_end=2.5)
    ref, n_ref = _events(path, False, monkeypatch, t_end=2.5)
    assert n_fast > 100 and n_ref == 0 and len(fast) > 100
    assert fast == ref
