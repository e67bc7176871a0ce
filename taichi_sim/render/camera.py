"""An orbit camera in plain numpy: view matrix, projection to the screen, screen rays.

Conventions (those of GGUI, so the matrices agree with ``ti.ui.Camera``):
world y is up; the vertical field of view is ``fov`` degrees; screen coordinates ``(u, v)`` are
in [0, 1] x [0, 1] with u to the right and v UP (v = 0 is the bottom row), as
``ti.ui.Window.get_cursor_pos()`` reports them.
"""
from __future__ import annotations

import math

import numpy as np

PITCH_LIMIT = math.radians(89.0)


class OrbitCamera:
    """A camera orbiting ``target`` at ``distance`` (m), at ``yaw`` / ``pitch`` (radians).

    ``yaw = 0, pitch = 0`` looks along -z (the camera sits on the +z side); positive pitch
    raises the camera. Orbiting, zooming and framing change only the target, distance, yaw and
    pitch.

    Args:
        aspect: width / height of the image.
        inset: fraction of the image width covered on the left (by a control panel): the target
            is drawn centred in the rest, which framing fills.
        bottom: fraction of the image height covered at the bottom (by the energy charts),
            likewise left out of the framing.
        top: fraction of the image height covered at the top (by a status panel), likewise.
    """

    def __init__(self, aspect: float, target=(0.0, 0.0, 0.0), distance: float = 3.0,
                 yaw: float = 0.0, pitch: float = 0.0, fov: float = 45.0, inset: float = 0.0,
                 bottom: float = 0.0, top: float = 0.0):
        if not 0.0 <= inset < 0.9:
            raise ValueError(f"inset must be in [0, 0.9), got {inset}")
        if not 0.0 <= bottom < 0.9:
            raise ValueError(f"bottom must be in [0, 0.9), got {bottom}")
        if not (0.0 <= top and bottom + top < 0.9):
            raise ValueError(f"top must be >= 0 and bottom + top < 0.9, got top {top}, bottom {bottom}")
        self.aspect = float(aspect)
        self.target = np.asarray(target, np.float64).reshape(3).copy()
        self.distance = float(distance)
        self.yaw = float(yaw)
        self.pitch = float(np.clip(pitch, -PITCH_LIMIT, PITCH_LIMIT))
        self.fov = float(fov)
        self.inset = float(inset)
        self.bottom = float(bottom)
        self.top = float(top)

    # -- pose ---------------------------------------------------------------------------------

    @property
    def tan_half(self) -> tuple[float, float]:
        """tan of half the (horizontal, vertical) field of view."""
        tan_v = math.tan(math.radians(self.fov) / 2.0)
        return tan_v * self.aspect, tan_v

    @property
    def forward(self) -> np.ndarray:
        """Unit viewing direction."""
        cp = math.cos(self.pitch)
        return -np.array([cp * math.sin(self.yaw), math.sin(self.pitch), cp * math.cos(self.yaw)])

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, back) unit vectors of the camera frame in world coordinates."""
        back = -self.forward
        right = np.cross([0.0, 1.0, 0.0], back)
        right /= np.linalg.norm(right)
        up = np.cross(back, right)
        return right, up, back

    @property
    def look_at(self) -> np.ndarray:
        """The point the camera looks at (m): the target, shifted sideways so that the target
        appears centred in the part of the image right of the inset, above the bottom strip and
        below the top one."""
        right, up, _ = self.basis()
        tan_h, tan_v = self.tan_half
        return self.target - self.distance * (self.inset * tan_h * right + (self.bottom - self.top) * tan_v * up)

    @property
    def position(self) -> np.ndarray:
        """Camera position (m)."""
        return self.look_at - self.distance * self.forward

    def orbit(self, du: float, dv: float) -> None:
        """Rotate about the target by a cursor move of (du, dv) screen units (a full screen
        width turns the camera half a revolution)."""
        self.yaw -= math.pi * du
        self.pitch = float(np.clip(self.pitch - math.pi * dv, -PITCH_LIMIT, PITCH_LIMIT))

    def zoom(self, factor: float) -> None:
        """Multiply the distance to the target by ``factor`` (< 1 moves closer)."""
        self.distance = float(np.clip(self.distance * factor, 1e-3, 1e6))

    def frame(self, lo, hi, *, margin: float = 1.1) -> None:
        """Aim at the centre of the box [lo, hi] (m) from the current direction, at the smallest
        distance where all its corners are in view (beside the inset) with ``margin`` (1.1: 10 %
        to spare)."""
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        self.target = 0.5 * (lo + hi)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])]) - self.target
        right, up, back = self.basis()
        tan_h, tan_v = self.tan_half
        tan_h *= (1.0 - self.inset) / margin
        tan_v *= (1.0 - self.bottom - self.top) / margin
        depth = corners @ back  # toward the camera
        needed = np.maximum(np.abs(corners @ right) / tan_h, np.abs(corners @ up) / tan_v) + depth
        self.distance = max(float(needed.max()), float(depth.max()) + 0.2, 1e-2)

    def distance_for(self, radius: float) -> float:
        """Distance (m) at which a sphere of ``radius`` (m) around the target just fits the
        narrower view angle (beside the inset)."""
        tan_h, tan_v = self.tan_half
        return radius / math.sin(math.atan(min(tan_v * (1.0 - self.bottom - self.top), tan_h * (1.0 - self.inset))))

    # -- matrices and mappings ----------------------------------------------------------------

    def view_matrix(self) -> np.ndarray:
        """4x4 world -> camera matrix acting on column vectors (camera looks along -z)."""
        right, up, back = self.basis()
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = right, up, back
        m[:3, 3] = -m[:3, :3] @ self.position
        return m

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Screen coordinates of world ``points`` ((k, 3), m).

        Returns ``(uv, depth)``: uv (k, 2) in screen units (v up), depth (k,) the distance in
        front of the camera along its axis (m; <= 0 means behind it, where uv is meaningless).
        """
        p = np.atleast_2d(np.asarray(points, np.float64))
        cam = (self.view_matrix() @ np.c_[p, np.ones(len(p))].T).T
        depth = -cam[:, 2]
        tan_h, tan_v = self.tan_half
        with np.errstate(divide="ignore", invalid="ignore"):
            ndc = np.stack([cam[:, 0] / tan_h, cam[:, 1] / tan_v], axis=1) / depth[:, None]
        return 0.5 * (ndc + 1.0), depth

    def screen_ray(self, u: float, v: float) -> tuple[np.ndarray, np.ndarray]:
        """The ray through screen point (u, v): ``(origin, direction)``, direction unit length."""
        tan_h, tan_v = self.tan_half
        right, up, back = self.basis()
        d = (2.0 * u - 1.0) * tan_h * right + (2.0 * v - 1.0) * tan_v * up - back
        return self.position, d / np.linalg.norm(d)

    def apply(self, camera) -> None:
        """Copy this pose onto a ``ti.ui.Camera``."""
        camera.position(*self.position.tolist())
        camera.lookat(*self.look_at.tolist())
        camera.up(0.0, 1.0, 0.0)
        camera.fov(self.fov)
