"""Scenes: a builder that allocates only what a scene asks for, and the presets over it."""
from .builder import SceneBuilder
from .params import Param
from .presets import SCENES, ScenePreset, build_scene, scene_preset
from .scene import Scene

__all__ = ["SceneBuilder", "Param", "SCENES", "ScenePreset", "build_scene", "scene_preset", "Scene"]
