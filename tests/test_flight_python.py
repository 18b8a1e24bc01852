"""The Python between two events (issue 26): what the event scanner, the flight audit and the
recording do per accepted step and per flight, cut without moving a bit of the run."""
from __future__ import annotations

import math

import numpy as np

from pcmm.ode import integrators
from pcmm.ode.witness import Guard


class _Opts:
    event_tol, max_steps = 1e-14, 1000


def _counted_guard(holding):
    """g = y0 - 0.3 t (no rate of its own: a forward difference), its calls counted."""
    calls = []

    def value(t, y):
        calls.append(t)
        return float(y[0]) - 0.3 * t
    return Guard("test", value, -1, "unmerge", holding=holding), calls


def test_a_pure_guard_value_is_asked_once_per_step_end():
    """A guard on a compiled holding force is a function of (t, y) alone: the step end's value just
    computed starts its forward difference (2 calls per step, not 3); a guard read through a loop's
    warm-started Newton solve is asked again (3 calls: its last bits follow the previous solve).  The
    rate is the same forward difference either way, (g(t + d, y + d f) - g(t, y)) / d."""
    f = np.array([0.7, -1.0])
    y0, y1 = np.array([1.0, 0.0]), np.array([1.07, -0.1])
    for holding, per_step in ((("compiled", 0, 0.0), 2), (None, 3)):
        guard, calls = _counted_guard(holding)
        st = integrators._Stepper(None, [guard], _Opts(), 0.0, y0, f, 1.0)
        calls.clear()
        assert st.accept(0.0, y0, 0.1, y1, f, None) is None
        assert len(calls) == per_step, (holding, calls)
        d = max(1e-7 * 0.1, 1e-12)
        want = ((1.07 + d * 0.7 - 0.3 * (0.1 + d)) - (1.07 - 0.3 * 0.1)) / d
        assert st.rates[0] == want and math.isclose(want, 0.7 - 0.3, rel_tol=1e-6)  # d = 1e-8: round-off / d
        assert st.g[0] == 1.07 - 0.3 * 0.1


# -- the flight audit reads the compiled loop's rows ------------------------------------------------------

def _flights(path, monkeypatch, corrupt=None):
    """The run of ``path`` and every audited flight's (t, y, kept) as the audit got them; ``corrupt``:
    a change applied to the audit's measurement (the test's own fault)."""
    from pcmm.run import audit
    seen = []
    real = audit.run_work

    def run_work(cfg, t, y, stepping, kept):
        seen.append((np.array(t), np.array(y), kept))
        return real(cfg, t, y, stepping, kept)
    with monkeypatch.context() as m:
        m.setattr(audit, "run_work", run_work)
        if corrupt is not None:
            corrupt(m, audit)
        run = pcmm.simulate(pcmm.load_scene(path))
    return run, seen


def _scenes(tmp_path):
    from builders import driven_cart_pendulum, pendulum
    return {"contd8": pendulum(tmp_path / "p", e=0.5, k=3.0, rest_angle=-2.0, merge=False, t_end=1.4,
                               spring_configurations=["c1"]),  # a tree: DOP853F, contd8 rows
            "scipy": driven_cart_pendulum(tmp_path / "c")}  # drives under auto: scipy's DOP853 rows


import pcmm  # noqa: E402
import pytest  # noqa: E402
from pcmm.run import dense  # noqa: E402
from pcmm.model import compiled  # noqa: E402

needs_loop = pytest.mark.skipif(not compiled.enabled(), reason="the compiled segment loop does not run here")


