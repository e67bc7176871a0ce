"""The cloth's triangles against the scene's objects inside vertex block descent.

A vertex term keeps each vertex off an object, but a box's edge or corner, or a sphere or
capsule thinner than the cloth's spacing, can pass through a triangle whose corners all stay
out. With the objects' face pass after the step waiting (it would move vertices past the
self-contact bounds, :attr:`~taichi_sim.scene.handoff.ContactTakeover.pauses_object_faces`), box edges
poked 8-14 mm into a fold's faces. Here each intact triangle is an object's contact partner
too, inside the solve, as a vertex is.

**The query.** Before the first guess is bounded and before every sweep, one loop over the
(triangle, object) pairs finds those within reach (twice the contact radius plus the step's
largest guessed move over ``bound_fraction``) and keeps, per pair, what the sweep's vertex solves read:

- the contact: the triangle's separation d from the object (the shape's
  ``triangle_contact``: exact for spheres and capsules, the separating axes' lower bound for a
  box), n the unit direction from the object to the triangle, w the barycentric weights of the
  triangle's nearest point and the object's surface velocity there;
- a separating plane: the object lies behind it and every corner beyond it (the shape's
  ``separating_plane``; a box's own sides first, cheaper than its thirteen axes).

The shape's geometry runs once per pair and sweep, in one loop, instead of in every vertex
solve of every incident triangle: compiled into each kernel that solves a vertex, it made the
first step wait for the compiler many times longer (docs/vbd.md).

- **Energy.** Within a sweep the separation is the query's, moved with the corners along n:
  d(x) = n . (sum_j w_j x_j) - (n . the nearest point at the query), as VBD's collision
  queries do. Below the contact radius r the energy 1/2 k (r - d)^2, k = ``stiffness`` m / dt^2
  with m the cloth's mean particle mass (one k for the three corners: the energy is the
  triangle's). Corner j's share of its gradient and Hessian is w_j. A nearest point at a
  corner is that vertex's own contact, already in its term, and is not counted again. Friction
  as for a vertex, on the nearest point's slip.
- **Bound.** A move of vertex i that nears the pair's plane by at most ``bound_fraction`` of
  its own distance to it keeps it beyond; with every corner beyond, the whole triangle is,
  and the object, behind the plane, cannot meet it, whatever the order the vertices are solved
  in (conservative advancement, as for the vertices themselves). A pair out of reach at the
  query is bounded by a ball: the object is at least the triangle's lower bound below away
  from every point of it, and a corner that moves by no more than ``bound_fraction`` of that
  keeps the triangle off.

What is left out, because the corners' own terms and bounds already do its work:

- a triangle no point of which can be within reach: the object's signed distance at the
  triangle's centroid, less the centroid's distance to its farthest corner, is a lower bound
  on the triangle's distance (a distance to a convex set changes no faster than the point);
- the energy of a triangle lying over one flat side of a box (each corner beyond that side's
  plane and within its outline: :meth:`~taichi_sim.scene.colliders.faces.FaceContact.flat_side`):
  its nearest point is a corner (its plane still bounds the corners);
- a sphere or capsule of radius R round enough for the cloth: a face with its corners on it
  dips in at most rho^2 / (2 R) (rho its circumradius) and cannot pass it whole. Below
  ``DIP`` x the contact radius (rho the rest mesh's largest, grown by ``FACE_STRETCH``) the
  object is met by vertices only. cloth-spin's 0.3 m sphere under its 32 x 32 cloth is one.
"""
import numpy as np
import taichi as ti

from .... import runtime
from .mesh_faces import MeshFaces, sharp_features

# A nearest point with a corner's weight above this is at that corner: the vertex's own term.
AT_CORNER = 1.0 - 1e-6
# Round objects are met by faces only where a face resting on them could dip in by this share of
# the contact radius or more (with its circumradius grown by FACE_STRETCH, a stretched cloth's):
# shallower, the corners' own contact keeps the faces out of the object, and the faces' terms
# would cost a sweep a third of its time for nothing (cloth-spin).
DIP, FACE_STRETCH = 0.5, 1.25


def largest_circumradius(x: np.ndarray, triangles: np.ndarray) -> float:
    """The largest circumradius (m) of ``triangles`` ((T, 3) ids) at positions ``x`` ((n, 3) m)."""
    if len(triangles) == 0:
        return 0.0
    a, b, c = (x[triangles[:, j]] for j in range(3))
    ab, bc, ca = (np.linalg.norm(u - v, axis=1) for u, v in ((a, b), (b, c), (c, a)))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    return float(np.max(ab * bc * ca / np.maximum(4.0 * area, 1e-300)))


# A pair's state after a query: out of reach (FAR), else the bits of the parts it holds: a
# separating plane (none where the triangle meets the object), an energy (none where the nearest
# point is a corner's or the triangle lies over a flat side).
FAR, PLANE, ENERGY = 0, 1, 2


