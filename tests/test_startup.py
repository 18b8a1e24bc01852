"""A plain ``pcmm run`` imports only what it uses (issue 26, item 4: start-up within 2x of
``import pinocchio``; benchmarks/startup.py measures it).  Timings are not asserted: what is
asserted is the list of modules a run leaves in ``sys.modules``, so a module-level import of a
view, a study backend or a scipy package that the run does not need fails here instead of
silently costing the start-up again.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

# Run the command line's own entry point, then list every module the process imported.
_DUMP = """
import json, sys
from pcmm.cli import main
try:
    code = main(sys.argv[2:])
finally:
    with open(sys.argv[1], "w") as fh:
        json.dump(sorted(sys.modules), fh)
sys.exit(code)
"""

# Optional extras and views a plain run must not load (figures only with --plots, the replay
# only with --replay, a progress bar only on a terminal, dask/pyarrow/zarr only for studies).
NEVER = ("matplotlib", "meshcat", "tqdm", "dask", "distributed", "pyarrow", "zarr", "pandas",
         "pcmm.viz", "pcmm.studies")

# scipy packages whose __init__ a plain run must not run: each imports scipy's array-API layer
# (0.2-0.3 s of CPU); the run loads the few compiled parts it needs alone (pcmm/_scipy.py).
# (scipy's own __init__, 15 ms, and numpy.random, 13 ms, are not needed either.)
NOT_INITIALISED = ("scipy", "scipy.integrate", "scipy.linalg", "scipy.optimize", "scipy.sparse", "scipy.special",
                   "scipy._lib._array_api", "numpy.random")


def modules_of_run(tmp_path, *args) -> list[str]:
    out = tmp_path / "modules.json"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p))
    proc = subprocess.run([sys.executable, "-c", _DUMP, str(out), "run", *args], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads(out.read_text())


def loaded(modules, prefix) -> list[str]:
    return [m for m in modules if m == prefix or m.startswith(prefix + ".")]


@pytest.fixture(scope="module")
def plain_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("startup")
    return modules_of_run(tmp, str(ROOT / "examples" / "three_bar.toml"), "--out", str(tmp / "run"), "--quiet")


@pytest.mark.parametrize("name", NEVER)
def test_plain_run_does_not_import(plain_run, name):
    assert not loaded(plain_run, name), f"a plain 'pcmm run' imported {loaded(plain_run, name)[:5]}"


@pytest.mark.parametrize("name", NOT_INITIALISED)
def test_plain_run_does_not_initialise(plain_run, name):
    assert name not in plain_run, f"a plain 'pcmm run' ran {name}'s __init__"


def test_a_run_with_loops_initialises_no_scipy_package(tmp_path):
    """Example 2 (closed loops: partitioned coordinates, the method DOP853, a pivoted QR for the
    partition) for its first 0.05 s: no scipy package's __init__ either."""
    modules = modules_of_run(tmp_path, str(ROOT / "examples" / "double_folded.toml"), "--t-end", "0.05",
                             "--out", str(tmp_path / "run"), "--quiet")
    assert "pcmm.model.partitioned" in modules and "scipy.linalg._flapack" in modules
    assert not [name for name in NOT_INITIALISED if name in modules]


def test_the_dump_sees_what_a_run_imports(plain_run):
    """The dump is real: the run's own modules (Pinocchio, the run loop) are in it."""
    assert "pinocchio" in plain_run and "pcmm.run.loop" in plain_run and "numpy" in plain_run
    assert "pcmm.model._tree_dynamics" in plain_run and "scipy.linalg._flapack" in plain_run  # the parts alone
    # (the compiled segment loop steps a tree: scipy.integrate._ode is loaded only without it)


# The parts that replace scipy's on a run's path compute the same bits as scipy's own.

def _oscillator(t, y):
    """A damped, driven pendulum: a state of 4 with a fast and a slow mode."""
    return np.array([y[2], y[3], -9.0 * np.sin(y[0]) - 0.1 * y[2] + np.cos(3 * t),
                     -400.0 * y[1] - 0.5 * y[3] + 2.0 * np.sin(y[0])])


@pytest.mark.parametrize("rtol,atol,h", [(1e-10, 1e-12, 0.05), (1e-6, 1e-8, 0.3), (1e-3, 1e-6, 2.0), (1e-12, 1e-14, 0.5)])
def test_dop853_dense_step_has_scipys_bits(rtol, atol, h):
    """pcmm.ode.dop853 against scipy.integrate.DOP853 started with the same step: every step end
    and every dense value identical; the larger steps are split (rejected and re-taken), and the
    joined pieces read like scipy's OdeSolution."""
    from scipy.integrate import DOP853, OdeSolution
    from pcmm.ode.dop853 import dense_step
    y0 = np.array([0.3, -0.01, 0.2, 1.5])
    t0 = 0.25
    t1 = t0 + h
    ref = DOP853(_oscillator, t0, y0, t1, rtol=rtol, atol=atol, first_step=t1 - t0)
    ts, pieces = [t0], []
    while ref.status == "running":
        assert ref.step() is None
        ts.append(ref.t)
        pieces.append(ref.dense_output())
    expected = pieces[0] if len(pieces) == 1 else OdeSolution(ts, pieces)
    sol, message = dense_step(_oscillator, t0, y0, t1, rtol, atol)
    assert message is None
    grid = np.concatenate([np.linspace(t0, t1, 37), ts])
    assert np.array_equal(sol(grid), expected(grid))
    for t in grid[::5]:
        assert np.array_equal(sol(t), expected(t))
    if h >= 0.3:  # (the test's own premise: the pieces are exercised)
        assert len(pieces) > 1


