"""What the run does between two events is made once where it repeats, with the same bits
(docs/performance.md, "Between events, third round"):

* a fully driven configuration's merges read their guards at its (empty) state in one compiled call
  (``HoldingForces.at_state``, the same Horner sums and solve as ``unpack`` then ``forces``), and such a
  guard's rate starts from its value (``integrators._pure_value``);
* without the compiled evaluations, the guards on one holding-force evaluator share its answer at the
  state asked last, where that is a function of the state alone (``holding._LastState``: those merges,
  two guards at every sample of the known motion);
* ``Holds.applied`` gives the Applied it made last while nothing it is made from changed;
* the recording hands the log the name lists it made last for the configuration;
* the compiled segment loop's guard scans are made once per set of guard objects
  (``integrators._guard_scans``).

Each is checked against the route it replaces: the same events, times and recorded samples to the
bit, and the replaced work counted."""
from __future__ import annotations

import numpy as np
import pytest

from builders import EXAMPLES

import pcmm
from pcmm.events import holding
from pcmm.model.partitioned import PartitionedCoordinates
from pcmm.ode import integrators
from pcmm.run import loop, recording

CYCLE = EXAMPLES / "three_bar_cycle.toml"
# to 3.5 s: the fully driven configuration ("folded") is entered twice and left by the release of a merge
T_END = 3.5


def _run(t_end=T_END):
    return pcmm.simulate(pcmm.load_scene(CYCLE), pcmm.RunOptions(t_end=t_end))


def _fingerprint(run) -> tuple:
    """Everything a run records, as bytes: event times and records, every segment's times and states."""
    events = tuple((ev["t"], ev["name"], ev["kind"], ev["from"], ev["to"]) for ev in run.events)
    segments, log = [], run.segments
    for i in range(len(log)):
        t, y, q_start = log.arrays(i)
        segments.append((log.configuration(i), t.tobytes(), y.tobytes(), q_start.tobytes()))
    return events, tuple(segments), run.stats["steps"], run.stats["rhs_evals"]


class _Unshared(holding._LastState):
    """The route before: every guard asks its evaluator itself, at every call."""

    __slots__ = ()

    def at(self, t, y):
        q, v = self.unpack(t, y)
        return self.forces(t, q, v)


def _impure(e) -> bool:  # the route before: only a compiled holding guard's value stands for itself
    return getattr(e, "holding", None) is not None


def _count_known_motion_solves(monkeypatch) -> tuple[int, int]:
    """(unpacks of the fully driven configuration's coordinates during its known motion, its samples)."""
    counts = {"unpack": 0, "samples": 0}
    inside = [False]
    unpack, known = PartitionedCoordinates.unpack, loop._known_motion

    def counted_unpack(self, t, y):
        counts["unpack"] += inside[0]
        return unpack(self, t, y)

    def counted_known(cfg, t, y0, guards, opts):
        inside[0] = True
        try:
            seg = known(cfg, t, y0, guards, opts)
        finally:
            inside[0] = False
        counts["samples"] += seg.t.size
        return seg
    monkeypatch.setattr(PartitionedCoordinates, "unpack", counted_unpack)
    monkeypatch.setattr(loop, "_known_motion", counted_known)
    return counts


def _no_state_map_without_free_coordinates(monkeypatch):
    """The route before: a fully driven configuration's merges read (t, q, v), not its (empty) state."""
    agrees = holding.compiled.agrees

    def refused(checked, fn, reference, probes, what, key=None):
        if what == "holding forces at the state" and not len(probes[0][1]):
            return False
        return agrees(checked, fn, reference, probes, what, key=key)
    monkeypatch.setattr(holding.compiled, "agrees", refused)