@ti.data_oriented
class ObjectFaces:
    """Mixin of :class:`~.contact.SolveContact` (reads its ``obstacles``, ``radius``,
    ``fraction``, ``delta``, ``stiffness``, ``penalty_dt`` and ``_push``): the query, triangle
    terms and bounds of the module's docstring, for the obstacles whose collider tests faces
    (the scene's ``object_faces`` setting, on by default for a cloth), unless vbd's
    ``object_faces`` option is off; and, with the collider mesh in the solve (``body``), the
    :class:`~.mesh_faces.MeshFaces` of its sharp edges and vertices (``mesh_faces``, queried
    once per piece by :meth:`query_mesh_faces`; ``queries_faces``: the analytic objects'
    pairs, queried before every sweep too)."""

    def _init_object_faces(self, inputs, enabled: bool) -> None:
        mesh = inputs.cloth
        # (collider, needed: (count,) i32, pairs: (triangles, count) struct) per face-testing kind
        self.face_pairs = []
        self.mesh_faces = None  # the collider mesh's sharp features against the triangles (mesh_faces.py)
        if mesh is not None and enabled:
            rest = inputs.rest()
            rho = largest_circumradius(rest, mesh.triangles_np)
            dip = FACE_STRETCH ** 2 * rho ** 2 / 2.0
            real = runtime.real()
            vec = ti.types.vector(3, real)
            pair = ti.types.struct(state=ti.i32, plane_normal=vec, plane_offset=real, normal=vec, weights=vec,
                                   offset=real, surface_velocity=vec)
            for collider in self.obstacles:
                if getattr(collider, "mesh", None) is None:
                    continue  # the scene's object_faces is off
                # a round object of radius R: faces resting on it dip in rho^2 / (2 R) at most
                needed = [collider.curvature_radius(k) == 0.0 or dip / collider.curvature_radius(k) >= DIP * self.radius
                          for k in range(collider.count)]
                if any(needed):
                    flags = ti.field(ti.i32, shape=collider.count)
                    flags.from_numpy(np.asarray(needed, np.int32))
                    pairs = pair.field(shape=(max(1, mesh.triangle_count), collider.count))
                    self.face_pairs.append((collider, flags, pairs))
            body = self.body
            if body is not None:
                features = sharp_features(body.player.frames, body.collider.triangles_np, body.orientation,
                                          FACE_STRETCH * rho, body.skin)
                if len(features):
                    self.mesh_faces = body.faces = MeshFaces(body, features, mesh)
        self.has_mesh_faces = self.mesh_faces is not None
        # the analytic objects' pairs, queried before every sweep (the mesh's: once per piece)
        self.queries_faces = bool(self.face_pairs)
        self.has_object_faces = self.queries_faces or self.has_mesh_faces
        if not self.has_object_faces:
            return
        self.face_mesh = mesh
        self.face_reach = ti.field(runtime.real(), shape=())  # the query's reach this step (m)
        n = inputs.system.particle_count
        self.face_anchor = ti.Vector.field(3, runtime.real(), shape=n)  # each vertex at the last query (m)
        # how far from its anchor each vertex may move and keep its triangles out of reach at the
        # last query off the objects (m)
        self.face_room = ti.field(runtime.real(), shape=n)
        free = inputs.system.free.to_numpy().astype(bool)
        mass = inputs.system.mass.to_numpy()
        self.face_mass = float(mass[free].mean()) if free.any() else 1.0

    @ti.func
    def measure_face_reach(self, delta):
        """Set the step's query reach from its guessed moves ``delta`` (an (n,) field, m): far
        enough that a pair out of it leaves each corner room for its guess (a top-level
        statement and loop of the kernel)."""
        if ti.static(self.has_object_faces):
            self.face_reach[None] = 2.0 * self.radius
            for i in range(delta.shape[0]):
                ti.atomic_max(self.face_reach[None], 2.0 * self.radius + delta[i].norm() / self.fraction)

    @ti.func
    def query_faces(self, x, t):
        """Each (triangle, object) pair's contact and plane at positions x (an (n,) field, m)
        and time t (s), for the vertex solves until the next query (a loop of the kernel)."""
        if ti.static(self.queries_faces):
            mesh = self.face_mesh
            reach = self.face_reach[None]
            for i in range(x.shape[0]):
                self.face_anchor[i] = x[i]
                self.face_room[i] = ti.math.inf
            for collider, needed, pairs in ti.static(self.face_pairs):
                for face, o in ti.ndrange(mesh.triangle_count, collider.count):
                    state = FAR
                    tri = mesh.triangles[face]
                    centre = collider.path.center(o, t)
                    a, b, c = x[tri[0]] - centre, x[tri[1]] - centre, x[tri[2]] - centre
                    # (nested ifs: Taichi evaluates both sides of an ``and``)
                    if needed[o] and mesh.is_intact(face):
                        lower = self._lower_bound(collider, o, a, b, c)
                        if lower >= reach:  # the corners' room keeps it off
                            for j in ti.static(range(3)):
                                ti.atomic_min(self.face_room[tri[j]], lower)
                        else:
                            gap, n = collider.separating_plane(o, a, b, c)
                            if gap > 0.0:
                                state = PLANE
                                pairs[face, o].plane_normal = n
                                # the object's side: behind the nearest corner by the gap
                                pairs[face, o].plane_offset = ti.min(n.dot(a), ti.min(n.dot(b), n.dot(c))) - gap + n.dot(centre)
                            if not collider.flat_side(o, a, b, c):
                                d, w, n, z = collider.triangle_contact(o, a, b, c)
                                if w.max() < AT_CORNER:
                                    state |= ENERGY
                                    pairs[face, o].normal = n
                                    pairs[face, o].weights = w
                                    pairs[face, o].offset = (w[0] * a + w[1] * b + w[2] * c).dot(n) - d + n.dot(centre)
                                    pairs[face, o].surface_velocity = collider.surface_velocity(o, t, z)
                    pairs[face, o].state = state

    @ti.func
    def query_mesh_faces(self, x):
        """The collider mesh's sharp features against the triangles at positions x (an (n,)
        field, m), once per piece, at its start (mesh_faces.py; loops of the kernel)."""
        if ti.static(self.has_mesh_faces):
            self.mesh_faces.query(x, self.face_reach[None])

    @ti.func
    def _corners(self, tri, x, i, p):
        """Triangle ``tri``'s corners, vertex i at ``p`` and the others where ``x`` has them,
        and the corner index of i (-1: not one)."""
        a, b, c = x[tri[0]], x[tri[1]], x[tri[2]]
        slot = -1
        if tri[0] == i:
            a, slot = p, 0
        elif tri[1] == i:
            b, slot = p, 1
        elif tri[2] == i:
            c, slot = p, 2
        return a, b, c, slot

    @ti.func
    def _lower_bound(self, collider, k, a, b, c):
        """A lower bound (m) on the separation of triangle (a, b, c) from object k (its frame)."""
        g = (a + b + c) / 3.0
        spread = ti.max((a - g).norm(), ti.max((b - g).norm(), (c - g).norm()))
        return collider.distance(k, g) - spread

    @ti.func
    def face_terms(self, i, x, dt, t, f, H):
        """Add the contact force (N) and PSD block (N/m) on vertex i of every intact triangle
        it is a corner of, against every face-testing object, at positions x (the last query's
        contacts moved with the corners)."""
        if ti.static(self.has_object_faces):
            k = self.stiffness * self.face_mass / (self.penalty_dt[None] * self.penalty_dt[None])
            mesh = self.face_mesh
            for collider, needed, pairs in ti.static(self.face_pairs):
                for o in range(collider.count):
                    for s in range(mesh.offsets[i], mesh.offsets[i + 1]):
                        face = mesh.incident[s]
                        if pairs[face, o].state & ENERGY:
                            tri = mesh.triangles[face]
                            a, b, c, slot = self._corners(tri, x, i, x[i])
                            w, n = pairs[face, o].weights, pairs[face, o].normal
                            d = (w[0] * a + w[1] * b + w[2] * c).dot(n) - pairs[face, o].offset
                            if d < self.radius and w[slot] > 0.0:
                                slip = (w[0] * self.delta[tri[0]] + w[1] * self.delta[tri[1]]
                                        + w[2] * self.delta[tri[2]]) - dt * pairs[face, o].surface_velocity
                                f, H = self._push(f, H, d, n, k, w[slot], slip, collider.friction[o], dt)
            if ti.static(self.has_mesh_faces):
                f, H = self.mesh_faces.terms(self, i, x, dt, k, f, H)
        return f, H

    @ti.func
    def face_scale(self, i, x, p, step, t, scale):
        """The share (<= ``scale``) of vertex i's ``step`` (m) from ``p`` that keeps each
        incident triangle off each object: beyond the pair's plane, and for the pairs out of
        reach at the query, within ``bound_fraction`` of the room they left it (from its anchor:
        a triangle whose corners each moved less than its lower bound cannot have reached the
        object)."""
        if ti.static(self.has_object_faces):
            mesh = self.face_mesh
            for collider, needed, pairs in ti.static(self.face_pairs):
                for o in range(collider.count):
                    for s in range(mesh.offsets[i], mesh.offsets[i + 1]):
                        face = mesh.incident[s]
                        if pairs[face, o].state & PLANE:
                            n = pairs[face, o].plane_normal
                            scale = ti.min(scale, self._approach_scale(p.dot(n) - pairs[face, o].plane_offset, n, step))
            if ti.static(self.queries_faces):
                length = step.norm()
                left = self.fraction * self.face_room[i] - (p - self.face_anchor[i]).norm()
                if length > left:
                    scale = ti.min(scale, ti.max(left, 0.0) / length)
            if ti.static(self.has_mesh_faces):
                scale = self.mesh_faces.scale(self, i, p, step, scale)
        return scale
