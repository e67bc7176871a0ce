"""A triangle-mesh collider (a body, rigid or moving by a sequence of frames) inside vertex
block descent: a contact plane per cloth vertex, found once per piece of a substep, with a
penalty energy, friction and a bound on each vertex's move that stays conservative on a mesh
that is not convex and that moves (docs/vbd-contact.md).

**Detection** (:meth:`MeshContact.detect`, before each piece's start guess), for a piece from
t0 to t1 within one frame segment (the mesh's vertices move linearly in it; pieces.py cuts a
piece at a frame's time):

- the nearest point p0 of the mesh posed at t0 to each free vertex x0 (where the cloth is, free
  of the mesh), within ``reach``, on triangle f with barycentric weights w. The vertex's side
  is found where it is, before the body moves: a limb that moves further than its thickness
  in a piece cannot put the vertex on its far side;
- carried with the triangle to t1: p1 = w . f's corners at t1 (the mesh's motion over the
  piece at that point, u = p1 - p0, is the surface's for friction), the normal n0 = (x0 - p0)
  / |x0 - p0| turned as f's own normal turns;
- the vertex's free ball: the distance D from x0 to the nearest triangle at t1 that does not lie
  wholly behind the plane (p1, n1). A triangle behind the plane cannot be met from in front of
  it; any other is at least D away. On a convex part every triangle near the contact lies behind
  its tangent plane and D is the distance to the next part of the body (the other leg); in a
  fold of the body D is small, and so is the bound there.

A vertex with nothing within ``reach`` is at least ``reach`` from the mesh at t0, and at least
``reach`` less the mesh's largest move over the piece from it at t1 (or, farther off, its
distance to the box holding every frame of the mesh).

**Energy**, as for the analytic objects (contact.py): with d = n1 . (x - p1) - skin, below the
contact radius r the penalty 1/2 k (r - d)^2 along n1, k = ``stiffness`` m / dt^2, and friction
on the slip relative to the surface (the vertex's displacement less u).

**Bound**: a vertex's move keeps it within ``bound_fraction`` of D (or of the lower bound above)
from x0, and nears the plane (p1, n1) by at most ``bound_fraction`` of its distance to it; a
vertex the body's motion put behind the plane at t1 (by at most the body's move over the piece)
goes no deeper than it was. So in front of the plane and within the ball, the vertex meets no
triangle at t1, whatever the body's shape.

The cloth's triangles against the mesh's sharp edges and vertices (a bump of the body sharper
than the cloth's spacing, which could poke between cloth vertices) are mesh_faces.py's.
"""
import numpy as np
import taichi as ti

from .... import runtime
from ....collide.closest_points import closest_barycentric

# A triangle whose corners lie no further than this share of the skin in front of a vertex's
# contact plane counts as behind it (round-off of corners on the plane itself).
BEHIND_TOLERANCE = 1e-4
# The body's largest move over a piece within reach of any cloth vertex is held to this share of
# bound_fraction x the room a vertex is given (pieces.py cuts the piece): a vertex the body
# pushes then has a short way out, and a thin part of the body (a paddle) cannot move past a
# vertex in one piece. Judged per vertex over the triangles within its reach (``pace``), so a
# limb moving fast away from the cloth does not cut the pieces of the whole step.
MESH_PACE = 0.8
FOUND = 1  # a vertex's state: a contact plane within reach


def _orientation(vertices: np.ndarray, triangles: np.ndarray) -> int:
    """+1 when ``triangles`` ((T, 3) ids) close a volume wound counter-clockwise seen from
    outside at ``vertices`` ((V, 3) m), -1 when clockwise, 0 when they are not closed with one
    winding (every directed edge once, and its reverse once)."""
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]).astype(np.int64)
    key = edges[:, 0] * (int(triangles.max()) + 1) + edges[:, 1]
    reverse = edges[:, 1] * (int(triangles.max()) + 1) + edges[:, 0]
    if len(np.unique(key)) != len(key) or not np.isin(reverse, key).all():
        return 0
    a, b, c = (vertices[triangles[:, j]] for j in range(3))
    volume = float(np.einsum("ij,ij->", a, np.cross(b, c))) / 6.0
    return 1 if volume > 0 else -1 if volume < 0 else 0


