"""Scenes: a builder that allocates only what a scene asks for, and the presets over it."""
from .builder import SceneBuilder
from .grab import Grabber
from .params import Param
from .preset import ScenePreset
from .presets import SCENES, build_scene, scene_preset
from .scene import Scene

__all__ = ["SceneBuilder", "Param", "Grabber", "SCENES", "ScenePreset", "build_scene", "scene_preset", "Scene"]
