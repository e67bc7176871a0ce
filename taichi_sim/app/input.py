"""Keys and mouse for the launcher, in plain Python (tested without a window).

Mouse: right-drag orbits the camera, middle-drag (or the i and o keys) zooms; GGUI 1.7.4
reports no scroll-wheel events. Left-drag goes to a :class:`GrabHook` when the scene has one
(the launcher builds every scene that can be grabbed with grab on).
"""
from __future__ import annotations

import math
from typing import Protocol, Sequence

import numpy as np

from ..render.camera import OrbitCamera
from .session import Session

#: Key -> (action, what it does). GGUI names keys by their character (" " is the space bar);
#: GGUI 1.7.4 reports letters, the space bar, Tab, Escape and the arrows, but no digits or
#: punctuation, so every action sits on one of those.
KEYMAP: dict[str, tuple[str, str]] = {
    " ": ("pause", "pause / resume"),
    "n": ("step", "single step (pauses)"),
    "r": ("reset", "reset (applies pending parameters)"),
    "m": ("mesh", "show / hide the cloth surface"),
    "k": ("springs", "show / hide springs"),
    "p": ("particles", "show / hide particles"),
    "c": ("strain", "strain colour map on / off"),
    "t": ("trail", "show / hide trails"),
    "e": ("energy", "show / hide the energy plot"),
    "x": ("contacts", "show / hide the contacts held in vbd's solve (magenta: the cloth on itself, green: on objects)"),
    "f": ("home", "frame the view (home)"),
    "Down": ("next_scene", "next scene"),
    "Up": ("previous_scene", "previous scene"),
    "Right": ("next_integrator", "next integrator (first panel)"),
    "Left": ("previous_integrator", "previous integrator (first panel)"),
    "i": ("zoom_in", "zoom in"),
    "o": ("zoom_out", "zoom out"),
    "h": ("help", "this help"),
    "Escape": ("quit", "quit"),
}

MOUSE_HELP = ("right-drag: orbit the camera", "middle-drag: zoom",
              "left-drag: pull the cloth or chain (the particle follows the mouse)")

ZOOM_STEP = 1.15


def help_lines() -> list[str]:
    """The help overlay's lines: every key and mouse action."""
    keys = [f"{'space' if k == ' ' else k:>6}  {text}" for k, (_, text) in KEYMAP.items()]
    return keys + [""] + list(MOUSE_HELP)


def apply_key(key: str, session: Session, camera: "CameraControl") -> str | None:
    """Do what ``key`` means; returns the action's name (None for an unmapped key)."""
    if key not in KEYMAP:
        return None
    action = KEYMAP[key][0]
    options = session.options
    if action == "pause":
        session.toggle_pause()
    elif action == "step":
        session.step()
    elif action == "reset":
        session.reset()
    elif action in ("mesh", "springs", "particles", "strain", "trail", "energy", "contacts"):
        setattr(options, action, not getattr(options, action))
    elif action == "help":
        session.show_help = not session.show_help
    elif action == "home":
        camera.home()
    elif action in ("next_scene", "previous_scene"):
        session.cycle_scene(1 if action == "next_scene" else -1)
    elif action in ("next_integrator", "previous_integrator"):
        session.cycle_integrator(0, 1 if action == "next_integrator" else -1)
    elif action in ("zoom_in", "zoom_out"):
        camera.zoom(1 / ZOOM_STEP if action == "zoom_in" else ZOOM_STEP)
    return action


class GrabHook(Protocol):
    """Where left-drags go. Rays are (origin (3,), unit direction (3,)) in world space (m)."""

    def pick(self, origin: np.ndarray, direction: np.ndarray) -> float | None:
        """Find what a press along the ray would grab; return its distance from the ray (m), or
        None when nothing is in reach (the controller holds the closest of several hooks)."""

    def hold(self) -> None:
        """Grab what the last :meth:`pick` found."""

    def drag(self, origin: np.ndarray, direction: np.ndarray, normal: np.ndarray | None = None) -> None:
        """Move the held point to where the ray meets the plane through the picked point with
        unit ``normal`` (the camera's viewing direction; default: the picking ray's)."""

    def release(self) -> None:
        """Let go."""


