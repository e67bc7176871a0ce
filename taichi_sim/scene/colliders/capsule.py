"""Capsules that translate along scripted paths: the collider kind, whole (its spec, kernels,
npz keys and numpy side; :mod:`.shape`)."""
from dataclasses import dataclass

import numpy as np
import taichi as ti

from ... import runtime
from ...collide.closest_points import closest_barycentric, inside, segment_parameters
from ...geometry import primitives
from ...geometry.distances import segment_point_distance
from ...part import PartSpec
from .faces import corner, on_triangle
from .path import SpherePath
from .shape import register_shape, rows
from .translating import TranslatingShapes


@ti.func
def segment_to_triangle(e0, e1, a, b, c):
    """The nearest points of segment [e0, e1] and a triangle it does not cross (see
    :func:`segment_crosses_triangle`): (distance (m),
    the triangle point's barycentric weights, the segment's point). The nearest pair of a
    segment and a triangle apart joins an end of one to the other or an edge to an edge."""
    best = 0.0 * a[0] + 1e30
    best_w = 0.0 * a
    best_z = e0
    for end in range(2):  # dynamic loops: one copy of each test
        e = ti.select(end == 0, e0, e1)
        w = closest_barycentric(e, a, b, c)
        d = (on_triangle(w, a, b, c) - e).norm()
        if d < best:
            best, best_w, best_z = d, w, e
    for j in range(3):
        p, q = corner(j, a, b, c), corner((j + 1) % 3, a, b, c)
        uv = segment_parameters(p, q, e0, e1)
        on_edge, on_segment = p + uv[0] * (q - p), e0 + uv[1] * (e1 - e0)
        d = (on_edge - on_segment).norm()
        if d < best:
            best, best_z = d, on_segment
            best_w = 0.0 * a
            best_w[j] = 1.0 - uv[0]
            best_w[(j + 1) % 3] = uv[0]
    return best, best_w, best_z


@ti.func
def segment_crosses_triangle(e0, e1, a, b, c):
    """Whether segment [e0, e1] passes through triangle (a, b, c) (its ends on either side of
    the plane, the crossing inside)."""
    normal = (b - a).cross(c - a)
    h0, h1 = (e0 - a).dot(normal), (e1 - a).dot(normal)
    crosses = False
    if h0 * h1 < 0.0:
        crosses = inside(e0 + h0 / (h0 - h1) * (e1 - e0), a, b, c)
    return crosses


@ti.func
def capsule_to_triangle(e, radius, a, b, c):
    """The capsule of ``radius`` (m) round the segment -e to e (m) about the origin against
    triangle (a, b, c): (separation (m, negative inside; -radius where the axis passes through
    the triangle), barycentric weights of the triangle's nearest point, the unit normal from the
    capsule to it, the capsule's surface point there). Exact apart."""
    dist, w, z = segment_to_triangle(-e, e, a, b, c)
    if segment_crosses_triangle(-e, e, a, b, c):  # the axis passes through: as deep as r
        dist = 0.0 * dist
    p = w[0] * a + w[1] * b + w[2] * c
    n = (b - a).cross(c - a).normalized()  # on the axis itself: out through the face's normal
    if dist > 0.0:
        n = (p - z) / dist
    return dist - radius, w, n, z + radius * n


@ti.func
def capsule_end_overlap(e, radius, a, b, c, side):
    """How deep triangle (a, b, c) overlaps the capsule of :func:`capsule_to_triangle` (m) and
    the unit direction out (``side``: the way from the capsule to the face at the step's start)."""
    depth, out = 0.0 * a[0], side
    if segment_crosses_triangle(-e, e, a, b, c):
        # the distance from the features holds only apart: pushed back along the side the
        # face came from, past the capsule's extent that way
        reach = ti.abs(e.dot(side)) + radius
        depth = reach - ti.min(a.dot(side), ti.min(b.dot(side), c.dot(side)))
    else:
        d, _, n, _ = capsule_to_triangle(e, radius, a, b, c)
        depth, out = -d, n
    return depth, out


