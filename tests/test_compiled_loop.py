"""The compiled segment loop (pcmm/model/_segment_loop.hpp): Hairer's DOP853 stepping a tree's
compiled right-hand side in C++.  It must be the Fortran code DOP853F ran before (the same steps),
its dense output must be DOP853's 7th-order interpolant (scipy's, to round-off), and the runs it
drives must be the Python-stepped runs (events to 1e-12 s, states to 1e-10)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate as si

from pcmm.model import compiled

td = compiled._tree_dynamics
needs_loop = pytest.mark.skipif(td is None or not hasattr(td, "SegmentLoop"),
                                reason=f"the compiled segment loop is not built: {compiled.why_not()}")

# whole runs use it only where the compiled right-hand side runs (not under PCMM_COMPILED=0)
runs_loop = pytest.mark.skipif(td is None or not hasattr(td, "SegmentLoop") or not compiled.enabled(),
                               reason=f"the compiled evaluations are off: {compiled.why_not()}")

K, MASS = 4.0, 1.5  # a slider on a spring: x'' = -(K / MASS) x
W = np.sqrt(K / MASS)
NO_GUARDS = (np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0))


def _oscillator():
    """A prismatic joint along x with a spring of stiffness K (the force elements' KD row), no gravity."""
    tree = td.Tree()
    tree.add_joint("JointModelPX", 0, np.eye(3), np.zeros(3), np.zeros(3), 0.0)
    tree.set_inertia(1, MASS, np.zeros(3), 0.1 * np.eye(3))
    tree.finalize(np.zeros(3), np.zeros(1), np.array([[K, 0.0]]))
    return tree


def _exact(t, x0=1.0, v0=0.5):
    t = np.asarray(t, float)
    return np.array([x0 * np.cos(W * t) + v0 / W * np.sin(W * t), -x0 * W * np.sin(W * t) + v0 * np.cos(W * t)])


def contd8(t_old, h, cont, t):
    """Hairer's contd8 on the coefficients dense() returns (the integrator's own reading of them is
    pcmm.ode.integrators._Contd8; this one is written from dop853.f independently)."""
    s = (np.asarray(t, float) - t_old) / h
    s1 = 1.0 - s
    c = cont[:, :, None] if s.ndim else cont
    par = c[4] + s * (c[5] + s1 * (c[6] + s * c[7]))
    return c[0] + s * (c[1] + s1 * (c[2] + s * (c[3] + s1 * par)))


@needs_loop
def test_the_steps_are_hairers_fortran_steps():
    """The same accepted steps as scipy's ode('dop853') (the Fortran code) with pcmm's beta, to the
    last bit on this problem, and the end state the closed form's to the tolerance."""
    y0 = _exact(0.0)
    fortran = []
    ode = si.ode(lambda t, y: [y[1], -K / MASS * y[0]]).set_integrator("dop853", rtol=1e-10, atol=1e-12,
                                                                       nsteps=100000, beta=0.04)
    ode.set_solout(lambda t, y: fortran.append((t, *y)))
    ode.set_initial_value(y0, 0.0)
    ode.integrate(10.0)
    loop = td.SegmentLoop(_oscillator(), 0.0, y0, 10.0, 1e-10, 1e-12, np.inf, 100000, 0.04, *NO_GUARDS, False)
    assert loop.run() == 0
    steps = loop.take()
    fortran = np.array(fortran[1:])  # the first call is at t0, before any step
    assert steps.shape == fortran.shape and steps.shape[0] > 50
    np.testing.assert_allclose(steps, fortran, rtol=1e-15, atol=1e-15)
    assert steps[-1, 0] == 10.0
    np.testing.assert_allclose(steps[-1, 1:], _exact(10.0), atol=1e-8)
    evaluations, attempts, accepted, rejected = loop.counts()
    assert accepted == steps.shape[0] and attempts == accepted + rejected
    assert evaluations == 2 + 11 * attempts + accepted  # f(t0), hinit's one, 11 stages, the last on acceptance


@needs_loop
def test_dense_output_is_dop853s_interpolant():
    """Every step's dense output against scipy's DOP853 dense output over the same step (the same
    7th-order interpolant: round-off apart) and against the closed form (to the tolerance)."""
    y0 = _exact(0.0)
    loop = td.SegmentLoop(_oscillator(), 0.0, y0, 3.0, 1e-10, 1e-12, np.inf, 100000, 0.04, *NO_GUARDS, True)
    rhs = lambda t, y: np.array([y[1], -K / MASS * y[0]])  # noqa: E731
    worst_scipy = worst_exact = 0.0
    n = 0
    while loop.run() == 1:
        t_old, t_new, y_new, f_new = loop.candidate()
        np.testing.assert_array_equal(f_new, rhs(t_new, y_new))
        t_a, h, cont = loop.dense()
        assert t_a == t_old and abs(t_old + h - t_new) <= 4e-16 * max(1.0, t_new)
        ts = np.linspace(t_old, t_new, 9)
        ours = contd8(t_a, h, cont, ts)
        y_old = contd8(t_a, h, cont, t_old)
        np.testing.assert_allclose(contd8(t_a, h, cont, t_new), y_new, rtol=0, atol=1e-15)
        step = si.DOP853(rhs, t_old, y_old, t_new + 1.0, rtol=1e-10, atol=1e-12, first_step=h)
        step.step()
        assert step.t == t_new
        worst_scipy = max(worst_scipy, np.max(np.abs(ours - step.dense_output()(ts))))
        worst_exact = max(worst_exact, np.max(np.abs(ours - _exact(ts))))
        n += 1
    assert n > 15
    assert worst_scipy < 1e-14  # round-off: the states are of order one
    assert worst_exact < 1e-8   # the global error at rtol 1e-10 over 3 s


# ---- whole runs: the compiled loop against the Python-stepped Fortran code, the reference ---------------------------
def _simulate(path, monkeypatch, loops: dict):
    """A run with the integrators' compiled loops set to ``loops`` ({} : the Python-stepped Fortran
    DOP853, with the same compiled right-hand side)."""
    import pcmm
    from pcmm.ode import integrators
    monkeypatch.setattr(integrators, "SEGMENT_LOOPS", loops)
    monkeypatch.setattr(compiled, "_register_segment_loop", lambda *args: None)
    return pcmm.simulate(pcmm.load_scene(path))


def _both_paths(path, monkeypatch):
    """(the run through the compiled tree loop, the Python-stepped run, the every_step flag of each
    compiled loop made: True where a guard not affine in the state has Python scan every step)."""
    made = []

    def counting(*args):
        made.append(args[-1])
        return td.SegmentLoop(*args)
    fast = _simulate(path, monkeypatch, {td.Tree: counting})
    return fast, _simulate(path, monkeypatch, {}), made


# the shipped examples with tree configurations integrated by DOP853F (the rimless wheel's and the
# compass gait's configurations all hold a pinned foot, a cut joint: scipy's DOP853 steps those)
TREE_EXAMPLES = ["three_bar.toml", "three_bar_stop.toml"]


@runs_loop
@pytest.mark.parametrize("scene", TREE_EXAMPLES)
def test_whole_runs_are_the_python_stepped_runs(monkeypatch, scene):
    """The same events at the same times (1e-12 s), the same recorded steps and states (1e-10),
    where the compiled loop integrates the segments it can."""
    from builders import EXAMPLES
    path = EXAMPLES / scene
    fast, slow, made = _both_paths(path, monkeypatch)
    assert made, "no segment ran the compiled loop"
    assert len(fast.events) >= 1
    assert [e["name"] for e in fast.events] == [e["name"] for e in slow.events]
    for a, b in zip(fast.events, slow.events, strict=True):
        assert abs(a["t"] - b["t"]) <= 1e-12
    assert len(fast.segments) == len(slow.segments)
    for a, b in zip(fast.segments, slow.segments):
        assert a.t.shape == b.t.shape
        np.testing.assert_allclose(a.t, b.t, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-10)
        np.testing.assert_allclose(a.v, b.v, rtol=0, atol=1e-10)
    assert fast.stats["steps"] == slow.stats["steps"]


@runs_loop
def test_a_guard_not_affine_in_the_state_is_scanned_by_python_at_every_step(tmp_path, monkeypatch):
    """A pendulum falling onto a stop watched by its contact gap (not affine in the state): the
    compiled loop hands every accepted step to the Python event scanner, and the run is the
    Python-stepped one (impacts to 1e-12 s, steps to 1e-10)."""
    from builders import pendulum
    path = pendulum(tmp_path, 0.5, q0=0.3, t_end=1.0)
    text = path.read_text()
    coordinate = '[transitions.guard]\ntype = "coordinate"\nvalue = -1.5707963267948966\n'
    assert coordinate in text
    text = text.replace(coordinate, '[transitions.guard]\ntype = "gap"\nvalue = 0.0\n')
    path.write_text(text.replace('[transitions.guard.measure]\njoint = "J1"\n', ""))
    fast, slow, made = _both_paths(path, monkeypatch)
    assert made and all(made)  # every step through Python: the gap is not affine
    assert len(fast.events) >= 1 and fast.events[0]["name"] == "stop"
    for a, b in zip(fast.events, slow.events, strict=True):
        assert a["name"] == b["name"] and abs(a["t"] - b["t"]) <= 1e-12
    for a, b in zip(fast.segments, slow.segments, strict=True):
        np.testing.assert_allclose(a.t, b.t, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-10)
        np.testing.assert_allclose(a.v, b.v, rtol=0, atol=1e-10)


@runs_loop
@pytest.mark.parametrize("budget", [20, 37])
def test_a_spent_step_budget_stops_both_paths_alike(monkeypatch, budget):
    """More steps than solver.max_steps: the same error at the same step, with the steps taken
    kept in the partial run (Example 1: within its first segment, and just after the latch)."""
    import pcmm
    from builders import EXAMPLES
    from pcmm.errors import SimulationError
    from pcmm.ode import integrators
    monkeypatch.setattr(compiled, "_register_segment_loop", lambda *args: None)
    scene = pcmm.load_scene(EXAMPLES / "three_bar.toml")
    outcomes = []
    for loops in ({td.Tree: td.SegmentLoop}, {}):
        monkeypatch.setattr(integrators, "SEGMENT_LOOPS", loops)
        with pytest.raises(SimulationError) as caught:
            pcmm.simulate(scene, pcmm.RunOptions(max_steps=budget))
        assert f"more than {budget} steps" in str(caught.value)
        outcomes.append((str(caught.value), caught.value.partial.segments[-1].t))
    (fast, t_fast), (slow, t_slow) = outcomes
    assert fast == slow
    assert t_fast.size == t_slow.size > 1
    np.testing.assert_allclose(t_fast, t_slow, rtol=0, atol=1e-12)


@runs_loop
def test_a_time_guard_is_scanned_in_the_loop(tmp_path, monkeypatch):
    """Example 1 let go from its latched configuration by a timer at 0.5 s (a time guard: affine,
    scanned in C++), where it latches again at once: the events are the Python-stepped run's, and
    so is every segment's end state (1e-10).  (The segment after the second latch starts from a
    state 4e-16 away, the release read on another dense output, at 46 rad/s: there the two runs'
    step times drift apart by up to 3e-10 s while their states agree to 2e-12.)"""
    from builders import copy_example, example_text
    text = example_text() + ('\n[[transitions]]\nname = "let go"\ntype = "release"\nfrom = "config2"\n'
                             'to = "config1"\nguard = { type = "time", at = 0.5 }\n')
    path = copy_example(tmp_path, "three_bar.toml", text)
    fast, slow, made = _both_paths(path, monkeypatch)
    assert len(made) >= 3 and not any(made)  # every segment scanned in C++
    names = [e["name"] for e in fast.events]
    assert names[:2] == ["O3 latches", "let go"] and names == [e["name"] for e in slow.events]
    assert fast.events[1]["t"] == pytest.approx(0.5, abs=1e-12)
    for a, b in zip(fast.events, slow.events, strict=True):
        assert abs(a["t"] - b["t"]) <= 1e-12
    for a, b in zip(fast.segments, slow.segments, strict=True):
        assert a.t[-1] == pytest.approx(b.t[-1], abs=1e-12)
        np.testing.assert_allclose(a.q[[0, -1]], b.q[[0, -1]], rtol=0, atol=1e-10)
        np.testing.assert_allclose(a.v[[0, -1]], b.v[[0, -1]], rtol=0, atol=1e-10)


@pytest.mark.parametrize("scene", TREE_EXAMPLES)
def test_a_guards_affine_form_is_its_value(scene):
    """Guard.affine (what the compiled loop scans) against the guard's own value and rate, at random
    states of every tree configuration a shipped example's transitions watch; and None where the
    value is not affine (re-armed after a bounce).  The loop relies on it without checking."""
    import pcmm
    from builders import EXAMPLES
    from pcmm.events.guards import make_guard
    from pcmm.model.mechanism import Mechanism
    sc = pcmm.load_scene(EXAMPLES / scene)
    mech = Mechanism(sc)
    rng = np.random.default_rng(26)
    checked = 0
    for tr in sc.transitions:
        cfg = mech[tr.source]
        if cfg.coords.constrained:
            continue
        guard = make_guard(cfg, tr, context=0.3)
        c, ct, d = guard.affine
        c = np.zeros(2 * cfg.nv) if c is None else c
        for _ in range(5):
            t, y = rng.uniform(0.0, 2.0), rng.uniform(-3.0, 3.0, 2 * cfg.nv)
            f = np.concatenate([y[cfg.nv:], rng.uniform(-5.0, 5.0, cfg.nv)])  # [q' = v, any acceleration]
            assert guard(t, y) == pytest.approx(c @ y + ct * t + d, rel=1e-15, abs=1e-15)
            assert guard.rate(t, y, f) == pytest.approx(c @ f + ct, rel=1e-15, abs=1e-15)
        assert make_guard(cfg, tr, rearm=True, context=0.3).affine is None
        checked += 1
    assert checked >= 1


# ---- drives without loops: prescribed coordinates, the right-hand side compiled whole ---------------------------------
G = 9.81


def _cart_state(t, coefficients):
    """x(t), x'(t), x''(t) of the cart's drive (a polynomial, low order first), by hand."""
    c = np.asarray(coefficients, float)
    x = sum(ck * t**k for k, ck in enumerate(c))
    x1 = sum(k * ck * t**(k - 1) for k, ck in enumerate(c) if k >= 1)
    x2 = sum(k * (k - 1) * ck * t**(k - 2) for k, ck in enumerate(c) if k >= 2)
    return x, x1, x2


@runs_loop
def test_a_driven_carts_compiled_right_hand_side_is_the_closed_form(tmp_path):
    """The cart's x(t) prescribed (a cubic: its f'' varies), the bar free on it: the compiled rhs is
    (m L^2 / 3) q'' = -m g (L/2) cos q + m x'' (L/2) sin q, and rhs_with_power's last entry the drive
    force's power F x' with F = (m_cart + m) x'' - m (L/2) (q'' sin q + q'^2 cos q) (no force
    element): both derived by hand, at random states and times."""
    import pcmm
    from builders import driven_cart_pendulum
    from pcmm.model.mechanism import Mechanism
    coefficients, m, L, m_cart = (0.1, 0.2, 0.9, -0.4), 0.8, 0.5, 1.3
    cfg = Mechanism(pcmm.load_scene(driven_cart_pendulum(tmp_path, coefficients, m=m, L=L, m_cart=m_cart)))["swing"]
    coords = cfg.coords
    assert coords.evaluations == "compiled" and coords._compiled_drives() is not None
    assert list(coords.I) == [cfg.joint_slice["J1"].start] and list(coords.D) == [cfg.joint_slice["X"].start]
    rng = np.random.default_rng(26)
    for _ in range(8):
        t, q, w = rng.uniform(0.0, 2.0), rng.uniform(-3.0, 3.0), rng.uniform(-4.0, 4.0)
        _, x1, x2 = _cart_state(t, coefficients)
        qdd = (-m * G * L / 2 * np.cos(q) + m * x2 * L / 2 * np.sin(q)) / (m * L * L / 3)
        force = (m_cart + m) * x2 - m * L / 2 * (qdd * np.sin(q) + w * w * np.cos(q))
        y = np.array([q, w])
        np.testing.assert_allclose(coords.rhs(t, y), [w, qdd], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(coords.rhs_with_power(t, np.append(y, 0.3)), [w, qdd, force * x1], rtol=1e-12,
                                   atol=1e-12)
        # and the Python evaluation it replaces, to round-off
        np.testing.assert_allclose(coords.rhs(t, y), coords._python_rhs(t, y), rtol=1e-14, atol=1e-14)


def _drive_scene(name, tmp_path):
    from builders import EXAMPLES, driven_cart_pendulum
    return driven_cart_pendulum(tmp_path) if name == "cart" else EXAMPLES / name


@runs_loop
@pytest.mark.parametrize("scene", ["cart", "three_bar_cycle.toml"])
def test_drive_runs_with_the_compiled_right_hand_side_are_the_python_runs(tmp_path, monkeypatch, scene):
    """Every configuration with drives and a free coordinate evaluates its right-hand side compiled
    (before issue 26's drives: 'python: not compiled: drives only'), and the run is the Python
    evaluations' run (PCMM_COMPILED=0): the same events at the same times (1e-12 s), the same steps,
    states to 1e-10. The impulses are solved in Python in both runs: the compiled impulse agrees with
    it to round-off, which three_bar_cycle's accumulations amplify to ~5e-10 s (a one-ulp nudge of
    the Python run does the same; tests/test_compiled_impulse.py holds it to that), and this test is
    about the right-hand side.  Both are stepped by pcmm's DOP853 in Python (the method "DOP853"):
    "auto" steps them in the compiled loop, round-off apart (tests/test_compiled_holding.py)."""
    import pcmm
    import pcmm.events.impulse as impulse
    monkeypatch.setattr(impulse, "compiled_impulse", lambda cfg, plan: None)
    path = _drive_scene(scene, tmp_path)
    options = pcmm.RunOptions(method="DOP853")
    fast = pcmm.simulate(pcmm.load_scene(path), options)
    driven = {name for name, why in fast.stats["evaluations"].items()}
    assert driven and all(why == "compiled" or why.endswith("every coordinate driven")
                          for why in fast.stats["evaluations"].values()), fast.stats["evaluations"]
    assert "compiled" in fast.stats["evaluations"].values()
    monkeypatch.setenv("PCMM_COMPILED", "0")
    slow = pcmm.simulate(pcmm.load_scene(path), options)
    assert all(why.startswith("python") for why in slow.stats["evaluations"].values())
    assert len(fast.events) >= 4
    assert [e["name"] for e in fast.events] == [e["name"] for e in slow.events]
    for a, b in zip(fast.events, slow.events, strict=True):
        assert abs(a["t"] - b["t"]) <= 1e-12
    assert fast.stats["steps"] == slow.stats["steps"]
    assert len(fast.segments) == len(slow.segments)
    for a, b in zip(fast.segments, slow.segments):
        assert a.t.shape == b.t.shape
        np.testing.assert_allclose(a.t, b.t, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-10)
        np.testing.assert_allclose(a.v, b.v, rtol=0, atol=1e-10)


@runs_loop
def test_dop853f_steps_a_driven_configuration_in_the_compiled_loop(tmp_path, monkeypatch):
    """Under DOP853F the driven cart's segments (its flights between bounces with their work appended:
    rhs_with_power) run in the compiled loop (Hairer's steps, the stages at their own times), and the
    run is the Python-stepped Fortran code's: the first segment's steps to 1e-12 s, events to 1e-12 s,
    every segment's end states to 1e-10.  (After a bounce the two restart from impact states located
    on different dense outputs, contd8 against scipy's re-taken step, a few ulp apart; at rtol 1e-10
    the error estimate of a step is of round-off size, so their steps part, by up to 6e-9 s in the
    flights' step times, while the states at the events agree: as for a tree: test_a_time_guard_is_scanned_in_the_loop)"""
    from builders import driven_cart_pendulum
    from pcmm.model.partitioned import PartitionedCoordinates, _drive_segment_loop
    path = driven_cart_pendulum(tmp_path, solver={"method": "DOP853F", "rtol": 1e-10, "atol": 1e-12})
    made = []

    def counting(*args, **options):
        made.append(options)
        return _drive_segment_loop(*args, **options)
    fast = _simulate(path, monkeypatch, {td.Tree: td.SegmentLoop, PartitionedCoordinates: counting})
    slow = _simulate(path, monkeypatch, {})
    assert len(made) == len(fast.events) + 1  # every segment of 'swing' (the last: to t_end)
    assert sum(1 for o in made if o.get("power")) == len(fast.events)  # the flights after each bounce
    assert len(fast.events) >= 4 and [e["name"] for e in fast.events] == [e["name"] for e in slow.events]
    for a, b in zip(fast.events, slow.events, strict=True):
        assert abs(a["t"] - b["t"]) <= 1e-12
    first, first_slow = fast.segments[0], slow.segments[0]
    assert first.t.shape == first_slow.t.shape and first.t.size > 5
    np.testing.assert_allclose(first.t, first_slow.t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(first.q, first_slow.q, rtol=0, atol=1e-10)
    for a, b in zip(fast.segments, slow.segments, strict=True):
        assert a.t[-1] == pytest.approx(b.t[-1], abs=1e-12)
        np.testing.assert_allclose(a.q[[0, -1]], b.q[[0, -1]], rtol=0, atol=1e-10)
        np.testing.assert_allclose(a.v[[0, -1]], b.v[[0, -1]], rtol=0, atol=1e-10)


def test_drives_that_cannot_be_compiled_say_why(tmp_path):
    """Where the drives' right-hand side is not compiled, the configuration says why and evaluates in
    Python: every coordinate driven (nothing to integrate), a loop (its Newton solve), point springs
    (not the linear force elements the compiled tree holds); a run there builds no compiled tree."""
    import pcmm
    from builders import EXAMPLES, driven_cart_pendulum
    from pcmm.model.mechanism import Mechanism
    spring = {"name": "tie", "type": "point_spring", "a": "link1", "point_a": [0.5, 0.0], "b": "cart",
              "point_b": [0.0, -0.3], "k": 20.0, "rest": 0.2}
    path = driven_cart_pendulum(tmp_path / "sprung", t_end=0.2, forces=[spring])
    sprung = Mechanism(pcmm.load_scene(path))["swing"].coords
    assert sprung._drives_refused == "point springs" and sprung._compiled_drives() is None
    assert sprung.evaluations == "python: not compiled: point springs"
    compiled.forget_trees()
    run = pcmm.simulate(pcmm.load_scene(path))
    assert run.stats["evaluations"]["swing"] == "python: not compiled: point springs" and compiled.trees_built() == 0
    mech = Mechanism(pcmm.load_scene(driven_cart_pendulum(tmp_path)))
    rest = mech["rest"].coords
    assert rest._drives_refused == "every coordinate driven" and rest._compiled_drives() is None
    assert rest.evaluations == "python: not compiled: every coordinate driven"
    sc = pcmm.load_scene(EXAMPLES / "double_folded.toml")
    looped = [Mechanism(sc)[c.name].coords for c in sc.configurations.values() if sc.drives_in(c.name) and c.cut_joints]
    assert looped and all(c._drives_refused == "loops" and c._compiled_drives() is None for c in looped)


def _sequential_dot(A, x):
    """``A @ x`` (a matrix and a vector, or two matrices) summed term by term in order: numpy's dot
    goes through BLAS, whose kernels sum in another order (and round otherwise)."""
    A, x = np.asarray(A, float), np.asarray(x, float)
    X = x[:, None] if x.ndim == 1 else x
    out = np.zeros((A.shape[0], X.shape[1]))
    for r in range(A.shape[0]):
        for i in range(X.shape[1]):
            acc = 0.0
            for j in range(A.shape[1]):
                acc += A[r, j] * X[j, i]
            out[r, i] = acc
    return out[:, 0] if x.ndim == 1 else out


@needs_loop
def test_with_scipys_tableau_the_loop_steps_as_scipys_dop853(monkeypatch):
    """SegmentLoop(tableau=...) is scipy's DOP853 (pcmm.ode.dop853.DOP853): on the oscillator, the same
    accepted steps to the last bit as that class with its dot products summed in order, and its dense
    output (DenseStep on the loop's F) the same; against numpy's BLAS dot products the steps part at
    the size the error estimate's round-off moves the step-size control (1e-7 here, at rtol 1e-6),
    which is why the method DOP853 is not stepped by it (pcmm.ode.integrators.COMPILED_SCIPY_STEPS)."""
    import types

    from pcmm.ode import dop853
    from pcmm.ode.dop853 import DOP853, DenseStep, packed_tableau
    tree = _oscillator()
    y0 = _exact(0.0)

    def reference():
        ref = DOP853(tree.rhs, 0.0, y0, 10.0, rtol=1e-6, atol=1e-9)
        steps = []
        while ref.status == "running":
            ref.step()
            steps.append((ref.t, *ref.y))
        return np.array(steps)
    with_blas = reference()
    monkeypatch.setattr(dop853, "np", types.SimpleNamespace(**{**vars(np), "dot": _sequential_dot}))
    steps = reference()
    loop = td.SegmentLoop(_oscillator(), 0.0, y0, 10.0, 1e-6, 1e-9, np.inf, 100000, 0.0, *NO_GUARDS, False,
                          tableau=packed_tableau())
    assert loop.run() == 0
    ours = loop.take()
    assert ours.shape == steps.shape == with_blas.shape and ours.shape[0] > 10
    assert ours.tobytes() == steps.tobytes()
    np.testing.assert_allclose(ours, with_blas, rtol=0, atol=1e-6)
    np.testing.assert_allclose(ours[-1, 1:], _exact(10.0), atol=1e-4)
    loop = td.SegmentLoop(_oscillator(), 0.0, y0, 10.0, 1e-6, 1e-9, np.inf, 100000, 0.0, *NO_GUARDS, True,
                          tableau=packed_tableau())
    ref = DOP853(tree.rhs, 0.0, y0, 10.0, rtol=1e-6, atol=1e-9)
    for _ in range(5):
        assert loop.run() == 1
        ref.step()
        dense = DenseStep(*loop.dense())
        ts = np.linspace(ref.t_old, ref.t, 7)
        assert dense(ts).tobytes() == ref.dense_output()(ts).tobytes()


@runs_loop
def test_an_extension_built_without_compiled_drives_falls_back_and_says_so(tmp_path, monkeypatch):
    """An extension built from sources before compiled drives (its Tree has no set_drives: a stale
    build) is refused for drives, with the remedy, and the configuration evaluates in Python."""
    import types

    import pcmm
    from builders import driven_cart_pendulum
    from pcmm.model.mechanism import Mechanism

    class OldTree:  # the extension's Tree as built before: no set_drives, no rhs_with_power
        pass
    monkeypatch.setattr(compiled, "_tree_dynamics", types.SimpleNamespace(**{**vars(compiled._tree_dynamics),
                                                                             "Tree": OldTree}))
    coords = Mechanism(pcmm.load_scene(driven_cart_pendulum(tmp_path)))["swing"].coords
    assert coords._compiled_drives() is None
    assert coords.evaluations.startswith("python: this build of pcmm.model._tree_dynamics has no compiled drives")
    assert "pip install -e ." in coords.evaluations
    y = np.array([0.3, -0.2])
    np.testing.assert_array_equal(coords.rhs(0.4, y), coords._python_rhs(0.4, y))


@runs_loop
def test_a_bouncing_trees_flights_run_compiled_and_are_the_python_runs(tmp_path, monkeypatch):
    """A pendulum on a spring bouncing on a stop (a tree: no loop, no drive): every flight between
    two bounces (its work appended: rhs_with_power) runs the compiled right-hand side in the
    compiled loop (before: TreeCoordinates.rhs_with_power in Python, stepped by Python), and the run
    is the Python evaluations' run (PCMM_COMPILED=0): the same events at the same times (1e-12 s),
    the same number of steps, every segment's end states to 1e-10.  (Inside a flight the step
    times part, as on main before: the first segment's event is located on contd8 against scipy's
    re-taken step, a few ulp apart, and at rtol 1e-10 a step's error estimate is of round-off size;
    measured 3e-8 to 2e-5 s with these flights Python-stepped, 3e-8 to 3e-6 s compiled.)"""
    import pcmm
    from builders import pendulum
    path = pendulum(tmp_path, e=0.5, k=3.0, rest_angle=-2.0, merge=False, t_end=1.4, spring_configurations=["c1"])
    made = []
    real = compiled.segment_loop

    def counting(tree, *args, **options):
        made.append(options.get("power", False))
        return real(tree, *args, **options)
    monkeypatch.setattr(compiled, "segment_loop", counting)
    fast = pcmm.simulate(pcmm.load_scene(path))
    assert fast.stats["evaluations"] == {"c1": "compiled"}
    assert len(fast.events) >= 4
    assert sum(made) == len(fast.events), "a flight between bounces was not stepped by the compiled loop"
    monkeypatch.setenv("PCMM_COMPILED", "0")
    slow = pcmm.simulate(pcmm.load_scene(path))
    assert slow.stats["evaluations"]["c1"].startswith("python")
    assert [e["name"] for e in fast.events] == [e["name"] for e in slow.events]
    for a, b in zip(fast.events, slow.events, strict=True):
        assert abs(a["t"] - b["t"]) <= 1e-12
    assert len(fast.segments) == len(slow.segments) == len(fast.events) + 1
    for a, b in zip(fast.segments, slow.segments, strict=True):
        assert a.t[-1] == pytest.approx(b.t[-1], abs=1e-12)
        np.testing.assert_allclose(a.q[[0, -1]], b.q[[0, -1]], rtol=0, atol=1e-10)
        np.testing.assert_allclose(a.v[[0, -1]], b.v[[0, -1]], rtol=0, atol=1e-10)
    assert fast.stats["steps"] == slow.stats["steps"]


def _spring_pendulum_coords(tmp_path, k=3.0, rest=-2.0, m=1.5, L=0.6):
    import pcmm
    from builders import pendulum
    from pcmm.model.mechanism import Mechanism
    path = pendulum(tmp_path, e=0.5, L=L, m=m, k=k, rest_angle=rest, merge=False, spring_configurations=["c1"])
    return Mechanism(pcmm.load_scene(path))["c1"].coords


@runs_loop
def test_a_trees_compiled_flight_right_hand_side_is_the_closed_form(tmp_path):
    """The compiled rhs_with_power of a spring pendulum (bar m, L on a pivot, torque -k (q - rest)):
    [v, (-m g L/2 cos q - k (q - rest)) / (m L^2 / 3), -k (q - rest) v] (gravity's power is left
    to the potential energy), whatever the work appended."""
    from builders import G
    k, rest, m, L = 3.0, -2.0, 1.5, 0.6
    coords = _spring_pendulum_coords(tmp_path, k, rest, m, L)
    assert coords._compiled_flight() is not None
    for q, v, W in [(0.3, -1.2, 0.0), (-1.1, 2.5, 7.0)]:
        spring = -k * (q - rest)
        expected = [v, (-m * G * L / 2 * np.cos(q) + spring) / (m * L * L / 3), spring * v]
        np.testing.assert_allclose(coords.rhs_with_power(0.0, np.array([q, v, W])), expected, rtol=1e-13, atol=1e-13)


def test_an_extension_built_without_compiled_flights_falls_back_and_says_so(tmp_path, monkeypatch):
    """An extension built before a tree had rhs_with_power (no TREE_POWER: a stale build): a tree's
    flights evaluate in Python, their segment loop is refused (Python steps them), and why_not
    names the remedy."""
    import types

    from pcmm.model.tree import _flight_segment_loop
    if compiled._tree_dynamics is None:
        pytest.skip(f"no compiled extension: {compiled.why_not()}")
    old = {name: value for name, value in vars(compiled._tree_dynamics).items() if name != "TREE_POWER"}
    monkeypatch.setattr(compiled, "_tree_dynamics", types.SimpleNamespace(**old))
    coords = _spring_pendulum_coords(tmp_path)
    if not compiled.enabled():
        pytest.skip(f"the compiled evaluations are off: {compiled.why_not()}")
    assert coords._compiled_flight() is None
    assert "no compiled flights of a tree" in compiled.why_not() and "pip install -e ." in compiled.why_not()
    y = np.array([0.3, -0.2, 1.0])
    np.testing.assert_array_equal(coords.rhs_with_power(0.4, y), coords._python_rhs_with_power(0.4, y))
    with pytest.raises(ValueError, match="no compiled right-hand side"):
        _flight_segment_loop(coords, 0.0, y, 1.0)


@needs_loop
def test_kept_dense_outputs_are_each_steps_own_and_leave_steps_and_counts_alone():
    """With keep_dense (a flight, for its energy audit) the loop forms every accepted step's dense
    output as it accepts it (take_dense(), one row per step): the steps and the evaluation count
    are those of a loop without it; each row is that step's contd8 (its ends the recorded states,
    scipy's DOP853 dense output of the same step to round-off, the closed form to the tolerance);
    at a candidate step, dense() gives the kept row's bits, and counts its 3 evaluations only when
    asked, as a loop without keep_dense does."""
    y0 = _exact(0.0)
    args = (0.0, y0, 3.0, 1e-10, 1e-12, np.inf, 100000, 0.04, *NO_GUARDS)
    plain, kept = td.SegmentLoop(_oscillator(), *args, False), td.SegmentLoop(_oscillator(), *args, False, keep_dense=True)
    assert plain.run() == kept.run() == 0
    steps = plain.take()
    np.testing.assert_array_equal(kept.take(), steps)
    assert kept.counts() == plain.counts()
    rows = kept.take_dense()
    assert rows.shape == (len(steps), 2 + 8 * 2) and len(steps) > 15 and kept.take_dense().shape[0] == 0
    def rhs(t, y):
        return np.array([y[1], -K / MASS * y[0]])
    ends = np.vstack([np.concatenate([[0.0], y0]), steps])
    worst_scipy = 0.0
    for (t_old, *y_old), (t_new, *y_new), row in zip(ends[:-1], ends[1:], rows):
        assert row[0] == t_old
        cont = row[2:].reshape(8, 2)
        ts = np.linspace(t_old, t_new, 9)
        ours = contd8(t_old, row[1], cont, ts)
        np.testing.assert_allclose(ours[:, [0, -1]].T, [y_old, y_new], rtol=0, atol=1e-15)
        step = si.DOP853(rhs, t_old, np.array(y_old), t_new + 1.0, rtol=1e-10, atol=1e-12, first_step=row[1])
        step.step()
        worst_scipy = max(worst_scipy, np.max(np.abs(ours - step.dense_output()(ts))))
        np.testing.assert_allclose(ours, _exact(ts), rtol=0, atol=1e-8)
    assert worst_scipy < 1e-14
    # every step a candidate: dense() at every other one, in both loops
    plain, kept = td.SegmentLoop(_oscillator(), *args, True), td.SegmentLoop(_oscillator(), *args, True, keep_dense=True)
    k = 0
    while plain.run() == 1:
        assert kept.run() == 1
        row = kept.take_dense()
        assert row.shape == (1, 18)
        if k % 2 == 0:
            t_old, h, cont = plain.dense()
            assert kept.dense()[2].tobytes() == cont.tobytes() == row[0, 2:].tobytes() and row[0, 1] == h
        assert kept.counts() == plain.counts()
        k += 1
    assert k > 15