def test_the_merges_of_a_fully_driven_configuration_read_their_guards_in_one_compiled_call(monkeypatch):
    if not holding.compiled.enabled():
        pytest.skip("the compiled extension is not available")
    counts = _count_known_motion_solves(monkeypatch)
    guards = []
    known = loop._known_motion

    def kept(cfg, t, y0, gs, opts):
        guards.append((cfg, t, gs))
        return known(cfg, t, y0, gs, opts)
    monkeypatch.setattr(loop, "_known_motion", kept)
    now = _fingerprint(_run())
    n_now, samples = counts["unpack"], counts["samples"]
    assert samples > 10 and guards
    # each merge's guard reads the compiled evaluator at the state (its `holding`), and gives the Python
    # evaluator's value at the coordinates unpack gives, to the bit, all along the stay
    cfg, t0, gs = guards[0]
    assert len(gs) == 2 and all(g.holding is not None for g in gs)
    y = np.zeros(0)
    for t in np.linspace(t0, t0 + 0.25, 101):
        for g in gs:
            fast, i, offset = g.holding
            q, v = cfg.coords.unpack(t, y)
            python = fast.forces(t, q, v)  # the same solve at the unpacked (q, v)
            assert g(t, y) == float(python[i]) - offset
    counts["unpack"] = counts["samples"] = 0
    with monkeypatch.context() as m:
        _no_state_map_without_free_coordinates(m)
        m.setattr(holding, "_LastState", _Unshared)
        m.setattr(integrators, "_pure_value", _impure)
        guards.clear()
        before = _fingerprint(_run())
        assert all(g.holding is None for g in guards[0][2])
    assert counts["samples"] == samples
    assert now == before  # the same run to the bit: events, times, every segment's samples, steps, evaluations
    # before: each sample's coordinates read by `assemble`, then by each guard at the sample, a forward
    # difference away and at the sample again (its value could not stand for itself); now by `assemble` only
    assert counts["unpack"] > 5 * n_now and n_now <= 1.2 * samples


def test_the_merges_of_a_fully_driven_configuration_share_one_solve_per_state(monkeypatch):
    """With the Python evaluations (PCMM_COMPILED=0): the guards share their evaluator's answer."""
    monkeypatch.setenv("PCMM_COMPILED", "0")
    counts = _count_known_motion_solves(monkeypatch)
    shared = _fingerprint(_run())
    n_shared, samples = counts["unpack"], counts["samples"]
    assert samples > 10
    counts["unpack"] = counts["samples"] = 0
    with monkeypatch.context() as m:
        m.setattr(holding, "_LastState", _Unshared)
        m.setattr(integrators, "_pure_value", _impure)
        before = _fingerprint(_run())
    assert counts["samples"] == samples
    # the same run to the bit: events, times, every segment's samples, steps and evaluations
    assert shared == before
    # two merges, each asked at a sample's state, at the state a forward difference away and again at the
    # sample's state for that difference (the value could not stand for itself): about 7 reads of the
    # coordinates a sample before; now the sample itself, the difference, and the second guard's read of
    # the state the first just asked is shared: about 3 (the located release adds a few more)
    assert counts["unpack"] > 1.8 * n_shared
    assert n_shared <= 4 * samples


def test_last_state_answers_again_only_at_the_same_state():
    calls = []

    def forces(t, q, v):
        calls.append(t)
        return {"a": float(t) + float(q.sum())}
    shared = holding._LastState(forces, lambda t, y: (np.array([t, *y]), np.zeros(1)))
    y = np.array([0.25])
    first = shared.at(1.0, y)
    assert shared.at(1.0, y.copy()) is first and calls == [1.0]  # the same state: the same answer
    assert shared.at(1.0, np.array([0.5]))["a"] == 2.5  # another state at the same instant: solved
    assert shared.at(2.0, np.array([0.5]))["a"] == 4.5  # another instant: solved
    assert calls == [1.0, 1.0, 2.0]
    # -0.0 is not 0.0's bytes: solved again (the same value: always right)
    shared.at(3.0, np.array([0.0]))
    shared.at(3.0, np.array([-0.0]))
    assert calls[-2:] == [3.0, 3.0]


def test_applied_is_made_again_only_where_what_it_is_made_from_changed(monkeypatch):
    made = []
    record = recording.record_samples

    def kept(traj, cfg, seg, offsets, q_start, holds, stepping):
        if holds.items:
            made.append((cfg, tuple(holds.items), holds.applied(cfg)))
        return record(traj, cfg, seg, offsets, q_start, holds, stepping)
    monkeypatch.setattr(recording, "record_samples", kept)
    run = _run()
    assert run.stats["impacts"] > 100 and len(made) > 100
    for (cfg, items, applied), (cfg2, items2, applied2) in zip(made, made[1:]):
        if cfg2 is cfg and len(items) == len(items2) and all(a is b for a, b in zip(items, items2)):
            assert applied2 is applied  # the same configuration and holds in one run: the one made last
        else:
            assert applied2 is not applied
    assert len({id(a) for _, _, a in made}) < len(made) / 10


