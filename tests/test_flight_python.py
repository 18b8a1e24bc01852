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