@dataclass(frozen=True)
class Capsule(PartSpec):
    """A capsule: the points within ``radius`` (m) of the segment centre +- ``half_axis`` (m,
    a 3-vector, nonzero: a zero-length capsule is a sphere, use one)."""

    path: SpherePath
    radius: float
    half_axis: tuple
    friction: float = 0.0

    def __post_init__(self):
        if not self.radius > 0:
            raise ValueError("capsule_radius must be > 0")
        e = np.asarray(self.half_axis, float)
        if e.shape != (3,) or not np.linalg.norm(e) > 0:
            raise ValueError("capsule_length must be > 0 (half_axis a nonzero 3-vector)")
        if not self.friction >= 0:
            raise ValueError("capsule_friction must be >= 0")


@register_shape
@ti.data_oriented
class CapsuleColliders(TranslatingShapes):
    """Capsules (see :class:`Capsule` and :class:`TranslatingShapes`)."""

    name, key, order = "capsules", "capsule", 11
    noun, label = "capsule", "capsules"
    # capsule_half_axis: (K, 3), centre to end-cap centre
    size_keys = ("capsule_radius", "capsule_half_axis")

    def __init__(self, capsules: list[Capsule], free, mesh=None, system=None):
        real = runtime.real()
        self.radius = ti.field(real, shape=len(capsules))
        self.half_axis = ti.Vector.field(3, real, shape=len(capsules))
        super().__init__(capsules, free, mesh, system)

    def shape_values(self, capsules) -> list:
        return [(self.radius, [c.radius for c in capsules]), (self.half_axis, [c.half_axis for c in capsules])]

    @staticmethod
    def thinnest(capsule: Capsule) -> float:
        return capsule.radius

    def curvature_radius(self, k: int) -> float:
        return float(self.shapes[k].radius)

    def size_arrays(self) -> dict:
        return {"capsule_radius": np.asarray([c.radius for c in self.shapes], float),
                "capsule_half_axis": np.asarray([c.half_axis for c in self.shapes], float)}

    @classmethod
    def point_depths(cls, x, objects):
        centers, half = rows(objects["capsule_center"]), rows(objects["capsule_half_axis"])
        radii = np.ravel(objects["capsule_radius"]).astype(np.float64)
        distance = [segment_point_distance(x, np.broadcast_to(c - h, x.shape), np.broadcast_to(c + h, x.shape))
                    for c, h in zip(centers, half)]
        return radii[None] - np.stack(distance, axis=1).reshape(len(x), len(radii))

    @classmethod
    def thinnest_sizes(cls, objects):
        return np.ravel(objects["capsule_radius"]).astype(np.float64)

    @staticmethod
    def drawn_mesh(capsule: Capsule):
        # a touch smaller than the collider, as the sphere's
        return primitives.capsule(np.asarray(capsule.half_axis, float), 0.98 * capsule.radius)

    @staticmethod
    def bounding_box(capsule: Capsule) -> tuple:
        return tuple(np.abs(np.asarray(capsule.half_axis, float)) + capsule.radius)

    @ti.func
    def triangle_contact(self, k, a, b, c):
        return capsule_to_triangle(self.half_axis[k], self.radius[k], a, b, c)

    @ti.func
    def end_overlap(self, k, a, b, c, side):
        return capsule_end_overlap(self.half_axis[k], self.radius[k], a, b, c, side)

    @ti.func
    def closest_on_axis(self, k, q):
        e = self.half_axis[k]
        u = ti.math.clamp(q.dot(e) / e.dot(e), -1.0, 1.0)
        return u * e

    @ti.func
    def distance(self, k, q):
        return (q - self.closest_on_axis(k, q)).norm() - self.radius[k]

    @ti.func
    def normal(self, k, q):
        d = q - self.closest_on_axis(k, q)
        n = 0.0 * q
        n[1] = 1.0  # on the axis itself (a particle started inside): out along y
        if d.norm() > 0.0:
            n = d.normalized()
        return n


Capsule.part_class = CapsuleColliders
