"""Under "auto", a configuration with drives and no loop is stepped by the compiled segment loop with
scipy's DOP853 tableau (pcmm.ode.integrators.AUTO_DOP853), not by pcmm's DOP853 in Python: the same
method, its steps round-off apart (the error estimate's sums in another order, which at rtol 1e-10 is
a sum of stages that nearly cancel).  Against the Python-stepped run (the method "DOP853", the
reference) the events are the same in number, order and kind, and their times and the final state
lie within ten times what a one-ulp nudge of the reference's post-impact velocities moves them (its
own round-off sensitivity, as tests/test_compiled_impulse.py bounds the compiled impulse).  The
impulses are the Python solve's in all three runs: this is about the stepping."""
from __future__ import annotations

import numpy as np
import pytest
from builders import EXAMPLES, driven_cart_pendulum, nudge_impulses

import pcmm
import pcmm.events.impulse as impulse
from pcmm.model import compiled
from pcmm.ode import integrators

pytestmark = pytest.mark.skipif(not compiled.enabled() or not hasattr(compiled._tree_dynamics, "SegmentLoop"),
                                reason=f"the compiled segment loop does not run here: {compiled.why_not()}")


def _run(path, monkeypatch, method, nudge=False, loops=None):
    with monkeypatch.context() as m:
        m.setattr(impulse, "compiled_impulse", lambda cfg, plan: None)
        if nudge:
            nudge_impulses(m)
        if loops is not None:
            real = integrators._segment_loop

            def counting(*args, **kwargs):
                loop, progress = real(*args, **kwargs)
                loops.append(loop is not None and kwargs.get("tableau") is not None)
                return loop, progress
            m.setattr(integrators, "_segment_loop", counting)
        return pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(method=method))


@pytest.mark.slow  # the working cycle three times (7.5 s, 531 events each)
@pytest.mark.parametrize("scene", ["cart", "three_bar_cycle"])
def test_auto_steps_drives_in_the_compiled_loop(scene, tmp_path, monkeypatch):
    path = driven_cart_pendulum(tmp_path) if scene == "cart" else EXAMPLES / f"{scene}.toml"
    loops = []
    fast = _run(path, monkeypatch, "auto", loops=loops)
    assert loops and all(loops), "a segment of a driven configuration was not stepped by the compiled loop"
    ref = _run(path, monkeypatch, "DOP853")
    nudged = _run(path, monkeypatch, "DOP853", nudge=True)
    kinds = lambda run: [(e["name"], e["from"], e["to"], e["merge"], e["impact"]) for e in run.events]  # noqa: E731
    assert kinds(fast) == kinds(ref) == kinds(nudged) and len(ref.events) >= 4
    gap = max(abs(a["t"] - b["t"]) for a, b in zip(fast.events, ref.events))
    own = max(abs(a["t"] - b["t"]) for a, b in zip(nudged.events, ref.events))
    assert gap <= max(10 * own, 1e-12), (gap, own)
    a, b, c = fast.segments[-1], ref.segments[-1], nudged.segments[-1]
    assert a.configuration == b.configuration and a.t[-1] == b.t[-1]
    moved = max(np.max(np.abs(c.q[-1] - b.q[-1])), np.max(np.abs(c.v[-1] - b.v[-1])))
    state = max(np.max(np.abs(a.q[-1] - b.q[-1])), np.max(np.abs(a.v[-1] - b.v[-1])))
    assert state <= max(10 * moved, 1e-10), (state, moved)


def test_the_loops_scipy_dense_output_is_dense_steps_to_the_bit():
    """The compiled loop's steps keep scipy's dense output (DenseStep's F rows); its evaluation at one
    time (integrators._ScipyDense: Horner on Python floats) gives DenseStep's bits, at drawn steps and
    times, the steps' ends included; an array of times is DenseStep's own."""
    from pcmm.ode.dop853 import DenseStep
    rng = np.random.default_rng(853)
    for _ in range(200):
        n = int(rng.integers(1, 7))
        t_old = float(rng.uniform(-5, 5))
        t_new = t_old + float(10.0 ** rng.uniform(-9, 0))
        y_old, F = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3), rng.standard_normal((7, n))
        fast, ref = integrators._ScipyDense(t_old, t_new, y_old, F), DenseStep(t_old, t_new, y_old, F)
        for t in [t_old, t_new, *rng.uniform(t_old, t_new, 5), np.float64(t_new)]:
            assert fast(t).tobytes() == ref(t).tobytes(), (t, fast(t), ref(t))
        ts = rng.uniform(t_old, t_new, 4)
        assert fast(ts).tobytes() == ref(ts).tobytes()
