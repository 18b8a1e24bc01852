"""pcmm: impact dynamics of planar constrained metamorphic mechanisms.

Song et al., "An Approach for the Impact Dynamic Modeling and Simulation of
Planar Constrained Metamorphic Mechanism", Shock and Vibration 2020.

    >>> import pcmm
    >>> scene = pcmm.load_scene("examples/three_bar.toml")
    >>> traj = pcmm.simulate(scene)
    >>> traj.events[0]["t"]
"""
from .errors import ModelError, PcmmError, SceneError, SimulationError, UsageError
from .scene import Scene, load_scene
from .simulate import RunOptions, simulate
from .trajectory import Trajectory

__all__ = ["load_scene", "simulate", "RunOptions", "Trajectory", "Scene", "PcmmError", "SceneError",
           "ModelError", "SimulationError", "UsageError"]
__version__ = "0.1.0"
