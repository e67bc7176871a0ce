"""Cloth triangles against objects: each face tested over the step's relative motion.

The vertex tests of the object colliders let an object smaller than the cloth's spacing pass
between vertices, through a triangle, and let a box's corner or a thin capsule cut a face whose
corners stay out. This pass closes that gap for spheres, capsules and boxes: each intact
triangle near an object is marched along its motion in the object's frame by conservative
advancement (the plane through the object's nearest point, normal to the separation, keeps the
object on one side and the face at distance d on the other, and no point of a face whose
corners move linearly nears that plane faster than its fastest corner, so an advance by d over
that rate never crosses the surface; a face that does not near it cannot touch in the step),
and a face that reaches the surface heading in is stopped there.

The shapes' distances to a triangle live in each kind's file: exact from the features for
spheres and capsules (:func:`.sphere.sphere_to_triangle`, :func:`.capsule.capsule_to_triangle`),
a lower bound from the separating axes for boxes (:func:`.box.box_separation`, exact as an
overlap).
"""
import numpy as np
import taichi as ti

from ... import field_io, runtime
from ...collide.friction import inelastic_friction

# Rounds of face pushes per step (they stop when one pushes nothing): a push can move a corner
# another face shares into the object. A cloth wrapped tight round a 0.01 m sphere took up to
# 46 rounds a step (tests/test_object_faces.py); most steps of a draped cloth take 1 to 3.
MAX_FACE_ROUNDS = 64
# Faces wrapped round a small object share corners, and pushing one out along its normal
# pushes a shared corner into the next: plain projections (1.0) still overlapped by 3.6 % of a
# sphere's radius after 32 rounds; pushing 1.5 times as far from the second round of a step on
# met them sooner. The first round pushes plainly: a cloth resting on a sphere, lifted 1.5
# times its faces' dip every step, fell back and its energy rose above its start.
OVER_RELAX = 1.5
# The break-even of a serial gather: a face's test taken as ten springs' force (a guess; at
# 64 x 64, 8k faces, serial was 4 % faster than parallel on 2 vCPUs). A serial gather also
# meets the faces in a fixed order, so a run repeats itself exactly.
SERIAL_FACES = runtime.SERIAL_WORK // 10
# The least weight of free corners at a point the march pushes (their changes are at most
# 1 / this times the point's).
MIN_FREE_WEIGHT = 0.5
# Advances per face and object: as many as a vertex gets (see shapes.MAX_ADVANCES).
MAX_FACE_ADVANCES = 48
# A face that starts a step deeper inside than this fraction of the object's thinnest size is
# left to the vertex test (a tangle the face pass could not undo, or a face that starts inside
# after a reset): pushing it out along its shortest way could just as well push it through.
LEFT_TO_VERTICES = 0.05
# A face may end a step overlapping an object by this fraction of its thinnest size: a cloth
# draped on a sphere has its faces' chords dip in by l^2 / (8 r) whenever its vertices settle
# onto the surface; without it a 64 x 64 cloth falling on the 0.3 m sphere had 338 face pushes
# a step (2.3 with it), and its 3000 steps took 4.56 s against 3.92 s.
ALLOWED_OVERLAP = 0.005


@ti.func
def on_triangle(w, a, b, c):
    return w[0] * a + w[1] * b + w[2] * c


@ti.func
def corner(j, a, b, c):
    """Corner j (0, 1 or 2, known only at run time) of triangle (a, b, c)."""
    return ti.select(j == 0, a, ti.select(j == 1, b, c))


