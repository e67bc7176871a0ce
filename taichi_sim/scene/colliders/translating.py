"""What the collider kinds that translate along scripted paths (capsules, boxes, and a kind a
plug-in adds) share: paths, step starts, the continuous vertex test by conservative advancement
and the response."""
import numpy as np
import taichi as ti

from ... import field_io, runtime
from ...collide.friction import inelastic_friction
from ...part import MovingSource, ScenePart, SolidMesh
from .faces import FaceContact
from .obstacle import Obstacle
from .path import PathFields
from .shape import Shape
from .step_start import StepStart

# Marching rounds per particle and shape: a segment that grazes the surface needs many short
# advances; past this many the particle keeps the end-only test (it ends outside, or is
# pushed out along the surface's normal at its end).
MAX_ADVANCES = 48
# An advance that leaves the march this close (relative to the shape's thinnest size) counts as
# touching: a ray marched by signed distance only approaches the surface.
TOUCH_FRACTION = 1e-4


@ti.data_oriented
class TranslatingShapes(Shape, FaceContact, Obstacle, ScenePart):
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


