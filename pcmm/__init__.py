"""pcmm: impact dynamics of planar constrained metamorphic mechanisms.

Song et al., "An Approach for the Impact Dynamic Modeling and Simulation of
Planar Constrained Metamorphic Mechanism", Shock and Vibration 2020.

    >>> import pcmm
    >>> scene = pcmm.load_scene("examples/three_bar.toml")
    >>> traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=0.2))
    >>> round(traj.events[0]["t"], 4)  # the paper's t_p = 0.1674 s
    0.1673

The package's face is lazy (PEP 562): ``import pcmm`` loads only the errors; each name below is
imported from its layer when first used, so validating a scene loads no Pinocchio and a saved
run replays without one.
"""
from .errors import ModelError, PcmmError, SceneError, SimulationError, UsageError

__version__ = "0.1.0"

#: the public names and the module of each
_PUBLIC = {
    "load_scene": "pcmm.scene.load",
    "simulate": "pcmm.run.loop",
    "RunOptions": "pcmm.scene.settings",
    "Scene": "pcmm.scene.spec",
    "Trajectory": "pcmm.results.trajectory",
}

__all__ = ["load_scene", "simulate", "RunOptions", "Trajectory", "Scene", "PcmmError", "SceneError",
           "ModelError", "SimulationError", "UsageError"]


def __getattr__(name: str):
    if name in _PUBLIC:
        import importlib
        value = getattr(importlib.import_module(_PUBLIC[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'pcmm' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_PUBLIC))