def test_applied_follows_its_reference_frozen_state(monkeypatch):
    scene = pcmm.load_scene(CYCLE)
    seen = {}
    record = recording.record_samples

    def keep(traj, cfg, seg, offsets, q_start, holds, stepping):
        if holds.items and "holds" not in seen:
            seen["holds"], seen["cfg"] = holds, cfg
        return record(traj, cfg, seg, offsets, q_start, holds, stepping)
    monkeypatch.setattr(recording, "record_samples", keep)
    pcmm.simulate(scene, pcmm.RunOptions(t_end=0.3))
    holds, cfg = seen["holds"], seen["cfg"]
    first = holds.applied(cfg)
    assert holds.applied(cfg) is first
    ref = first.reference
    frozen = ref.coords.frozen_state()
    moved = dict(frozen, I=np.array(frozen["I"][::-1]))  # another partition of the reference's coordinates
    monkeypatch.setattr(type(ref.coords), "frozen_state", lambda self: dict(moved))
    again = holds.applied(cfg)
    assert again is not first and again.frozen["I"].tobytes() == moved["I"].tobytes()
    assert again.acting is first.acting and again.springs is first.springs  # (their maps: as before)
    assert holds.applied(cfg) is again


def test_segment_loop_scans_are_made_once_per_guard_set(monkeypatch):
    if not holding.compiled.enabled():
        pytest.skip("no compiled segment loop without the compiled extension")
    made = []
    scans = integrators._scan_guards

    def counted(events, ny, progress):
        out = scans(events, ny, progress)
        made.append(out)
        return out
    monkeypatch.setattr(integrators, "_scan_guards", counted)
    given = []
    guard_scans = integrators._guard_scans

    def compared(events, ny, progress):
        out = guard_scans(events, ny, progress)
        given.append((out, scans(events, ny, progress)))  # what the classification makes afresh
        return out
    monkeypatch.setattr(integrators, "_guard_scans", compared)
    integrators._SCANS.clear()
    _run()
    assert len(given) > 100 and len(made) < len(given) / 10
    for out, fresh in given:  # the same arguments as made afresh, value for value
        assert len(out) == len(fresh) == 6
        for a, b in zip(out[:4], fresh[:4]):
            assert a.shape == b.shape and a.tobytes() == b.tobytes() and not a.flags.writeable
        assert out[4] == fresh[4]
        assert out[5].keys() == fresh[5].keys()
        for key in out[5]:
            assert repr(out[5][key]) == repr(fresh[5][key])


def test_the_recording_names_are_made_once_per_configuration(monkeypatch):
    names = recording._names
    given = []

    def kept(log, cfg, coords, held):
        out = names(log, cfg, coords, held)
        given.append((cfg, list(held), out))
        return out
    monkeypatch.setattr(recording, "_names", kept)
    run = _run()
    assert len(given) == len(run.segments)
    assert len({id(n) for _, _, n in given}) <= len({(c.name, tuple(h)) for c, h, _ in given}) + 2
    for cfg, held, out in given:  # equal to the lists made afresh
        labels = list(cfg.coords.labels) + held
        assert out["constraint_labels"] == labels and out["links"] == list(cfg.links)
        assert out["force_names"] == list(cfg.forces.names)
    # a plain list of segments (no log) gets its lists as before
    assert recording._names([], given[0][0], given[0][0].coords, []) is not given[0][2]


