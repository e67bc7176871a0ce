"""Applications over the renderer: the interactive launcher and offscreen recording.

:class:`Session` (scenes stepped in lockstep plus the control state) and :class:`Runner` (one
scene, one integrator, frozen on divergence) are plain Python; only
:class:`~taichi_sim.app.launcher.Launcher` needs a display.
"""
from .record import Clip, Recording, record
from .runner import Runner
from .session import Session
from .showcase import SHOWCASE, Showcase, record_showcase

__all__ = ["Clip", "Recording", "record", "Runner", "Session", "SHOWCASE", "Showcase", "record_showcase"]
