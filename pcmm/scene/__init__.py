"""A scene as data: the TOML format (schema, expressions, settings), the URDF reader, the
validated dataclasses (spec), derived configurations, variations and ``pcmm new``'s templates.
Nothing here builds a model: validating a scene needs no Pinocchio."""
from .load import load_scene, load_scene_data

__all__ = ["load_scene", "load_scene_data"]
