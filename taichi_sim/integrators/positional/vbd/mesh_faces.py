"""The cloth's triangles against a collider mesh's sharp edges and vertices inside vertex block
descent (docs/vbd-contact.md, "A mesh collider in the solve").

:class:`~.mesh_contact.MeshContact` keeps every cloth vertex off the mesh, but an edge or corner
of the mesh sharper than the cloth's spacing (a table's edge, a thin limb) can come up between
the vertices of a triangle whose corners all stay out. Here each such mesh feature is a contact
partner of the cloth's triangles, as the analytic objects are (faces.py), with the same energy,
friction and bounds.

**Which features.** A cloth triangle of circumradius rho lying across an edge whose two faces'
normals differ by theta, its corners on the faces, has the edge up to rho sin(theta / 2) above
its plane; likewise across a vertex whose faces' normals differ from their mean by phi at most,
rho sin(phi). Only an edge or vertex where that dip reaches ``MESH_DIP`` of the skin in some
frame (rho the rest cloth's largest, grown by faces.FACE_STRETCH) is a feature: the corners' own
terms keep the faces off the rest. A closed mesh's concave edges never are (a segment between
two points outside both faces' planes stays outside them); an open mesh's boundary edges always
are. A vertex at the end of a feature edge is covered by that edge. A smooth body has none, and
then nothing here is compiled in.

**Finding them.** A grid of the collider's kind (:class:`~taichi_sim.scene.colliders.mesh_grid.TriangleGrid`,
its cells about the features' median length) lists the features of each frame segment by their
boxes over the segment, grown by the skin; a cloth triangle looks at the cells its box, grown by
the query's reach, meets, and tests the features' boxes before their distance (none when the
mesh is far: one box test).

**The query**, once per piece before its start guess is bounded, as the vertices' contact planes
are found once per piece (the analytic objects' faces are queried before every sweep too; the
mesh's, so queried, made the table example 3 to 5 times slower: docs/vbd-contact.md): per
cloth triangle the ``SLOTS`` nearest features within reach of the mesh posed at the
piece's end t1 (where the vertices' contact planes are carried), each with what the vertex
solves read:

- the contact: the triangle's distance d from the feature (a segment or a point; both convex)
  less the skin, n the unit direction from the feature's nearest point to the triangle's, w the
  triangle point's barycentric weights, and the feature's move over the piece there (friction
  acts on the slip relative to it);
- the side: the same two nearest points where they were at the piece's start (the feature's
  with the body then, the triangle's at ``MeshContact.anchor``, the cloth free of the mesh). A
  feature that crosses the triangle, or lies on the other side of it than then (the body's
  move over the piece took it through), has n the direction between them then and d below
  zero: the energy pushes the triangle back over it, and the pair has no plane;
- otherwise a separating plane: n through the feature's nearest point (the feature lies behind
  it, every point of the triangle d beyond it).

Energy, friction and bound are faces.py's: d(x) = n . (sum_j w_j x_j) - offset below the
contact radius, 1/2 k (r - d)^2 with corner j's share w_j; each corner nears the plane by at
most ``bound_fraction`` of its distance; features within reach beyond the slots, or none within
reach, leave each corner ``bound_fraction`` of their distance (or of the reach) to move from
where the query found it. With features, the body's move over a piece near the cloth is held
to ``MESH_PACE`` x ``bound_fraction`` of the distance a face keeps from them, the skin and the
contact radius (:meth:`~.mesh_contact.MeshContact.piece_length`): a feature then cannot pass a
face between two queries (a box rising at 3 m/s went through a resting cloth at the vertices'
pace alone, tests/test_vbd_mesh_faces.py).
"""
import numpy as np
import taichi as ti

from .... import runtime
from ....collide.closest_points import closest_barycentric, inside, segment_parameters
from ....scene.colliders.mesh_grid import TriangleGrid, cell_id, cells

