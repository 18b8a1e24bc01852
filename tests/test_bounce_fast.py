"""A bounce's fast path (issue 26, item 2): the record formed from the impulse's arrays, the entry and
the re-arm of a bounce into its own configuration give the run of the general route to the bit, and
the per-bounce physics checks still catch a wrong bounce."""
from __future__ import annotations

import math

import numpy as np
import pytest

import builders
import pcmm
from pcmm.errors import SimulationError
from pcmm.events import records, transitions
from pcmm.model import compiled

# the record formed from the compiled impulse's arrays: where the compiled impulse runs
needs_compiled = pytest.mark.skipif(not compiled.enabled(), reason="the compiled impulse does not run here")


@pytest.fixture(autouse=True)
def _python_route(monkeypatch):
    """These tests hold the Python route of a bounce (the reference and the fallback: the impulse solve,
    the record from its arrays, the entry) to the general one, and plant their defects in it: every bounce
    takes it here.  The bounce in one compiled call, which replaces it once it has given its bits, is held
    to it in tests/test_compiled_bounce.py."""
    monkeypatch.setattr(transitions, "compiled_bounce", lambda cfg, tr: None)


def _general_record(cfg, tr, t, imp, q):
    return records.event_record(cfg, tr, t, cfg.name, False, imp, q=q)


def _events(traj) -> list[str]:
    """Every event as the text of its dict: keys, order, types and numbers (repr: to the bit)."""
    return [repr(dict(e)) for e in traj.events]


def _pendulum(tmp_path):
    # a bar released horizontal onto a stop on the frame 0.3 rad below (a stable point contact,
    # e = 0.85): about 90 bounces, then the merge
    return pcmm.load_scene(builders.pendulum(tmp_path, 0.85, qs=-0.3, t_end=3.0))


def _counting(monkeypatch):
    """Count the bounces whose record is kept as its numbers."""
    kept = []
    fast = records.bounce_record

    def counted(*args):
        out = fast(*args)
        kept.append(isinstance(out, records.BounceRecord))
        return out
    monkeypatch.setattr(transitions, "bounce_record", counted)
    return kept


@needs_compiled
def test_a_bounce_record_is_the_general_record_to_the_bit(tmp_path, monkeypatch):
    scene = _pendulum(tmp_path)
    kept = _counting(monkeypatch)
    fast = pcmm.simulate(scene)
    bounces = sum(e["transition"] == "stop" and not e["merge"] for e in fast.events)
    assert bounces >= 80 and sum(kept) == bounces - 1  # the first bounce builds (and checks) the plan
    monkeypatch.setattr(transitions, "bounce_record", _general_record)
    general = pcmm.simulate(scene)
    assert _events(fast) == _events(general)
    assert fast.events == general.events
    # the log keeps the numbers in one table either way
    assert [t.n for t in fast.events._tables] == [t.n for t in general.events._tables]
    # the impulse-momentum balance of every bounce, from its record's momenta and external impulses
    from pcmm.events.momentum import balance
    for e in fast.events:
        linear, angular = balance(e)
        scale = max(abs(x) for x in e["momentum"]["linear_before"] + [e["momentum"]["angular_before"]])
        assert np.abs(linear).max() <= 1e-12 * scale and abs(angular) <= 1e-12 * scale
    rows = [np.vstack(t.blocks)[:t.n] for t in fast.events._tables]
    rows_general = [np.vstack(t.blocks)[:t.n] for t in general.events._tables]
    assert all(a.tobytes() == b.tobytes() for a, b in zip(rows, rows_general))


