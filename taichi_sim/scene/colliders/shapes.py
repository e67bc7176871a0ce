"""Capsules and axis-aligned boxes that translate along scripted paths, tested over the step's
relative motion by conservative advancement."""
from dataclasses import dataclass

import numpy as np
import taichi as ti

from ... import field_io, runtime
from ...collide.friction import inelastic_friction
from ...geometry import primitives
from ...part import MovingSource, PartSpec, ScenePart, SolidMesh
from .faces import FaceContact, box_separation, segment_crosses_triangle, segment_to_triangle
from .obstacle import Obstacle
from .path import PathFields, SpherePath
from .step_start import StepStart

# Marching rounds per particle and shape: a segment that grazes the surface needs many short
# advances; past this many the particle keeps the end-only test (it ends outside, or is
# pushed out along the surface's normal at its end).
MAX_ADVANCES = 48
# An advance that leaves the march this close (relative to the shape's thinnest size) counts as
# touching: a ray marched by signed distance only approaches the surface.
TOUCH_FRACTION = 1e-4


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


@ti.data_oriented
class _TranslatingShapes(FaceContact, Obstacle, ScenePart):
    """What capsules and boxes share: paths, step starts, the march and the response.

    In a shape's frame a free particle goes from a = p0 - c(t - h) to b = p1 - c(t). Starting
    outside, it marches along a -> b by the signed distance to the surface (conservative
    advancement: a step never crosses the surface), so it finds where the segment first
    touches however fast the shape moves; from there the particle moves on by the rest of its
    step's motion along the surface's tangent plane (then back onto the surface if that entered
    it), so it stays on the side it came from and a resting particle still slides, and gets the inelastic, Coulomb-friction response against the shape's
    velocity. A particle that ends inside after starting inside (a reset, a jump) is pushed out
    along the normal at its end. Given a ``mesh`` (and the ``system``), the triangles are
    tested too (:class:`FaceContact`).
    """

    def __init__(self, shapes, free, mesh=None, system=None):
        real = runtime.real()
        self.count = K = len(shapes)
        self.shapes = tuple(shapes)
        self.paths = [s.path for s in shapes]
        self.free = free
        self.path = PathFields(K)
        self.friction = ti.field(real, shape=K)
        self.touch = ti.field(real, shape=K)
        # with the shape's own fields (its subclass's __init__ allocated them): one kernel
        field_io.write(*self.path.values(self.paths), *self.shape_values(shapes),
                       (self.friction, [s.friction for s in shapes]),
                       (self.touch, [TOUCH_FRACTION * self.thinnest(s) for s in shapes]))
        self.start = StepStart(free.shape[0])
        self.serial = runtime.serial_loops(free.shape[0] * K)
        self._init_faces(mesh, system, [self.bounding_box(s) for s in shapes], [self.thinnest(s) for s in shapes])
        self.move_to(0.0)

    def shape_values(self, shapes) -> list:
        """(field, values) pairs of the shape's own fields (its sizes), written with the
        paths' in one kernel."""
        return []

    def restore(self) -> None:
        self.start.restore()
        self.move_to(0.0)

    @classmethod
    def from_specs(cls, specs, context):
        """One collider for every shape of this kind the scene asked for."""
        return cls(list(specs), context.system.free, mesh=context.faces, system=context.system)

    def move_to(self, t: float) -> None:
        """Place every shape where its path puts it at time t (s)."""
        self.t = t

    def reset(self) -> None:
        self.move_to(0.0)

    def features(self) -> dict:
        return {self.name: self.count, **({"object_faces": True} if self.mesh is not None else {})}

    def arrays(self) -> dict:
        return {f"{self.key}_center": self.centers(), **self.size_arrays()}

    def visuals(self) -> list:
        out = []
        for k, shape in enumerate(self.shapes):
            vertices, normals, triangles = self.drawn_mesh(shape)
            out.append(SolidMesh(vertices=vertices, normals=normals, triangles=triangles,
                                 place=lambda k=k: self.centers()[k], reach=np.asarray(self.bounding_box(shape))))
        return out

    def energy_sources(self) -> list:
        return [MovingSource(f"moving {self.key}", self.fastest_speed())]

    def fastest_speed(self) -> float:
        return max(p.fastest_speed() for p in self.paths)

    def __call__(self, state, t: float, h: float) -> None:
        self.start.begin(state, t, h)
        self.move_to(t)
        self._collide(state, self.start.x, t, h)
        self._faces(state, self.start.x, t, h)
        self.start.end(state, t)

    @ti.func
    def surface_velocity(self, k, t, r):
        return self.path.velocity(k, t)  # they translate only

    @ti.kernel
    def _collide(self, y: ti.template(), x_start: ti.template(), t: float, h: float):
        ti.loop_config(serialize=self.serial)
        for i in range(y.x.shape[0]):  # a range-for: serialize applies
            if self.free[i]:
                for k in range(self.count):
                    center = self.path.center(k, t)
                    a = x_start[i] - self.path.center(k, t - h)
                    b = y.x[i] - center
                    hit = self.distance(k, b) < 0.0
                    q = b
                    if self.distance(k, a) >= 0.0:
                        length = (b - a).norm()
                        s = 0.0
                        if length > 0.0:
                            direction = (b - a) / length
                            for _ in range(MAX_ADVANCES):
                                p = a + s * direction
                                dist = self.distance(k, p)
                                if dist <= self.touch[k]:
                                    # touching counts only when heading in: a convex shape is
                                    # never re-entered by a segment that leaves its surface
                                    hit = hit or direction.dot(self.normal(k, p)) < 0.0
                                    break
                                s += dist
                                if s >= length:
                                    break
                            if hit:  # where the march stopped: outside, or touching
                                q = a + ti.min(s, length) * direction
                    if hit:
                        # from where it met the surface, the step's motion along it is kept (a
                        # resting particle slides) and the motion into it dropped
                        m = self.normal(k, q)
                        rest = b - q
                        q += rest - ti.min(rest.dot(m), 0.0) * m
                        n = self.normal(k, q)
                        dist = self.distance(k, q)
                        if dist < 0.0:
                            q -= dist * n
                        y.x[i] = center + q
                        y.v[i] = inelastic_friction(y.v[i], self.path.velocity(k, t), n, self.friction[k])


