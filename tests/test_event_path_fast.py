"""The event path's lean evaluations give the very bits of the plain formulas they replace
(issue 26 item 2): the mass matrix's symmetrization, the drives' values, the dense output read
once per root-finder iterate, the bounce's entry check."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

import pcmm
from pcmm.events.entry import pose_mismatches
from pcmm.model.mechanism import Mechanism
from pcmm.model.pinocchio_helpers import mass_matrix
from pcmm.model.rows import Drives
from pcmm.ode import integrators

ROOT = Path(__file__).resolve().parents[1]


def test_symmetrized_mass_matrix_is_the_triangle_sum_to_the_bit():
    rng = np.random.default_rng(11)
    for n in (1, 2, 3, 5):
        for _ in range(50):
            M = rng.normal(size=(n, n))
            M[rng.random((n, n)) < 0.3] = -0.0  # signed zeros: the sum turns them into 0.0
            expected = np.triu(M) + np.triu(M, 1).T
            got = np.where(np.triu(np.ones((n, n), bool)), M, M.T) + 0.0
            assert got.tobytes() == expected.tobytes()
    cfg = Mechanism(pcmm.load_scene(ROOT / "examples" / "three_bar.toml"))["config1"]
    q = pin.randomConfiguration(cfg.model)
    raw = pin.crba(cfg.model, cfg.data, q).copy()
    M = mass_matrix(cfg.model, cfg.data, q)
    assert M.tobytes() == (np.triu(raw) + np.triu(raw, 1).T).tobytes()
    assert np.array_equal(M, M.T) and np.all(np.linalg.eigvalsh(M) > 0)


def test_drive_values_in_one_pass_are_each_orders_horner_sum():
    d = Drives(joints=("a", "b"), index=(0, 2),
               coefficients=(np.array([0.3, np.pi, -0.25, 1.5e-3]), np.array([1.0, 0.0, 2.0])))
    for t in (0.0, 0.1, 1.0 / 3.0, 7.2, -2.5):
        f, f1, f2 = d.values(t)
        for k, got in enumerate((f, f1, f2)):
            assert got.tobytes() == d.value(t, k).tobytes()
        # closed form of the first: 0.3 + pi t - 0.25 t^2 + 1.5e-3 t^3 and its derivatives
        assert np.isclose(f[0], 0.3 + np.pi * t - 0.25 * t**2 + 1.5e-3 * t**3, rtol=1e-14, atol=1e-14)
        assert np.isclose(f1[0], np.pi - 0.5 * t + 4.5e-3 * t**2, rtol=1e-14, atol=1e-14)
        assert np.isclose(f2[1], 4.0, rtol=0, atol=0)


def test_root_finder_reads_each_iterate_once():
    calls = []

    def sol(u):
        calls.append(u)
        return np.array([u - 0.3, 1.0])
    at = integrators._last_state(sol)
    value = (lambda u, y: y[0])
    rate = (lambda u, y, f: y[1])
    root = integrators._bracketed_newton(lambda u: value(u, at(u)), lambda u: rate(u, at(u), None),
                                         0.0, 1.0, -0.3, 0.7, 1e-14)
    assert abs(root - 0.3) < 1e-15
    assert len(calls) == len(set(calls))  # value and rate at one iterate: one evaluation


def test_a_bounce_enters_its_own_configuration_with_zero_offsets():
    cfg = Mechanism(pcmm.load_scene(ROOT / "examples" / "three_bar_cycle.toml"))["open"]
    q = np.array([0.4, 1.5, 3.0])
    offsets, problems = pose_mismatches(cfg, cfg, q, q.copy())
    assert problems == [] and offsets == {link: 0.0 for link in cfg.links}
    # a posture a full turn on: the same link poses, offsets of -2 pi (the general route)
    offsets, problems = pose_mismatches(cfg, cfg, q, q + np.array([2 * np.pi, 0.0, 0.0]))
    assert problems == [] and all(abs(o + 2 * np.pi) < 1e-12 or abs(o) < 1e-12 for o in offsets.values())


def test_impulse_solves_by_lapack_directly_are_numpys_to_the_bit():
    from pcmm.events.impulse import _least_squares
    from pcmm.model.rows import solve
    rng = np.random.default_rng(5)
    for m, n in ((5, 3), (3, 3), (4, 1), (7, 4)):
        for _ in range(200):
            A, b = rng.normal(size=(m, n)), rng.normal(size=m)
            assert _least_squares(A, b).tobytes() == np.linalg.lstsq(A, b, rcond=None)[0].tobytes()
    for n in (1, 2, 3):
        for _ in range(200):
            A = rng.normal(size=(n, n))
            A = A @ A.T + 0.1 * np.eye(n)
            B = rng.normal(size=(n, 5))
            assert solve(A, B).tobytes() == np.linalg.solve(A, B).tobytes()
    # the cut system's velocity map of a tree (identity rows plus a cut joint's planar rows):
    # least squares recovers the tree velocity it was made from
    T = np.vstack([np.eye(3), rng.normal(size=(2, 3))])
    v = np.array([0.3, -1.2, 2.5])
    assert np.allclose(_least_squares(T, T @ v), v, rtol=0, atol=1e-14)


def _grid_states(cfg, t0, rng, n=17):
    """An event grid's times and states of ``cfg`` (one column each), near its stops."""
    ts = np.linspace(t0, t0 + 0.01, n)
    ny = cfg.coords.ny if cfg.coords.constrained else 2 * cfg.nv
    ys = rng.uniform(-0.2, 0.2, (ny, n))
    ys[:ny // 2] += np.pi / 2  # coordinates near the O2 pin's value
    return ts, ys


def test_event_grid_reads_a_joint_guard_at_every_sample_in_one_call_to_the_bit():
    from pcmm.events.guards import make_guard
    mech = Mechanism(pcmm.load_scene(ROOT / "examples" / "three_bar_cycle.toml"))
    cfg = mech["open"]
    q0, v0 = np.array([0.3, np.pi / 2 - 0.01, np.pi - 0.05]), np.array([np.pi, 0.4, -0.2])
    cfg.coords.pack(0.3 / np.pi, q0, v0)  # the partition: O1 driven, O2 and O3 the state
    rng = np.random.default_rng(2)
    tr = next(t for t in mech.scene.transitions_from("open") if t.name == "O2 pin")
    for rearm in (False, True):
        g = make_guard(cfg, tr, rearm=rearm)
        assert g.many is not None
        ts, ys = _grid_states(cfg, 0.31, rng)
        ys[2] = np.where(np.arange(17) % 2 == 0, 0.5, -0.5)  # O2's rate: approaching, then leaving the pin
        expected = [g(t, ys[:, k]) for k, t in enumerate(ts)]
        got = g.many(ts, ys)
        assert np.array(got).tobytes() == np.array(expected, float).tobytes()
        # the value is O2 - pi/2 itself where the guard approaches (plain value)
        assert got[0] == ys[0, 0] - np.pi / 2
        wide = g.on_state(cfg.coords.ny)  # a flight's state carries its work as one more component
        longer = np.vstack([ys, np.ones(17)])
        assert wide.many(ts, longer) == got
    # a tree (Example 1): its state is (q, v) itself
    tree_cfg = Mechanism(pcmm.load_scene(ROOT / "examples" / "three_bar_stop.toml"))
    name = tree_cfg.scene.initial_configuration
    cfg = tree_cfg[name]
    checked = 0
    for tr in tree_cfg.scene.transitions_from(name):  # the O3 stop: link3 - link2, the row of O3 alone
        g = make_guard(cfg, tr)
        if g is None or g.many is None:
            continue
        ts, ys = _grid_states(cfg, 0.0, rng)
        assert np.array(g.many(ts, ys)).tobytes() == np.array([g(t, ys[:, k]) for k, t in enumerate(ts)], float).tobytes()
        checked += 1
    assert checked == 1


def _reference_cut_q_and_T(cfg, q, joints):
    """The cut model's q and T built joint by joint (the construction before the layout was kept)."""
    from pcmm.events.cutting import _PLANAR_ROWS, _structure
    from pcmm.model.pinocchio_helpers import LOCAL, joint_jacobian
    model, data = cfg.model, cfg.data
    qp = cfg.to_pin(q)
    pin.computeJointJacobians(model, data, qp)
    new, _, jmap, _, cut_ids, *_ = _structure(cfg, tuple(joints))
    parts, T = [], np.zeros((new.nv, model.nv))
    for jid in range(1, model.njoints):
        nj, j = new.joints[jmap[jid]], model.joints[jid]
        if jid in cut_ids:
            parts.append(np.array([0.0, 0.0, 1.0, 0.0]))
            T[nj.idx_v:nj.idx_v + 3] = joint_jacobian(model, data, jid, LOCAL)[_PLANAR_ROWS]
        else:
            parts.append(qp[j.idx_q:j.idx_q + j.nq])
            T[nj.idx_v:nj.idx_v + nj.nv, j.idx_v:j.idx_v + j.nv] = np.eye(j.nv)
    return np.concatenate(parts), T


def test_cut_system_from_its_kept_layout_is_the_joint_by_joint_one():
    from pcmm.events.cutting import cut
    cfg = Mechanism(pcmm.load_scene(ROOT / "examples" / "three_bar.toml"))["config1"]
    rng = np.random.default_rng(9)
    for joints in (("O3",), ("O2",), ("O2", "O3"), ("O1",)):
        for _ in range(3):
            q = rng.uniform(-3.0, 3.0, cfg.nv)
            cs = cut(cfg, q, joints)
            q_ref, T_ref = _reference_cut_q_and_T(cfg, q, joints)
            assert cs.q.tobytes() == q_ref.tobytes() and cs.T.tobytes() == T_ref.tobytes()
            # the cut system moves as the tree: its links' velocities are the tree's (T maps v)
            v = rng.normal(size=cfg.nv)
            assert cs.T.shape == (cfg.nv + 2 * len(joints), cfg.nv)
            assert np.allclose(cs.J_cut @ (cs.T @ v), 0.0, atol=1e-12)  # the cut joints' rows hold


def test_drive_rows_on_a_cut_system_name_the_driven_joint():
    mech = Mechanism(pcmm.load_scene(ROOT / "examples" / "three_bar_cycle.toml"))
    cfg = mech["open"]
    from pcmm.events.cutting import cut
    q = np.array([0.2, 1.5, 3.1])
    for joints in (("O2",), ("O1",)):
        cs = cut(cfg, q, joints)
        for _ in range(2):  # the second time from the kept columns
            J = cfg.coords.equality(0.0, cs.model, cs.data)
            expected = np.zeros((1, cs.model.nv))
            expected[0, cs.model.joints[cs.model.getJointId("O1")].idx_v] = 1.0
            assert J.tobytes() == expected.tobytes()


def test_normal_speed_is_contact_states_without_its_kinematics():
    from pcmm.events.contact import contact_state, normal_speed
    mech = Mechanism(pcmm.load_scene(ROOT / "examples" / "three_bar_cycle.toml"))
    cfg = mech["open"]
    rng = np.random.default_rng(4)
    for tr in mech.scene.transitions_from("open"):
        for _ in range(5):
            q, v = rng.uniform(-3, 3, cfg.nv), rng.normal(size=cfg.nv)
            assert normal_speed(cfg, q, v, tr.contact) == contact_state(cfg, q, v, tr.contact)[2]
        # closed form for a joint stop: -s q'_j, negative while the joint moves towards its pin
        j = cfg.joint_slice[tr.contact.joint].start
        assert normal_speed(cfg, q, v, tr.contact) == -tr.contact.stop_sign * v[j]


def test_a_joint_guard_reads_the_state_entry_itself():
    """Beside drives without a loop (and on a tree) a joint coordinate is an entry of the state:
    the guard reads it without assembling (q, v), the same value as through them."""
    from pcmm.events.guards import make_guard
    mech = Mechanism(pcmm.load_scene(ROOT / "examples" / "three_bar_cycle.toml"))
    cfg = mech["open"]
    assert cfg.coords.state_entry(0) is None  # O1 is driven: not in the state
    assert cfg.coords.state_entry(1) == (0, 2) and cfg.coords.state_entry(2) == (1, 3)
    t = 0.4
    y = cfg.coords.pack(t, np.array([np.pi * t, 1.5, 3.0]), np.array([np.pi, 0.25, -0.5]))
    for tr in mech.scene.transitions_from("open"):
        g = make_guard(cfg, tr)
        row, offset = cfg.measure_row(tr.guard.measure)
        q, v = cfg.coords.unpack(t, y)
        assert g(t, y) == row @ q - (tr.guard.value - offset)
        assert g.rate(t, y, None) == row @ v


def test_the_zero_time_cycle_check_reads_two_events_of_a_long_log():
    """At every event the run checks its last ZERO_TIME_CYCLE events for a cycle of switches at
    one instant; a compact event log builds each record it is asked for, so a log whose ends
    differ in time is judged from those two records alone (one, with the event just kept)."""
    from collections.abc import Sequence

    from pcmm.run.actions import ZERO_TIME_CYCLE, zero_time_cycle

    class Counted(Sequence):  # a log that counts the records it builds
        def __init__(self, events):
            self.events, self.built = list(events), 0

        def __len__(self):
            return len(self.events)

        def __getitem__(self, i):
            if isinstance(i, slice):
                out = self.events[i]
                self.built += len(out)
                return out
            self.built += 1
            return self.events[i]
    log = Counted([{"t": 0.01 * k, "name": "pin", "from": "a", "to": "b"} for k in range(300)])
    assert zero_time_cycle(log) == ""
    assert log.built == 2
    log.built = 0
    assert zero_time_cycle(log, {"t": 2.99, "name": "pin", "from": "a", "to": "b"}) == ""  # the last, as kept
    assert log.built == 1
    # a real cycle at one instant is still found (every record of the tail read)
    cycle = Counted([{"t": 1.0, "name": n, "from": f, "to": g}
                     for _ in range(ZERO_TIME_CYCLE // 2) for n, f, g in (("go", "x", "y"), ("back", "y", "x"))])
    assert zero_time_cycle(cycle) == "'go' (x -> y), 'back' (y -> x)"
