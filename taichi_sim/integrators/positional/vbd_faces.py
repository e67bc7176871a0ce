"""The cloth's triangles against the scene's objects inside vertex block descent.

A vertex term keeps each vertex off an object, but a box's edge or corner, or a sphere or
capsule thinner than the cloth's spacing, can pass through a triangle whose corners all stay
out. With the objects' face pass after the step waiting (it would move vertices past the
self-contact bounds, :attr:`~.vbd_scene.SceneAttachment.pauses_object_faces`), box edges
poked 8-14 mm into a fold's faces. Here each intact triangle is an object's contact partner
too, inside the solve, exactly as a vertex is:

- **Energy.** With d the triangle's separation from the object (the shape's
  ``triangle_contact``: exact for spheres and capsules, the separating axes' lower bound for a
  box), n the unit direction from the object to the triangle and w the barycentric weights of
  the triangle's nearest point, below the contact radius r the energy 1/2 k (r - d)^2, k =
  ``stiffness`` m / dt^2 with m the cloth's mean particle mass (one k for the three corners:
  the energy is the triangle's). Corner j's share of its gradient and Hessian is w_j (the
  nearest point moves by w_j per unit move of corner j). A nearest point at a corner is that
  vertex's own contact, already in its term, and is not counted again. Friction as for a
  vertex, on the nearest point's slip.
- **Bound.** The object lies behind the plane through its nearest point, normal n, and the
  triangle d beyond it; a corner's move moves every point of the triangle by at most its own
  length, so a move of vertex i that nears that plane by at most ``bound_fraction`` x d keeps
  every incident triangle off the object, whatever the order the vertices are solved in
  (conservative advancement, as for the vertices themselves).

What is left out, because the corners' own terms and bounds already do its work:

- a triangle no point of which can be within reach: the object's signed distance at the
  triangle's centroid, less the centroid's distance to its farthest corner, is a lower bound
  on the triangle's distance (a distance to a convex set changes no faster than the point);
- a triangle lying over one flat side of a box (each corner beyond that side's plane and within
  its outline: :meth:`~taichi_sim.scene.colliders.faces.FaceContact.flat_side`): its nearest
  point is a corner, and each corner's bound keeps it beyond the plane, so the triangle too;
- a sphere or capsule of radius R round enough for the cloth: a face with its corners on it
  dips in at most rho^2 / (2 R) (rho its circumradius) and cannot pass it whole. Below
  ``DIP`` x the contact radius (rho the rest mesh's largest, grown by ``FACE_STRETCH``) the
  object is met by vertices only. cloth-spin's 0.3 m sphere under its 32 x 32 cloth is one.
"""
import numpy as np
import taichi as ti

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