# A mesh edge or vertex is a feature where a cloth triangle lying across it, corners on the
# faces, could have it this share of the skin above its plane (module docstring).
MESH_DIP = 0.5
# features kept per cloth triangle and query; more within reach shorten the corners' room for the
# whole piece, to bound_fraction of the nearest left out. Near a corner of a 2 cm plate a triangle
# reaches five edges or more, and with 4 slots a vertex the plate pushed up could not follow it
# (tests/test_vbd_mesh_contact.py, the thin plate)
SLOTS = 8
# The features' grid cells, in rooms a vertex is given per piece (about the cloth's spacing)
GRID_ROOMS = 4
# A pair's state (faces.py's): out of reach (FAR), else the bits of the parts it holds.
FAR, PLANE, ENERGY = 0, 1, 2
# A nearest point with a corner's weight above this is at that corner: the vertex's own term.
AT_CORNER = 1.0 - 1e-6


def sharp_features(frames: np.ndarray, triangles: np.ndarray, orientation: int, dip_length: float,
                   skin: float) -> np.ndarray:
    """(K, 2) vertex ids of the mesh's features (module docstring): edges (i, j), vertices
    (i, i). ``frames`` (F, V, 3) m; ``triangles`` (T, 3) ids; ``orientation`` +1 / -1 for a
    closed mesh wound counter-clockwise / clockwise seen from outside, 0 for a shell of two
    sides; ``dip_length`` (m) the cloth's largest circumradius (rho); ``skin`` (m)."""
    triangles = np.asarray(triangles, np.int64)
    T = len(triangles)
    corners = frames[:, triangles]  # (F, T, 3, 3)
    normals = np.cross(corners[:, :, 1] - corners[:, :, 0], corners[:, :, 2] - corners[:, :, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=2, keepdims=True), 1e-300)
    threshold = MESH_DIP * skin / max(dip_length, 1e-300)  # sin of the half angle (edges)
    # every undirected edge with its triangles and their third corners
    directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    owner = np.tile(np.arange(T), 3)
    third = np.concatenate([triangles[:, 2], triangles[:, 0], triangles[:, 1]])
    key = np.sort(directed, axis=1)
    edges, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    sharp = counts != 2  # a boundary or non-manifold edge
    convex = np.ones(len(edges), bool)  # (a two-sided shell's edges all are, from one side)
    two = np.flatnonzero(counts == 2)
    if len(two):
        order = np.argsort(inverse, kind="stable")
        starts = np.concatenate([[0], np.cumsum(counts)])[two]
        first, second = order[starts], order[starts + 1]  # the two directed entries of each edge
        f1, f2 = owner[first], owner[second]
        cos = np.einsum("fkj,fkj->fk", normals[:, f1], normals[:, f2])
        half_sin = np.sqrt(np.clip((1.0 - cos) / 2.0, 0.0, 1.0))  # sin(theta / 2)
        steep = half_sin >= threshold
        if orientation != 0:
            # convex where the second face's third corner lies behind the first's outward plane
            a = frames[:, directed[first, 0]]
            behind = np.einsum("fkj,fkj->fk", orientation * normals[:, f1], frames[:, third[second]] - a) < 0.0
            steep &= behind
            convex[two] = behind.any(axis=0)
        sharp[two] = steep.any(axis=0)
    kept = edges[sharp]
    # vertices: the most their faces' normals turn from their (area-free) mean, in some frame
    V = frames.shape[1]
    covered = np.zeros(V, bool)
    covered[kept.reshape(-1)] = True
    ids = triangles.reshape(-1)
    face_of = np.repeat(np.arange(T), 3)
    mean = np.zeros((frames.shape[0], V, 3))
    np.add.at(mean, (slice(None), ids), normals[:, face_of])
    mean /= np.maximum(np.linalg.norm(mean, axis=2, keepdims=True), 1e-300)
    cos_v = np.einsum("fkj,fkj->fk", mean[:, ids], normals[:, face_of])  # (F, 3T)
    least = np.full((frames.shape[0], V), 1.0)
    np.minimum.at(least, (slice(None), ids), cos_v)
    sin_v = np.sqrt(np.clip(1.0 - least ** 2, 0.0, 1.0))
    steep_v = ((sin_v >= threshold) | (least < 0.0)).any(axis=0)
    # a vertex all of whose edges are concave (a pit) lies behind every face's plane round it
    reaching = np.zeros(V, bool)
    reaching[edges[convex].reshape(-1)] = True
    points = np.flatnonzero(steep_v & ~covered & reaching)
    return np.concatenate([kept, np.stack([points, points], axis=1)]).astype(np.int64)


