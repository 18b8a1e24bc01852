"""Model only what a scene requires: configurations are built when the run reaches them,
contacts are the declared points only, and a run that does not display loads no geometry."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin

import pcmm
from builders import joint_xml, link_xml, robot_xml, scene_doc, write_scene
from pcmm.model.mechanism import Mechanism

ROOT = Path(__file__).resolve().parents[1]
THREE_BAR = ROOT / "examples" / "three_bar.toml"


def test_configuration_built_only_when_reached():
    scene = pcmm.load_scene(THREE_BAR)
    before = pcmm.simulate(scene, pcmm.RunOptions(t_end=0.1))  # the latch fires at 0.167 s
    assert before.stats["configurations_built"] == ["config1"]
    after = pcmm.simulate(scene, pcmm.RunOptions(t_end=0.2))
    assert after.stats["configurations_built"] == ["config1", "config2"]


def test_only_declared_points_are_modelled():
    cfg = Mechanism(pcmm.load_scene(THREE_BAR))["config1"]
    ops = [f.name for f in cfg.model.frames if f.type == pin.FrameType.OP_FRAME]
    # one transition with two contact points (link2 and link3 centroids); no collision pairs
    assert len(ops) == 2 and all(n.startswith("pcmm:") for n in ops)


def test_a_run_without_display_loads_no_geometry_and_no_viewer(tmp_path):
    code = ("import json, sys, pcmm; s = pcmm.load_scene(sys.argv[1]); pcmm.simulate(s, pcmm.RunOptions(t_end=0.2)); "
            "print(json.dumps(sorted(m for m in ('meshcat', 'matplotlib', 'pcmm.viz.replay', 'pcmm.viz.plots') if m in sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code, str(THREE_BAR)], capture_output=True, text=True, check=True)
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert "meshcat" not in loaded and "pcmm.viz.replay" not in loaded and "matplotlib" not in loaded


def test_the_dynamics_model_reads_no_visuals(tmp_path, capfd):
    """Visuals are the replay's: the dynamics model is built from the URDF without <visual>,
    <collision> and <material>, so a visual urdfdom cannot read prints nothing (urdfdom wrote
    four 'Error:' lines to stderr for this one) and the model is the same as without it."""
    bad_visual = ('<visual><geometry><box size="a b c"/></geometry>'
                  '<material name="x"><color rgba="1 0"/></material></visual>')
    models = {}
    for name, visual in (("plain", ""), ("bad_visual", bad_visual)):
        urdf = robot_xml("b", link_xml("frame"), joint_xml("J", "revolute", "frame", "bar"),
                         link_xml("bar", 2.0, com=(0.2, 0.0), izz=0.05, ixx=1.0, iyy=1.0, visual=visual))
        doc = scene_doc({"c": f"{name}.urdf"}, {"J": 0.3}, {"J": 0.0}, t_end=0.1, name="v")
        models[name] = Mechanism(pcmm.load_scene(write_scene(tmp_path, doc, {f"{name}.urdf": urdf}, f"{name}.toml")))["c"]
    err = capfd.readouterr().err
    assert "Error" not in err, err
    for m in models.values():  # a bar of 2 kg, centroid 0.2 m out: M = izz + m r^2
        assert np.allclose(m.mass_matrix(np.array([0.3])), [[0.05 + 2 * 0.2 ** 2]])