@needs_compiled
def test_a_bounce_record_reads_as_its_dict(tmp_path, monkeypatch):
    scene = _pendulum(tmp_path)
    outs = []
    handle = transitions.TRANSITIONS["stop"]

    def keep(*args):
        out = handle(*args)
        outs.append(out.event)
        return out
    monkeypatch.setitem(transitions.TRANSITIONS, "stop", keep)
    traj = pcmm.simulate(scene)
    rec = next(e for e in outs if isinstance(e, records.BounceRecord))
    whole = rec.record()
    assert dict(rec) == whole and list(rec) == list(whole) and len(rec) == len(whole)
    i = outs.index(rec)
    assert traj.events[i] == whole
    assert rec["t"] == whole["t"] and type(rec["t"]) is float
    assert rec["name"] == "stop" and rec["impact"] is True and rec["merge"] is False
    assert rec["restitution"] == 0.85 and rec["kinetic_energy_after"] == whole["kinetic_energy_after"]
    assert rec.get("friction") is None and "cut_impulses" in rec
    for key in ("t", "kinetic_energy_after", "name", "merge", "restitution", "impulse", "momentum", "absent"):
        got, want = rec.get(key, "default"), whole.get(key, "default")  # a number, a constant, a block, none
        assert got == want and type(got) is type(want)
    # Newton's law and the energy from the record's own numbers
    vn = whole["normal_velocity"]
    assert vn["after"] == pytest.approx(-0.85 * vn["before"], rel=1e-12)
    assert whole["energy_dissipated"] > 0


@needs_compiled
def test_three_bar_cycle_records_are_the_general_ones(monkeypatch):
    scene = pcmm.load_scene(builders.EXAMPLES / "three_bar_cycle.toml")
    options = pcmm.RunOptions(t_end=1.5)
    kept = _counting(monkeypatch)
    fast = pcmm.simulate(scene, options)
    assert sum(kept) > 80
    monkeypatch.setattr(transitions, "bounce_record", _general_record)
    general = pcmm.simulate(scene, options)
    assert _events(fast) == _events(general)


@needs_compiled
def test_a_record_plan_whose_numbers_differ_is_refused(tmp_path, monkeypatch):
    """The plan is checked at the stop's first bounce against the general record: one number off by
    one ulp refuses it for good, with its reason, and every record is then the general one."""
    scene = _pendulum(tmp_path)
    numbers = records._bounce_numbers

    def off_by_an_ulp(*args):
        out = numbers(*args)
        out[5] = math.nextafter(out[5], math.inf)
        return out
    monkeypatch.setattr(records, "_bounce_numbers", off_by_an_ulp)
    records.BOUNCE_RECORD_REFUSED.clear()
    kept = _counting(monkeypatch)
    traj = pcmm.simulate(scene)
    assert not any(kept)
    assert records.BOUNCE_RECORD_REFUSED == {("c1", "stop"): "its numbers differ from the general record's"}
    monkeypatch.setattr(transitions, "bounce_record", _general_record)
    assert _events(traj) == _events(pcmm.simulate(scene))


def test_a_bounce_with_a_wrong_restitution_is_caught(tmp_path, monkeypatch):
    """A bounce whose velocity follows another restitution than its stop's (a planted defect in the
    impulse the bounce goes on with) stops the run, naming Newton's law, the stop and the instant."""
    scene = _pendulum(tmp_path)
    solve = transitions.solve_impulse
    calls = []

    def wrong_e(cfg, t, q, v, contact, restitution, cut, name=None):
        calls.append(t)
        if len(calls) < 3:
            return solve(cfg, t, q, v, contact, restitution, cut, name=name)
        imp = solve(cfg, t, q, v, contact, 0.9 * restitution, cut, name=name)
        imp.restitution = restitution  # the record would claim the stop's own
        return imp
    monkeypatch.setattr(transitions, "solve_impulse", wrong_e)
    with pytest.raises(SimulationError) as err:
        pcmm.simulate(scene)
    text = str(err.value)
    assert "restitution law" in text and "'stop'" in text and f"t = {calls[2]:.9g} s" in text
    # the law's own numbers: vn+ = -0.9 e vn- instead of -e vn-
    assert "e = 0.85" in text