@ti.data_oriented
class CapsuleColliders(_TranslatingShapes):
    """Capsules (see :class:`Capsule` and :class:`_TranslatingShapes`)."""

    name, key, order = "capsules", "capsule", 11

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

    @staticmethod
    def drawn_mesh(capsule: Capsule):
        # a touch smaller than the collider, as the sphere's
        return primitives.capsule(np.asarray(capsule.half_axis, float), 0.98 * capsule.radius)

    @staticmethod
    def bounding_box(capsule: Capsule) -> tuple:
        return tuple(np.abs(np.asarray(capsule.half_axis, float)) + capsule.radius)

    @ti.func
    def triangle_contact(self, k, a, b, c):
        e = self.half_axis[k]
        dist, w, z = segment_to_triangle(-e, e, a, b, c)
        if segment_crosses_triangle(-e, e, a, b, c):  # the axis passes through: as deep as r
            dist = 0.0 * dist
        p = w[0] * a + w[1] * b + w[2] * c
        n = (b - a).cross(c - a).normalized()  # on the axis itself: out through the face's normal
        if dist > 0.0:
            n = (p - z) / dist
        return dist - self.radius[k], w, n, z + self.radius[k] * n

    @ti.func
    def end_overlap(self, k, a, b, c, side):
        depth, out = 0.0 * a[0], side
        e = self.half_axis[k]
        if segment_crosses_triangle(-e, e, a, b, c):
            # the distance from the features holds only apart: pushed back along the side the
            # face came from, past the capsule's extent that way
            reach = ti.abs(e.dot(side)) + self.radius[k]
            depth = reach - ti.min(a.dot(side), ti.min(b.dot(side), c.dot(side)))
        else:
            d, _, n, _ = self.triangle_contact(k, a, b, c)
            depth, out = -d, n
        return depth, out

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


@ti.data_oriented
class BoxColliders(_TranslatingShapes):
    """Axis-aligned boxes (see :class:`Box` and :class:`_TranslatingShapes`)."""

    KEEPS_START_OVERLAP = True
    name, key, order = "boxes", "box", 12

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


Capsule.part_class = CapsuleColliders
Box.part_class = BoxColliders
