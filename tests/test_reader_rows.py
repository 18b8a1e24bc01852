"""A segment reader's rows (PartitionedCoordinates.rows on a compiled loop, Loop.rows in
pcmm/model/_loops.hpp): Phi_q and the bias without the KKT solve.  The flight audit's power
(pcmm.run.audit.power) takes the rows and solves for the multipliers itself; before, the reader's
rows() ran the compiled KKT solve and kept only its rows (two solves per quadrature node)."""
from __future__ import annotations

import builders
import numpy as np
import pytest

import pcmm
from pcmm.model import compiled
from pcmm.model.mechanism import Mechanism
from pcmm.model.rows import constrained_accelerations
from pcmm.run.audit import power

needs_extension = pytest.mark.skipif(not compiled.enabled() or not hasattr(compiled._tree_dynamics, "Loop"),
                                     reason=f"the compiled loops are not here: {compiled.why_not()}")


class Counting:
    """A compiled loop whose calls are counted by name."""

    def __init__(self, loop):
        self.loop, self.calls = loop, {}

    def __getattr__(self, name):
        fn = getattr(self.loop, name)

        def counted(*args):
            self.calls[name] = self.calls.get(name, 0) + 1
            return fn(*args)
        return counted


@needs_extension
def test_the_audit_power_on_a_compiled_reader_solves_once(tmp_path, monkeypatch):
    """A slider-crank whose slider is driven, x = x0 - 0.05 t - 0.4 t^2 (its bias -f'' = 0.8 is in the
    rows): at a state of the loop the audit's power reads the rows once and runs no compiled KKT solve;
    the rows are the compiled KKT's to the bit, and the power is the Python rows' (``_phi``, a second
    evaluation: Pinocchio's Python binding) to round-off."""
    monkeypatch.setenv(compiled.ENV, "1")
    x0 = 0.1 * np.cos(0.5) + 0.3 * np.cos(np.arcsin(-0.1 * np.sin(0.5) / 0.3))
    scene = pcmm.load_scene(builders.slider_crank_slider_driven(tmp_path, [x0, -0.05, -0.4]))
    cfg = Mechanism(scene)["c"]
    coords = cfg.coords
    q, v = coords.project(0.0, np.array([0.5, np.arcsin(-0.1 * np.sin(0.5) / 0.3) - 0.5, x0]), np.zeros(3))
    y = coords.pack(0.0, q, v)  # empty: the drive moves the whole mechanism (one degree of freedom)
    t = 0.2
    with coords.restored(coords.frozen_state(), q) as reader:
        loop = reader._compiled_loop()
        assert loop is not None, reader.evaluations
        counting = Counting(loop)
        monkeypatch.setattr(reader, "_compiled_loop", lambda: counting)
        qt, vt = reader.unpack(t, y)
        counting.calls.clear()
        p = power(cfg, reader, t, qt, vt)
        assert counting.calls == {"rows": 1}, counting.calls  # before: {"kkt": 1}
        Jq, bias = loop.rows(t, qt, vt)
        kkt = loop.kkt(t, qt, vt)
        np.testing.assert_array_equal(Jq, kkt[2])
        np.testing.assert_array_equal(bias, kkt[3])
        assert bias[-1] == 0.8  # the drive's row: -f''(t)
        _, Jp, bp = reader._phi(t, qt, need_bias=True, v=vt)
    np.testing.assert_allclose(Jq, Jp, rtol=0, atol=1e-13)
    np.testing.assert_allclose(bias, bp, rtol=0, atol=1e-12)
    _, lam = constrained_accelerations(cfg, qt, vt, Jp, bp, forces=coords.forces)
    reference = float(coords.forces.generalized(qt, vt) @ vt) + float(lam @ (Jp @ vt))
    assert reference != 0.0  # the drive does work here
    assert p == pytest.approx(reference, rel=1e-11, abs=0)