@needs_loop
@pytest.mark.parametrize("form", ["contd8", "scipy"])
def test_flight_rows_give_the_interpolants_states_to_the_bit(form, tmp_path, monkeypatch):
    """Each audited flight keeps the loop's rows (no interpolant formed): the states at its Gauss nodes
    read off the rows, on numpy arrays or on Python floats, are those of every step's interpolant formed
    from its row (dense_states), bit for bit; a node on a step's end is left to dense_states."""
    (tmp_path / "p").mkdir(), (tmp_path / "c").mkdir()
    path = _scenes(tmp_path)[form]
    run, seen = _flights(path, monkeypatch)
    want_form = integrators.contd8_row_dense if form == "contd8" else integrators.scipy_row_dense
    flights = [(t, y, kept) for t, y, kept in seen if kept and len(t) > 1]
    assert len(flights) >= 4 and all(type(e) is integrators._Row and e.form is want_form for _, _, ks in flights for e in ks)
    assert max(len(t) for t, _, _ in flights) > 2  # a flight of several steps
    width = flights[0][2][0].row.shape[0]
    assert min(4 * (len(t) - 1) for t, _, _ in flights) * (width - 2) // 8 <= dense._FLOAT_SIZE  # on floats
    for t, y, kept in flights:
        times = (t[:-1, None] + ((t[1:] - t[:-1]) / 2)[:, None] * (np.array([0.1, 0.7, 1.3, 1.9]))).ravel()
        k_of = np.arange(times.shape[0]) // 4
        formed = [(lambda s: lambda fun: s)(e(None)) for e in kept]  # each step's interpolant, as formed before
        want = dense.dense_states(t, y, times, (None, None, None), formed)
        floats = dense.states_on_rows(t, y, times, k_of, kept)
        arrays = dense._row_states(kept, k_of, times)
        assert floats.tobytes() == want.tobytes() and arrays.tobytes() == want.tobytes()
        assert dense.states_on_rows(t, y, times, k_of, kept, 1)[:1].tobytes() == want[:1].tobytes()
        on_end = times.copy()
        on_end[1] = t[1]
        assert dense.states_on_rows(t, y, on_end, k_of, kept) is None
    # and every node state is on the recorded motion: the interpolant at a step's end is that end's state
    t, y, kept = flights[-1]
    ends = dense._row_states(kept, np.arange(len(t) - 1), t[1:] * (1 - 1e-16))
    np.testing.assert_allclose(ends, y[:, 1:], rtol=0, atol=1e-9)


