"""A study at scale (issue 25 item 4, issue 26): what a sweep spends outside its runs.

The plan is validated with one scene build per run (not one per run and per swept value), the
table is made durable in batches (an fsync at most once a second and at the end), and the rows
stay those a sweep reported as written after a kill."""
from __future__ import annotations

from pathlib import Path

import pytest

import pcmm
from pcmm.errors import SceneError
from pcmm.scene.spec import Scene
from pcmm.studies.sweep import Axis, make_plan, validate_plan

from builders import EXAMPLES

THREE_BAR = EXAMPLES / "three_bar.toml"
STOP = EXAMPLES / "three_bar_stop.toml"


@pytest.fixture
def builds(monkeypatch):
    """Count the scene builds (``Scene.with_values``)."""
    count = [0]
    real = Scene.with_values

    def counted(self, values):
        count[0] += 1
        return real(self, values)
    monkeypatch.setattr(Scene, "with_values", counted)
    return count


def test_a_valid_plan_is_validated_with_one_build_per_run(builds):
    # 40 random samples of two paths: every value distinct, so checking each value alone too
    # cost 3 builds a run (120); each run's own build checks its values as well
    plan = make_plan([Axis("forces.tau1.value", low=1.8, high=2.2), Axis("forces.tau3.value", low=0.15, high=0.35)],
                     "random", 40, 1)
    validate_plan(pcmm.load_scene(THREE_BAR), plan)
    assert builds[0] == 40


def test_a_bad_value_is_still_named_on_its_own(builds):
    scene = pcmm.load_scene(STOP)
    plan = make_plan([Axis("forces.tau1.value", (1.0, 2.0)), Axis("transitions.O3 stop.restitution", (0.5, 1.5))])
    with pytest.raises(SceneError) as info:
        validate_plan(scene, plan)
    assert info.value.problems == [f"--set transitions.O3 stop.restitution = 1.5: {STOP}: "
                                   "transitions[0] (O3 stop).restitution: = 1.5: must be in [0, 1]"]
    # run 0 (valid), run 1 (fails), then its two values alone
    assert builds[0] == 4