@pytest.mark.parametrize("compiled", ["1", "0"])
def test_the_cut_run_is_the_run(monkeypatch, compiled):
    """The whole cycle (to T_END) with every cut of this file, and with the routes they replace, to the bit,
    also with the Python evaluations (PCMM_COMPILED=0)."""
    monkeypatch.setenv("PCMM_COMPILED", compiled)
    now = _fingerprint(_run())
    with monkeypatch.context() as m:
        _no_state_map_without_free_coordinates(m)
        m.setattr(holding, "_LastState", _Unshared)
        m.setattr(integrators, "_pure_value", _impure)
        m.setattr(integrators, "_guard_scans", lambda events, ny, progress: integrators._scan_guards(events, ny, progress))
        applied = holding.Holds.applied

        def fresh_applied(self, cfg):
            self._applied = None
            return applied(self, cfg)
        m.setattr(holding.Holds, "applied", fresh_applied)
        names = recording._names
        m.setattr(recording, "_names", lambda log, cfg, coords, held: names([], cfg, coords, held))
        before = _fingerprint(_run())
    assert now == before


def test_the_compiled_steps_dense_output_at_one_time_is_dense_steps():
    """A compiled step's scipy dense output at one time (the root finder's and the event state's call),
    written out per component, against pcmm.ode.dop853.DenseStep's array route: the same bits, at the
    step's ends, inside and just outside it, for states of 1 to 6 components over 12 orders of magnitude."""
    from pcmm.ode.dop853 import DenseStep
    rng = np.random.default_rng(26)
    for k in range(3000):
        n = 1 + k % 6
        t0, h = rng.uniform(-5, 5), 10 ** rng.uniform(-8, 0)
        y0 = rng.normal(size=n) * 10 ** rng.uniform(-3, 3, size=n)
        F = rng.normal(size=(7, n)) * 10 ** rng.uniform(-6, 2, size=(7, n))
        fast, reference = integrators._ScipyDense(t0, t0 + h, y0, F), DenseStep(t0, t0 + h, y0, F)
        for x in (0.0, 1.0, rng.uniform(), rng.uniform(-0.1, 1.1)):
            t = t0 + x * h
            for at in (t, np.float64(t), np.array(t)):
                assert fast(at).tobytes() == reference(np.float64(t)).tobytes()
    # another number of rows than DOP853's seven: the general loop, the same bits too
    F = rng.normal(size=(5, 3))
    fast, reference = integrators._ScipyDense(0.0, 0.5, np.ones(3), F), DenseStep(0.0, 0.5, np.ones(3), F)
    assert fast(0.2).tobytes() == reference(np.float64(0.2)).tobytes()


def _random_rows(rng, k, n, scipy):
    """A flight of ``k`` steps (times ``t``) and each step's dense row of ``n`` components, either form."""
    t = np.cumsum(np.concatenate([[rng.uniform(-3, 3)], 10 ** rng.uniform(-7, -1, size=k)]))
    rows = []
    for s in range(k):
        coefficients = rng.normal(size=8 * n) * 10 ** rng.uniform(-6, 2, size=8 * n)
        second = t[s + 1] if scipy else t[s + 1] - t[s]  # (t_old, t_new, ...) or (t_old, h, ...)
        rows.append(np.concatenate([[t[s], second], coefficients]))
    form = integrators.scipy_row_dense if scipy else integrators.contd8_row_dense
    block = np.array(rows)  # (as take_dense hands them: rows of one array)
    return t, [integrators._Row(row, form) for row in block]


def test_the_flight_audits_nodes_and_states_in_one_compiled_call():
    """``dense.compiled_node_states`` against ``audit._nodes`` and ``audit._node_states`` (the Python floats,
    or numpy for a long flight: ``states_on_rows``, itself held to each step's interpolant to the bit by
    tests/test_flight_python.py): the same times, weights and states to the bit, both row forms, 1 to 40
    steps, some components only; None where a node falls on a step's end, as the Python path."""
    from pcmm.run import audit, dense
    if not holding.compiled.enabled() or dense._gauss_states() is None:
        pytest.skip("the compiled extension (with gauss_states) is not available")
    rng = np.random.default_rng(2026)
    for trial in range(600):
        k, n, scipy = 1 + int(rng.integers(0, 6)) if trial % 10 else 40, 1 + trial % 5, bool(trial % 2)
        t, kept = _random_rows(rng, k, n, scipy)
        y = np.zeros((n + 1, k + 1))
        components = n if trial % 3 else max(1, n - 1)
        got = dense.compiled_node_states(t, y, kept, audit._NODES_1_FLOATS, audit._WEIGHTS_FLOATS, components)
        times, weights = audit._nodes(t)
        states = audit._node_states(t, y, times, kept, components)
        assert got is not None and states is not None
        assert got[0].tobytes() == times.tobytes() and got[1].tobytes() == weights.tobytes()
        assert got[2].shape == (components, 4 * k)
        assert got[2].tobytes() == np.ascontiguousarray(states[:components]).tobytes()
    # a step shorter than its nodes' round-off: a node on the step's end, left to dense_states by both
    t = np.array([1.0, 1.0 + 1e-16 * 2, 1.5])
    _, kept = _random_rows(rng, 2, 2, True)
    kept = [integrators._Row(np.concatenate([[t[s], t[s + 1]], e.row[2:]]), e.form) for s, e in enumerate(kept)]
    y = np.zeros((3, 3))
    times, _ = audit._nodes(t)
    assert audit._node_states(t, y, times, kept, 2) is None
    assert dense.compiled_node_states(t, y, kept, audit._NODES_1_FLOATS, audit._WEIGHTS_FLOATS, 2) is None


