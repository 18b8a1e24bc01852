"""The per-event glue cut for speed (issue 26, item 2) gives the same bits as the route it replaces.

* The flight audit's states at its Gauss nodes are evaluated at once on the kept steps' DOP853
  polynomials (:func:`pcmm.run.dense._polynomial_states`); the reference is the definition: each
  step's own interpolant called at the times inside it, a recorded state at a step's end.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from builders import driven_cart_pendulum, pendulum

import pcmm
from pcmm.ode.dop853 import DenseStep
from pcmm.ode.integrators import _Contd8, _ScipyDense
from pcmm.run import dense

EXAMPLES = __import__("pathlib").Path(__file__).resolve().parents[1] / "examples"


class _Kept:
    """A kept step (Segment.dense's entries: ``fun -> interpolant``)."""

    def __init__(self, sol):
        self.sol = sol

    def __call__(self, fun):
        return self.sol


def _steps(rng, kind, n, ny):
    """``n`` random steps of increasing time and their interpolants of ``kind`` (random coefficients:
    the evaluation, not the integrator, is under test)."""
    t = np.cumsum(np.concatenate([[rng.uniform(0.0, 2.0)], rng.uniform(1e-3, 0.3, n)]))
    sols = []
    for k in range(n):
        if kind == "contd8" or (kind == "mixed" and k % 2):
            sols.append(_Contd8(t[k], t[k + 1] - t[k], rng.normal(size=(8, ny))))
        elif kind == "scipy dense" or (kind == "dense steps" and k % 2):
            sols.append(_ScipyDense(t[k], t[k + 1], rng.normal(size=ny), rng.normal(size=(7, ny))))
        else:
            sols.append(DenseStep(t[k], t[k + 1], rng.normal(size=ny), rng.normal(size=(7, ny))))
    y = rng.normal(size=(ny, n + 1))
    return t, y, sols


def _reference(t, y, sols, times):
    """Each time on its own step's interpolant, called with the times inside that step; a time on a
    recorded step's end is the recorded state (what dense_states promises)."""
    out = np.empty((y.shape[0], len(times)))
    n = len(t)
    for i, ti in enumerate(times):
        k = min(max(int(np.searchsorted(t, ti, side="right")) - 1, 0), n - 2)
        if ti == t[k]:
            out[:, i] = y[:, k]
        elif ti == t[k + 1]:
            out[:, i] = y[:, k + 1]
    for k, sol in enumerate(sols):
        cols = [i for i, ti in enumerate(times) if min(max(int(np.searchsorted(t, ti, side="right")) - 1, 0), n - 2) == k
                and ti != t[k] and ti != t[k + 1]]
        if cols:
            out[:, cols] = np.asarray(sol(np.asarray(times)[cols]), float).reshape(y.shape[0], len(cols))
    return out


@pytest.mark.parametrize("kind", ["dense step", "scipy dense", "dense steps", "contd8", "mixed"])
@pytest.mark.parametrize("seed", range(6))
def test_states_at_once_are_each_steps_interpolant_to_the_bit(kind, seed):
    rng = np.random.default_rng(seed)
    n, ny = int(rng.integers(1, 6)), int(rng.integers(1, 8))
    t, y, sols = _steps(rng, kind, n, ny)
    kept = [_Kept(s) for s in sols]
    h = np.diff(t) / 2
    nodes = (t[:-1, None] + h[:, None] * (np.polynomial.legendre.leggauss(4)[0] + 1)).ravel()  # the audit's
    cases = [nodes, rng.uniform(t[0], t[-1], 9),  # unsorted
             np.concatenate([nodes[::-1], t, [t[-1], t[0]]]),  # steps' ends among them, in any order
             t[[0, -1]], t[-1:], np.empty(0)]
    for times in cases:
        got = dense.dense_states(t, y, times, (None, None, None), kept)
        want = _reference(t, y, sols, times)
        assert got.shape == want.shape and got.tobytes() == want.tobytes(), (kind, times)


def test_one_form_is_evaluated_at_once_and_any_other_step_by_step(monkeypatch):
    """The at-once route is taken where every step is of one form (else it would not be under test),
    and declines a mixed segment, which goes step by step (the same bits: the test above)."""
    rng = np.random.default_rng(7)
    taken = []
    real = dense._polynomial_states
    monkeypatch.setattr(dense, "_polynomial_states", lambda *a: taken.append(real(*a)) or taken[-1])
    for kind in ("dense step", "dense steps", "contd8", "mixed"):
        t, y, sols = _steps(rng, kind, 4, 3)
        dense.dense_states(t, y, (t[:-1] + t[1:]) / 2, (None, None, None), [_Kept(s) for s in sols])
    assert [x is not None for x in taken] == [True, True, True, False]


def _macro_impacts(path, monkeypatch, at_once: bool):
    with monkeypatch.context() as m:
        if not at_once:
            m.setattr(dense, "_polynomial_states", lambda *a: None)
        return pcmm.simulate(pcmm.load_scene(path)).stats["macro_impacts"]


@pytest.mark.parametrize("scene", ["spring pendulum, compiled", "spring pendulum, DOP853", "driven cart pendulum",
                                   "three_bar_cycle"])
def test_the_audit_is_the_same_to_the_bit(scene, tmp_path, monkeypatch):
    """Every flight's residual, evaluated at once and step by step: the same numbers.  The kept steps
    are contd8 rows (a tree's compiled loop), DOP853's stages (pcmm's DOP853), scipy's ``y_old, F`` rows
    (drives stepped by the compiled loop with scipy's tableau)."""
    if scene.startswith("spring pendulum"):
        solver = {"method": "DOP853"} if scene.endswith("DOP853") else None
        path = pendulum(tmp_path, e=0.5, k=3.0, rest_angle=-2.0, merge=False, t_end=1.4, spring_configurations=["c1"],
                        solver=solver)
    elif scene == "driven cart pendulum":
        path = driven_cart_pendulum(tmp_path, e=0.8, t_end=1.5)
    else:
        path = EXAMPLES / "three_bar_cycle.toml"
    at_once, stepwise = _macro_impacts(path, monkeypatch, True), _macro_impacts(path, monkeypatch, False)
    flights = sum(m["flights"] for m in at_once)
    assert flights >= 3 and any(m["flight_energy_residual_max"] > 0 for m in at_once)
    assert json.dumps(at_once) == json.dumps(stepwise)


def _holding_series(traj):
    """Every segment's derived holding forces and its context's locks and offsets, as values."""
    out = []
    for i, seg in enumerate(traj.segments):
        ctx = traj.segments._contexts[int(traj.segments._row(i)[0])][2]
        out.append((seg.constraint_labels, seg.constraint_forces.tobytes(), seg.q.tobytes(),
                    [h.label for h in ctx.holds.items], sorted(ctx.offsets.items())))
    return out


def test_a_shared_context_keeps_the_locks_and_offsets_of_its_segments(monkeypatch):
    """The recording compares the run's own locks and angle offsets with the latest context and copies
    them only where the log keeps a new one (SegmentContext.kept).  three_bar_cycle's first 2.5 s (locks
    taken and released: O3 held while O2 bounces, and the other way round): every segment's holding
    forces, coordinates, locks and offsets are those of a run where every segment keeps a context of its
    own, copied when it was recorded; and the contexts kept are copies, not the run's objects."""
    from pcmm.run import recording
    opts = pcmm.RunOptions(t_end=2.5)
    shared = pcmm.simulate(pcmm.load_scene(EXAMPLES / "three_bar_cycle.toml"), opts)
    with monkeypatch.context() as m:
        m.setattr(recording.SegmentContext, "__eq__", lambda a, b: False)  # never shared
        own = pcmm.simulate(pcmm.load_scene(EXAMPLES / "three_bar_cycle.toml"), opts)
    n, contexts = len(shared.segments), len(shared.segments._contexts)
    assert len(own.segments._contexts) == len(own.segments) == n > 100 and contexts < n / 5
    held = [c for _, _, c in shared.segments._contexts if c.holds.items]
    assert held and len(held) < contexts  # stays with locks and without
    a, b = _holding_series(shared), _holding_series(own)
    assert a == b
    assert any(r[3] for r in a) and any(not r[3] for r in a)  # segments with locks and without


def test_same_reads_integer_arrays_by_their_bytes_and_floats_by_value():
    """recording._same on a partition's integer indices (compared by bytes) gives ==' s answer; floats
    keep value semantics (-0.0 equals 0.0, NaN is not NaN) and dtypes that differ compare by value."""
    from pcmm.run.recording import _same
    cases = [(np.array([0, 2]), np.array([0, 2]), True), (np.array([0, 2]), np.array([0, 3]), False),
             (np.array([0, 2]), np.array([0, 2, 3]), False), (np.array([0, 2], np.int32), np.array([0, 2]), True),
             (np.array([True, False]), np.array([True, False]), True), (np.array([], int), np.array([], int), True),
             (np.array([0.0]), np.array([-0.0]), True), (np.array([np.nan]), np.array([np.nan]), False),
             ({"I": np.array([1]), "D": np.array([0, 2]), "ny": 2}, {"I": np.array([1]), "D": np.array([0, 2]), "ny": 2},
              True),
             ({"I": np.array([1]), "D": np.array([0, 2]), "ny": 2}, {"I": np.array([2]), "D": np.array([0, 1]), "ny": 2},
              False)]
    for x, y, want in cases:
        assert _same(x, y) is want and _same(y, x) is want, (x, y)


@pytest.mark.parametrize("scene", ["driven cart pendulum", "driven cart pendulum, Python stepping", "three_bar_cycle"])
def test_the_audit_on_the_runs_coordinates_is_the_audit_on_a_reader(scene, tmp_path, monkeypatch):
    """Drives without a loop and every step's dense output kept: the flight's work is read on the run's
    own coordinates (audit.run_work), no reader made.  The same residuals to the bit as on a reader of
    each segment, and the run itself untouched (the same events and samples).  Where a step's dense
    output is formed from its stages (pcmm's DOP853 in Python: the right-hand side is asked) the reader
    is made, as before."""
    from pcmm.run import audit
    if scene.endswith("Python stepping"):
        monkeypatch.setenv("PCMM_COMPILED", "0")
    path = EXAMPLES / "three_bar_cycle.toml" if scene == "three_bar_cycle" else driven_cart_pendulum(tmp_path, e=0.8)
    opts = pcmm.RunOptions(t_end=2.5) if scene == "three_bar_cycle" else pcmm.RunOptions()
    real = audit.run_work
    taken = []
    monkeypatch.setattr(audit, "run_work", lambda *a: taken.append(real(*a)) or taken[-1])
    on_run = pcmm.simulate(pcmm.load_scene(path), opts)
    monkeypatch.setattr(audit, "run_work", lambda *a: None)
    on_reader = pcmm.simulate(pcmm.load_scene(path), opts)
    flights = sum(m["flights"] for m in on_run.stats["macro_impacts"])
    assert flights >= 3 and len(taken) == flights
    if scene.endswith("Python stepping"):
        assert all(w is None for w in taken)
    else:
        assert all(w is not None for w in taken)
    assert json.dumps(on_run.stats["macro_impacts"]) == json.dumps(on_reader.stats["macro_impacts"])
    assert [e["t"] for e in on_run.events] == [e["t"] for e in on_reader.events]
    for a, b in zip(on_run.segments, on_reader.segments, strict=True):
        assert a.t.tobytes() == b.t.tobytes() and a.q.tobytes() == b.q.tobytes() and a.v.tobytes() == b.v.tobytes()


@pytest.mark.parametrize("scene", ["pendulum (a point contact)", "driven cart pendulum (a joint stop with an arm)"])
def test_the_event_records_impulse_is_its_normal_impulse_along_the_normal(scene, tmp_path):
    """events/records.event_dict forms the impulse's vector on Python floats (numpy's products, the
    same bits): P n for a point contact, (M / arm) n for a revolute stop with an arm, to the bit,
    and the record's normal is the impulse's unit normal."""
    if scene.startswith("pendulum"):
        path = pendulum(tmp_path, 0.9, q0=0.0, t_end=2.0)
    else:
        path = driven_cart_pendulum(tmp_path, e=0.8)
    events = [e for e in pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions()).events if e["impact"]]
    assert len(events) >= 2
    for e in events:
        imp, n = e["impulse"], np.array(e["normal"])
        assert abs(np.hypot(*n) - 1.0) < 1e-15 and all(type(x) is float for x in imp["vector"] + e["normal"])
        if "joint" in imp:
            assert imp["normal"] == imp["moment"] / imp["arm"] and imp["moment"] != 0.0
        assert imp["vector"] == [float(np.float64(imp["normal"]) * n[0]) + 0.0, float(np.float64(imp["normal"]) * n[1]) + 0.0]
