"""The renderer: one or more scenes, side by side, in a GGUI window seen by an orbit camera."""
from __future__ import annotations

import contextlib
import math
from typing import Sequence

import numpy as np
import taichi as ti

from ..scene.visual import SceneVisual
from .camera import OrbitCamera
from .drawer import DRAWABLE_LIMIT, DrawOptions, SceneDrawer, layout_offsets

BACKGROUND = (0.075, 0.085, 0.105)
AMBIENT = (0.38, 0.38, 0.40)
LIGHT = (0.72, 0.70, 0.66)
_BACKGROUND_RGB = np.round(np.asarray(BACKGROUND) * 255).astype(np.int16)
BACKGROUND_RETRIES = 5
"""How many times :meth:`Renderer.read_image` declares and reads again a frame that came back as
background only (a GGUI fault on Mesa's software Vulkan; the method's docstring)."""


@contextlib.contextmanager
def _quiet_taichi_warnings():
    """Raise Taichi's log level to errors for the duration (restored to warnings after, if they
    were shown before)."""
    warn = ti._logging.is_logging_effective(ti.WARN)
    ti.set_logging_level(ti.ERROR)
    try:
        yield
    finally:
        if warn:
            ti.set_logging_level(ti.WARN)


class Renderer:
    """Draws ``visuals`` into ``window``: scene k shifted along x by ``offsets[k]`` (m).

    The renderer reads positions (a scene's field or an array); it never steps a scene.
    Staging fields are allocated once here, so build one renderer per set of scenes and reuse it.

    Args:
        window: a ``ti.ui.Window`` (see :func:`taichi_sim.render.open_window`).
        visuals: what to draw, one :class:`SceneVisual` per scene.
        size: the window's (width, height) in pixels.
        inset: fraction of the window width a control panel covers on the left; the scenes are
            framed in the rest.
        bottom: fraction of the window height the energy charts cover at the bottom (likewise).
        top: fraction of the window height a status panel covers at the top (likewise).
    """

    def __init__(self, window, visuals: Sequence[SceneVisual], size: tuple[int, int], *,
                 inset: float = 0.0, bottom: float = 0.0, top: float = 0.0):
        if not visuals:
            raise ValueError("Renderer needs at least one scene visual")
        self.window = window
        self.size = (int(size[0]), int(size[1]))
        self.canvas = window.get_canvas()
        self.scene = window.get_scene()
        self.ti_camera = ti.ui.Camera()
        self.visuals = list(visuals)
        self.offsets = layout_offsets(self.visuals)
        self.drawers = [SceneDrawer(v, off) for v, off in zip(self.visuals, self.offsets)]
        self._last_options: Sequence[DrawOptions] | None = None  # of a frame not read yet
        self._overlay = self._extras = None  # of that frame
        yaw, pitch = self.visuals[0].view
        self.camera = OrbitCamera(self.size[0] / self.size[1], yaw=math.radians(yaw),
                                  pitch=math.radians(pitch), inset=inset,
                                  bottom=bottom, top=top)
        self.home()

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The box (m) holding every scene's start-up bounds at its offset."""
        lo = np.min([v.bounds[0] + off for v, off in zip(self.visuals, self.offsets)], axis=0)
        hi = np.max([v.bounds[1] + off for v, off in zip(self.visuals, self.offsets)], axis=0)
        return lo, hi

    def home(self) -> None:
        """Frame every scene from its preferred direction (the start-up view)."""
        yaw, pitch = self.visuals[0].view
        self.camera.yaw, self.camera.pitch = math.radians(yaw), math.radians(pitch)
        self.camera.frame(*self.bounds())
        self._home_distance = self.camera.distance

    def follow(self, positions: Sequence[np.ndarray], *, rate: float = 0.25, max_growth: float = 2.5) -> None:
        """Back the camera off (smoothly, by ``rate`` of the gap per call, up to ``max_growth``
        times the start-up distance) until every drawable point of ``positions`` (one (n, 3)
        array per scene, m) is in view. It never moves closer: framing stays steady. Side by
        side it does nothing: panels keep a common, fixed frame, so a run that blows up does
        not shrink the others."""
        if len(self.drawers) > 1:
            return
        pts = [np.asarray(p, np.float64).reshape(-1, 3) + off for p, off in zip(positions, self.offsets)]
        pts = np.concatenate(pts)
        with np.errstate(invalid="ignore"):
            pts = pts[np.all(np.abs(pts) <= DRAWABLE_LIMIT, axis=1)]
        if not len(pts):
            return
        radius = float(np.max(np.linalg.norm(pts - self.camera.target, axis=1)))
        wanted = min(self.camera.distance_for(1.05 * radius), max_growth * self._home_distance)
        if wanted > self.camera.distance:
            self.camera.distance += rate * (wanted - self.camera.distance)

    def label_points(self) -> list[np.ndarray]:
        """World point (m) above the middle of each scene, where its label goes."""
        return [np.array([0.5 * (v.bounds[0][0] + v.bounds[1][0]), v.bounds[1][1], v.center[2]]) + off
                for v, off in zip(self.visuals, self.offsets)]

    def render(self, sources: Sequence, options: DrawOptions | Sequence[DrawOptions], *,
               overlay=None, extras=None) -> list[int]:
        """Draw one frame: ``sources[k]`` is scene k's position field or an (n, 3) array.

        ``options`` applies to every scene, or is one per scene. ``overlay`` (or None): called
        with the canvas after the scenes, to draw 2D over them (the energy plot, a legend).
        ``extras`` (or None): called with the ``ti.ui`` scene after the scenes' geometry, to
        add 3D geometry from its own staging fields (the contacts the launcher shows).
        Returns, per scene, how many particles were not drawable (non-finite or huge) and kept
        their previous position.
        Read the frame with :meth:`read_image` (offscreen) or ``window.show()`` (on screen).
        """
        if isinstance(options, DrawOptions):
            options = [options] * len(self.drawers)
        held = [d.sync(src) for d, src in zip(self.drawers, sources)]
        with _quiet_taichi_warnings():  # GGUI's own staging kernels warn about f64 -> f32
            for drawer, opts in zip(self.drawers, options):
                drawer.update(opts, self.camera.position)
        self._overlay, self._extras = overlay, extras
        self._declare(options)
        self._last_options = options
        return held

    def _declare(self, options: Sequence[DrawOptions]) -> None:
        """Hand this frame's camera, lights and geometry to GGUI (the staging fields as they are)."""
        eye = self.camera.position
        right, up, _ = self.camera.basis()
        self.camera.apply(self.ti_camera)
        self.scene.set_camera(self.ti_camera)
        self.scene.ambient_light(AMBIENT)
        light = eye + self.camera.distance * (0.4 * up + 0.3 * right)
        self.scene.point_light(tuple(light.tolist()), LIGHT)
        with _quiet_taichi_warnings():
            for drawer, opts in zip(self.drawers, options):
                drawer.draw(self.scene, opts)
            if self._extras is not None:
                self._extras(self.scene)
            self.canvas.set_background_color(BACKGROUND)
            self.canvas.scene(self.scene)
            if self._overlay is not None:
                self._overlay(self.canvas)

    def clear_trails(self) -> None:
        """Forget every trail (after a reset, so no line joins the old path to the start)."""
        for d in self.drawers:
            d.clear_trail()

    def read_image(self) -> np.ndarray:
        """The drawn frame as an (height, width, 3) uint8 RGB array, top row first.

        Reading consumes the frame (a second read returns background only): call once per
        :meth:`render`. GGUI 1.7.4 on Mesa's software Vulkan now and then hands back a frame of
        background only although the scene was declared (seen under load, after a window had
        drawn other renderers' scenes; never reproducible on demand; once in a run of the whole
        suite three reads in a row came back so): such a frame is declared again from the same
        staging fields and read again, up to :data:`BACKGROUND_RETRIES` times. A view that shows
        nothing at all pays for those extra frames.
        """
        image = self._read()
        for _ in range(BACKGROUND_RETRIES):
            if self._last_options is None or not self._is_background(image):
                break
            self._declare(self._last_options)
            image = self._read()
        self._last_options = None
        return image

    def _read(self) -> np.ndarray:
        buf = self.window.get_image_buffer_as_numpy()  # (W, H, 4) float in [0, 1], y up
        rgb = np.flip(np.transpose(buf[:, :, :3], (1, 0, 2)), axis=0)
        return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)

    @staticmethod
    def _is_background(image: np.ndarray) -> bool:
        return bool(np.all(np.abs(image.astype(np.int16) - _BACKGROUND_RGB) <= 2))
