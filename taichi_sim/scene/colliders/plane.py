"""A static plane (any normal) with restitution and Coulomb friction: the collider kind, whole
(its spec, kernel, npz keys and numpy side; :mod:`.shape`)."""
from dataclasses import dataclass

import numpy as np
import taichi as ti

from ... import field_io, runtime
from ...part import PartSpec, ScenePart
from ..visual import Plane
from .shape import Shape, register_shape


@register_shape
@ti.data_oriented
class PlaneCollider(Shape, ScenePart):
    """A ground plane: a free particle below it is projected onto it, and its normal velocity
    is reflected and scaled by ``restitution`` (0: it stops, 1: elastic bounce); ``friction``
    mu scales the tangential velocity down by mu * (1 + e) |v_n| (Coulomb), never reversing it.

    The plane does not move and is a half-space, so the end-only test is already continuous:
    a particle whose step crossed it ends below it.

    Args:
        point: a point on the plane (m); normal: its upward normal (nonzero, see
            :class:`GroundPlane`; normalised here).
    """

    name = key = "plane"
    order = 20
    noun = label = "ground plane"
    # plane_point (3,) m; plane_normal (3,), the side it points to outside; faces are not judged
    # (a flat plane is entered by a face only where a corner enters it)
    size_keys, moving = ("plane_point", "plane_normal"), False

    def __init__(self, point, normal, restitution: float, friction: float, free):
        real = runtime.real()
        normal = np.asarray(normal, float)
        self.point_np = np.asarray(point, float)
        self.normal_np = normal / np.linalg.norm(normal)
        self.free = free
        self.serial = runtime.serial_loops(free.shape[0])
        self.point = ti.Vector.field(3, real, shape=())
        self.normal = ti.Vector.field(3, real, shape=())
        self.restitution = ti.field(real, shape=())
        self.friction = ti.field(real, shape=())
        # one kernel, where item assignment compiles one per scalar (eight)
        field_io.write((self.point, self.point_np), (self.normal, self.normal_np),
                       (self.restitution, float(restitution)), (self.friction, float(friction)))

    @classmethod
    def from_specs(cls, specs: list["GroundPlane"], context) -> "PlaneCollider":
        """The scene's ground: the last :class:`GroundPlane` asked for (a scene has one)."""
        s = specs[-1]
        return cls(s.point, s.normal, s.restitution, s.friction, context.system.free)

    def __call__(self, state, t: float, h: float) -> None:
        self._project(state)

    def features(self) -> dict:
        return {"plane": True}

    def arrays(self) -> dict:
        return {"plane_point": self.point_np, "plane_normal": self.normal_np}

    @classmethod
    def point_depths(cls, x, objects):
        point, normal = np.ravel(objects["plane_point"]), np.ravel(objects["plane_normal"])
        return -((x - point) @ (normal / np.linalg.norm(normal)))[:, None]

    def visuals(self) -> list:
        return [Plane(point=self.point_np.reshape(3).astype(np.float64), normal=self.normal_np.reshape(3))]

    @ti.kernel
    def _project(self, y: ti.template()):
        n = self.normal[None]
        ti.loop_config(serialize=self.serial)
        for i in range(y.x.shape[0]):  # a range-for: serialize applies
            if self.free[i]:
                depth = (y.x[i] - self.point[None]).dot(n)
                if depth < 0.0:
                    y.x[i] -= depth * n
                    vn = y.v[i].dot(n)
                    if vn < 0.0:
                        tangential = y.v[i] - vn * n
                        speed_t = tangential.norm()
                        scale = 1.0
                        if speed_t > 0.0:
                            scale = ti.max(0.0, 1.0 + self.friction[None] * (1.0 + self.restitution[None]) * vn / speed_t)
                        y.v[i] = scale * tangential - self.restitution[None] * vn * n


@dataclass(frozen=True)
class GroundPlane(PartSpec):
    """A ground plane through ``point`` (m) with upward ``normal`` (a nonzero 3-vector),
    ``restitution`` in [0, 1] and Coulomb ``friction``; see :class:`PlaneCollider`."""

    point: tuple
    normal: tuple
    restitution: float
    friction: float = 0.0

    part_class = PlaneCollider

    def __post_init__(self):
        if not 0.0 <= self.restitution <= 1.0:
            raise ValueError("restitution must be in [0, 1]")
        if not self.friction >= 0:
            raise ValueError("plane_friction must be >= 0")
        n = np.asarray(self.normal, float)
        if n.shape != (3,) or not np.linalg.norm(n) > 0:
            raise ValueError("plane_normal must be a nonzero 3-vector")
