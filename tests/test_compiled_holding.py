"""The compiled holding forces (pcmm/model/_holding.hpp) and the compiled segment loop's scan of the
guards that watch them (a merge held by compression only; a reaction guard).

* The compiled evaluator against the Python KKT solve it replaces (``Holds.forces``:
  ``constrained_accelerations`` on the reference configuration, built from scratch at each call),
  to 1e-12 of the forces' scale, at states drawn around the run's own (off the trajectory too), on
  the working cycle (a drive, two holds in ``folded``) and on a pendulum of our own (a tree, no
  drive) whose second joint is pressed onto its pin by a preloaded spring and let go when the
  pin's holding moment turns tensile.
* The releases (unmerge events) of both at the Python evaluator's times, with the same events in
  number, order and kind, within what a one-ulp nudge of the Python route's own guard value moves
  them (its round-off sensitivity).
* The guard steps the compiled loop hands back: only candidates, not every step.
* ``PCMM_COMPILED=0`` still gives the Python route.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from builders import EXAMPLES, bar_xml, joint_xml, link_xml, robot_xml, scene_doc, stop, write_scene

import pcmm
from pcmm.events import holding
from pcmm.model import compiled
from pcmm.ode import integrators

pytestmark = pytest.mark.skipif(not compiled.enabled() or not hasattr(compiled._tree_dynamics, "HoldingForces"),
                                reason=f"the compiled holding forces do not run here: {compiled.why_not()}")

CYCLE = EXAMPLES / "three_bar_cycle.toml"
ROOT = Path(__file__).resolve().parents[1]


def locked_pendulum(folder: Path, preload: float = 0.02, t_end: float = 2.2, method: str = "auto",
                    release_at: float | None = None) -> Path:
    """Two bars on J1 (the frame, at the origin) and J2 (link 1's tip, 0.4 m), gravity, released from
    horizontal at rest with J2 0.05 rad off its pin at J2 = 0.  A spring at J2 (tau = preload - 0.5
    q2 - 0.002 q2') presses link 2 onto the pin: it strikes it (e = 0.7), the bounces accumulate, the
    pin merges (configuration 'locked', J2 locked) and holds by compression only: it lets go when the
    moment it must apply turns tensile, twice within 2.2 s (0.418 s and 2.006 s).  ``release_at``: the
    pin holds for good (unmerge = false) and a release 'let go' watches its holding force instead (a
    reaction guard), firing when it drops to that value."""
    urdf = robot_xml("dp", link_xml("frame"), joint_xml("J1", "revolute", "frame", "link1"), bar_xml("link1", 0.4, 0.5),
                     joint_xml("J2", "revolute", "link1", "link2", xyz=(0.4, 0.0)), bar_xml("link2", 0.3, 0.3))
    tr = stop("pin", "open", 0.7, {"type": "coordinate", "measure": {"joint": "J2"}, "value": 0.0,
                                   "direction": "increasing"},
              {"joint": "J2", "arm": 0.15}, merge_to="locked", cut=["J2"], unmerge=release_at is None)
    transitions = [tr]
    if release_at is not None:
        transitions.append({"name": "let go", "type": "release", "from": "locked", "to": "open",
                            "guard": {"type": "reaction", "of": "pin", "value": release_at, "direction": "decreasing"}})
    spring = {"name": "spring J2", "type": "linear", "on": {"joint": "J2"}, "measure": {"joint": "J2"},
              "value": preload, "k": 0.5, "c": 0.002, "configurations": ["open"]}
    doc = scene_doc({"open": "dp.urdf", "locked": {"from": "open", "lock": ["J2"]}}, {"J1": 0.0, "J2": -0.05},
                    {"J1": 0.0, "J2": 0.0}, t_end=t_end, forces=[spring], transitions=transitions,
                    solver={"method": method, "rtol": 1e-10, "atol": 1e-12}, name="locked_pendulum")
    return write_scene(folder, doc, {"dp.urdf": urdf})


def _checked_evaluators(monkeypatch, seen):
    """Holds.evaluator wrapped: at each evaluator a segment builds, its compiled forces against the
    from-scratch Python KKT solve (Holds.forces) at the segment's start and at states drawn about it."""
    prepared = holding.Holds.evaluator
    rng = np.random.default_rng(26)

    def checked(self, cfg):
        fast = prepared(self, cfg)
        if getattr(fast, "labels", None) is not None:  # the compiled one
            q0, v0 = self._probe_state if hasattr(self, "_probe_state") else (None, None)
            for k in range(6):
                t = 0.1 + 7 * rng.random()
                q = rng.uniform(-np.pi, np.pi, cfg.nv)
                v = rng.uniform(-3, 3, cfg.nv)
                got = fast(t, q, v)
                want = self.forces(cfg, t, q, v)
                seen.append((cfg.name, got, want))
        return fast
    monkeypatch.setattr(holding.Holds, "evaluator", checked)


@pytest.mark.parametrize("scene", ["cycle", "pendulum"])
def test_compiled_holding_forces_are_the_python_kkt_solve(scene, monkeypatch, tmp_path):
    path = CYCLE if scene == "cycle" else locked_pendulum(tmp_path)
    seen = []
    _checked_evaluators(monkeypatch, seen)
    run = pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=2.2))
    assert len(seen) >= 12, "the compiled evaluator was never built"
    assert set(run.stats["holding_evaluations"].values()) == {"compiled"}, run.stats["holding_evaluations"]
    holds_seen = set()
    for name, got, want in seen:
        assert got.keys() == want.keys() and got
        holds_seen.add((name, len(got)))
        scale = max(abs(x) for x in want.values())
        for k in got:
            assert abs(got[k] - want[k]) <= 1e-12 * scale, (name, k, got[k], want[k])
    if scene == "cycle":
        assert ("folded", 2) in holds_seen and any(n != "folded" for n, _ in holds_seen)


