"""A scene's mechanism: all its configurations, each built when a run first reaches it.

It wires a :class:`~pcmm.configuration.Configuration` (the model of one URDF)
to its coordinate strategy (:func:`~pcmm.constraints.coordinates_for`), so
neither of those two modules imports the other's layer above it.
"""
from __future__ import annotations

import numpy as np

from .configuration import Configuration
from .constraints import coordinates_for
from ..scene.spec import Scene


class Mechanism:
    """All configurations of a scene, each built when the run first reaches it.

    A configuration derived by locking joints (:mod:`pcmm.derive`) is built when the run enters
    it (:meth:`enter`), for its locked joints' values at that instant, and built again if a later
    entry finds other values; ``mechanism[name]`` is the model the run last entered."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self._built: dict[str, Configuration] = {}
        self._derived: dict[str, list[Configuration]] = {}  # every model built per derived configuration

    def build(self, spec) -> Configuration:
        """A configuration's model and coordinates, built now (not cached)."""
        return Configuration(self.scene, spec, coordinates_for)

    def __getitem__(self, name: str) -> Configuration:
        if name not in self._built:
            if self.scene.configurations[name].derivation is not None:
                return self.enter(name)  # values given in the scene, else a clear error
            self._built[name] = self.build(self.scene.configurations[name])
        return self._built[name]

    def enter(self, name: str, src: Configuration | None = None, q: np.ndarray | None = None) -> Configuration:
        """The model of ``name`` as the run enters it from ``src`` at ``q``."""
        spec = self.scene.configurations[name]
        if spec.derivation is None:
            return self[name]
        from ..scene.derive import concrete, entry_values, same_values
        values = entry_values(spec, src, q)
        built = self._derived.setdefault(name, [])
        cfg = next((c for c in built if same_values(dict(c.spec.derivation.values), values)), None)
        if cfg is None:
            cfg = self.build(spec if spec.xml is not None else concrete(spec, values))
            built.append(cfg)
        self._built[name] = cfg
        return cfg

    @property
    def built(self) -> tuple[str, ...]:
        return tuple(self._built)

    @property
    def derived(self) -> dict[str, list[dict[str, float]]]:
        """{derived configuration: [its locked joints' values, one entry per model built]}."""
        return {name: [dict(c.spec.derivation.values) for c in cfgs] for name, cfgs in self._derived.items()}