def test_brentq_has_scipys_bits():
    """pcmm.ode.roots.brentq against scipy.optimize.brentq: the same root, bit for bit, on
    guards of every shape and tolerances from 1e-15 to 1e-3, and the same failures."""
    from scipy.optimize import brentq as scipy_brentq
    from pcmm.ode.roots import brentq
    rng = np.random.default_rng(7)
    guards = [lambda x: np.sin(x) - 0.3, lambda x: x ** 3 - 2 * x - 5, lambda x: np.exp(x) - 2,
              lambda x: (x - 1.3) ** 5, lambda x: np.tanh(20 * (x - 0.7)), lambda x: np.cos(x) - x,
              lambda x: 1e-12 * (x - 0.123456789)]
    compared = failures = 0
    for g in guards:
        for a, b, tol in zip(rng.uniform(-3, 1, 60), rng.uniform(1, 4, 60), 10 ** rng.uniform(-15, -3, 60)):
            if g(a) * g(b) > 0:
                continue
            results = []
            for solve in (scipy_brentq, brentq):
                try:
                    results.append(solve(g, a, b, xtol=tol, rtol=4 * np.finfo(float).eps))
                except RuntimeError:
                    results.append("no convergence")
            assert results[0] == results[1], (a, b, tol, results)
            compared += 1
            failures += results[0] == "no convergence"
    assert compared > 300
    with pytest.raises(ValueError, match="different signs"):
        brentq(lambda x: x * x + 1, -1.0, 1.0)
    with pytest.raises(ValueError, match="NaN"):
        brentq(lambda x: np.nan, -1.0, 1.0)


def test_scipy_parts_are_scipys_own_objects():
    """The parts pcmm._scipy loads alone are the very objects the ordinary imports give."""
    code = ("import sys; from pcmm import _scipy; L = _scipy.lapack(); o = _scipy.ode(); "
            "c = _scipy.dop853_coefficients(); assert 'scipy.integrate' not in sys.modules; "
            "assert 'scipy.linalg' not in sys.modules; "
            "import scipy.linalg.lapack as la, scipy.integrate as si; "
            "from scipy.integrate._ivp import dop853_coefficients as c2; "
            "assert la.dpotrf is L.dpotrf and la.dpotrs is L.dpotrs and la.dgesv is L.dgesv; "
            "assert si.ode is o and c2 is c and si.quad is not None; print('same')")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p))
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert proc.stdout.strip() == "same", proc.stderr


def test_minimize_bounded_has_scipys_bits():
    """pcmm.ode.roots.minimize_bounded against scipy's minimize_scalar(method="bounded"): the
    same minimiser, bit for bit, on smooth, kinked and flat functions and tolerances from 1e-14
    to 1e-3 (and the budget of evaluations hit alike)."""
    from scipy.optimize import minimize_scalar
    from pcmm.ode.roots import minimize_bounded
    rng = np.random.default_rng(11)
    functions = [lambda x: (x - 0.3) ** 2, lambda x: np.sin(3 * x), lambda x: abs(x - 0.123456),
                 lambda x: -np.exp(-((x - 1.7) / 0.01) ** 2), lambda x: 1.0, lambda x: x ** 4 - x,
                 lambda x: np.cos(40 * x) + 0.1 * x]
    for fun in functions:
        for lo, width, tol in zip(rng.uniform(-2, 2, 30), 10 ** rng.uniform(-6, 1, 30), 10 ** rng.uniform(-14, -3, 30)):
            hi = lo + width
            for maxiter in (500, 7):
                ref = minimize_scalar(fun, bounds=(lo, hi), method="bounded", options={"xatol": tol, "maxiter": maxiter})
                assert minimize_bounded(fun, lo, hi, xatol=tol, maxiter=maxiter) == float(ref.x), (lo, hi, tol, maxiter)


@pytest.mark.parametrize("rtol,atol,max_step", [(1e-10, 1e-12, np.inf), (1e-6, 1e-9, 0.05), (1e-3, 1e-6, np.inf)])
def test_dop853_method_steps_as_scipys(rtol, atol, max_step):
    """The method DOP853 (pcmm.ode.dop853.DOP853) against scipy.integrate.DOP853 over a whole
    interval from scipy's own first step: every accepted step, derivative and dense value
    identical."""
    from scipy.integrate import DOP853 as ScipyDOP853
    from pcmm.ode.dop853 import DOP853
    y0 = np.array([0.3, -0.01, 0.2, 1.5])
    ours, ref = (cls(_oscillator, 0.0, y0, 3.0, max_step=max_step, rtol=rtol, atol=atol) for cls in (DOP853, ScipyDOP853))
    steps = 0
    while ref.status == "running":
        assert ours.step() == ref.step()
        assert (ours.t, ours.status) == (ref.t, ref.status)
        assert np.array_equal(ours.y, ref.y) and np.array_equal(ours.f, ref.f)
        grid = np.linspace(ref.t_old, ref.t, 5)
        assert np.array_equal(ours.dense_output()(grid), ref.dense_output()(grid))
        steps += 1
    assert ours.status == "finished" and steps > 10


def test_pivots_are_scipys():
    """pcmm.model.rows.pivots against scipy.linalg.qr(A, pivoting=True)'s: the same column
    order on full-rank, badly scaled and rank-deficient (repeated columns) Jacobians."""
    import scipy.linalg as sla
    from pcmm.model.rows import pivots
    rng = np.random.default_rng(5)
    for m in range(1, 5):
        for k in range(m, 8):
            for _ in range(20):
                A = rng.normal(size=(m, k)) * 10 ** rng.uniform(-3, 3, size=k)
                if rng.random() < 0.3:
                    A[:, rng.integers(k)] = A[:, 0]
                assert np.array_equal(pivots(A), sla.qr(A, pivoting=True)[2])
    assert pivots(np.zeros((2, 0))).size == 0