def test_a_bounce_re_arms_with_the_merges_guards_it_had(monkeypatch):
    """Bouncing in a configuration that holds a merge by compression only (three_bar_cycle's
    'O2_locked' and 'O3_locked'): the merge's guard is built once per stay, and the run is the one
    whose every re-arm builds it again, to the bit."""
    from pcmm.events import holding
    from pcmm.run import loop
    scene = pcmm.load_scene(builders.EXAMPLES / "three_bar_cycle.toml")
    options = pcmm.RunOptions(t_end=1.5)
    built, calls = holding.Holds.unmerge_guards, []

    def counted(self, cfg):
        calls.append(cfg.name)
        return built(self, cfg)
    monkeypatch.setattr(holding.Holds, "unmerge_guards", counted)
    kept = pcmm.simulate(scene, options)
    stays = 1 + sum(a["from"] != a["to"] for a in kept.events)
    assert len(calls) <= stays < len(kept.events) / 10
    monkeypatch.setattr(loop, "_unmerge_guards", lambda cfg, holds, phase, cache, offsets=None: holds.unmerge_guards(cfg))
    calls.clear()
    rebuilt = pcmm.simulate(scene, options)
    assert len(calls) > len(kept.events)
    assert _events(kept) == _events(rebuilt)
    assert kept.stats["macro_impacts"] == rebuilt.stats["macro_impacts"]
    seg_a, seg_b = kept.segments[-1], rebuilt.segments[-1]
    assert seg_a.t.tobytes() == seg_b.t.tobytes() and seg_a.q.tobytes() == seg_b.q.tobytes()
    assert seg_a.v.tobytes() == seg_b.v.tobytes()


def test_without_the_compiled_impulse_the_record_is_the_general_one(tmp_path, monkeypatch):
    """PCMM_COMPILED=0: the impulse is the Python solve's (no momenta at hand), so every bounce keeps
    the general record, and says why."""
    monkeypatch.setenv("PCMM_COMPILED", "0")
    scene = _pendulum(tmp_path)
    records.BOUNCE_RECORD_REFUSED.clear()
    kept = _counting(monkeypatch)
    traj = pcmm.simulate(scene)
    assert len(kept) > 80 and not any(kept)
    assert records.BOUNCE_RECORD_REFUSED == {("c1", "stop"): "the impulse was not solved compiled (no momenta at hand)"}
    assert all(type(e) is dict for e in traj.events)


def _planted_impulse(monkeypatch, plant, after: int = 3):
    """From the ``after``-th impulse on, ``plant(imp)`` alters the solved impulse the bounce goes on with."""
    solve = transitions.solve_impulse
    calls = []

    def planted(*args, **kw):
        imp = solve(*args, **kw)
        calls.append(args[1])
        if len(calls) >= after:
            plant(imp)
        return imp
    monkeypatch.setattr(transitions, "solve_impulse", planted)
    return calls


def test_a_bounce_that_creates_energy_is_caught(tmp_path, monkeypatch):
    """The energy check runs on the fast record's route too: an impulse whose kinetic energy after
    exceeds the one before (no drive to supply it) stops the run at that bounce."""
    scene = _pendulum(tmp_path)

    def more_energy(imp):
        imp.ke_after = 1.5 * imp.ke_before
    calls = _planted_impulse(monkeypatch, more_energy)
    with pytest.raises(SimulationError) as err:
        pcmm.simulate(scene)
    text = str(err.value)
    assert "would create energy" in text and "'stop'" in text and f"t = {calls[2]:.9g} s" in text


