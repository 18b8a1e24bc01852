"""Model only what a scene requires: configurations are built when the run reaches them,
contacts are the declared points only, and a run that does not display loads no geometry."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pinocchio as pin

import pcmm
from pcmm.configuration import Mechanism

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
            "print(json.dumps(sorted(m for m in ('meshcat', 'matplotlib', 'pcmm.replay', 'pcmm.plots') if m in sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code, str(THREE_BAR)], capture_output=True, text=True, check=True)
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert "meshcat" not in loaded and "pcmm.replay" not in loaded and "matplotlib" not in loaded
