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


def test_a_merged_urdf_written_on_the_other_2pi_branch_runs_the_same(tmp_path):
    """Example 1's merged URDF with O3's yaw written -pi instead of pi: the same posture, so the
    same run.  The torsion spring tau3 across O3 (k = 0.026 N m/rad) measures theta3 - theta2 as the
    run's series give it (pi, continuing configuration 1), not as the URDF writes it (-pi): before
    that, it pushed with 2 pi k = 0.163 N m more after the latch and the run ended 3.5 rad apart."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    ref = pcmm.simulate(pcmm.load_scene(_copy(tmp_path / "a", "3.141592653589793")))
    other = pcmm.simulate(pcmm.load_scene(_copy(tmp_path / "b", "-3.141592653589793")))
    assert [e["t"] for e in other.events] == [e["t"] for e in ref.events] and len(ref.events) == 1
    a, b = ref.segments[-1], other.segments[-1]
    i = a.force_names.index("tau3")
    assert b.forces[0, i] == pytest.approx(a.forces[0, i], abs=1e-12)  # not 0.163 N m apart
    assert b.forces[0, i] == pytest.approx(0.2300 - 0.026 * (a.theta[0, 3] - a.theta[0, 2]), abs=1e-12)  # Eq. 44
    np.testing.assert_allclose(b.q[-1], a.q[-1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.theta[-1], a.theta[-1], rtol=0, atol=1e-9)
    assert b.potential[-1] == pytest.approx(a.potential[-1], abs=1e-9)  # the spring's energy too


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