def test_a_bounce_that_breaks_a_drive_is_caught():
    """The entry of a bounce still checks every row at the post-impact velocity: three_bar_cycle's
    crank O1 is driven (O1' = pi), and a bounce leaving it at pi + 1e-3 stops the run naming the
    drive's row, by 1e-3 rad/s."""
    scene = pcmm.load_scene(builders.EXAMPLES / "three_bar_cycle.toml")
    mp = pytest.MonkeyPatch()
    try:
        def crank_off(imp):
            imp.v_after = imp.v_after.copy()
            imp.v_after[0] += 1e-3  # O1, the first coordinate
        calls = _planted_impulse(mp, crank_off, after=5)
        with pytest.raises(SimulationError) as err:
            pcmm.simulate(scene, pcmm.RunOptions(t_end=1.0))
    finally:
        mp.undo()
    text = str(err.value)
    assert "'O1.drive' (the drive of joint O1) by" in text and f"t = {calls[4]:.9g} s" in text
    by = float(text.split("'O1.drive' (the drive of joint O1) by ")[1].split()[0])
    assert by == pytest.approx(1e-3, rel=1e-9)


def test_a_bounce_entry_reads_its_drive_rows_residual_as_the_product_gives():
    """A bounce's entry in a tree whose rows are drives reads each row's residual off the driven
    coordinate's rate (``entry._unit_columns``): the number ``max |Phi_q (v - v_new)|`` gives, to the bit,
    on three_bar_cycle's bounces as they come and with the crank nudged by 2e-9 rad/s (above the
    1e-9 floor the short route answers alone, below the tolerance 1e-9 x max|v| the general check
    allows, max|v| >= pi here, so the run goes on)."""
    from pcmm.events import entry
    scene = pcmm.load_scene(builders.EXAMPLES / "three_bar_cycle.toml")
    seen = []
    fast = entry.enter_bounce

    def compared(cfg, t, q, v, what="bounce"):
        q_new, v_new, residual = fast(cfg, t, q, v, what)
        Jq = cfg.coords.rows(t, q_new, v_new)[0]
        seen.append((residual, float(np.abs(Jq @ (v - v_new)).max()), entry._unit_columns(cfg.coords)))
        return q_new, v_new, residual
    mp = pytest.MonkeyPatch()
    try:
        mp.setattr(transitions, "enter_bounce", compared)

        def nudged(imp):
            imp.v_after = imp.v_after.copy()
            imp.v_after[0] += 2e-9  # O1, the driven crank
        _planted_impulse(mp, nudged, after=40)
        pcmm.simulate(scene, pcmm.RunOptions(t_end=1.5))
    finally:
        mp.undo()
    assert len(seen) > 80 and all(cols == (0,) for _, _, cols in seen)
    assert all(np.float64(a).tobytes() == np.float64(b).tobytes() for a, b, _ in seen)
    residuals = [a for a, _, _ in seen]
    first = next(i for i, a in enumerate(residuals) if a > 1e-12)  # the first nudged bounce
    assert first >= 30 and all(1.5e-9 < a < 2.5e-9 for a in residuals[first:])
    assert all(a <= 1e-14 for a in residuals[:first])  # (0 with the compiled impulse, round-off without)


def test_the_re_arm_reads_a_joint_stops_speed_off_the_state():
    """``loop._pending`` reads a joint stop's normal speed off the state where the joint's rate is an
    entry of it (``loop._stop_speed``) instead of unpacking the state: the same number as
    ``normal_speed`` of the unpacked state at every re-arm of three_bar_cycle (a tree while 'open',
    drives beside free coordinates after), and the run of the unpacking route, to the bit."""
    from pcmm.events.contact import normal_speed
    from pcmm.run import loop
    scene = pcmm.load_scene(builders.EXAMPLES / "three_bar_cycle.toml")
    options = pcmm.RunOptions(t_end=2.5)
    pending, compared = loop._pending, []

    def checked(cfg, guards, t, y0, *rest):
        q, v = cfg.coords.unpack(t, y0)
        for g in guards:
            c = getattr(g.transition, "contact", None)
            if g.action == "transition" and c is not None and c.joint is not None:
                got = loop._stop_speed(cfg.coords, cfg, y0, c)
                compared.append((cfg.name, got, normal_speed(cfg, q, v, c)))
        return pending(cfg, guards, t, y0, *rest)
    mp = pytest.MonkeyPatch()
    try:
        mp.setattr(loop, "_pending", checked)
        fast = pcmm.simulate(scene, options)
        mp.setattr(loop, "_pending", pending)
        mp.setattr(loop, "_stop_speed", lambda *args: None)  # every speed from the unpacked state
        general = pcmm.simulate(scene, options)
    finally:
        mp.undo()
    assert {name for name, _, _ in compared} >= {"O2_locked", "O3_locked"}
    assert len(compared) > 200 and [c for c in compared if c[1] is None or c[1] != c[2]] == []
    assert _events(fast) == _events(general)
    a, b = fast.segments[-1], general.segments[-1]
    assert a.q.tobytes() == b.q.tobytes() and a.v.tobytes() == b.v.tobytes()


