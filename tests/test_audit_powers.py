"""The flight-energy audit's power at the quadrature nodes of a flight with drives and no loop
(pcmm.run.audit.drive_powers: the nodes unpacked at once, the drive rows built once) is
pcmm.run.audit.power's, node by node, to the bit; checked on every flight of the working cycle
to its first re-locks, and the audit figures are those of the node-by-node route."""
from __future__ import annotations

import numpy as np
from builders import EXAMPLES

import pcmm
from pcmm.run import audit

#: the working cycle to 1.5 s (its first merges, the O2 release at 1.199 s, re-locks): the run's
#: common part with the whole cycle, the t_end given as a run option
CYCLE, SHORT = EXAMPLES / "three_bar_cycle.toml", pcmm.RunOptions(t_end=1.5)


def test_drive_powers_are_power_node_by_node(monkeypatch):
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


def test_drive_powers_leave_a_tree_to_power():
    """A tree has no rows: the node-by-node product is already all there is (None)."""
    from pcmm.model.mechanism import Mechanism
    scene = pcmm.load_scene(EXAMPLES / "three_bar.toml")
    cfg = Mechanism(scene)[scene.initial_configuration]
    y = np.zeros((2 * cfg.nv, 2))
    assert audit.drive_powers(cfg, cfg.coords, np.array([0.0, 0.1]), y) is None
