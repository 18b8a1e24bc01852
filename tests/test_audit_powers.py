"""The flight-energy audit's power at the quadrature nodes of a flight with drives and no loop
(pcmm.run.audit.drive_powers: the nodes unpacked at once, the drive rows built once) is
pcmm.run.audit.power's, node by node, to the bit; checked on every flight of the working cycle
to its first re-locks, and the audit figures are those of the node-by-node route.  That is the Python
route (python_drive_powers); the compiled one (Tree.drive_powers, its own KKT solve at each node) is
power's to round-off."""
from __future__ import annotations

import numpy as np
from builders import EXAMPLES

import pcmm
from pcmm.run import audit

#: the working cycle to 1.5 s (its first merges, the O2 release at 1.199 s, re-locks): the run's
#: common part with the whole cycle, the t_end given as a run option
CYCLE, SHORT = EXAMPLES / "three_bar_cycle.toml", pcmm.RunOptions(t_end=1.5)


def test_drive_powers_are_power_node_by_node(monkeypatch):
    monkeypatch.setattr(audit, "_compiled_drive_powers", lambda cfg, coords: None)  # the Python route
    prepared, flights = audit.drive_powers, []

    def checked(cfg, coords, times, states):
        got = prepared(cfg, coords, times, states)
        want = np.array([audit.power(cfg, coords, ti, *coords.unpack(ti, states[:, i]))
                         for i, ti in enumerate(times)])
        flights.append((got, want))
        return got

    monkeypatch.setattr(audit, "drive_powers", checked)
    fast = pcmm.simulate(pcmm.load_scene(CYCLE), SHORT)
    assert len(flights) > 20  # the bounces of the first merges
    for got, want in flights:
        assert got is not None and got.tobytes() == want.tobytes()
        assert np.any(got != 0.0)  # the springs, dampers and the motor do work in flight
    # the audit figures, node by node without the prepared route: the same repr
    monkeypatch.setattr(audit, "drive_powers", lambda cfg, coords, times, states: None)
    slow = pcmm.simulate(pcmm.load_scene(CYCLE), SHORT)
    assert repr(fast.stats["macro_impacts"]) == repr(slow.stats["macro_impacts"])
    assert any(m["flights"] for m in fast.stats["macro_impacts"])


def test_compiled_drive_powers_are_power_to_round_off(monkeypatch):
    """Where the drives are compiled, the audit's powers come from one compiled call per flight
    (before: undefined, Tree.drive_powers did not exist), node by node power's to 1e-12 of the
    flight's largest power, and the audit's figures move by round-off only."""
    from pcmm.model import compiled
    if not compiled.enabled() or not hasattr(compiled._tree_dynamics.Tree, "drive_powers"):
        import pytest
        pytest.skip(f"no compiled drive powers here: {compiled.why_not()}")
    real, flights = audit.drive_powers, []

    def checked(cfg, coords, times, states):
        got = real(cfg, coords, times, states)
        want = np.array([audit.power(cfg, coords, ti, *coords.unpack(ti, states[:, i]))
                         for i, ti in enumerate(times)])
        flights.append((got, want, audit._compiled_drive_powers(cfg, coords) is not None))
        return got

    monkeypatch.setattr(audit, "drive_powers", checked)
    fast = pcmm.simulate(pcmm.load_scene(CYCLE), SHORT)
    assert len(flights) > 20 and all(used for _, _, used in flights)
    for got, want, _ in flights:
        assert np.max(np.abs(got - want)) <= 1e-12 * np.max(np.abs(want)), (got, want)
    monkeypatch.setattr(audit, "drive_powers", lambda cfg, coords, times, states: None)
    slow = pcmm.simulate(pcmm.load_scene(CYCLE), SHORT)
    for a, b in zip(fast.stats["macro_impacts"], slow.stats["macro_impacts"], strict=True):
        assert a["flights"] == b["flights"]
        assert abs(a["flight_energy_residual_max"] - b["flight_energy_residual_max"]) <= 1e-13


def test_drive_powers_leave_a_tree_to_power():
    """A tree has no rows: the node-by-node product is already all there is (None)."""
    from pcmm.model.mechanism import Mechanism
    scene = pcmm.load_scene(EXAMPLES / "three_bar.toml")
    cfg = Mechanism(scene)[scene.initial_configuration]
    y = np.zeros((2 * cfg.nv, 2))
    assert audit.drive_powers(cfg, cfg.coords, np.array([0.0, 0.1]), y) is None
