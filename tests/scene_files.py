"""Copies of shipped scenes in a temporary folder, for tests that delete them after a run."""
from __future__ import annotations

import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def copy_example1(tmp_path: Path) -> Path:
    """``examples/three_bar.toml`` and its two URDFs under ``tmp_path`` (same relative layout);
    returns the scene's path."""
    (tmp_path / "examples").mkdir()
    (tmp_path / "urdf").mkdir()
    scene = tmp_path / "examples" / "three_bar.toml"
    shutil.copy(ROOT / "examples" / "three_bar.toml", scene)
    for f in ("three_bar_config1.urdf", "three_bar_config2.urdf"):
        shutil.copy(ROOT / "urdf" / f, tmp_path / "urdf" / f)
    return scene
