"""An orbit camera in plain numpy: view matrix, projection to the screen, screen rays.

Conventions (those of GGUI, so the matrices agree with ``ti.ui.Camera``):
world y is up; the camera looks from ``position`` at ``target``; the vertical field of view is
``fov`` degrees; screen coordinates ``(u, v)`` are in [0, 1] x [0, 1] with u to the right and v
UP (v = 0 is the bottom row), as ``ti.ui.Window.get_cursor_pos()`` reports them.
"""
from __future__ import annotations

import math

import numpy as np

PITCH_LIMIT = math.radians(89.0)


class OrbitCamera:
    """A camera orbiting ``target`` at ``distance`` (m), at ``yaw`` / ``pitch`` (radians).

    ``yaw = 0, pitch = 0`` looks along -z (the camera sits on the +z side); positive pitch
    raises the camera. Orbiting, zooming and framing change only these four numbers.
    """

    def __init__(self, target=(0.0, 0.0, 0.0), distance: float = 3.0, yaw: float = 0.0,
                 pitch: float = 0.0, fov: float = 45.0):
        self.target = np.asarray(target, np.float64).reshape(3).copy()
        self.distance = float(distance)
        self.yaw = float(yaw)
        self.pitch = float(np.clip(pitch, -PITCH_LIMIT, PITCH_LIMIT))
        self.fov = float(fov)

    # -- pose ---------------------------------------------------------------------------------

    @property
    def forward(self) -> np.ndarray:
        """Unit vector from the camera towards the target."""
        cp = math.cos(self.pitch)
        return -np.array([cp * math.sin(self.yaw), math.sin(self.pitch), cp * math.cos(self.yaw)])

    @property
    def position(self) -> np.ndarray:
        """Camera position (m)."""
        return self.target - self.distance * self.forward

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, back) unit vectors of the camera frame in world coordinates."""
        back = -self.forward
        right = np.cross([0.0, 1.0, 0.0], back)
        right /= np.linalg.norm(right)
        up = np.cross(back, right)
        return right, up, back

    def orbit(self, du: float, dv: float) -> None:
        """Rotate about the target by a cursor move of (du, dv) screen units (a full screen
        width turns the camera half a revolution)."""
        self.yaw -= math.pi * du
        self.pitch = float(np.clip(self.pitch - math.pi * dv, -PITCH_LIMIT, PITCH_LIMIT))

    def zoom(self, factor: float) -> None:
        """Multiply the distance to the target by ``factor`` (< 1 moves closer)."""
        self.distance = float(np.clip(self.distance * factor, 1e-3, 1e6))

    def frame(self, lo, hi, aspect: float, *, margin: float = 1.1) -> None:
        """Aim at the centre of the box [lo, hi] (m) from the current direction, at the smallest
        distance where all its corners are in view with ``margin`` (1.1: 10 % to spare)."""
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        self.target = 0.5 * (lo + hi)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])]) - self.target
        right, up, back = self.basis()
        tan_v = math.tan(math.radians(self.fov) / 2.0) / margin
        tan_h = tan_v * aspect
        depth = corners @ back  # toward the camera
        needed = np.maximum(np.abs(corners @ right) / tan_h, np.abs(corners @ up) / tan_v) + depth
        self.distance = max(float(needed.max()), float(depth.max()) + 0.2, 1e-2)

    def distance_for(self, radius: float, aspect: float) -> float:
        """Distance (m) at which a sphere of ``radius`` (m) just fits the narrower view angle."""
        half_v = math.radians(self.fov) / 2.0
        half_h = math.atan(math.tan(half_v) * aspect)
        return radius / math.sin(min(half_v, half_h))

    # -- matrices -----------------------------------------------------------------------------

    def view_matrix(self) -> np.ndarray:
        """4x4 world -> camera matrix acting on column vectors (camera looks along -z)."""
        right, up, back = self.basis()
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = right, up, back
        m[:3, 3] = -m[:3, :3] @ self.position
        return m

    # -- screen <-> world ---------------------------------------------------------------------

    def project(self, points, aspect: float) -> tuple[np.ndarray, np.ndarray]:
        """Screen coordinates of world ``points`` ((k, 3), m).

        Returns ``(uv, depth)``: uv (k, 2) in screen units (v up), depth (k,) the distance in
        front of the camera along its axis (m; <= 0 means behind it, where uv is meaningless).
        """
        p = np.atleast_2d(np.asarray(points, np.float64))
        cam = (self.view_matrix() @ np.c_[p, np.ones(len(p))].T).T
        depth = -cam[:, 2]
        f = 1.0 / math.tan(math.radians(self.fov) / 2.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            ndc = np.stack([cam[:, 0] * f / aspect, cam[:, 1] * f], axis=1) / depth[:, None]
        return 0.5 * (ndc + 1.0), depth

    def screen_ray(self, u: float, v: float, aspect: float) -> tuple[np.ndarray, np.ndarray]:
        """The ray through screen point (u, v): ``(origin, direction)``, direction unit length."""
        t = math.tan(math.radians(self.fov) / 2.0)
        right, up, back = self.basis()
        d = (2.0 * u - 1.0) * t * aspect * right + (2.0 * v - 1.0) * t * up - back
        return self.position, d / np.linalg.norm(d)

    def apply(self, camera) -> None:
        """Copy this pose onto a ``ti.ui.Camera``."""
        camera.position(*self.position.tolist())
        camera.lookat(*self.target.tolist())
        camera.up(0.0, 1.0, 0.0)
        camera.fov(self.fov)