@needs_loop
def test_the_audit_still_catches_a_wrong_drive_power_or_a_wrong_flight_state(tmp_path, monkeypatch):
    """The cart pendulum's drive does work in every flight.  Its audit balances each flight to round-off;
    a drive power off by 1e-4 of itself, or node velocities read 1e-5 off the flight (the rows read wrong),
    shows in the residual by orders of magnitude: the audit still measures, it is not bypassed."""
    from builders import driven_cart_pendulum
    path = driven_cart_pendulum(tmp_path)
    clean, seen = _flights(path, monkeypatch)
    assert any(kept for _, _, kept in seen)

    def wrong_power(m, audit):
        real = audit.drive_powers
        m.setattr(audit, "drive_powers", lambda *a: real(*a) * (1 + 1e-4))

    def wrong_states(m, audit):
        real, compiled_real = audit.states_on_rows, audit.compiled_node_states

        def shifted(*a, **k):
            states = real(*a, **k)
            if states is not None:
                states = states.copy()
                states[states.shape[0] // 2:] += 1e-5  # the velocities
            return states

        def compiled_shifted(*a):  # (the nodes and their states in one compiled call, where there is one)
            got = compiled_real(*a)
            if got is not None:
                times, weights, states = got
                states = states.copy()
                states[states.shape[0] // 2:] += 1e-5
                got = times, weights, states
            return got
        m.setattr(audit, "states_on_rows", shifted)
        m.setattr(audit, "compiled_node_states", compiled_shifted)
    (m0,) = clean.stats["macro_impacts"]
    assert m0["flights"] >= 3 and 0 < m0["flight_energy_residual_max"] < 1e-10 and m0["flight_energy_relative_max"] < 1e-9
    for corrupt in (wrong_power, wrong_states):
        run, _ = _flights(path, monkeypatch, corrupt)
        (m1,) = run.stats["macro_impacts"]
        assert [e["t"] for e in run.events] == [e["t"] for e in clean.events]  # the run itself untouched
        assert m1["flight_energy_residual_max"] > 1e3 * m0["flight_energy_residual_max"], (corrupt.__name__, m1, m0)


def test_a_tree_flight_power_at_all_nodes_at_once_is_the_per_node_power_to_round_off(tmp_path, monkeypatch):
    """A tree's flight (Example 1's stop variant after its first bounce: the paper's Eq. 44 motor torque
    with its damping and the two torsion springs) has no constraint row: the audit's power at its Gauss
    nodes, Q(q, v) . v with Q = Q0 - K q - Dv v, is formed for
    every node at once (matrix products) instead of node by node.  Against power() at each of 200
    states drawn over a turn and 10 rad/s: within 8 ulps of the sum of the magnitudes of its terms;
    and the flight's residual in the run stays a round-off figure."""
    from pcmm.run import audit
    got = []
    real = audit.flight_work

    def capture(cfg, coords, t, y, stepping, q_start, kept=None):
        got.append((cfg, coords))
        return real(cfg, coords, t, y, stepping, q_start, kept)
    monkeypatch.setattr(audit, "flight_work", capture)
    from builders import EXAMPLES
    run = pcmm.simulate(pcmm.load_scene(EXAMPLES / "three_bar_stop.toml"))
    assert got, "no tree flight audited"
    cfg, coords = got[0]
    forces = coords.forces
    assert not len(coords.labels) and forces.points is None and np.any(forces.K) and np.any(forces.Dv)
    rng = np.random.default_rng(7)
    nv = cfg.nv
    states = np.concatenate([rng.uniform(-np.pi, np.pi, (nv, 200)), rng.uniform(-10, 10, (nv, 200))])
    times = np.linspace(0.0, 1.0, 200)
    many = audit.tree_powers(coords, times, states)
    for i in range(200):
        q, v = coords.unpack(times[i], states[:, i])
        one = audit.power(cfg, coords, times[i], q, v)
        scale = float((np.abs(forces.Q0) + np.abs(forces.K) @ np.abs(q) + np.abs(forces.Dv) @ np.abs(v)) @ np.abs(v))
        assert abs(many[i] - one) <= 8 * np.finfo(float).eps * scale, (i, many[i], one)
    (m,) = run.stats["macro_impacts"]
    assert m["flights"] >= 1 and m["flight_energy_relative_max"] < 1e-9
    # not taken where a row or a point spring is: those stay node by node
    assert audit.tree_powers(type("C", (), {"labels": ["row"], "forces": forces})(), times, states) is None


def test_one_step_nodes_on_floats_are_the_array_nodes_to_the_bit():
    """A flight of one step (most of a bouncing run's) has its Gauss nodes and weights formed on Python
    floats: the same operations as the arrays' (t_k + h (x + 1), h w), the same bits, at step sizes
    from 1e-14 s to 1 s and times from 1e-3 to 1e3 s."""
    from pcmm.run import audit
    rng = np.random.default_rng(3)
    for _ in range(2000):
        t0 = rng.uniform(-10, 10) * 10.0 ** rng.integers(-3, 3)
        t = np.array([t0, t0 + abs(rng.standard_normal()) * 10.0 ** rng.integers(-14, 0)])
        h = ((t[1:] - t[:-1]) / 2)[:, None]
        want = (t[:-1, None] + h * (audit.GAUSS_NODES + 1)).ravel(), (h * audit.GAUSS_WEIGHTS).ravel()
        got = audit._nodes(t)
        assert got[0].tobytes() == want[0].tobytes() and got[1].tobytes() == want[1].tobytes()
    nodes, weights = audit._nodes(np.array([0.0, 2.0]))
    assert np.allclose(nodes, 1 + audit.GAUSS_NODES) and weights.sum() == pytest.approx(2.0, rel=1e-15)


@pytest.mark.parametrize("form", ["contd8", "scipy"])
def test_rows_of_random_coefficients_give_the_interpolants_states_to_the_bit(form):
    """Synthetic rows (random coefficients of 1 to 5 components, 1 to 6 steps, steps from 1e-9 s to
    0.3 s at times up to 1e3 s): the states read off the rows, on floats and on arrays, are each step's
    interpolant's (formed from its row), bit for bit, at 4 times strictly inside each step."""
    rng = np.random.default_rng(11 if form == "contd8" else 12)
    make = integrators.contd8_row_dense if form == "contd8" else integrators.scipy_row_dense
    for _ in range(300):
        n, steps = int(rng.integers(1, 6)), int(rng.integers(1, 7))
        t = np.cumsum(np.concatenate([[rng.uniform(-1, 1) * 10.0 ** rng.integers(0, 4)],
                                      10.0 ** rng.uniform(-9, -0.5, steps)]))
        kept = []
        for k in range(steps):
            coefficients = rng.standard_normal(8 * n) * 10.0 ** rng.integers(-3, 3, 8 * n)
            head = [t[k], t[k + 1] - t[k]] if form == "contd8" else [t[k], t[k + 1]]
            kept.append(integrators._Row(np.concatenate([head, coefficients]), make))
        y = rng.standard_normal((n, steps + 1))
        x = np.sort(rng.uniform(0.01, 0.99, (steps, 4)), axis=1)
        times = (t[:-1, None] + (t[1:] - t[:-1])[:, None] * x).ravel()
        k_of = np.repeat(np.arange(steps), 4)
        inside = (times > t[k_of]) & (times < t[k_of + 1])
        times, k_of = times[inside], k_of[inside]
        if not times.size:
            continue
        formed = [(lambda s: lambda fun: s)(e(None)) for e in kept]
        want = np.stack([formed[k](None)(ti) for ti, k in zip(times, k_of)], axis=1)
        floats = dense.states_on_rows(t, y, times, k_of, kept)
        arrays = dense._row_states(kept, k_of, times)
        assert floats.tobytes() == want.tobytes() and arrays.tobytes() == want.tobytes()
