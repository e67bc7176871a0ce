"""Moving, spinning spheres, tested continuously over the step's relative motion."""
from dataclasses import dataclass, replace

import numpy as np
import taichi as ti

from ... import field_io, runtime
from ...collide.closest_points import closest_barycentric
from ...collide.friction import inelastic_friction
from ...geometry.primitives import unit_sphere
from ...part import MovingSource, PartSpec, ScenePart, SolidMesh
from .faces import FaceContact, on_triangle
from .obstacle import Obstacle
from .path import PathFields, SpherePath
from .shape import Shape, register_shape, rows
from .step_start import StepStart
from .translating import TOUCH_FRACTION


@ti.func
def sphere_to_triangle(radius, a, b, c):
    """A sphere of ``radius`` (m) at the origin against triangle (a, b, c): (separation (m,
    negative inside), barycentric weights of the triangle's nearest point, the unit normal from
    the sphere to it, the sphere's surface point there)."""
    w = closest_barycentric(0.0 * a, a, b, c)
    p = on_triangle(w, a, b, c)
    dist = p.norm()
    n = (b - a).cross(c - a).normalized()  # at the centre itself: out through the face's normal
    if dist > 0.0:
        n = p / dist
    return dist - radius, w, n, radius * n


@register_shape
@ti.data_oriented
class SphereColliders(Shape, FaceContact, Obstacle, ScenePart):
    """Spheres that particles cannot enter, however fast they move.

    After each accepted step, in each sphere's frame a free particle goes from p0 - c(t - h) to
    p1 - c(t) (p0: its position at the step start, see :class:`StepStart`). If that segment
    enters the sphere (an exact ray-sphere root) or ends inside it, the particle goes back to
    where the segment first met the surface, then on by the rest of its step's motion along the
    tangent plane there, projected radially to the surface: so it stays on the side it came
    from, and a particle resting on the sphere still slides. It loses its approaching
    normal velocity relative to the surface and, with friction mu > 0, has its tangential
    relative velocity reduced by mu * |that normal velocity| (Coulomb), never reversed. The
    surface velocity is v_c + omega x r, so a spinning sphere drags what lies on it. A particle
    that starts a step inside (only after a reset or a jump) is pushed out along c -> p1.

    Given a ``mesh``, the triangles are tested too (:class:`FaceContact`): a sphere smaller
    than the cloth's spacing cannot pass between vertices through a face.

    Args:
        paths: one :class:`SpherePath` per sphere; radii (m) and frictions alike.
        free: the system's (n,) i32 field, 1 for particles that move.
        continuous: False tests only the end positions of vertices (the old projection, which
            lets a sphere that moves more than its radius per step pass through): kept to compare.
        mesh: the cloth's :class:`~taichi_sim.mesh.TriangleMesh`, or None (vertices only);
        system: the :class:`~taichi_sim.systems.particles.ParticleSystem` (its inverse masses
            share the faces' pushes), needed with a mesh.
    """

    name, key = "spheres", "sphere"
    order = 10
    noun, label = "sphere", "spheres"
    size_keys = ("sphere_radius",)  # (K,); sphere_omega (K, 3) rad/s when one spins, not judged

    def __init__(self, paths: list[SpherePath], radii: list[float], frictions: list[float], free,
                 continuous: bool = True, mesh=None, system=None):
        real = runtime.real()
        self.count = K = len(paths)
        self.paths = list(paths)
        self.free = free
        self.continuous = bool(continuous)
        self.path = PathFields(K)
        self.radius = ti.field(real, shape=K)
        self.friction = ti.field(real, shape=K)
        self.touch = ti.field(real, shape=K)
        field_io.write(*self.path.values(self.paths), (self.radius, radii), (self.friction, frictions),
                       (self.touch, [TOUCH_FRACTION * r for r in radii]))
        self.start = StepStart(free.shape[0])
        self.serial = runtime.serial_loops(free.shape[0] * K)
        self.paths0 = tuple(self.paths)
        self._init_faces(mesh if continuous else None, system, [(r, r, r) for r in radii], radii)
        self.move_to(0.0)

    def set_speed(self, speed: float) -> None:
        """Move every sphere that travels in a straight line (drop, sweep) at ``speed`` (m/s)
        from now on, continuing from where it is (a live change must not teleport it)."""
        for k, path in enumerate(self.paths):
            v = np.asarray(path.velocity, float)
            norm = float(np.linalg.norm(v))
            if norm == 0.0:
                continue
            center, _ = path.at(self.t)
            v_new = v / norm * float(speed)
            self.paths[k] = replace(path, velocity=tuple(v_new), center0=tuple(center - v_new * self.t))
        self.path.upload(self.paths)

    def restore(self) -> None:
        """The paths as built (live speed changes undone), at t = 0."""
        self.paths = list(self.paths0)
        self.path.upload(self.paths)
        self.start.restore()
        self.move_to(0.0)

    @classmethod
    def from_specs(cls, specs: list["Sphere"], context) -> "SphereColliders":
        """One collider for every :class:`Sphere` the scene asked for (the last one's
        ``continuous`` holds for all)."""
        return cls([s.path for s in specs], [s.radius for s in specs], [s.friction for s in specs],
                   context.system.free, continuous=specs[-1].continuous, mesh=context.faces, system=context.system)

    def move_to(self, t: float) -> None:
        """Place every sphere where its path puts it at time t (s)."""
        self.t = t

    def reset(self) -> None:
        self.move_to(0.0)

    def features(self) -> dict:
        return {"spheres": self.count, **({"object_faces": True} if self.mesh is not None else {})}

    def arrays(self) -> dict:
        out = {"sphere_center": self.centers(), "sphere_radius": self.radius.to_numpy().astype(np.float64)}
        if any(p.spin for p in self.paths):
            out["sphere_omega"] = np.stack([p.angular_velocity() for p in self.paths])
        return out

    @classmethod
    def point_depths(cls, x, objects):
        centers, radii = rows(objects["sphere_center"]), np.ravel(objects["sphere_radius"]).astype(np.float64)
        return radii[None] - np.linalg.norm(x[:, None] - centers[None], axis=2)

    @classmethod
    def thinnest_sizes(cls, objects):
        return np.ravel(objects["sphere_radius"]).astype(np.float64)

    def visuals(self) -> list:
        # a touch smaller than the collider: cloth vertices rest on its surface, and the flat
        # triangles between them would otherwise dip into the drawn sphere
        unit, tris = unit_sphere()
        return [SolidMesh(vertices=0.98 * float(r) * unit, normals=unit, triangles=tris,
                          place=lambda k=k: self.centers()[k], reach=np.full(3, float(r)), hidden_from_above=True)
                for k, r in enumerate(self.radius.to_numpy())]

    def energy_sources(self) -> list:
        return [MovingSource("moving sphere", self.fastest_speed())]

    def fastest_speed(self) -> float:
        """The largest speed (m/s) any sphere's surface reaches: its centre's plus |omega| r."""
        radii = self.radius.to_numpy()
        return max(p.fastest_speed() + abs(p.spin) * float(r) for p, r in zip(self.paths, radii))

    def __call__(self, state, t: float, h: float) -> None:
        if self.continuous:
            self.start.begin(state, t, h)
        self.move_to(t)
        self._collide(state, self.start.x, t, h, self.continuous)
        if self.continuous:
            self._faces(state, self.start.x, t, h)
            self.start.end(state, t)

    def curvature_radius(self, k: int) -> float:
        return float(self.radius[k])

    @ti.func
    def triangle_contact(self, k, a, b, c):
        return sphere_to_triangle(self.radius[k], a, b, c)

    @ti.func
    def surface_velocity(self, k, t, r):
        return self.path.velocity(k, t) + self.path.omega[k].cross(r)

    @ti.func
    def distance(self, k, q):
        return q.norm() - self.radius[k]

    @ti.func
    def normal(self, k, q):
        n = 0.0 * q
        n[1] = 1.0  # at the centre itself: out along y
        if q.norm() > 0.0:
            n = q.normalized()
        return n

    @ti.kernel
    def _collide(self, y: ti.template(), x_start: ti.template(), t: float, h: float, continuous: ti.template()):
        ti.loop_config(serialize=self.serial)
        for i in range(y.x.shape[0]):  # a range-for: serialize applies
            if self.free[i]:
                for k in range(self.count):
                    c1 = self.path.center(k, t)
                    r = self.radius[k]
                    b = y.x[i] - c1
                    hit = b.norm_sqr() < r * r
                    n = ti.Vector([0.0, 1.0, 0.0], dt=y.x.dtype)
                    if b.norm() > 0.0:
                        n = b.normalized()
                    if ti.static(continuous):
                        a = x_start[i] - self.path.center(k, t - h)
                        if a.norm_sqr() >= r * r:  # started outside: the first root of |a + s d| = r
                            d = b - a
                            qa, qb, qc = d.dot(d), 2.0 * a.dot(d), a.dot(a) - r * r
                            disc = qb * qb - 4.0 * qa * qc
                            s = 2.0  # no root
                            if qa > 0.0 and disc >= 0.0:
                                s = (-qb - ti.sqrt(disc)) / (2.0 * qa)
                            if s >= 0.0 and s <= 1.0:
                                # from where it met the surface, the step's motion along it is
                                # kept (a resting particle slides) and the motion into it dropped
                                hit = True
                                met = a + s * d
                                m = met.normalized()
                                rest = b - met
                                n = (met + rest - rest.dot(m) * m).normalized()
                            elif hit:  # ends inside without a root: round-off at a graze
                                n = a.normalized()
                    if hit:
                        y.x[i] = c1 + r * n
                        v_surface = self.path.velocity(k, t) + self.path.omega[k].cross(r * n)
                        y.v[i] = inelastic_friction(y.v[i], v_surface, n, self.friction[k])


@dataclass(frozen=True)
class Sphere(PartSpec):
    """A sphere collider of ``radius`` (m) moving along ``path`` with Coulomb ``friction``;
    ``continuous``: see :class:`SphereColliders`."""

    path: SpherePath
    radius: float
    friction: float = 0.0
    continuous: bool = True

    part_class = SphereColliders

    def __post_init__(self):
        if not self.radius > 0:
            raise ValueError("sphere_radius must be > 0")
        if not self.friction >= 0:
            raise ValueError("sphere_friction must be >= 0")