def median_edge(inputs) -> float:
    """The median edge (m) of a scene's cloth at rest (its
    :class:`~taichi_sim.scene.handoff.ContactInputs`; 0 without a cloth)."""
    mesh = inputs.cloth
    if mesh is None or mesh.triangle_count == 0:
        return 0.0
    rest = inputs.rest()
    tris = mesh.triangles_np.astype(np.int64)
    return float(np.median(np.linalg.norm(rest[tris] - rest[np.roll(tris, 1, axis=1)], axis=2)))


@ti.data_oriented
class MeshContact:
    """The scene's :class:`~taichi_sim.scene.colliders.mesh_collider.MeshCollider` in
    :class:`~.contact.SolveContact` (module docstring).

    Args:
        collider: the scene's mesh collider (its frames, grid and skin; the Stepper skips its
            post-step pass while the solve holds it).
        system: the particle system (``free``, ``particle_count``).
        radius: the contact radius r (m).
        fraction: ``bound_fraction``.
        spacing: the cloth's typical edge (m), what the room a vertex is given is sized by.
    """

    def __init__(self, collider, system, *, radius: float, fraction: float, spacing: float):
        real = runtime.real()
        self.collider, self.system = collider, system
        self.skin = float(collider.skin)
        self.friction = float(collider.spec.friction)
        self.radius, self.fraction = float(radius), float(fraction)
        # what a vertex out of reach may move per piece, over bound_fraction (m)
        self.room = max(2.0 * self.radius, float(spacing))
        player = collider.player
        self.player = player
        V = player.frames.shape[1]
        n = system.particle_count
        self.triangles = ti.Vector.field(3, ti.i32, shape=len(collider.triangles_np))
        self.triangles.from_numpy(collider.triangles_np.astype(np.int32))
        self.before = ti.Vector.field(3, real, shape=V)  # the vertices at the piece's start, mesh frame (m)
        self.after = ti.Vector.field(3, real, shape=V)  # ... at its end (m)
        # the box holding every frame (mesh frame, m): a far vertex's distance to it bounds its room
        self.box_lo = tuple(float(v) for v in player.frames.min(axis=(0, 1)))
        self.box_hi = tuple(float(v) for v in player.frames.max(axis=(0, 1)))
        self.state = ti.field(ti.i32, shape=n)
        self.point = ti.Vector.field(3, real, shape=n)  # p1, world (m)
        self.normal = ti.Vector.field(3, real, shape=n)  # n1
        self.moved = ti.Vector.field(3, real, shape=n)  # u: the surface's move at p over the piece (m)
        # how far in front of the plane the vertex must stay (m): the nearly flat triangles' reach
        # in front of it, or less where the body's move put it behind that at the piece's start
        self.floor = ti.field(real, shape=n)
        self.anchor = ti.Vector.field(3, real, shape=n)  # x0 (m)
        self.ball = ti.field(real, shape=n)  # how far from x0 the vertex may move this piece (m)
        self.centre = ti.Vector.field(3, real, shape=2)  # the mesh's origin at the piece's start, end (m)
        self.span = ti.field(real, shape=())  # the piece's length (s)
        self.motion = ti.field(real, shape=())  # the body's largest move near the cloth over the piece (m)
        # the largest move over the piece (m) of a triangle within reach of a free vertex at t0
        self.local_motion = ti.field(real, shape=())
        self.faces = None  # the cloth's triangles against the sharp features (mesh_faces.py), if any
        self.detections = 0
        self.last_t = None
        self._speeds = (-1, None)
        self.self_nearest = None  # the self-contact bounds' distances ((n,) field, m), where the solve has them
        # +1 (-1): a closed mesh whose triangles wind counter-clockwise (clockwise) seen from
        # outside; a vertex that ended inside it is then pushed out, not further in. 0: a shell
        # of two sides (open, or not consistently wound), each vertex kept on its own side.
        self.orientation = _orientation(player.frames[0], collider.triangles_np)

    # -- the piece schedule's questions (host) ----------------------------------------------------

    def piece_length(self, x: np.ndarray, t: float, length: float, shortest: float) -> float:
        """How long (s, <= ``length``) a piece from t may be before its detection: it ends at the
        next frame's time when it would pass one (the motion is then linear over the piece), and,
        where the mesh has sharp features (mesh_faces.py), the body's largest move within reach
        of the cloth (``x`` (n, 3) m) stays below ``MESH_PACE`` x ``bound_fraction`` x the skin
        and the contact radius (not below ``shortest`` s). The vertices' own pace, judged per
        vertex, is :meth:`pace` after the detection."""
        player = self.player
        if player.animated and t * player.fps < player.count - 1:
            frame_end = (np.floor(t * player.fps * (1 + 1e-12) + 1e-9) + 1) / player.fps
            if frame_end < t + length * (1 - 1e-9):
                length = frame_end - t
        if self.faces is not None:
            # a sharp feature moves less than the distance a face keeps from it (the skin and
            # the contact radius) in a piece: it cannot pass a face between two queries. The
            # faces' query is not per vertex, so this pace stays the whole cloth's.
            speed = self.near_speed(x, t, length)
            allowed = MESH_PACE * self.fraction * min(self.room, self.skin + self.radius)
            if speed * length > allowed:
                length = max(allowed / speed, min(shortest, length))
        return length

    def pace(self) -> float:
        """The last detection's largest move of the body within reach of a free vertex, as a
        share of ``MESH_PACE`` x ``bound_fraction`` x the room (above 1: pieces.py shortens the
        piece by it; the move shrinks with the piece)."""
        return float(self.local_motion[None]) / (MESH_PACE * self.fraction * self.room)

    def near_speed(self, x: np.ndarray, t: float, length: float) -> float:
        """The largest speed (m/s) of the mesh's triangles within reach of the cloth at ``x``
        ((n, 3) m) over the piece from t of ``length`` s (0 beyond the last frame): no point of
        a triangle moves faster than its corners, nor the mesh's origin than its path."""
        player = self.player
        path_speed = float(np.linalg.norm(self.collider.spec.path.at(t)[1]))
        if not player.animated or t * player.fps >= player.count - 1:
            return path_speed
        k, _ = player.segment(t + 0.5 * length)
        lo_box, hi_box, speeds = self._segment_speeds(k)
        centre = self.collider.spec.path.at(t)[0]
        reach = self.skin + self.radius + 2.0 * self.collider.cell
        lo, hi = x.min(axis=0) - centre - reach, x.max(axis=0) - centre + reach
        near = np.all((hi_box >= lo) & (lo_box <= hi), axis=1)
        return path_speed + (float(speeds[near].max()) if near.any() else 0.0)

    def _segment_speeds(self, k: int):
        """Each triangle's box over frame segment k (lo, hi: (T, 3) m, mesh frame) and its
        fastest corner's speed there ((T,) m/s), kept for the segment's pieces."""
        if self._speeds[0] != k:
            lo, hi = self.player.segment_boxes(self.collider.triangles_np, k)
            step = np.linalg.norm(self.player.frames[k + 1] - self.player.frames[k], axis=1) * self.player.fps
            self._speeds = (k, (lo, hi, step[self.collider.triangles_np].max(axis=1)))
        return self._speeds[1]

    def detect(self, x, t0: float, t1: float, largest_move: float, x_np: np.ndarray) -> None:
        """The contact planes and bounds of a piece from t0 to t1 (s, one frame segment) at
        positions ``x`` ((n,) vec3 field, m, the piece's start; ``x_np`` the same as (n, 3)
        numpy): the module docstring. ``largest_move``: the most a cloth vertex is expected to
        move in the piece (m), which the reach grows by so that a vertex's guess fits its bound."""
        collider, player = self.collider, self.player
        segment = player.segment(0.5 * (t0 + t1))[0]
        collider.list_segment(segment)
        if self.faces is not None:
            self.faces.list_segment(segment)
        npr = runtime.np_real()
        start = player.vertices(t0)
        self.before.from_numpy(start.astype(npr))
        end = collider.follow(t1)
        self.after.from_numpy(end.astype(npr))
        c0 = collider.spec.path.at(t0)[0]
        c1 = collider.spec.path.at(t1)[0]
        # the body's move near the cloth (a vertex farther than the reach it sets cannot be met)
        motion = self.near_speed(x_np, t0, t1 - t0) * (t1 - t0)
        room = self.room
        if self.self_nearest is None:
            # no self-contact ball holds a vertex to about this already: room for its guess, up
            # to two grid cells around it (the query's cost; a vertex beyond gets what reach leaves)
            room = max(room, min(largest_move / self.fraction, 2.0 * collider.cell))
        reach = self.skin + self.radius + motion + room
        self._detect(x, ti.Vector(list(c0)), ti.Vector(list(c1)), reach, motion, t1 - t0)
        self.detections += 1
        self.last_t = t1

    # -- detection (kernel) ------------------------------------------------------------------------

    @ti.func
    def _nearest(self, corners, q, radius):
        """(distance (m), triangle, barycentric weights, the largest corner move (m, mesh frame,
        ``before`` to ``after``) of the triangles within ``radius``) of the mesh at ``corners``
        ((V,) field, mesh frame) nearest to q within ``radius``; triangle -1 when none is."""
        c = self.collider
        best, face, weights, moved = radius, -1, 0.0 * q, 0.0 * radius
        first, last = c._cells(q - radius, q + radius)
        span = ti.max(last - first + 1, 0)
        for k in range(span[0] * span[1] * span[2]):
            cell = c._cell_id(first, span, k)
            for e in range(c.cell_start[cell], c.cell_start[cell + 1]):
                f = c.cell_triangles[e]
                tri = self.triangles[f]
                a, b, d = corners[tri[0]], corners[tri[1]], corners[tri[2]]
                w = closest_barycentric(q, a, b, d)
                dist = (q - w[0] * a - w[1] * b - w[2] * d).norm()
                if dist < radius:
                    for j in ti.static(range(3)):
                        moved = ti.max(moved, (self.after[tri[j]] - self.before[tri[j]]).norm())
                if dist < best:
                    best, face, weights = dist, f, w
        return best, face, weights, moved

    @ti.func
    def _clear_distance(self, q, p, n, radius):
        """(the distance (m, at most ``radius``) from q to the nearest triangle at the piece's end
        (``after``, mesh frame) reaching more than the skin in front of the plane through p with
        normal n; how far in front of it (m, >= 0) the others reach): a point in front of the
        plane by more than the latter, and nearer to q than the former, is on no triangle."""
        c = self.collider
        best, offset = radius * 1.0, 0.0 * radius
        tolerance = BEHIND_TOLERANCE * self.skin
        first, last = c._cells(q - radius, q + radius)
        span = ti.max(last - first + 1, 0)
        for k in range(span[0] * span[1] * span[2]):
            cell = c._cell_id(first, span, k)
            for e in range(c.cell_start[cell], c.cell_start[cell + 1]):
                tri = self.triangles[c.cell_triangles[e]]
                a, b, d = self.after[tri[0]], self.after[tri[1]], self.after[tri[2]]
                front = ti.max(n.dot(a - p), ti.max(n.dot(b - p), n.dot(d - p)))
                if front > self.skin:
                    w = closest_barycentric(q, a, b, d)
                    best = ti.min(best, (q - w[0] * a - w[1] * b - w[2] * d).norm())
                elif front > tolerance:
                    # near the plane (a turned normal's round-off, a shallow fold): the vertex
                    # keeps beyond it instead of a tiny ball
                    w = closest_barycentric(q, a, b, d)
                    if (q - w[0] * a - w[1] * b - w[2] * d).norm() < radius:
                        offset = ti.max(offset, front)
        return best, offset

    @ti.func
    def _unit_normal(self, corners, tri):
        a, b, d = corners[tri[0]], corners[tri[1]], corners[tri[2]]
        return (b - a).cross(d - a).normalized()

    @ti.kernel
    def _detect(self, x: ti.template(), c0: ti.types.vector(3, float), c1: ti.types.vector(3, float),
                reach: float, motion: float, span: float):
        lo, hi = ti.Vector(self.box_lo), ti.Vector(self.box_hi)
        self.centre[0], self.centre[1] = c0, c1
        self.span[None] = span
        self.motion[None] = motion
        self.local_motion[None] = 0.0
        for i in range(self.system.particle_count):
            self.state[i] = 0
            self.anchor[i] = x[i]
            self.floor[i] = 0.0
            ball = 0.0 * reach
            if self.system.free[i]:
                q0 = x[i] - c0
                d0, face, w, moved = self._nearest(self.before, q0, reach)
                if face >= 0:
                    # the pace: every triangle within reach (not only the nearest: another part
                    # of the body may come at the vertex), the mesh's origin moving too
                    ti.atomic_max(self.local_motion[None], moved + (c1 - c0).norm())
                    tri = self.triangles[face]
                    p0 = w[0] * self.before[tri[0]] + w[1] * self.before[tri[1]] + w[2] * self.before[tri[2]]
                    p1 = w[0] * self.after[tri[0]] + w[1] * self.after[tri[1]] + w[2] * self.after[tri[2]]
                    face0 = self._unit_normal(self.before, tri)
                    n0 = face0 * ti.static(self.orientation or 1.0)
                    if d0 > 1e-6 * self.skin:
                        n0 = (q0 - p0) / d0
                        if ti.static(self.orientation != 0):
                            if n0.dot(face0) * self.orientation < 0.0:
                                n0 = -n0  # inside the closed mesh: out the nearest way
                    side = 1.0 if n0.dot(face0) >= 0.0 else -1.0
                    n1 = (n0 + side * (self._unit_normal(self.after, tri) - face0)).normalized()
                    q1 = x[i] - c1
                    clear, offset = self._clear_distance(q1, p1, n1, reach)
                    self.state[i] = FOUND
                    self.point[i] = p1 + c1
                    self.normal[i] = n1
                    self.moved[i] = (p1 + c1) - (p0 + c0)
                    self.floor[i] = ti.min(offset, n1.dot(q1 - p1))
                    ball = clear
                else:
                    # reach from the mesh at t0, less its move; or farther, off the box of all frames
                    q1 = x[i] - c1
                    outside = ti.max(ti.max(lo - q1, q1 - hi), 0.0).norm()
                    ball = ti.max(reach - motion, outside)
            self.ball[i] = self.fraction * ball

    def crowding(self, refreshes: int) -> float:
        """The largest share of its bound (its self-contact ball, moved on ``refreshes`` times
        in the piece, where the solve has ``self_nearest``; else its own) that a vertex must move
        this piece to get out to the skin where the body's move put it (0: none must). Above 1
        the piece's sweeps cannot push it out; pieces.py shortens the piece, since that push
        shrinks with it."""
        self.has_self_nearest = self.self_nearest is not None
        return float(self._crowding(refreshes))

    @ti.kernel
    def _crowding(self, refreshes: ti.i32) -> float:
        most = 0.0
        for i in range(self.system.particle_count):
            if self.state[i] == FOUND:
                push = self.skin - self.normal[i].dot(self.anchor[i] - self.point[i])
                if push > 0.0:
                    bound = self.ball[i]
                    if ti.static(self.has_self_nearest):
                        bound = ti.min(bound, refreshes * self.fraction * self.self_nearest[i])
                    ti.atomic_max(most, push / ti.max(bound, 1e-12))
        return most

    # -- the solve (kernel functions) --------------------------------------------------------------

    @ti.func
    def ball_scale(self, i, p, step, scale):
        """The share (<= ``scale``) of vertex i's ``step`` (m) from ``p`` that keeps it within
        its ball about x0 (the plane's share is :class:`~.contact.SolveContact`'s
        ``_approach_scale`` on :meth:`gap`)."""
        length = step.norm()
        left = self.ball[i] - (p - self.anchor[i]).norm()
        if length > left:
            scale = ti.min(scale, ti.max(left, 0.0) / length)
        return scale

    @ti.func
    def gap(self, i, p):
        """Vertex i's distance (m) at p in front of the level it must keep from its plane."""
        return self.normal[i].dot(p - self.point[i]) - self.floor[i]

    @ti.func
    def separation(self, i, p):
        """Vertex i's separation d (m) at p: its distance in front of its plane less the skin."""
        return self.normal[i].dot(p - self.point[i]) - self.skin

    @ti.func
    def touching(self, i, x):
        """Whether vertex i at positions ``x`` lies within the contact radius of its plane."""
        out = False
        if self.state[i] == FOUND:
            out = self.separation(i, x[i]) < self.radius
        return out
