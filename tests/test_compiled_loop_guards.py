"""A closed loop's joint-coordinate guard located in C++ (pcmm/model/_guard_eval.hpp, kind "loop";
pcmm/model/_locate.hpp): its value q_j - target and rate q'_j on the compiled Loop's own solutions, the
same solves in the same order as the Python locator (pcmm.ode.integrators._locate_python) makes through
PartitionedCoordinates.unpack, so the same event times to the bit.  Checked on Example 2 (the slider's
stop E, a dependent coordinate of the loop closed at C), its working cycle, and drawn four-bars whose
rocker strikes a stop, each run with the compiled locator and with the Python one."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from builders import four_bar_rocker_stop, slider_crank_stop

import pcmm
from pcmm.events import guards
from pcmm.model import compiled
from pcmm.model.mechanism import Mechanism
from pcmm.ode import integrators

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

pytestmark = pytest.mark.skipif(not compiled.enabled() or not hasattr(compiled._tree_dynamics, "locate_guard"),
                                reason="the compiled locator of guards read by an evaluator is not built here")


def _counted(monkeypatch):
    """Counts the compiled locations of a loop's guard (their descriptions' kind "loop") and what they gave."""
    calls = []
    real = integrators._locate

    def spy(e, sol, t_a, t_b, g_a, tol):
        ev = getattr(e, "evaluator", None)
        if ev is not None and callable(ev[0]):
            calls.append(ev[0]() is not None)
        return real(e, sol, t_a, t_b, g_a, tol)
    monkeypatch.setattr(integrators, "_locate", spy)
    return calls


def _runs(path, monkeypatch, t_end=None):
    """(compiled locator, Python locator) runs of the scene at ``path``."""
    options = pcmm.RunOptions(t_end=t_end) if t_end else pcmm.RunOptions()
    calls = _counted(monkeypatch)
    fast = pcmm.simulate(pcmm.load_scene(path), options)
    taken = sum(calls)
    with monkeypatch.context() as m:
        m.setattr(guards, "COMPILED_LOOP_GUARDS", False)
        slow = pcmm.simulate(pcmm.load_scene(path), options)
    return fast, slow, taken


def _same_bits(fast, slow):
    assert [(e["name"], e["from"], e["to"]) for e in fast.events] == [(e["name"], e["from"], e["to"]) for e in slow.events]
    for a, b in zip(fast.events, slow.events):
        assert a["t"] == b["t"] and a["v_after"] == b["v_after"], (a["t"], b["t"])
    assert len(fast.segments) == len(slow.segments)
    for a, b in zip(fast.segments, slow.segments):
        assert a.t.tobytes() == b.t.tobytes() and a.q.tobytes() == b.q.tobytes() and a.v.tobytes() == b.v.tobytes()


@pytest.mark.parametrize("name, t_end, events", [("double_folded.toml", None, 47), ("double_folded_cycle.toml", 9.0, 40)])
def test_example_2_locates_its_stop_in_cpp_with_the_python_bits(monkeypatch, name, t_end, events):
    """Example 2's 47 impacts at the stop E (E a dependent coordinate of the loop) and the first 9 s of
    its cycle: every event of the loop's guard located by the compiled locator; the same events, event
    times, velocities and recorded samples as the Python locator's, to the bit."""
    fast, slow, taken = _runs(EXAMPLES / name, monkeypatch, t_end)
    assert len(fast.events) >= events
    assert taken >= events  # each event's location, and the candidate steps that did not fire
    _same_bits(fast, slow)


@pytest.mark.parametrize("seed", [3, 11])
def test_drawn_four_bars_and_a_slider_crank_locate_as_in_python(tmp_path, monkeypatch, seed):
    """A four-bar turned by a torque whose rocker strikes a stop (the rocker's angle D a coordinate of the
    loop), drawn; and a slider-crank whose slider strikes a stop: the compiled locator takes their
    guards, and the runs are the Python locator's to the bit."""
    rng = np.random.default_rng(seed)
    path = four_bar_rocker_stop(tmp_path / "fb", e=float(rng.uniform(0.3, 0.8)),
                                rocker_stop=float(rng.uniform(1.6, 2.2)), torque=float(rng.uniform(1.5, 5.0)),
                                theta0=float(rng.uniform(0.9, 1.1)), t_end=1.0)
    fast, slow, taken = _runs(path, monkeypatch)
    assert fast.events and taken >= 1
    _same_bits(fast, slow)
    path = slider_crank_stop(tmp_path / "sc", e=float(rng.uniform(0.3, 0.8)), t_end=1.0)
    fast, slow, taken = _runs(path, monkeypatch)
    assert fast.events and taken >= 1
    _same_bits(fast, slow)


def test_the_evaluator_reads_the_python_guard_at_the_loops_solutions():
    """At states along Example 2's first flight, the compiled description's value and rate are the Python
    guard's to the bit (the same Loop solving at the same state)."""
    scene = pcmm.load_scene(EXAMPLES / "double_folded.toml")
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=2.0))
    cfg = Mechanism(scene)["config1"]
    tr = scene.transitions[0]
    guard = guards.make_guard(cfg, tr)
    seg = traj.segments[0]
    y0 = cfg.coords.pack(float(seg.t[0]), seg.q[0], seg.v[0])
    describe = guard.evaluator[0]
    assert callable(describe)
    cfg.coords.unpack(float(seg.t[0]), y0)  # the compiled Loop built and seeded on this thread
    desc = describe()
    assert desc is not None and desc[0] == "loop" and desc[2] == cfg.joint_names.index("E")
    for k in range(0, len(seg.t), max(1, len(seg.t) // 7)):
        t = float(seg.t[k])
        y = np.concatenate([seg.q[k][cfg.coords.I], seg.v[k][cfg.coords.I]])
        value, rate = compiled._tree_dynamics.guard_value(desc, y, t)
        assert value == guard(t, y) and rate == guard.rate(t, y, None)
