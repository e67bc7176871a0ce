"""A capped cylinder collider kind, defined in this file alone by the route a plug-in author
takes (docs/collisions.md, "Adding a collider shape"): its spec, its kernels, its npz keys and
its numpy side, registered on import. tests/test_shape_contract.py puts it in vbd's solve, in
the post-step pass of the other methods and in `check`.

A cylinder here is the points within ``radius`` (m) of the segment centre +- ``half_axis`` (m)
whose projection onto the axis falls between its ends: flat caps, sharp rims (convex, as the
contract's conservative bounds need). Its triangle bound is the larger of two lower bounds on a
face's separation, each with the plane that keeps them apart: its enclosing capsule's (exact on
the side) and its cap planes' (exact over a cap).
"""
from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_sim import runtime
from taichi_sim.geometry import primitives
from taichi_sim.part import PartSpec
from taichi_sim.scene.colliders import SpherePath, TranslatingShapes, register_shape
from taichi_sim.scene.colliders.capsule import capsule_end_overlap, capsule_to_triangle
from taichi_sim.scene.colliders.shape import rows


@dataclass(frozen=True)
class Cylinder(PartSpec):
    """A capped cylinder of ``radius`` (m) round the segment centre +- ``half_axis`` (m, a
    nonzero 3-vector) translating along ``path``, with Coulomb ``friction``."""

    path: SpherePath
    radius: float
    half_axis: tuple
    friction: float = 0.0

    def __post_init__(self):
        if not self.radius > 0:
            raise ValueError("cylinder_radius must be > 0")
        e = np.asarray(self.half_axis, float)
        if e.shape != (3,) or not np.linalg.norm(e) > 0:
            raise ValueError("cylinder half_axis must be a nonzero 3-vector")
        if not self.friction >= 0:
            raise ValueError("cylinder_friction must be >= 0")


@ti.func
def cap_planes_to_triangle(e, a, b, c):
    """Triangle (a, b, c) against the slab between the cap planes of a cylinder of half axis
    ``e`` (m) about the origin: (signed gap beyond the nearer cap's plane (m), the barycentric
    weights of the corners nearest it, the cap's unit outward normal). A gap > 0 keeps the face
    off the cylinder, which lies inside the slab."""
    half = e.norm()
    u = e / half
    p = ti.Vector([a.dot(u), b.dot(u), c.dot(u)])
    gap, n, side = p.min() - half, u, p
    if -p.max() - half > gap:
        gap, n, side = -p.max() - half, -u, -p
    near = ti.select(side <= side.min() + 1e-6 * (half + ti.abs(p).max()), 1.0, 0.0)
    return gap, near / near.sum(), n


@register_shape
@ti.data_oriented
class CylinderColliders(TranslatingShapes):
    """Capped cylinders (see :class:`Cylinder`): the post-step pass is
    :class:`~taichi_sim.scene.colliders.TranslatingShapes`'."""

    name, key, order = "cylinders", "cylinder", 14
    noun, label = "cylinder", "cylinders"
    size_keys = ("cylinder_radius", "cylinder_half_axis")

    def __init__(self, cylinders: list[Cylinder], free, mesh=None, system=None):
        real = runtime.real()
        self.radius = ti.field(real, shape=len(cylinders))
        self.half_axis = ti.Vector.field(3, real, shape=len(cylinders))
        super().__init__(cylinders, free, mesh, system)

    def shape_values(self, cylinders) -> list:
        return [(self.radius, [c.radius for c in cylinders]), (self.half_axis, [c.half_axis for c in cylinders])]

    @staticmethod
    def thinnest(cylinder: Cylinder) -> float:
        return min(cylinder.radius, float(np.linalg.norm(cylinder.half_axis)))

    def size_arrays(self) -> dict:
        return {"cylinder_radius": np.asarray([c.radius for c in self.shapes], float),
                "cylinder_half_axis": np.asarray([c.half_axis for c in self.shapes], float)}

    @staticmethod
    def drawn_mesh(cylinder: Cylinder):
        e = np.asarray(cylinder.half_axis, float)
        return primitives.rod(-0.98 * e, 0.98 * e, 0.98 * cylinder.radius)

    @staticmethod
    def bounding_box(cylinder: Cylinder) -> tuple:
        # (the enclosing capsule's box: a loose bound is all the face pass's broad phase needs)
        return tuple(np.abs(np.asarray(cylinder.half_axis, float)) + cylinder.radius)

    # -- the kernels ------------------------------------------------------------------------

    @ti.func
    def _offsets(self, k, q):
        """(radial offset from the axis (m, a vector), past the side (m), past a cap (m), the
        cap's outward unit normal) of q in cylinder k's frame."""
        e = self.half_axis[k]
        half = e.norm()
        along = q.dot(e) / half
        radial = q - along * e / half
        cap = e / half * ti.select(along >= 0.0, 1.0, -1.0)
        return radial, radial.norm() - self.radius[k], ti.abs(along) - half, cap

    @ti.func
    def distance(self, k, q):
        _, side, end, _ = self._offsets(k, q)
        outside = ti.sqrt(ti.max(side, 0.0) ** 2 + ti.max(end, 0.0) ** 2)
        return outside + ti.min(ti.max(side, end), 0.0)

    @ti.func
    def normal(self, k, q):
        radial, side, end, cap = self._offsets(k, q)
        out = cap  # on the axis itself: out through the cap
        if radial.norm() > 0.0:
            out = radial.normalized()
        n = cap
        if side > 0.0 and end > 0.0:  # beyond the rim: from the rim's nearest point
            n = (side * out + end * cap).normalized()
        elif side > end:  # the side is nearer (inside) or the only one passed (outside)
            n = out
        return n

    @ti.func
    def triangle_contact(self, k, a, b, c):
        e = self.half_axis[k]
        d, w, n, z = capsule_to_triangle(e, self.radius[k], a, b, c)
        gap, near, cap = cap_planes_to_triangle(e, a, b, c)
        if gap > d:
            p = near[0] * a + near[1] * b + near[2] * c
            d, w, n, z = gap, near, cap, p - gap * cap
        return d, w, n, z

    @ti.func
    def end_overlap(self, k, a, b, c, side):
        # the smaller of two pushes that each separate: out of the enclosing capsule, or every
        # corner past a cap's plane
        depth, out = capsule_end_overlap(self.half_axis[k], self.radius[k], a, b, c, side)
        gap, _, cap = cap_planes_to_triangle(self.half_axis[k], a, b, c)
        if -gap < depth:
            depth, out = -gap, cap
        return depth, out

    # -- the numpy side (`check`, the start warning) -----------------------------------------

    @classmethod
    def point_depths(cls, x, objects):
        centers, half = rows(objects["cylinder_center"]), rows(objects["cylinder_half_axis"])
        radii = np.ravel(objects["cylinder_radius"]).astype(np.float64)
        length = np.linalg.norm(half, axis=1)
        q = x[:, None] - centers[None]  # (N, K, 3)
        along = np.einsum("nkd,kd->nk", q, half / length[:, None])
        side = np.linalg.norm(q - along[..., None] * (half / length[:, None])[None], axis=2) - radii[None]
        end = np.abs(along) - length[None]
        outside = np.hypot(np.maximum(side, 0.0), np.maximum(end, 0.0))
        return -(outside + np.minimum(np.maximum(side, end), 0.0))

    @classmethod
    def thinnest_sizes(cls, objects):
        return np.minimum(np.ravel(objects["cylinder_radius"]), np.linalg.norm(rows(objects["cylinder_half_axis"]), axis=1))


Cylinder.part_class = CylinderColliders
