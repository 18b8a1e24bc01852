"""The compiled loops' right-hand side (pcmm/model/_loops.hpp) on terms the examples leave at zero:
Example 2's drive is uniform (f'' = 0: the drive row's acceleration term, the KKT right-hand side's
-f'', vanishes) and Andrews' point spring has no damping (its -c L' term vanishes).  Here Example 2
turns its crank with an accelerating law and carries a damped point spring: compiled against the
Python evaluation (a second implementation) at random states near each loop segment's start, to
1e-10 relative, and the run's configurations stay compiled (the probe check would otherwise hand
them to Python without a failure)."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from test_compiled_loops import _compare_at_random_states, _loop_starts

import pcmm
from pcmm.model import compiled

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(not compiled.enabled() or not hasattr(compiled._tree_dynamics, "Loop"),
                                reason="the compiled loops are not built here")

DRIVE = ("coefficients = [3.141592653589793, 0.6283185307179586]",
         "coefficients = [3.141592653589793, 0.6283185307179586, 0.9]")  # theta1'' = 1.8 rad/s^2
DAMPED_SPRING = """
[[forces]]
name = "damped point spring"
type = "point_spring"
a = "frame"
point_a = [0.05, 0.12]
b = "link3"
point_b = [0.05, 0.0]
k = 40.0
rest = 0.08
c = 2.5
"""


def _example2_accelerating_and_damped(tmp_path: Path) -> Path:
    (tmp_path / "scenes").mkdir()
    shutil.copytree(ROOT / "urdf", tmp_path / "urdf")
    text = (ROOT / "examples" / "double_folded.toml").read_text()
    assert text.count(DRIVE[0]) == 1
    text = text.replace(DRIVE[0], DRIVE[1]) + DAMPED_SPRING
    path = tmp_path / "scenes" / "double_folded_accelerating.toml"
    path.write_text(text)
    return path


def test_an_accelerating_drive_and_a_damped_point_spring_are_the_python_evaluation(tmp_path):
    scene = pcmm.load_scene(_example2_accelerating_and_damped(tmp_path))
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=1.0))
    assert set(traj.stats["evaluations"].values()) == {"compiled"}, traj.stats["evaluations"]
    starts = _loop_starts(scene, traj)
    assert starts, "the scene visits a configuration with loops"
    assert _compare_at_random_states(scene, starts, np.random.default_rng(3)) < 1e-10