@needs_compiled
def test_a_record_read_from_arrays_that_differ_from_the_impulses_dicts_is_refused(tmp_path, monkeypatch):
    """The compiled impulse keeps its joints' impulses as the solve's array (``ArrayImpulse.arrays``)
    and forms their dict when first read; the fast record reads the array, the general record the dict.
    An array one ulp off the dict it gave (planted) is caught at the stop's first bounce: the plan is
    refused, and every record is the general one, the run's of the general route to the bit."""
    from pcmm.events import impulse
    scene = _pendulum(tmp_path)
    solve = impulse._compiled_solve

    def planted(*args):
        imp = solve(*args)
        if imp is not None:
            assert isinstance(imp, impulse.ArrayImpulse) and imp.joint_impulses  # the dict, formed now
            cut, mu, joints = imp.arrays
            joints = joints.copy()
            joints[0, 0] = math.nextafter(joints[0, 0], math.inf)
            imp.arrays = (cut, mu, joints)
        return imp
    monkeypatch.setattr(impulse, "_compiled_solve", planted)
    records.BOUNCE_RECORD_REFUSED.clear()
    kept = _counting(monkeypatch)
    traj = pcmm.simulate(scene)
    assert len(kept) > 80 and not any(kept)
    assert records.BOUNCE_RECORD_REFUSED == {("c1", "stop"): "its numbers differ from the general record's"}
    monkeypatch.setattr(impulse, "_compiled_solve", solve)
    monkeypatch.setattr(transitions, "bounce_record", _general_record)
    assert _events(traj) == _events(pcmm.simulate(scene))


@needs_compiled
def test_a_compiled_impulses_dicts_are_its_arrays():
    """``ArrayImpulse``'s dicts formed when read: the names of the compiled plan over the rows of its
    arrays, the drives' [0, 0, mu] (three_bar_cycle's crank), and the contact's impulses on b and a
    equal and opposite (a revolute joint stop: moments -s P and s P)."""
    from pcmm.events import impulse
    scene = pcmm.load_scene(builders.EXAMPLES / "three_bar_cycle.toml")
    got = []
    mp = pytest.MonkeyPatch()
    solve = impulse._compiled_solve
    try:
        mp.setattr(impulse, "_compiled_solve", lambda *a: got.append(solve(*a)) or got[-1])
        pcmm.simulate(scene, pcmm.RunOptions(t_end=1.0))
    finally:
        mp.undo()
    assert len(got) > 50
    for imp in got:
        cut, mu, joints = imp.arrays
        fast = imp.solved[0]
        assert list(imp.joint_impulses) == list(fast.joint_names) and fast.joint_names[0] == "O1"
        assert [imp.joint_impulses[n] for n in fast.joint_names] == joints.tolist()
        assert list(imp.cut_impulses.values()) == cut.tolist() and len(imp.cut_impulses) == 1
        assert imp.constraint_rows == {"O1.drive": float(mu[0])}
        assert imp.constraint_impulses == {"O1.drive": [0.0, 0.0, float(mu[0])]}
        (_, _, Fb, mb), (_, _, Fa, ma) = imp.contact_impulses
        assert mb == -ma and mb != 0.0 and list(Fb) == [0.0, 0.0] and list(Fa) == [0.0, 0.0]
        assert abs(mb) == abs(imp.P)
