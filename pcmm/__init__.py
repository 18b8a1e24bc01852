"""pcmm: impact dynamics of planar constrained metamorphic mechanisms.

Song et al., "An Approach for the Impact Dynamic Modeling and Simulation of
Planar Constrained Metamorphic Mechanism", Shock and Vibration 2020.

    >>> import pcmm
    >>> scene = pcmm.load_scene("examples/three_bar.toml")
    >>> traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=0.2))
    >>> round(traj.events[0]["t"], 4)  # the paper's t_p = 0.1674 s
    0.1673
"""
import os as _os
import sys as _sys

_argv = getattr(_sys, "orig_argv", _sys.argv)
_as_command = (_os.path.basename(_sys.argv[0] if _sys.argv else "") == "pcmm" or "pcmm.cli" in _argv[:4])
try:
    from .errors import ModelError, PcmmError, SceneError, SimulationError, UsageError
    from .scene import load_scene
    from .settings import RunOptions
    from .simulate import simulate
    from .spec import Scene
    from .trajectory import Trajectory
    if _as_command:  # the console script's next line imports the command line: inside this guard too
        from . import cli as _cli  # noqa: F401
except (KeyboardInterrupt, ImportError) as _exc:
    # Ctrl-C while Pinocchio and scipy load, before the command line's own handling. A compiled
    # (pybind11) module that is initialising when the signal lands turns the KeyboardInterrupt
    # into "ImportError: initialization failed" with the interrupt as its cause: both are Ctrl-C.
    _chain, _interrupted = _exc, False
    while _chain is not None and not _interrupted:
        _interrupted = isinstance(_chain, KeyboardInterrupt)
        _chain = _chain.__cause__ or _chain.__context__
    if _interrupted and _as_command:
        print("pcmm: interrupted by the user (Ctrl-C) while starting", file=_sys.stderr)
        raise SystemExit(130) from None
    raise

# The data model and the results call the layers above them through these bindings (the loader's
# validation for Scene.with_values; the views for Trajectory.show/plot, imported when first used).
from . import spec as _spec, trajectory as _trajectory  # noqa: E402
from .variations import with_values as _with_values  # noqa: E402


def _show(traj, *others, **options):
    from .replay import Inline
    return Inline(traj, *others, **options)


def _plot(traj, **options):
    from .plots import figures
    return figures(traj, **options)


_spec.EDIT_VALUES = _with_values
_trajectory.VIEWS.update(show=_show, plot=_plot)

__all__ = ["load_scene", "simulate", "RunOptions", "Trajectory", "Scene", "PcmmError", "SceneError",
           "ModelError", "SimulationError", "UsageError"]
__version__ = "0.1.0"