class GrabberHook:
    """Adapts a scene's grab API (``pick``, ``grab``, ``drag_to``, ``release``; see
    :class:`taichi_sim.scene.grab.Grabber`) to :class:`GrabHook`, for a scene drawn shifted by
    ``offset`` (m). The held particle is pulled toward where the mouse ray meets a plane facing
    the camera through the point picked, so it follows the cursor across the screen.

    Args:
        grabber: the scene's grab API.
        offset: (3,) where the scene is drawn relative to its own coordinates (m).
        reach: the farthest a particle may be from the ray to be picked (m).
    """

    def __init__(self, grabber, offset, reach: float):
        self.grabber = grabber
        self.offset = np.asarray(offset, np.float64).reshape(3)
        self.reach = float(reach)
        self.anchor = np.zeros(3)  # the picked particle where it was picked (scene coordinates, m)
        self.pick_direction = np.array([0.0, 0.0, -1.0])
        self.candidate: int | None = None

    def pick(self, origin, direction) -> float | None:
        local = np.asarray(origin, np.float64) - self.offset
        direction = np.asarray(direction, np.float64)
        self.candidate = self.grabber.pick(local, direction, max_distance=self.reach)
        if self.candidate is None:
            return None
        x = np.asarray(self.grabber.scene.state.x.to_numpy()[self.candidate], np.float64)
        self.anchor, self.pick_direction = x, direction
        depth = float(np.dot(x - local, direction))
        return float(np.linalg.norm(x - local - depth * direction))

    def hold(self) -> None:
        self.grabber.grab(self.candidate)

    def drag(self, origin, direction, normal=None) -> None:
        local = np.asarray(origin, np.float64) - self.offset
        direction = np.asarray(direction, np.float64)
        normal = self.pick_direction if normal is None else np.asarray(normal, np.float64)
        facing = float(np.dot(direction, normal))
        if facing <= 1e-6:  # the ray runs along the plane or away from it: keep the last target
            return
        s = float(np.dot(self.anchor - local, normal)) / facing
        self.grabber.drag_to(local + s * direction)

    def release(self) -> None:
        self.grabber.release()


class CameraControl:
    """The orbit camera plus the mouse state that drives it and the grab hooks.

    Args:
        camera: the renderer's camera (changed in place).
        home: called to restore the start-up view.
        hooks: :class:`GrabHook` objects (one per panel whose scene can be grabbed).
    """

    def __init__(self, camera: OrbitCamera, home, hooks: Sequence[GrabHook] = ()):
        self.camera = camera
        self._home = home
        self.hooks = list(hooks)
        self.user_moved = False  # the user orbited or zoomed: automatic framing stops
        self.held: GrabHook | None = None
        self._last: tuple[float, float] | None = None
        self._left_before = False

    def home(self) -> None:
        self._home()
        self.user_moved = False

    def zoom(self, factor: float) -> None:
        self.camera.zoom(factor)
        self.user_moved = True

    def update(self, u: float, v: float, *, left: bool, right: bool, middle: bool,
               over_panel: bool = False) -> None:
        """Feed one frame's cursor position (screen units, v up) and mouse buttons.

        Right-drag orbits, middle-drag zooms (up: closer). A left press not over the control
        panel picks with every hook and holds the closest hit; dragging moves it; releasing lets
        go.
        """
        last, self._last = self._last, (u, v)
        du, dv = (0.0, 0.0) if last is None else (u - last[0], v - last[1])
        pressed = left and not self._left_before
        self._left_before = left
        if right and (du or dv):
            self.camera.orbit(du, dv)
            self.user_moved = True
        elif middle and dv:
            self.zoom(math.exp(-2.0 * dv))
        if pressed and not over_panel and self.held is None:
            origin, direction = self.camera.screen_ray(u, v)
            hits = [(d, hook) for d, hook in ((h.pick(origin, direction), h) for h in self.hooks)
                    if d is not None]
            if hits:
                self.held = min(hits, key=lambda hit: hit[0])[1]
                self.held.hold()
        elif left and self.held is not None:
            if du or dv:
                self.held.drag(*self.camera.screen_ray(u, v), self.camera.forward)
        elif not left and self.held is not None:
            self.held.release()
            self.held = None