@ti.data_oriented
class MeshFaces:
    """The cloth's triangles against the sharp features of the collider mesh that
    :class:`~.mesh_contact.MeshContact` ``body`` meets (module docstring); its query, terms and
    bounds are called by :class:`~.faces.ObjectFaces` beside the analytic objects'.

    Args:
        body: the solve's :class:`~.mesh_contact.MeshContact` (the mesh's pose at the piece's
            start and end, the cloth at its start).
        features: (K, 2) vertex ids of the features (:func:`sharp_features`), K >= 1.
        cloth: the scene's cloth :class:`~taichi_sim.mesh.TriangleMesh` (triangles, incidence).
    """

    def __init__(self, body, features: np.ndarray, cloth):
        real = runtime.real()
        vec = ti.types.vector(3, real)
        self.body, self.cloth = body, cloth
        collider = body.collider
        self.collider = collider
        self.skin = body.skin
        self.friction = body.friction
        self.features_np = np.asarray(features, np.int64)
        self.count = len(self.features_np)
        self.features = ti.Vector.field(2, ti.i32, shape=self.count)
        self.features.from_numpy(self.features_np.astype(np.int32))
        # the collider's kind of grid, listing the features, refilled per frame segment, its
        # cells GRID_ROOMS rooms: a triangle's query box, grown by its reach, meets a few
        player = collider.player
        self.grid = TriangleGrid.covering(player.frames, self.features_np, self.skin, cell=GRID_ROOMS * body.room)
        capacity = max(self.grid.entries(*self._boxes(k)) for k in range(player.segment_count))
        self.cell_start = ti.field(ti.i32, shape=self.grid.cell_count + 1)
        self.cell_features = ti.field(ti.i32, shape=max(1, capacity))
        self.listed_segment = -1
        pair = ti.types.struct(state=ti.i32, plane_normal=vec, plane_offset=real, normal=vec, weights=vec,
                               offset=real, surface_velocity=vec)
        self.pairs = pair.field(shape=(max(1, cloth.triangle_count), SLOTS))
        self.used = ti.field(ti.i32, shape=max(1, cloth.triangle_count))  # slots a triangle holds
        n = body.system.particle_count
        self.anchor = ti.Vector.field(3, runtime.real(), shape=n)  # each vertex at the query (m)
        # how far from its anchor each vertex may move and keep its triangles off the features
        # not in their slots (m)
        self.room = ti.field(runtime.real(), shape=n)

    def _boxes(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Each feature's box over frame segment k grown by the skin ((K, 3) m each, mesh frame)."""
        lo, hi = self.collider.player.segment_boxes(self.features_np, k)
        return lo - self.skin, hi + self.skin

    def list_segment(self, segment: int) -> None:
        """List the features by the grid's cells over frame segment ``segment`` (a no-op when
        listed already)."""
        if segment != self.listed_segment:
            start, listed = self.grid.lists(*self._boxes(segment))
            self.cell_start.from_numpy(start.astype(np.int32))
            self.cell_features.from_numpy(np.pad(listed, (0, self.cell_features.shape[0] - len(listed)))
                                          .astype(np.int32))
            self.listed_segment = segment

    # -- geometry (kernel functions) ---------------------------------------------------------------

    @ti.func
    def _ends(self, k, corners, centre):
        """Feature k's two ends (m, world) with the mesh at ``corners`` ((V,) field, its frame)
        about ``centre``; a vertex feature's ends coincide."""
        ids = self.features[k]
        return corners[ids[0]] + centre, corners[ids[1]] + centre

    @ti.func
    def _closest(self, p, q, a, b, c):
        """(distance (m), the feature's nearest point parameter s on p + s (q - p), the
        triangle's barycentric weights) of segment pq (a point where p = q) and triangle abc;
        distance 0 where the segment crosses the triangle (s, w: the crossing)."""
        w = closest_barycentric(p, a, b, c)
        best = (p - (w[0] * a + w[1] * b + w[2] * c)).norm()
        s = 0.0 * best
        if (q - p).norm_sqr() > 0.0:
            wq = closest_barycentric(q, a, b, c)
            dq = (q - (wq[0] * a + wq[1] * b + wq[2] * c)).norm()
            if dq < best:
                best, s, w = dq, 1.0 + 0.0 * best, wq
            corners = ti.Matrix.cols([a, b, c])
            for j in ti.static(range(3)):
                u, v = corners[:, j], corners[:, (j + 1) % 3]
                st = segment_parameters(p, q, u, v)
                d = (p + st[0] * (q - p) - (u + st[1] * (v - u))).norm()
                if d < best:
                    best, s = d, st[0]
                    w = 0.0 * w
                    w[j] = 1.0 - st[1]
                    w[(j + 1) % 3] = st[1]
            n = (b - a).cross(c - a)
            hp, hq = n.dot(p - a), n.dot(q - a)
            if hp * hq < 0.0:
                sc = hp / (hp - hq)
                m = p + sc * (q - p)
                if inside(m, a, b, c):
                    best, s = 0.0 * best, sc
                    w = closest_barycentric(m, a, b, c)
        return best, s, w

    # -- the query (faces.py's query_mesh_faces calls it, from the piece's begin) --------------------

    @ti.func
    def query(self, x, reach):
        """Each cloth triangle's nearest features within ``reach`` (m, grown by what a corner
        the body pushes may have to move) at positions ``x`` ((n,) vec3 field, m, the piece's
        start), the mesh where it is at the piece's end: their contacts and planes for the
        vertex solves of the piece, and each vertex's ``room`` (loops of the kernel)."""
        body, cloth = self.body, self.cloth
        for i in range(x.shape[0]):
            self.anchor[i] = x[i]
            self.room[i] = ti.math.inf
        # a corner the body pushes moves with it, by up to its move and the skin: the reach (and
        # so the room of corners out of it) covers that too
        reach += (body.motion[None] + self.skin) / body.fraction
        c0, c1 = body.centre[0], body.centre[1]
        span = ti.max(body.span[None], 1e-30)
        lo_box, hi_box = ti.Vector(body.box_lo) + c1, ti.Vector(body.box_hi) + c1
        for face in range(cloth.triangle_count):
            self.used[face] = 0
            if cloth.is_intact(face):
                tri = cloth.triangles[face]
                a, b, c = x[tri[0]], x[tri[1]], x[tri[2]]
                grow = reach + self.skin
                lo = ti.min(a, ti.min(b, c)) - grow
                hi = ti.max(a, ti.max(b, c)) + grow
                free = reach  # the corners' room: what no feature nearer than it leaves
                if all(hi >= lo_box) and all(lo <= hi_box):  # the mesh is near (else one box test)
                    kept = ti.Vector([-1] * SLOTS)
                    dist = ti.Vector([grow] * SLOTS, dt=x.dtype)
                    first, last = cells(self.grid, lo - c1, hi - c1)
                    span_cells = ti.max(last - first + 1, 0)
                    for m in range(span_cells[0] * span_cells[1] * span_cells[2]):
                        cell = cell_id(self.grid, first, span_cells, m)
                        for e in range(self.cell_start[cell], self.cell_start[cell + 1]):
                            k = self.cell_features[e]
                            p, q = self._ends(k, body.after, c1)
                            # the boxes first, then whether it is kept already (listed in another
                            # cell), then the distance (nested ifs: Taichi evaluates both sides
                            # of an ``and``)
                            if all(ti.max(p, q) >= lo) and all(ti.min(p, q) <= hi):
                                seen = False
                                for j in ti.static(range(SLOTS)):
                                    if kept[j] == k:
                                        seen = True
                                d = grow
                                if not seen:
                                    # (one name for each part: ``_`` bound to a scalar and then a
                                    # vector aborts Taichi's compiler at opt_level 0)
                                    d = self._closest(p, q, a, b, c)[0]
                                if d < grow:
                                    # into the slots in order of distance; the one pushed out
                                    # shortens the room
                                    for j in ti.static(range(SLOTS)):
                                        if d < dist[j]:
                                            d, dist[j] = dist[j], d
                                            k, kept[j] = kept[j], k
                                    if k >= 0:
                                        free = ti.min(free, d)
                    used = 0
                    for j in ti.static(range(SLOTS)):
                        if kept[j] >= 0:
                            used += 1
                    self.used[face] = used
                    for j in range(used):  # (not unrolled: one copy of the geometry to compile)
                        self._keep(face, j, kept[j], tri, a, b, c, c0, c1, span)
                for j in ti.static(range(3)):
                    ti.atomic_min(self.room[tri[j]], free)

    @ti.func
    def _keep(self, face, slot, k, tri, a, b, c, c0, c1, span):
        """Slot ``slot`` of cloth triangle ``face`` (corners a, b, c, m): feature k's contact
        and plane."""
        body = self.body
        p, q = self._ends(k, body.after, c1)
        p0, q0 = self._ends(k, body.before, c0)
        d, s, w = self._closest(p, q, a, b, c)
        on_feature = p + s * (q - p)
        on_triangle = w[0] * a + w[1] * b + w[2] * c
        # the same two points where they were at the piece's start (the cloth then free of the
        # mesh): a feature on the other side of the triangle than then went through it
        ax, bx, cx = body.anchor[tri[0]], body.anchor[tri[1]], body.anchor[tri[2]]
        before = w[0] * ax + w[1] * bx + w[2] * cx - (p0 + s * (q0 - p0))
        n = on_triangle - on_feature
        through = d <= 1e-9 * self.skin or n.dot(before) < 0.0
        if through and before.norm_sqr() > 0.0:
            n = before
        n = n.normalized()
        separation = d
        state = FAR
        if through:
            separation = n.dot(on_triangle) - ti.max(n.dot(p), n.dot(q))
        else:
            # the feature (convex) lies behind the plane through its nearest point, the
            # triangle d beyond it
            state = PLANE
            self.pairs[face, slot].plane_normal = n
            self.pairs[face, slot].plane_offset = n.dot(on_feature)
        if w.max() < AT_CORNER:
            state |= ENERGY
            self.pairs[face, slot].normal = n
            self.pairs[face, slot].weights = w
            # d(x) = n . (sum w_j x_j) - offset: the separation less the skin
            self.pairs[face, slot].offset = n.dot(on_triangle) - (separation - self.skin)
            self.pairs[face, slot].surface_velocity = (on_feature - (p0 + s * (q0 - p0))) / span
        self.pairs[face, slot].state = state

    # -- the vertex solves (faces.py's face_terms and face_scale call them) ------------------------

    @ti.func
    def terms(self, solve, i, x, dt, k, f, H):
        """Add the force (N) and block (N/m) on vertex i of its triangles' feature contacts
        (stiffness k, N/m) at positions x; ``solve`` the :class:`~.contact.SolveContact`."""
        cloth = self.cloth
        for s in range(cloth.offsets[i], cloth.offsets[i + 1]):
            face = cloth.incident[s]
            for j in range(self.used[face]):
                if self.pairs[face, j].state & ENERGY:
                    tri = cloth.triangles[face]
                    a, b, c, slot = solve._corners(tri, x, i, x[i])
                    w, n = self.pairs[face, j].weights, self.pairs[face, j].normal
                    d = (w[0] * a + w[1] * b + w[2] * c).dot(n) - self.pairs[face, j].offset
                    if d < solve.radius and w[slot] > 0.0:
                        slip = (w[0] * solve.delta[tri[0]] + w[1] * solve.delta[tri[1]]
                                + w[2] * solve.delta[tri[2]]) - dt * self.pairs[face, j].surface_velocity
                        f, H = solve._push(f, H, d, n, k, w[slot], slip, self.friction, dt)
        return f, H

    @ti.func
    def scale(self, solve, i, p, step, scale):
        """The share (<= ``scale``) of vertex i's ``step`` (m) from ``p`` that keeps it beyond
        the planes of its triangles' feature pairs and within ``bound_fraction`` of its room
        from where the query found it."""
        cloth = self.cloth
        for s in range(cloth.offsets[i], cloth.offsets[i + 1]):
            face = cloth.incident[s]
            for j in range(self.used[face]):
                if self.pairs[face, j].state & PLANE:
                    n = self.pairs[face, j].plane_normal
                    scale = ti.min(scale, solve._approach_scale(p.dot(n) - self.pairs[face, j].plane_offset, n, step))
        length = step.norm()
        left = solve.fraction * self.room[i] - (p - self.anchor[i]).norm()
        if length > left:
            scale = ti.min(scale, ti.max(left, 0.0) / length)
        return scale
