"""Rendering: scenes drawn with GGUI (Vulkan), on screen or offscreen, and written to video.

The renderer reads scenes (through :func:`taichi_sim.scene.visual.describe`); it never steps
them. Importing this package needs no Vulkan; opening a window does.
"""
from .camera import OrbitCamera
from .drawer import DrawOptions, SceneDrawer
from .renderer import Renderer
from .video import VideoWriter, parse_size
from .vulkan import RenderUnavailable, has_display, open_window, vulkan_problem

__all__ = ["OrbitCamera", "DrawOptions", "SceneDrawer", "Renderer", "VideoWriter", "parse_size",
           "RenderUnavailable", "has_display", "open_window", "vulkan_problem"]