@ti.data_oriented
class ObjectFaces:
    """Mixin of :class:`~.vbd_contact.SolveContact` (reads its ``obstacles``, ``radius``,
    ``fraction``, ``delta``, ``stiffness``, ``penalty_dt`` and ``_push``): the triangle terms
    and bounds of the module's docstring, for the obstacles whose collider tests faces (the
    scene's ``object_faces`` setting, on by default for a cloth), unless vbd's ``object_faces``
    option is off."""

    def _init_object_faces(self, scene, enabled: bool) -> None:
        mesh = scene.mesh
        self.face_obstacles, self.faces_needed = [], []
        if mesh is not None and enabled:
            rest = scene.rest_x if scene.rest_x is not None else scene.state.to_numpy()[0]
            dip = FACE_STRETCH ** 2 * largest_circumradius(rest, mesh.triangles_np) ** 2 / 2.0
            for collider in self.obstacles:
                if getattr(collider, "mesh", None) is None:
                    continue  # the scene's object_faces is off
                # a round object of radius R: faces resting on it dip in rho^2 / (2 R) at most
                needed = [collider.curvature_radius(k) == 0.0 or dip / collider.curvature_radius(k) >= DIP * self.radius
                          for k in range(collider.count)]
                if any(needed):
                    field = ti.field(ti.i32, shape=collider.count)
                    field.from_numpy(np.asarray(needed, np.int32))
                    self.face_obstacles.append(collider)
                    self.faces_needed.append(field)
        self.has_object_faces = bool(self.face_obstacles)
        self.face_pairs = list(zip(self.face_obstacles, self.faces_needed))
        if not self.has_object_faces:
            return
        self.face_mesh = mesh
        free = scene.system.free.to_numpy().astype(bool)
        mass = scene.system.mass.to_numpy()
        self.face_mass = float(mass[free].mean()) if free.any() else 1.0

    @ti.func
    def _corners(self, tri, x, i, p, centre):
        """Triangle ``tri``'s corners in an object's frame (centre ``centre``), vertex i at
        ``p`` and the others where ``x`` has them, and the corner index of i (-1: not one)."""
        a, b, c = x[tri[0]] - centre, x[tri[1]] - centre, x[tri[2]] - centre
        slot = -1
        if tri[0] == i:
            a, slot = p - centre, 0
        elif tri[1] == i:
            b, slot = p - centre, 1
        elif tri[2] == i:
            c, slot = p - centre, 2
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
        it is a corner of, against every face-testing object at time t (s), at positions x."""
        if ti.static(self.has_object_faces):
            f, H, unused = self._each_face(i, x, x[i], t, self.radius, dt, f, H, 1.0, f, False)
        return f, H

    @ti.func
    def face_scale(self, i, x, p, step, t, scale):
        """The share (<= ``scale``) of vertex i's ``step`` (m) from ``p`` (the others where
        ``x`` has them) that keeps each incident triangle off each object by the bound."""
        if ti.static(self.has_object_faces):
            # a triangle farther than |step| / bound_fraction cannot limit the step
            zero = ti.Vector.zero(x.dtype, 3)
            force, block, scale = self._each_face(i, x, p, t, step.norm() / self.fraction, 0.0, zero,
                                                  zero.outer_product(zero), scale, step, True)
        return scale

    @ti.func
    def _each_face(self, i, x, p, t, reach, dt, f, H, scale, step, bound: ti.template()):
        """Visit every intact triangle of vertex i (at ``p``, the others where ``x`` has them)
        that may lie within ``reach`` (m) of a face-testing object at time t (s): add its
        contact to (f, H), or (``bound``) cut ``scale`` so that ``step`` keeps it off."""
        k = self.stiffness * self.face_mass / (self.penalty_dt[None] * self.penalty_dt[None])
        mesh = self.face_mesh
        for collider, needed in ti.static(self.face_pairs):
            for o in range(collider.count):
                if not needed[o]:
                    continue
                centre = collider.path.center(o, t)
                for s in range(mesh.offsets[i], mesh.offsets[i + 1]):
                    face = mesh.incident[s]
                    if not mesh.is_intact(face):
                        continue
                    tri = mesh.triangles[face]
                    a, b, c, slot = self._corners(tri, x, i, p, centre)
                    # (nested ifs: Taichi evaluates both sides of an ``and``)
                    if self._lower_bound(collider, o, a, b, c) >= reach:
                        continue
                    if collider.flat_side(o, a, b, c):
                        continue
                    if ti.static(bound):
                        gap, n = collider.separating_plane(o, a, b, c)
                        scale = ti.min(scale, self._approach_scale(gap, n, step))
                    else:
                        d, w, n, z = collider.triangle_contact(o, a, b, c)
                        if d < self.radius and w.max() < AT_CORNER and w[slot] > 0.0:
                            slip = (w[0] * self.delta[tri[0]] + w[1] * self.delta[tri[1]]
                                    + w[2] * self.delta[tri[2]]) - dt * collider.surface_velocity(o, t, z)
                            f, H = self._push(f, H, d, n, k, w[slot], slip, collider.friction[o], dt)
        return f, H, scale