def _python_holding(monkeypatch):
    monkeypatch.setattr(holding, "_compiled_evaluator", lambda *args: (None, "the test's reference"))


def _nudged_holding(monkeypatch):
    """The Python route with every guard value on a holding force moved by one ulp towards zero's
    other side: the reference's own round-off sensitivity."""
    _python_holding(monkeypatch)
    plain = holding.guard_value

    def nudged(cfg, forces, label, offset=0.0):
        value = plain(cfg, forces, label, offset)
        return lambda t, y: float(np.nextafter(value(t, y), np.inf))
    monkeypatch.setattr(holding, "guard_value", nudged)
    from pcmm.events import guards
    monkeypatch.setattr(guards, "holding_guard_value", nudged)


def _run(path, options=None):
    return pcmm.simulate(pcmm.load_scene(path), options or pcmm.RunOptions())


def _compare(fast, ref, nudged):
    kinds = lambda run: [(e["name"], e.get("kind")) for e in run.events]  # noqa: E731
    assert kinds(fast) == kinds(ref) == kinds(nudged)
    own = max(abs(a["t"] - b["t"]) for a, b in zip(nudged.events, ref.events))
    gap = max(abs(a["t"] - b["t"]) for a, b in zip(fast.events, ref.events))
    return gap, own


@pytest.mark.parametrize("method", ["auto", "DOP853F", "reaction"])
def test_pendulum_releases_at_the_python_times(method, monkeypatch, tmp_path):
    path = (locked_pendulum(tmp_path, release_at=-0.05) if method == "reaction" else
            locked_pendulum(tmp_path, method=method))
    fast = _run(path)
    with monkeypatch.context() as m:
        _python_holding(m)
        ref = _run(path)
    with monkeypatch.context() as m:
        _nudged_holding(m)
        nudged = _run(path)
    releases = [e["t"] for e in ref.events if e.get("kind") == "release"]
    if method == "reaction":  # let go a little after the force turned tensile
        assert len(releases) == 2 and 0.418 < releases[0] < 0.5 and 2.006 < releases[1] < 2.1, releases
    else:
        assert len(releases) == 2 and abs(releases[0] - 0.418) < 1e-3 and abs(releases[1] - 2.006) < 1e-3
    gap, own = _compare(fast, ref, nudged)
    assert gap <= max(10 * own, 1e-12), (gap, own)
    assert set(fast.stats["holding_evaluations"].values()) == {"compiled"}
    assert set(ref.stats["holding_evaluations"].values()) == {"python: the test's reference"}


def test_the_loop_scans_holding_guards_itself(monkeypatch, tmp_path):
    """Under DOP853F the locked pendulum's long segment in 'locked' (0.16 s to the release at 2.006 s)
    comes back to Python only at candidate steps: its holding guard is scanned in C++."""
    path = locked_pendulum(tmp_path, method="DOP853F")
    accepted, recorded = [0], [0]
    accept, record = integrators._Stepper.accept, integrators._record_steps

    def counting_accept(self, *args, **kw):
        if any(getattr(e, "holding", None) is not None for e in self.events):
            accepted[0] += 1
        return accept(self, *args, **kw)

    def counting_record(st, steps, kept=None):
        if any(getattr(e, "holding", None) is not None for e in st.events):
            recorded[0] += len(steps)
        return record(st, steps, kept)
    monkeypatch.setattr(integrators._Stepper, "accept", counting_accept)
    monkeypatch.setattr(integrators, "_record_steps", counting_record)
    run = _run(path)
    assert any(e.get("kind") == "release" for e in run.events)
    assert recorded[0] > 4 * accepted[0] > 0, (recorded[0], accepted[0])  # before: every step accepted in Python


def test_cycle_releases_at_the_python_times(monkeypatch):
    """The working cycle to 3.5 s (its first O2 and O3 releases, 1.199 s and 2.23 s, and the O2
    release of the second turn): the same events, at the Python evaluator's times within ten times
    what a one-ulp nudge of its guard values moves them."""
    options = pcmm.RunOptions(t_end=3.5)
    fast = _run(CYCLE, options)
    with monkeypatch.context() as m:
        _python_holding(m)
        ref = _run(CYCLE, options)
    with monkeypatch.context() as m:
        _nudged_holding(m)
        nudged = _run(CYCLE, options)
    assert sum(e.get("kind") == "release" for e in ref.events) >= 3
    gap, own = _compare(fast, ref, nudged)
    assert gap <= max(10 * own, 1e-12), (gap, own)


def test_python_route_without_the_extension(tmp_path):
    """PCMM_COMPILED=0: the holding forces are the Python evaluator's and say so."""
    path = locked_pendulum(tmp_path, t_end=0.5)
    code = ("import pcmm, sys\nr = pcmm.simulate(pcmm.load_scene(sys.argv[1]))\n"
            "print(sorted(set(r.stats['holding_evaluations'].values())))\n"
            "print(sum(e.get('kind') == 'release' for e in r.events))")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=300,
                         env={**os.environ, "PCMM_COMPILED": "0", "PYTHONPATH": str(ROOT)}, check=True).stdout.split("\n")
    assert out[0] == "['python: PCMM_COMPILED=0 in the environment']" and out[1] == "1"
