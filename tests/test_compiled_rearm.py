"""A re-armed joint stop on a driven configuration, scanned by the compiled segment loop (issue 26).

Right after a bounce the stop's coordinate guard is re-armed (pcmm.events.guards.make_guard, rearm:
held on its unfired side until its rate approaches the stop).  On a driven configuration the free
coordinate and its rate are entries of the state, so the guard is linear in the state (Guard.linear)
though not affine (the coordinates are constrained); the compiled loop scans it (pcmm/model/
_segment_loop.hpp, `linear`) and hands a flight's step back to Python only where the guard may fire.
Before, every step of such a flight went through Python's scanner (_Stepper.accept).
"""
from __future__ import annotations

import numpy as np
import pytest
from builders import EXAMPLES, driven_cart_pendulum

import pcmm
from pcmm.model import compiled
from pcmm.ode import integrators
from pcmm.ode.integrators import _Stepper

pytestmark = pytest.mark.skipif(compiled._tree_dynamics is None or not compiled.enabled(),
                                reason=f"the compiled segment loop is not built or is off: {compiled.why_not()}")


def _run_counting(scene, m):
    """The run, and per segment the steps Python's scanner was handed (the candidate steps)."""
    handed = []
    accept = _Stepper.accept

    def counting(self, *args, **kwargs):
        handed[-1] += 1
        return accept(self, *args, **kwargs)
    segment_loop = integrators._segment_loop

    def loop(*args, **kwargs):
        handed.append(0)
        got = segment_loop(*args, **kwargs)
        assert got[0] is not None, "the compiled segment loop did not run"
        return got
    m.setattr(_Stepper, "accept", counting)
    m.setattr(integrators, "_segment_loop", loop)
    return pcmm.simulate(scene), handed


def _every_step_to_python(m):
    """The route before the linear scan: a guard linear but not affine in the state sends every step of
    its segment to Python's scanner."""
    m.setattr(integrators, "_linear_scan", lambda e, ny: None)


@pytest.mark.parametrize("scene_of", ["cart", "cycle"])
def test_flights_after_a_bounce_stay_in_the_compiled_loop(tmp_path, scene_of):
    path = driven_cart_pendulum(tmp_path, e=0.5, coefficients=(0.05, 0.3, 0.6, -0.5), t_end=2.5) \
        if scene_of == "cart" else EXAMPLES / "three_bar_cycle.toml"
    scene = pcmm.load_scene(path)
    with pytest.MonkeyPatch.context() as m:
        traj, handed = _run_counting(scene, m)
    with pytest.MonkeyPatch.context() as m:
        _every_step_to_python(m)
        before, handed_before = _run_counting(scene, m)
    impacts = [e for e in traj.events if e.get("impact")]
    assert len(impacts) >= 3, "the scene must bounce (flights after re-arming)"
    # the same run, to the bit: the loop steps the same way and Python locates each event on the same step
    assert [(e["name"], e["t"]) for e in traj.events] == [(e["name"], e["t"]) for e in before.events]
    for a, b in zip(traj.segments, before.segments):
        assert np.array_equal(a.t, b.t) and np.array_equal(a.q, b.q) and np.array_equal(a.v, b.v)
    # Python's scanner is handed each segment's event step and few more (a step where a guard comes near
    # zero: a flight whose end is near its start), where before it had every step of those segments
    steps = sum(len(s.t) - 1 for s in traj.segments)
    assert len(handed) == len(handed_before)  # (the rigid segments of no free coordinate: no loop)
    extra, extra_before = sum(handed) - len(handed), sum(handed_before) - len(handed)
    assert extra <= len(handed) / 3, (extra, len(handed))
    assert extra_before > 4 * extra, (extra_before, extra, steps)
