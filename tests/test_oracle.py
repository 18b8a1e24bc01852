"""The differential oracle (tests/oracle.py) over every shipped example and the scenes the tests build.

Each case runs a scene (a short ``t_end`` where its run is long), recomputes every recorded
series at sampled instants of every segment from ``(t, q, v)`` and the scene's data alone
(an independent Pinocchio model, force elements, constraint rows and KKT solve), checks every
event, and checks the same on the run resampled at ``dt``.  The prefix cases run each scene to
two ``t_end`` values and require the common part of every series, of its ``dt`` resampling and
of its CSV to agree.  ``docs/oracle.md`` says what is checked and how to add a scene.
"""
from __future__ import annotations

import math

import pytest

import pcmm
from pcmm.errors import SimulationError

import builders
import oracle
from builders import EXAMPLES

#: every shipped example: (t_end, dt of the resampled check), short where the run is long
EXAMPLE_RUNS = {
    "three_bar.toml": (0.4, 0.01),  # the latch at 0.167 s and the locked stretch after it
    "three_bar_stop.toml": (0.5, 0.01),  # the stop, its bounces and the merge
    "andrews.toml": (0.03, 0.001),  # the seven-body loop, the whole run
    "double_folded.toml": (1.5, 0.05),  # the driven loop, the slider's stop, bounces and merge
    "double_folded_cycle.toml": (1.5, 0.05),
    "three_bar_cycle.toml": (1.3, 0.05),  # merges, the fold, and the first release
}


def _findings(path, t_end=None, dt=None, **options):
    """The oracle's findings on the run (a run that stops keeps its partial trajectory)."""
    scene = pcmm.load_scene(path)
    try:
        traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=t_end, **options) if t_end else pcmm.RunOptions(**options))
    except SimulationError as exc:
        if exc.partial is None or not exc.partial.segments:
            raise
        traj = exc.partial
    found = oracle.check_run(path, traj=traj)
    if dt is not None:
        found += oracle.check_run(path, traj=traj.resampled(dt))
    return traj, found


def _show(found) -> str:
    seen, lines = set(), []
    for f in found:
        if f.what not in seen:
            seen.add(f.what)
            lines.append(str(f))
    return f"{len(found)} disagreements, {len(lines)} kinds:\n" + "\n".join(lines[:20])


@pytest.mark.parametrize("name", sorted(EXAMPLE_RUNS))
def test_every_example_agrees_with_the_oracle(name):
    assert sorted(p.name for p in EXAMPLES.glob("*.toml")) == sorted(EXAMPLE_RUNS), \
        "a new example: give it a t_end and dt in EXAMPLE_RUNS"
    t_end, dt = EXAMPLE_RUNS[name]
    traj, found = _findings(EXAMPLES / name, t_end, dt)
    assert len(traj.segments) >= 1
    assert not found, _show(found)


#: the scenes tests/builders.py builds, with numbers that make their events happen within t_end
BUILT = {
    "ball": lambda d: builders.ball(d, 0.5, h=0.3, t_end=0.8),
    "pendulum": lambda d: builders.pendulum(d, 0.5, q0=0.3, t_end=1.2),
    "spring_pendulum": lambda d: builders.spring_pendulum(d, 3.0, 0.1, t_end=0.5),
    "two_link": lambda d: builders.two_link(d, 0.6, 1.0, 0.7, t_end=0.4),
    "two_free_bodies": lambda d: builders.two_free_bodies(d, 0.8, 1.0, 2.0, 0.01, 0.03),
    "two_balls": lambda d: builders.two_balls(d, 0.5, 0.8),
    "flat_bar": lambda d: builders.flat_bar(d, 0.5, t_end=0.35),
    "slider_crank_slider_driven": lambda d: builders.slider_crank_slider_driven(d, [0.35, 0.02, -0.01], t_end=0.5),
    "parallelogram": lambda d: builders.parallelogram(d, 0.5, 2.0, t_end=0.5),
    "slider_crank_stop": lambda d: builders.slider_crank_stop(d, 0.5, t_end=1.0),
    "four_bar_rocker_stop": lambda d: builders.four_bar_rocker_stop(d, 0.5, 2.2, torque=5.0, t_end=0.6),
    "four_bar_latch": lambda d: builders.four_bar_latch(d),
}


@pytest.mark.parametrize("name", sorted(BUILT))
def test_every_built_scene_agrees_with_the_oracle(name, tmp_path):
    traj, found = _findings(BUILT[name](tmp_path), dt=0.01)
    assert not found, _show(found)


def test_the_copied_example_agrees_with_the_oracle(tmp_path):
    """tests/scene_files.py's copy of Example 1 (the scene the deletion tests run)."""
    from scene_files import copy_example1
    _, found = _findings(copy_example1(tmp_path), 0.25, 0.01)
    assert not found, _show(found)


#: (scene, the shorter t_end, the longer one, dt): each shorter run ends inside a stretch that the
#: longer run goes on through (a locked stretch, a bounce sequence, a driven loop)
PREFIX = [
    ("three_bar.toml", 0.12, 0.3, 0.01),
    ("three_bar.toml", 0.2, 0.35, 0.01),
    ("three_bar_stop.toml", 0.2, 0.4, 0.01),
    ("double_folded.toml", 0.8, 1.6, 0.05),
    ("andrews.toml", 0.01, 0.02, 0.001),
    ("three_bar_cycle.toml", 0.3, 0.7, 0.05),
]


@pytest.mark.parametrize("name, t_short, t_long, dt", PREFIX)
def test_a_shorter_run_is_the_first_part_of_a_longer_one(name, t_short, t_long, dt, tmp_path):
    problems = oracle.check_prefix(EXAMPLES / name, t_short, t_long, dt, tmp_path)
    assert not problems, "\n".join(problems[:20])


def test_the_oracle_sees_a_wrong_number(tmp_path):
    """The oracle can fail: one recorded holding moment, energy and pose changed by a little
    are each reported at their instant."""
    traj = pcmm.simulate(pcmm.load_scene(EXAMPLES / "three_bar.toml"), pcmm.RunOptions(t_end=0.3))
    seg = traj.segments[1]
    k = seg.constraint_labels.index("O3.hold")
    seg.constraint_forces[3, k] += 1e-3
    seg.kinetic[0] += 1e-6
    seg.xy[-1, 2, 0] += 1e-6
    traj.events[0]["kinetic_energy_after"] += 1e-4
    found = oracle.check_run(EXAMPLES / "three_bar.toml", traj=traj, samples=len(seg.t))
    whats = {f.what for f in found}
    assert "config2: constraint force O3.hold" in whats
    assert "config2: kinetic energy" in whats
    assert "config2: x,y of link2" in whats
    # the kinetic energy after the latch is the event record's too
    assert any(f.what.startswith("event 'O3 latches': kinetic_energy_after") for f in found)
    assert all(math.isclose(f.t, seg.t[3]) or math.isclose(f.t, seg.t[0]) or math.isclose(f.t, seg.t[-1])
               for f in found)
