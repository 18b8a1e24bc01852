"""Configuration switching: states map by joint name, and the URDFs must agree on every
shared link's pose at the switch (within 1e-9), or the run stops naming the link."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

import pcmm

ROOT = Path(__file__).resolve().parents[1]


def _copy(tmp_path, yaw_o3: str):
    for name in ("three_bar_config1.urdf", "three_bar_config2.urdf"):
        shutil.copy(ROOT / "urdf" / name, tmp_path / name)
    u2 = tmp_path / "three_bar_config2.urdf"
    text = u2.read_text()
    old = 'rpy="0 0 3.141592653589793"'
    assert old in text
    u2.write_text(text.replace(old, f'rpy="0 0 {yaw_o3}"'))
    scene = (ROOT / "examples" / "three_bar.toml").read_text().replace("../urdf/", "")
    (tmp_path / "s.toml").write_text(scene)
    return tmp_path / "s.toml"


def test_mismatched_merged_pose_stops_with_the_link_named(tmp_path):
    path = _copy(tmp_path, "3.0")  # the merged link3 placed 0.1416 rad off the latch pose
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(pcmm.load_scene(path))
    msg = info.value.text()
    assert "link 'link3'" in msg and "three_bar_config2.urdf" in msg and "allowed 1e-09" in msg
    assert "0.142 rad" in msg or "0.1416" in msg  # the angle it differs by
    partial = info.value.partial
    assert partial.segments and partial.segments[-1].configuration == "config1"  # config 1 is kept


def test_state_maps_by_joint_name_and_poses_agree(tmp_path):
    traj = pcmm.simulate(pcmm.load_scene(_copy(tmp_path, "3.141592653589793")), pcmm.RunOptions(t_end=0.2))
    before, after = traj.segments[0], traj.segments[1]
    assert after.coordinates == ["O1", "O2"]  # O3 is fixed in configuration 2
    # O1 and O2 keep their positions across the switch, link3's pose is continuous
    assert np.allclose(after.q[0], before.q[-1][:2], atol=1e-12)
    i1, i2 = before.links.index("link3"), after.links.index("link3")
    assert np.allclose(after.xy[0, i2], before.xy[-1, i1], atol=1e-9)
    assert after.theta[0, i2] == pytest.approx(before.theta[-1, i1], abs=1e-9)


@pytest.mark.parametrize("scene,t_end", [("double_folded.toml", 3.3)])
def test_potential_energy_is_continuous_across_a_merge(scene, t_end):
    """A body merged with the frame keeps its (constant) gravity energy: the slider welded at
    the stop (m g y = 0.455 * 9.81 * -0.1425 = -0.636 J) must not drop out of the total."""
    traj = pcmm.simulate(pcmm.load_scene(ROOT / "examples" / scene), pcmm.RunOptions(t_end=t_end))
    merge = [i for i, e in enumerate(traj.events) if e["merge"]]
    assert merge
    before, after = traj.segments[-2], traj.segments[-1]
    assert after.configuration == "config2" and before.configuration == "config1"
    assert after.potential[0] == pytest.approx(before.potential[-1], abs=1e-12)
    # and the welded slider's share is there: -m g y of the slider at the stop
    assert before.potential[-1] < -0.6
