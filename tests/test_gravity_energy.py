"""Configuration.gravity_energy's share of the bodies welded to the frame, computed once per model
(h-cycle2): the same value on a fresh build, on a build from the process cache, and for another
gravity (a model of its own)."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

import pcmm
from pcmm.model.mechanism import Mechanism

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("g", [9.81, 1.62])
def test_the_welded_share_is_m_g_y_of_the_slider_on_every_build(g):
    """double_folded's config2 has the slider (0.455 kg) welded at its stop, its centre at y = -0.1425 m:
    its share is m g y = -0.455 g 0.1425 J, by hand, whatever the posture of the free links."""
    scene = dataclasses.replace(pcmm.load_scene(ROOT / "examples" / "double_folded.toml"), gravity=(0.0, -g))
    want = 0.455 * -g * 0.1425
    for _ in range(2):  # built, then taken from the process's model cache
        cfg = Mechanism(scene)["config2"]
        for q in (np.full(cfg.nv, 0.3), np.linspace(-1.0, 2.0, cfg.nv)):
            free = pin.computePotentialEnergy(cfg.model, cfg.data, cfg.to_pin(q))
            assert cfg.gravity_energy(q) - free == pytest.approx(want, rel=1e-14, abs=1e-15)
