"""Axis-aligned boxes that translate along scripted paths: the collider kind, whole (its spec,
kernels, npz keys and numpy side; :mod:`.shape`)."""
from dataclasses import dataclass

import numpy as np
import taichi as ti

from ... import runtime
from ...geometry import primitives
from ...part import PartSpec
from .faces import corner
from .path import SpherePath
from .shape import register_shape, rows
from .translating import TranslatingShapes


@ti.func
def box_separation(half, a, b, c, axes=13):
    """A triangle (a, b, c) against the axis-aligned box of ``half`` extents about the origin,
    by the separating axes of the two (the box's three axes, the face's normal, and the nine
    crosses of their edges; Akenine-Moller 2001): (signed separation (m), the barycentric
    weights of the face's nearest corners along it, the unit axis from the box to the face).

    The separation is the largest gap between the two along any of those axes. Apart, that is
    a lower bound on their distance (the plane across that gap keeps them apart, all a march
    needs); overlapping, it is minus the shortest push along an axis that separates them.
    ``axes`` < 13 tries only the first ones (4: the box's axes and the face's normal), a
    cheaper and looser bound apart."""
    best = 0.0 * a[0] - 1e30
    axis_out = 0.0 * a
    for axis in range(axes):  # a dynamic loop: one copy of the body, not thirteen
        u = 0.0 * a
        if axis < 3:
            u[axis] = 1.0
        elif axis == 3:
            u = (b - a).cross(c - a)
        else:
            unit = 0.0 * a
            unit[(axis - 4) // 3] = 1.0
            j = (axis - 4) % 3
            u = unit.cross(corner((j + 1) % 3, a, b, c) - corner(j, a, b, c))
        length = u.norm()
        if length > 1e-12 * (b - a).norm_sqr():
            u /= length
            lo = ti.min(a.dot(u), ti.min(b.dot(u), c.dot(u)))
            hi = ti.max(a.dot(u), ti.max(b.dot(u), c.dot(u)))
            reach = (half * ti.abs(u)).sum()
            if lo - reach > best:
                best, axis_out = lo - reach, u
            if -reach - hi > best:
                best, axis_out = -reach - hi, -u
    # the corners nearest the box along the axis share the contact (a face lying on a box's
    # side touches it with all three)
    p = ti.Vector([a.dot(axis_out), b.dot(axis_out), c.dot(axis_out)])
    near = ti.select(p <= p.min() + 1e-6 * (half.max() + ti.abs(p).max()), 1.0, 0.0)
    return best, near / near.sum(), axis_out


@dataclass(frozen=True)
class Box(PartSpec):
    """An axis-aligned box of ``half_extents`` (m, three values > 0) about the path's centre."""

    path: SpherePath
    half_extents: tuple
    friction: float = 0.0

    def __post_init__(self):
        e = np.asarray(self.half_extents, float)
        if e.shape != (3,) or not np.all(e > 0):
            raise ValueError("box half_extents must be three values > 0")
        if not self.friction >= 0:
            raise ValueError("box_friction must be >= 0")


@register_shape
@ti.data_oriented
class BoxColliders(TranslatingShapes):
    """Axis-aligned boxes (see :class:`Box` and :class:`TranslatingShapes`)."""

    KEEPS_START_OVERLAP = True
    name, key, order = "boxes", "box", 12
    noun, label = "box", "boxes"
    size_keys = ("box_half_extents",)  # (K, 3), along x, y, z

    def __init__(self, boxes: list[Box], free, mesh=None, system=None):
        self.half = ti.Vector.field(3, runtime.real(), shape=len(boxes))
        super().__init__(boxes, free, mesh, system)

    def shape_values(self, boxes) -> list:
        return [(self.half, [b.half_extents for b in boxes])]

    @staticmethod
    def thinnest(box: Box) -> float:
        return float(min(box.half_extents))

    def size_arrays(self) -> dict:
        return {"box_half_extents": np.asarray([b.half_extents for b in self.shapes], float)}

    @classmethod
    def point_depths(cls, x, objects):
        centers, half = rows(objects["box_center"]), rows(objects["box_half_extents"])
        over = np.abs(x[:, None] - centers[None]) - half[None]
        outside = np.linalg.norm(np.maximum(over, 0.0), axis=2)
        inside = np.minimum(over.max(axis=2), 0.0)
        return -(outside + inside)

    @classmethod
    def thinnest_sizes(cls, objects):
        return rows(objects["box_half_extents"]).min(axis=1)

    @staticmethod
    def drawn_mesh(box: Box):
        return primitives.box(0.98 * np.asarray(box.half_extents, float))

    @staticmethod
    def bounding_box(box: Box) -> tuple:
        return tuple(box.half_extents)

    @ti.func
    def triangle_contact(self, k, a, b, c):
        gap, w, n = box_separation(self.half[k], a, b, c)
        p = w[0] * a + w[1] * b + w[2] * c
        return gap, w, n, p - gap * n  # a point on the plane across the gap: all the push needs

    @ti.func
    def end_overlap(self, k, a, b, c, side):
        gap, _, n = box_separation(self.half[k], a, b, c)
        return -gap, n

    @ti.func
    def separating_plane(self, k, a, b, c):
        # the box's axes and the face's normal separate most faces near a box (a fold falling on
        # it, a face over one side); the edges' nine crosses only where those four do not
        gap, _, n = box_separation(self.half[k], a, b, c, 4)
        if gap <= 0.0:
            gap, _, n = box_separation(self.half[k], a, b, c)
        return gap, n

    @ti.func
    def flat_side(self, k, a, b, c):
        # each corner beyond the same side's plane and within its outline on the other two axes
        # (a prism over that side, where the side is the nearest part of the box): the triangle
        # lies in the prism too, and its height over the side is least at a corner
        half = self.half[k]
        out = False
        for axis in ti.static(range(3)):
            for sign in ti.static((-1.0, 1.0)):
                beyond = (sign * a[axis] >= half[axis]) and (sign * b[axis] >= half[axis]) \
                    and (sign * c[axis] >= half[axis])
                within = True
                for other in ti.static(range(3)):
                    if ti.static(other != axis):
                        within = within and ti.abs(a[other]) <= half[other] and ti.abs(b[other]) <= half[other] \
                            and ti.abs(c[other]) <= half[other]
                if beyond and within:
                    out = True
        return out

    @ti.func
    def distance(self, k, q):
        over = ti.abs(q) - self.half[k]
        outside = ti.max(over, 0.0).norm()
        inside = ti.min(ti.max(over[0], ti.max(over[1], over[2])), 0.0)
        return outside + inside

    @ti.func
    def normal(self, k, q):
        over = ti.abs(q) - self.half[k]
        n = 0.0 * q
        if over.max() > 0.0:  # outside: towards q from its closest point
            n = ti.math.sign(q) * ti.max(over, 0.0)
            n = n.normalized()
        else:  # inside: out through the nearest face
            axis = 0
            if over[1] > over[axis]:
                axis = 1
            if over[2] > over[axis]:
                axis = 2
            n[axis] = 1.0 if q[axis] >= 0.0 else -1.0
        return n


Box.part_class = BoxColliders