@ti.data_oriented
class FaceContact:
    """Mixin of the object colliders: their faces' pass (see the module's docstring).

    The collider provides ``count``, ``path`` (:class:`PathFields`), ``friction``, ``touch``,
    ``free``, and the Taichi functions ``triangle_contact(k, a, b, c)`` (separation, weights,
    normal, surface point, in object k's frame), ``end_overlap(k, a, b, c, side)`` (how deep
    the face overlaps the object and the unit direction out; ``side``: the direction from the
    object to the face at the step's start) and ``surface_velocity(k, t, z)``; and calls
    :meth:`_init_faces` once and :meth:`_faces` after its vertex test, before the step's end
    positions are kept as the next start.

    What it does to a face that meets an object: the face's nearest point goes onto the
    tangent plane where it met the surface (the motion into the surface is dropped, the motion
    along it kept), and its velocity relative to the surface loses its approach and, by
    Coulomb, up to mu times that from its slip; both changes are shared by the corners by
    barycentric weight over mass (the smallest changes, in kinetic energy, that move the point
    so). Counted in ``face_contacts_total``.
    """

    # A box lets a face keep the overlap it started the step with. Pushed out fully, a face
    # draped over a box's edge (a corner on each side) was lifted off it every step and the
    # cloth's energy rose (0.15 J of 4.9 J in 20 steps in tests/test_colliders.py's fall).
    # Spheres and capsules push fully: a chord resting on them dips in only l^2 / (8 r), and
    # keeping it let overlaps ratchet up each step until a sphere smaller than the spacing,
    # pressed into the cloth, passed through it (after 23 steps at 3 m/s).
    KEEPS_START_OVERLAP = False

    def _init_faces(self, mesh, system, bounds, thinnest) -> None:
        """``bounds``: each object's half extents along x, y, z about its centre (m, its
        bounding box); ``thinnest``: its thinnest size (m), which scales LEFT_TO_VERTICES."""
        self.mesh = mesh
        self.face_contacts_total = 0
        # Set by the Stepper for a method whose solve keeps the cloth off itself (vbd with
        # self-contact): a face push after its step would move vertices past its bounds.
        self.faces_paused = False
        if mesh is None:
            return
        real = runtime.real()
        n = self.free.shape[0]
        self.system = system  # its inverse masses share the pushes
        self.face_count = ti.field(ti.i32, shape=())
        self.moved_in_round = ti.field(ti.i32, shape=n)  # the last round that moved each vertex
        self.rounds_run = 0
        self.serial_gather = runtime.serial_loops(mesh.triangle_count * self.count, SERIAL_FACES)
        self.candidate_count = ti.field(ti.i32, shape=())
        self.candidates = ti.Vector.field(2, ti.i32, shape=max(1, mesh.triangle_count * self.count))
        self.bound = ti.Vector.field(3, real, shape=self.count)
        self.left = ti.field(real, shape=self.count)
        self.allowed = ti.field(real, shape=self.count)
        thinnest = np.asarray(thinnest, np.float64)
        field_io.write((self.bound, np.asarray(bounds, np.float64)), (self.left, LEFT_TO_VERTICES * thinnest),
                       (self.allowed, ALLOWED_OVERLAP * thinnest))

    def _faces(self, state, x_start, t: float, h: float) -> None:
        if self.mesh is None or self.faces_paused:
            return
        # _face_round is large and branchy: Taichi's whole-kernel CFG pass was half of its
        # compile and bought no speed (runtime.without_cfg_optimisation).
        with runtime.without_cfg_optimisation():
            for round_ in range(MAX_FACE_ROUNDS):
                self.rounds_run += 1  # numbers the rounds of every step, so no reset is needed
                pushed = self._face_round(state, x_start, t, h, int(round_ == 0), self.rounds_run)
                self.face_contacts_total += pushed
                if pushed == 0:
                    break

    def curvature_radius(self, k: int) -> float:
        """The smallest radius of curvature (m) of object k's surface: 0 for a shape with edges
        and corners (the default), its radius for a sphere or a capsule. A face whose corners
        lie on a surface of radius R dips into it by at most rho^2 / (2 R), rho the face's
        circumradius, and cannot pass it whole while rho < R."""
        return 0.0

    @ti.func
    def separating_plane(self, k, a, b, c):
        """(Gap (m), unit normal from the object) of a plane with object k on one side and
        triangle (a, b, c) (its frame) ``gap`` beyond it on the other, when the gap is > 0:
        ``triangle_contact``'s by default; a shape may return a cheaper, looser one."""
        d, w, n, z = self.triangle_contact(k, a, b, c)
        return d, n

    @ti.func
    def flat_side(self, k, a, b, c):
        """Whether triangle (a, b, c) (object k's frame) lies where one flat side of the object
        is nearest to each of its corners, so that its nearest point to the object is one of
        them (the corners' own contact); False by default."""
        return False

    @ti.func
    def end_overlap(self, k, a, b, c, side):
        """Where ``triangle_contact``'s separation is signed (a sphere's), its overlap and
        normal; a shape whose separation is not overrides this."""
        d, _, n, _ = self.triangle_contact(k, a, b, c)
        return -d, n

    @ti.kernel
    def _face_round(self, y: ti.template(), x_start: ti.template(), t: float, h: float, first: ti.i32,
                    round_: ti.i32) -> ti.i32:
        """One Gauss-Seidel round; returns how many faces it moved. The faces that need a push
        are found in parallel, then pushed one after another, each seeing the pushes before it
        (a vertex shared by the faces round a contact takes them in turn, not their mean: a
        mean converges too slowly on a cloth stretched round a small object); where the gather
        is serial (see SERIAL_FACES), in the faces' order, so runs repeat. After the first
        round only faces with a corner the round before moved are looked at: the others were
        met then, and nothing they depend on has changed."""
        self.face_count[None] = 0
        self.candidate_count[None] = 0
        ti.loop_config(serialize=self.serial_gather)
        for f in range(self.mesh.triangle_count):
            tri = self.mesh.triangles[f]
            if self.mesh.is_intact(f) and (self.free[tri[0]] or self.free[tri[1]] or self.free[tri[2]]):
                moved_before = (self.moved_in_round[tri[0]] == round_ - 1 or self.moved_in_round[tri[1]] == round_ - 1
                                or self.moved_in_round[tri[2]] == round_ - 1)
                if first or moved_before:
                    for k in range(self.count):
                        if (self._near(y, x_start, tri, k, t, h)
                                and self._face_against(y, x_start, tri, k, t, h, first, False)):
                            slot = ti.atomic_add(self.candidate_count[None], 1)
                            self.candidates[slot] = ti.Vector([f, k])
        ti.loop_config(serialize=True)
        for c in range(self.candidate_count[None]):
            f, k = self.candidates[c][0], self.candidates[c][1]
            tri = self.mesh.triangles[f]
            if self._face_against(y, x_start, tri, k, t, h, first, True):
                for j in ti.static(range(3)):
                    self.moved_in_round[tri[j]] = round_
        return self.face_count[None]

    @ti.func
    def _near(self, y, x_start, tri, k, t, h):
        """Whether the face's swept box, in object k's frame, reaches the object's box."""
        c0, c1 = self.path.center(k, t - h), self.path.center(k, t)
        lo = ti.min(ti.min(x_start[tri[0]] - c0, y.x[tri[0]] - c1), ti.min(x_start[tri[1]] - c0, y.x[tri[1]] - c1))
        lo = ti.min(lo, ti.min(x_start[tri[2]] - c0, y.x[tri[2]] - c1))
        hi = ti.max(ti.max(x_start[tri[0]] - c0, y.x[tri[0]] - c1), ti.max(x_start[tri[1]] - c0, y.x[tri[1]] - c1))
        hi = ti.max(hi, ti.max(x_start[tri[2]] - c0, y.x[tri[2]] - c1))
        reach = self.bound[k] + self.touch[k]
        return all(lo <= reach) and all(hi >= -reach)

    @ti.func
    def _face_against(self, y, x_start, tri, k, t, h, first, apply: ti.template()):
        """Face ``tri`` against object k over the step: whether it must be moved, and (with
        ``apply``) moving it.

        A face that started clear, or overlapping by less than ``left`` (a chord resting on a
        curved surface), is marched; meeting the surface heading in, its nearest point goes
        onto the tangent plane there. Then, unless that moved it, the end decides: a face that
        ends overlapping has its corners below the shortest way out moved up onto it (and,
        after a step's first round, OVER_RELAX - 1 of the overlap beyond); where
        ``KEEPS_START_OVERLAP`` (boxes), only the overlap past what it started with counts."""
        c0, c1 = self.path.center(k, t - h), self.path.center(k, t)
        a0, b0, e0 = x_start[tri[0]] - c0, x_start[tri[1]] - c0, x_start[tri[2]] - c0
        a1, b1, e1 = y.x[tri[0]] - c1, y.x[tri[1]] - c1, y.x[tri[2]] - c1
        da, db, de = a1 - a0, b1 - b0, e1 - e0
        touch = self.touch[k]
        needed = False
        pushed = 0.0
        start_depth = 0.0 * touch
        side = 0.0 * a0  # the way from the object to the face at the start
        s = 0.0
        # (one call of the shape's distance, in the loop: each call site is compiled anew)
        for advance in range(MAX_FACE_ADVANCES):
            d, w, n, z = self.triangle_contact(k, a0 + s * da, b0 + s * db, e0 + s * de)
            if advance == 0:
                side, start_depth = n, -d
                if start_depth >= self.left[k]:
                    break
            if d <= touch:
                if on_triangle(w, da, db, de).dot(n) < 0.0:  # touching counts when heading in
                    depth = -(on_triangle(w, a1, b1, e1) - z).dot(n)
                    # a face resting on the surface may sink ``allowed`` before it is put back
                    # onto it (touching from the start, s = 0); one arriving is put back at once
                    if depth > touch + ti.select(s == 0.0, self.allowed[k], 0.0):
                        needed = True
                        if ti.static(apply):
                            pushed = self._push_face(y, tri, k, t, w, n, c1 + z, depth)
                break
            # the plane through the object's nearest point, normal n, keeps it on one side and
            # the face d beyond; the face nears that plane no faster than its fastest corner
            approach = ti.max(-da.dot(n), ti.max(-db.dot(n), -de.dot(n)))
            if approach <= 0.0:  # never nears it: no contact for the rest of the step
                break
            s += d / approach
            if s >= 1.0:
                break
        if start_depth < self.left[k] and pushed == 0.0:
            # past ``allowed``, a face goes out all the way (to its start's overlap, for a box):
            # resting faces then come back only every few steps, not every step
            target = 0.0 * start_depth
            if ti.static(self.KEEPS_START_OVERLAP):
                target = ti.max(start_depth, 0.0)
            depth, out = self.end_overlap(k, y.x[tri[0]] - c1, y.x[tri[1]] - c1, y.x[tri[2]] - c1, side)
            if depth > ti.max(target, self.allowed[k]) + touch:
                needed = True
                if ti.static(apply):
                    self._translate_face(y, tri, k, t, ti.select(first, 1.0, OVER_RELAX) * (depth - target), out)
        return needed

    @ti.func
    def _push_face(self, y, tri, k, t, w, n, z_world, depth):
        """Move face ``tri``'s point of weights ``w``, ``depth`` (m) below the tangent plane of
        normal ``n`` at the surface point ``z_world``, onto it, give it the contact response,
        and return how far it moved (m; 0 when the point is mostly pinned: MIN_FREE_WEIGHT)."""
        inv = ti.Vector([self.system.inverse_mass(tri[j]) for j in ti.static(range(3))])
        denom = (w * w * inv).sum()
        free_weight = (w * ti.select(inv > 0.0, 1.0, 0.0)).sum()
        moved = 0.0
        # a point nearer pinned corners than free ones is left to the end's test, which moves
        # only the free corners below the way out: shared by weight over mass, the free corners'
        # changes grow as 1 / their weight (a pin beside a moving object threw them at 1e6 m/s)
        if denom > 0.0 and free_weight >= MIN_FREE_WEIGHT:
            moved = depth
            u = on_triangle(w, y.v[tri[0]], y.v[tri[1]], y.v[tri[2]])
            v_surface = self.surface_velocity(k, t, z_world - self.path.center(k, t))
            du = inelastic_friction(u, v_surface, n, self.friction[k]) - u
            self.face_count[None] += 1
            for j in ti.static(range(3)):
                share = w[j] * inv[j] / denom
                y.x[tri[j]] += share * depth * n
                y.v[tri[j]] += share * du
        return moved

    @ti.func
    def _translate_face(self, y, tri, k, t, depth, out):
        """Move the face's free corners that lie below the plane ``out``, ``depth`` (m) above
        the deepest corner, up onto it (the least motion of corners that takes the face out
        along ``out``); each corner moved loses its approach along ``out`` and, by Coulomb,
        its slip."""
        c1 = self.path.center(k, t)
        heights = ti.Vector([(y.x[tri[j]] - c1).dot(out) for j in ti.static(range(3))])
        level = heights.min() + depth
        moved = False
        for j in ti.static(range(3)):
            below = level - heights[j]
            if self.free[tri[j]] and below > 0.0:
                y.x[tri[j]] += below * out
                # the surface's velocity where the corner is now (a sphere's spin included)
                v_surface = self.surface_velocity(k, t, y.x[tri[j]] - c1)
                y.v[tri[j]] = inelastic_friction(y.v[tri[j]], v_surface, out, self.friction[k])
                moved = True
        if moved:
            self.face_count[None] += 1