def test_the_cycles_flight_audit_is_the_python_one(monkeypatch):
    """Every flight of the cycle audited with the compiled nodes and with the Python ones: the same works
    to the bit, so the same residuals in the run's stats."""
    from pcmm.run import audit
    if not holding.compiled.enabled():
        pytest.skip("no compiled loop's rows without the compiled extension")
    works = []
    run_work = audit.run_work

    def both(cfg, t, y, stepping, kept):
        fast = run_work(cfg, t, y, stepping, kept)
        with monkeypatch.context() as m:
            m.setattr(audit, "compiled_node_states", lambda *args: None)
            python = run_work(cfg, t, y, stepping, kept)
        works.append((fast, python))
        return fast
    monkeypatch.setattr(audit, "run_work", both)
    run = _run(2.0)
    assert len(works) > 100 and all(w is not None for w, _ in works)
    assert all(a == b for a, b in works)
    assert run.stats["macro_impacts"]


def _count_holding_asks(monkeypatch) -> dict:
    """Counts each ask of a guard on a compiled holding force from Python (the guards made from now on)."""
    counts = {"asks": 0}
    made = holding.guard_value

    def counted(cfg, forces, label, offset=0.0):
        value = made(cfg, forces, label, offset)

        def asked(t, y):
            counts["asks"] += 1
            return value(t, y)
        asked.__dict__.update(value.__dict__)  # (holding, pure: what the scanner and the loop read)
        return asked
    monkeypatch.setattr(holding, "guard_value", counted)
    return counts


def test_the_holding_guards_at_a_segments_start_and_a_candidates_end_are_the_loops(monkeypatch):
    """A guard on a compiled holding force is scanned by the compiled loop itself, at the segment's start
    and at every step's end: where the loop hands a candidate step back, the scanner takes those values
    and rates (``guard_state()``) instead of asking the same compiled solve again at the same states.
    The same run to the bit as asking them, with far fewer asks."""
    from pcmm.ode.integrators import _holding_known
    if not holding.compiled.enabled() or not hasattr(holding.compiled._tree_dynamics.SegmentLoop, "guard_state"):
        pytest.skip("the compiled extension (with guard_state) is not available")
    counts = _count_holding_asks(monkeypatch)
    used = []

    def kept(loop, guards, m):
        out = _holding_known(loop, guards, m)
        used.append(out is not None and any(g is not None for g in out[0]))
        return out
    monkeypatch.setattr(integrators, "_holding_known", kept)
    now = _fingerprint(_run(2.0))
    asks = counts["asks"]
    assert sum(used) > 100
    counts["asks"] = 0
    with monkeypatch.context() as m:
        m.setattr(integrators, "_holding_known", lambda loop, guards, m: None)
        before = _fingerprint(_run(2.0))
    assert now == before  # events, times, every segment's samples, steps and evaluations, to the bit
    # asked before: at the start and at the candidate's end of each flight with a merge held by compression
    # only, a value and its forward difference each time (besides the re-arm's pending check, still asked)
    assert counts["asks"] - asks >= 2 * sum(used)  # (a value and its difference, each time the loop's are taken)
