"""Contact inside vertex block descent: the scene's objects and the cloth against itself as
energies in each vertex's 3x3 block, and the conservative bounds on each vertex's displacement
that keep anything from crossing between two detections (docs/vbd-contact.md)."""


import numpy as np
import taichi as ti

from .... import field_io, runtime
from ....collide.closest_points import closest_barycentric, segment_parameters
from ....collide.hash_grid import PrimitiveHash, cell_order
from ....collide.mesh_check import check_contact_mesh
from ....errors import ConfigError
from .faces import ObjectFaces
from .mesh_contact import FOUND, MeshContact, median_edge

CONTACTS_PER_VERTEX = 128  # contact pairs a vertex keeps between refreshes; more are counted, not kept
PAIRS_PER_VERTEX = 16  # room in the pair list per vertex
OVERSHOOT_BINS, OVERSHOOT_BINS_PER_OCTAVE = 64, 8  # the histogram of how far guesses leave the bounds
SELF_CONTACT = 1  # flag of a vertex in a self-contact pair (SolveContact.mark_contacts)
OBJECT_CONTACT = 2  # flag of a vertex within the contact radius of an object


@ti.data_oriented
class SolveContact(ObjectFaces):
    """What :class:`~.vbd.VBD` adds to vertex i's block when contact is in the solve.

    Objects (the ground plane, spheres, capsules, boxes, where they are at the substep's end;
    the collider mesh through :class:`~.mesh_contact.MeshContact`, ``body``, its contact plane
    per vertex found once per piece):
    with d the signed distance to the surface and n its outward normal, below the contact
    radius r the energy 1/2 k_i (r - d)^2 with k_i = ``stiffness`` m_i / dt^2 (dt the
    substep's length, ``penalty_dt``, also in each of its pieces), and IPC's lagged
    friction mu lambda f0(|u|) on the tangential slip u of the substep relative to the surface
    (lambda = k_i (r - d), f0 smoothed below |u| = ``friction_epsilon`` dt). Each vertex step
    is then shortened to ``bound_fraction`` times the vertex's distance to the nearest object
    (conservative advancement: a vertex outside a convex object cannot reach it).

    Self-contact: vertex-triangle and edge-edge pairs closer than r at the last refresh (a
    spatial hash at the current positions, once per piece of a substep or every ``refresh``
    sweeps), each
    pair the energy 1/2 k (r - d)^2 (k = ``stiffness`` m / dt^2, m the mean particle mass) plus
    friction ``self_friction`` as above. Every vertex's displacement since the refresh, less one
    translation ``shift`` common to all (the start guess's mean, when no particle is pinned), is
    capped at ``bound_fraction`` (< 1/2) times the distance from the vertex to the nearest
    primitive it is part of a pair with (Chen et al. 2025, "Offset Geometric Contact"): the
    two sides of any pair then close by less than their distance, so nothing crosses between
    refreshes, whatever the order the vertices are solved in.

    Args:
        inputs: what the scene offers (:class:`~taichi_sim.scene.handoff.ContactInputs`: its
            plane, its shapes (spheres, capsules, boxes), its collider mesh, its cloth).
        delta: the integrator's (n,) displacement field x - x0 (m) (read for the slip).
        objects: put the scene's objects in the solve.
        object_faces: with ``objects``, the cloth's triangles against them too (faces.py;
            a collider mesh's sharp edges and vertices: mesh_faces.py).
        self_contact: put the cloth against itself in the solve (needs a mesh).
        radius: contact radius r (m).
    """

    def __init__(self, inputs, delta, *, objects: bool, object_faces: bool, self_contact: bool, radius: float,
                 stiffness: float,
                 bound_fraction: float, friction_epsilon: float, self_friction: float, refresh: int):
        system = inputs.system
        real, n = runtime.real(), system.particle_count
        self.system, self.delta = system, delta
        self.plane = inputs.plane if objects else None
        self.obstacles = list(inputs.shapes) if objects else []
        self.has_plane = self.plane is not None
        # the scene's collider mesh (a body), its post-step pass skipped (mesh_contact.py)
        collider = inputs.collider_mesh if objects else None
        self.body = None
        if collider is not None:
            self.body = MeshContact(collider, system, radius=radius, fraction=bound_fraction,
                                    spacing=0.75 * median_edge(inputs))
        self.has_body = self.body is not None
        self.has_objects = self.has_plane or bool(self.obstacles) or self.has_body
        self.self_contact = bool(self_contact)
        self.stiffness, self.fraction = float(stiffness), float(bound_fraction)
        self.friction_epsilon, self.self_friction = float(friction_epsilon), float(self_friction)
        self.refresh_every = int(refresh)
        self.radius = float(radius)
        self.refreshes = 0  # detections run since construction
        # the step the penalty's stiffness is scaled by (s): the whole substep's, also in its pieces
        self.penalty_dt = ti.field(runtime.real(), shape=())
        self._init_object_faces(inputs, object_faces)  # the cloth's triangles against the objects (faces.py)
        if not self.self_contact:
            return
        mesh = inputs.cloth
        if mesh is None:
            raise ConfigError("vbd option self_contact needs a scene with a triangle mesh (a cloth)")
        if mesh.tearable:
            raise ConfigError("vbd option self_contact: a tearing cloth is not supported (its triangles change)")
        x0 = inputs.positions()
        tris = mesh.triangles_np.astype(np.int64)
        rest = inputs.rest_x if inputs.rest_x is not None else x0
        # refuses a start that already passes through itself: contact cannot untangle it
        check_contact_mesh(x0, tris, radius, rest=rest, name="vbd option contact_radius")
        self.mesh = mesh
        edges = np.unique(np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1),
                          axis=0)
        lengths = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
        # The reach of the bounds: a vertex with nothing nearer moves up to fraction x reach per
        # refresh. The nearest non-adjacent primitives of a flat grid are s / sqrt(2) away (s its
        # spacing), so a longer reach buys no motion there, and the pairs to test grow as its cube
        # in a pile; it must cover the contact radius.
        self.reach = max(radius, 0.75 * float(np.median(lengths)))
        mass, free = field_io.read(system.mass, system.free)  # one kernel, not one per field
        free = free.astype(bool)
        self.mean_mass = float(mass[free].mean()) if free.any() else 1.0
        self.all_free = bool(free.all())
        self.edge_count = len(edges)
        self.edges = ti.Vector.field(2, ti.i32, shape=max(1, len(edges)))
        self.triangle_alive = ti.field(ti.i32, shape=max(1, mesh.triangle_count))
        self.edge_alive = ti.field(ti.i32, shape=max(1, len(edges)))
        field_io.write((self.edges, edges if len(edges) else np.zeros((1, 2))),  # one kernel, not three
                       (self.triangle_alive, np.ones(self.triangle_alive.shape[0])),
                       (self.edge_alive, np.ones(self.edge_alive.shape[0])))
        # a vertex is a point: the triangles' boxes grow by all of the reach, the edges' by half each
        self.triangle_grid = PrimitiveHash(mesh.triangle_count, 3, self.reach, self.reach, entries_per_primitive=16)
        self.edge_grid = PrimitiveHash(len(edges), 2, self.reach, 0.5 * self.reach, entries_per_primitive=1,
                                       home_cell_only=True)
        self.ref_x = ti.Vector.field(3, real, shape=n)  # positions at the last refresh (m)
        self.nearest = ti.field(real, shape=n)  # distance to the nearest pair partner, capped at reach (m)
        self.shift = ti.Vector.field(3, real, shape=())  # the translation the bounds are measured from (m)
        # how far the bounds cut the start guess: vertices by |move| / bound, OVERSHOOT_BINS_PER_OCTAVE
        # bins an octave above 1 (VBD._begin fills it; pieces.py reads it)
        self.overshoot = ti.field(ti.i32, shape=OVERSHOOT_BINS)
        self.free_count = int(free.sum())
        self.pair_capacity = PAIRS_PER_VERTEX * n
        self.pair_ids = ti.Vector.field(4, ti.i32, shape=self.pair_capacity)
        self.pair_kind = ti.field(ti.i32, shape=self.pair_capacity)  # 0 vertex-triangle, 1 edge-edge
        self.pair_count = ti.field(ti.i32, shape=())
        self.per_vertex = CONTACTS_PER_VERTEX  # (read once: the kernels compile it in)
        self.vertex_pairs = ti.field(ti.i32, shape=(n, self.per_vertex))
        self.vertex_pair_count = ti.field(ti.i32, shape=n)
        self.dropped = ti.field(ti.i32, shape=())  # pairs not kept (lists full) since the last refresh
        self.dropped_total = 0
        self.pairs_total = 0
        if self.has_body:
            self.body.self_nearest = self.nearest  # its pace reads the self-contact bounds

    # -- detection (host side, once per refresh) -------------------------------------------------

    def refresh(self, x) -> int:
        """Find the pairs closer than the reach at positions ``x`` (the iterate, free of
        intersections), reset the bounds' reference to ``x`` and their shift to zero. Returns
        the number of hash boxes clipped (0 unless positions are non-finite or beyond floats'
        reach): then pairs may be missed and the step must not go on."""
        if not self.self_contact:
            return 0
        for grid, prims, alive in ((self.triangle_grid, self.mesh.triangles, self.triangle_alive),
                                   (self.edge_grid, self.edges, self.edge_alive)):
            # Cells as wide as the longest box: a box spans at most 2 per axis (never clipped, so
            # no pair is missed), and with c the cell and b a box, a query meets about (b + c)^4 / c^2
            # primitives on a sheet, least at c = b (1.8 times fewer than at c = b / 3).
            extent = grid.longest_box(x, x, prims, alive)
            grid.cell[None] = max(extent * 1.001, 1e-9)
            grid.build(x, x, prims, alive)
        self._collect(x)
        self.refreshes += 1
        count, dropped = int(self.pair_count[None]), int(self.dropped[None])
        self.pairs_total += min(count, self.pair_capacity)
        self.dropped_total += dropped
        return self.triangle_grid.overflowed() + self.edge_grid.overflowed()

    @ti.kernel
    def _collect(self, x: ti.template()):
        n = self.system.particle_count
        for i in range(n):
            self.nearest[i] = self.reach
            self.vertex_pair_count[i] = 0
            self.ref_x[i] = x[i]
        self.pair_count[None] = 0
        self.dropped[None] = 0
        self.shift[None] = ti.Vector.zero(x.dtype, 3)
        tg = self.triangle_grid
        for v in range(n):
            p = x[v]
            cell = tg.cell_of(p)
            first, last = tg.entries(tg.bucket(cell))
            for e in range(first, last):
                t = tg.items[e]
                tri = self.mesh.triangles[t]
                if tri[0] != v and tri[1] != v and tri[2] != v and all(cell >= tg.cell_lo[t]) \
                        and all(cell <= tg.cell_hi[t]) and all(p >= tg.lo[t]) and all(p <= tg.hi[t]):
                    a, b, c = x[tri[0]], x[tri[1]], x[tri[2]]
                    w = closest_barycentric(p, a, b, c)
                    d = (p - w[0] * a - w[1] * b - w[2] * c).norm()
                    self._near(ti.Vector([v, tri[0], tri[1], tri[2]]), 0, d)
        for e1 in range(self.edge_count):
            self._edge_query(e1, x)
        # The loops above fill the lists in whatever order their threads ran; each vertex's list
        # is put in the pairs' own order, so that its terms are summed in the same order in every
        # run (identical runs give identical results).
        for i in range(n):
            self._sort_pairs(i)

    @ti.func
    def _sort_pairs(self, i):
        """Insertion sort of vertex i's kept pairs by (kind, the four vertex ids)."""
        count = ti.min(self.vertex_pair_count[i], self.per_vertex)
        for a in range(1, count):
            slot = self.vertex_pairs[i, a]
            b = a
            while b > 0 and self._pair_before(slot, self.vertex_pairs[i, b - 1]):
                self.vertex_pairs[i, b] = self.vertex_pairs[i, b - 1]
                b -= 1
            self.vertex_pairs[i, b] = slot

    @ti.func
    def _pair_before(self, p, q) -> bool:
        """Whether pair slot p comes before pair slot q in (kind, ids) order."""
        before, decided = self.pair_kind[p] < self.pair_kind[q], self.pair_kind[p] != self.pair_kind[q]
        for k in ti.static(range(4)):
            if not decided and self.pair_ids[p][k] != self.pair_ids[q][k]:
                before, decided = self.pair_ids[p][k] < self.pair_ids[q][k], True
        return before

    @ti.func
    def _edge_query(self, e1, x):
        """The edges near edge e1, each pair once: found from the edge whose home cell comes
        first (:func:`~taichi_sim.collide.hash_grid.cell_order`), or from the lower index where
        the two share a home; so the cells before e1's home are not read at all."""
        eg = self.edge_grid
        # every edge whose box can meet e1's has its home in this range, and is there once
        c_lo, c_hi = eg.home_range(e1)
        home = eg.cell_lo[e1]
        ends, lo, hi = self.edges[e1], eg.lo[e1], eg.hi[e1]
        for i, j, k in ti.ndrange((home[0], c_hi[0] + 1), (c_lo[1], c_hi[1] + 1), (c_lo[2], c_hi[2] + 1)):
            cell = ti.Vector([i, j, k])
            order = cell_order(cell, home)
            if order >= 0:
                first, last = eg.entries(eg.bucket(cell))
                for e in range(first, last):
                    e2 = eg.items[e]
                    if (order > 0 or e2 > e1) and eg.is_home(cell, e) and eg.entry_overlaps(e, lo, hi):
                        other = self.edges[e2]
                        if ends[0] != other[0] and ends[0] != other[1] and ends[1] != other[0] \
                                and ends[1] != other[1]:
                            ids = ti.Vector([ends[0], ends[1], other[0], other[1]])
                            gap, _ = self._pair_geometry(ids, 1, x)
                            self._near(ids, 1, gap.norm())

    @ti.func
    def _near(self, ids, kind, d):
        """Record a pair at distance d (m): the bounds of its four vertices, and a contact pair
        when closer than the radius."""
        if d < self.reach:
            for k in ti.static(range(4)):
                ti.atomic_min(self.nearest[ids[k]], d)
            if d < self.radius:
                slot = ti.atomic_add(self.pair_count[None], 1)
                if slot < self.pair_capacity:
                    self.pair_ids[slot] = ids
                    self.pair_kind[slot] = kind
                    for k in ti.static(range(4)):
                        if self.system.free[ids[k]]:
                            s = ti.atomic_add(self.vertex_pair_count[ids[k]], 1)
                            if s < self.per_vertex:
                                self.vertex_pairs[ids[k], s] = slot
                            else:
                                ti.atomic_add(self.dropped[None], 1)
                else:
                    ti.atomic_add(self.dropped[None], 1)

    @ti.func
    def _pair_geometry(self, ids, kind, x):
        """(gap vector between the pair's closest points (m), the four vertices' signed weights):
        gap = sum_k w_k x[ids[k]]. Vertex-triangle: ids = (v, a, b, c), gap from the triangle to
        v; edge-edge: ids = (p, q, r, s), gap from segment rs to segment pq."""
        w = ti.Vector.zero(x.dtype, 4)
        if kind == 0:
            bary = closest_barycentric(x[ids[0]], x[ids[1]], x[ids[2]], x[ids[3]])
            w = ti.Vector([1.0, -bary[0], -bary[1], -bary[2]], dt=x.dtype)
        else:
            ab = segment_parameters(x[ids[0]], x[ids[1]], x[ids[2]], x[ids[3]])
            w = ti.Vector([1.0 - ab[0], ab[0], ab[1] - 1.0, -ab[1]], dt=x.dtype)
        gap = ti.Vector.zero(x.dtype, 3)
        for k in ti.static(range(4)):
            gap += w[k] * x[ids[k]]
        return gap, w

    # -- the per-vertex terms (inside the solve) -------------------------------------------------

    @ti.func
    def terms(self, i, x, m, dt, t):
        """Contact force on vertex i (N) and its PSD block of the Hessian (N/m) at the iterate
        ``x`` (the point's positions field), objects where they are at time t (s)."""
        f = ti.Vector.zero(x.dtype, 3)
        H = ti.Matrix.zero(x.dtype, 3, 3)
        f, H = self.object_terms(i, x, m, dt, t, f, H)
        f, H = self.self_terms(i, x, dt, f, H)
        return f, H

    @ti.func
    def object_terms(self, i, x, m, dt, t, f, H):
        """:meth:`terms`' objects: add their force (N) and block (N/m) on vertex i of mass m."""
        if ti.static(self.has_objects):
            k = self.stiffness * m / (self.penalty_dt[None] * self.penalty_dt[None])
            p = x[i]
            slip = self.delta[i]
            if ti.static(self.has_plane):
                n = self.plane.normal[None]
                f, H = self._push(f, H, (p - self.plane.point[None]).dot(n), n, k, 1.0, slip,
                                  self.plane.friction[None], dt)
            for collider in ti.static(self.obstacles):
                for c in range(collider.count):
                    q = p - collider.path.center(c, t)
                    d = collider.distance(c, q)
                    if d < self.radius:
                        n = collider.normal(c, q)
                        moved = slip - dt * collider.surface_velocity(c, t, q)
                        f, H = self._push(f, H, d, n, k, 1.0, moved, collider.friction[c], dt)
            if ti.static(self.has_body):
                body = self.body
                if body.state[i] == FOUND:
                    f, H = self._push(f, H, body.separation(i, p), body.normal[i], k, 1.0, slip - body.moved[i],
                                      body.friction, dt)
            f, H = self.face_terms(i, x, dt, t, f, H)
        return f, H

    @ti.func
    def self_terms(self, i, x, dt, f, H):
        """:meth:`terms`' self-contact pairs of vertex i: add their force (N) and block (N/m)."""
        if ti.static(self.self_contact):
            k = self.self_stiffness()
            for s in range(ti.min(self.vertex_pair_count[i], self.per_vertex)):
                pair = self.vertex_pairs[i, s]
                ids = self.pair_ids[pair]
                gap, w = self._pair_geometry(ids, self.pair_kind[pair], x)
                d = gap.norm()
                if d < self.radius and d > 0.0:
                    weight = ti.cast(0.0, x.dtype)
                    slip = ti.Vector.zero(x.dtype, 3)
                    for j in ti.static(range(4)):
                        if ids[j] == i:
                            weight = w[j]
                        slip += w[j] * self.delta[ids[j]]
                    f, H = self._push(f, H, d, gap / d, k, weight, slip, self.self_friction, dt)
        return f, H

    @ti.func
    def self_stiffness(self):
        """The self-contact penalty's stiffness (N/m): ``stiffness`` times the mean free
        particle's m / dt^2, dt the substep's."""
        return self.stiffness * self.mean_mass / (self.penalty_dt[None] * self.penalty_dt[None])

    @ti.func
    def _push(self, f, H, d, n, k, weight, slip, mu, dt):
        """Add the penalty 1/2 k (r - d)^2 along n and its friction, for a vertex that enters the
        gap with weight ``weight`` (d(gap)/dx_i = weight I)."""
        if d < self.radius:
            normal_force = k * (self.radius - d)
            nn = n.outer_product(n)
            f += normal_force * weight * n
            H += k * weight * weight * nn
            if mu > 0.0:
                u = slip - slip.dot(n) * n
                y = u.norm()
                eps = self.friction_epsilon * dt
                ratio = 1.0 / ti.max(y, 1e-30)  # f1(y) / y, IPC's mollifier below eps
                if y < eps:
                    ratio = 2.0 / eps - y / (eps * eps)
                scale = mu * normal_force * ratio
                f -= scale * weight * u
                H += scale * weight * weight * (ti.Matrix.identity(self.delta.dtype, 3) - nn)
        return f, H

    @ti.func
    def limit(self, i, old, new, start, t, x):
        """The displacement (m, from the substep's start ``start``) vertex i may take instead of
        ``new``, coming from ``old``: inside its ball around the refresh point plus the shift,
        then no further than ``bound_fraction`` of its distance to the nearest object, nor of
        the distance of any triangle it is a corner of to an object (its other corners where
        ``x``, an (n,) vec3 field, has them)."""
        out = new
        if ti.static(self.self_contact):
            centre = self.ref_x[i] - start + self.shift[None]
            bound = self.fraction * self.nearest[i]
            off = out - centre
            length = off.norm()
            if length > bound:
                out = centre + off * (bound / length)
        if ti.static(self.has_objects):
            p = start + old
            step = out - old
            scale = ti.cast(1.0, self.delta.dtype)
            if ti.static(self.has_plane):
                n = self.plane.normal[None]
                scale = ti.min(scale, self._approach_scale((p - self.plane.point[None]).dot(n), n, step))
            for collider in ti.static(self.obstacles):
                for c in range(collider.count):
                    q = p - collider.path.center(c, t)
                    scale = ti.min(scale, self._approach_scale(collider.distance(c, q), collider.normal(c, q), step))
            if ti.static(self.has_body):
                body = self.body
                if body.state[i] == FOUND:
                    scale = ti.min(scale, self._approach_scale(body.gap(i, p), body.normal[i], step))
                scale = body.ball_scale(i, p, step, scale)
            scale = self.face_scale(i, x, p, step, t, scale)
            out = old + scale * step
        return out

    @ti.func
    def _approach_scale(self, gap, n, step):
        """The share of ``step`` (m) that nears a convex object, ``gap`` (m) away along its
        outward normal n, by at most bound_fraction x gap: the object lies behind the tangent
        plane at its nearest point, so such a step cannot reach it. 1 from inside (pushed out)."""
        scale = ti.cast(1.0, self.delta.dtype)
        approach = -step.dot(n)
        if gap > 0.0 and approach > self.fraction * gap:
            scale = self.fraction * gap / approach
        return scale

    @ti.func
    def count_overshoot(self, i, delta, start):
        """Count vertex i in the histogram ``overshoot`` when displacement ``delta`` (m) lies
        outside its ball, by how far: |delta - centre| / radius, in bins of 1/8 octave above 1
        (the last bin holds the rest)."""
        centre = self.ref_x[i] - start + self.shift[None]
        ratio = (delta - centre).norm() / ti.max(self.fraction * self.nearest[i], 1e-30)
        if ratio > 1.0:  # (capped before the log: an infinite ratio has no bin)
            octaves = ti.log(ti.min(ratio, 2.0 ** (OVERSHOOT_BINS // OVERSHOOT_BINS_PER_OCTAVE))) / ti.log(2.0)
            b = ti.max(0, ti.min(ti.cast(octaves * OVERSHOOT_BINS_PER_OCTAVE, ti.i32), OVERSHOOT_BINS - 1))
            ti.atomic_add(self.overshoot[b], 1)

    def overshoot_above(self, share: float) -> float:
        """The smallest ratio |move| / bound that at most ``share`` of the free vertices' start
        guesses exceed (1.0: few enough leave their balls at all), from the last histogram."""
        counts = self.overshoot.to_numpy()
        allowed = share * self.free_count
        above = np.cumsum(counts[::-1])[::-1]  # above[b]: vertices in bins b and higher
        first = int(np.argmax(np.append(above, 0) <= allowed))  # the first bin with few enough above
        return 2.0 ** (first / OVERSHOOT_BINS_PER_OCTAVE)

    @ti.func
    def outside_ball(self, i, delta, start):
        """Whether displacement ``delta`` of vertex i lies outside its ball (round-off allowed)."""
        out = False
        if ti.static(self.self_contact):
            out = (delta - (self.ref_x[i] - start + self.shift[None])).norm() > self.fraction * self.nearest[i] * (1.0 + 1e-5)
        return out

    @ti.func
    def fit_shift(self, delta, free):
        """The translation the bounds are measured from: the mean start displacement when every
        particle is free (a pinned particle does not move, so then none); a top-level loop."""
        if ti.static(self.self_contact):
            if ti.static(self.all_free):
                total = ti.Vector.zero(delta.dtype, 3)
                ti.loop_config(serialize=True)  # a sum in one order: identical runs agree to the bit
                for i in range(self.system.particle_count):
                    total += delta[i]
                self.shift[None] = total / self.system.particle_count

    # -- what a viewer reads (the launcher's contacts toggle) ------------------------------------
    # Read-only views of the pairs the last detection kept, for drawing and scripts: nothing
    # here changes the solve.

    def warning(self) -> str:
        """The run's line for the pairs found but not kept (a vertex's list, or the pair list,
        full): their repulsion was left out of the solve ("" for none)."""
        dropped = getattr(self, "dropped_total", 0)  # (self-contact keeps lists; objects do not)
        if not dropped:
            return ""
        return (f"vbd: {dropped} contact pair(s) found but dropped from the solve (a vertex keeps "
                f"{self.per_vertex} between detections): the cloth may intersect itself (taichi-sim check "
                "FILE.npz tells)")

    def forget(self) -> None:
        """Drop the pairs of the last detection (after a reset or a jump of the positions they
        were found at, so a viewer does not show stale pairs). The solve loses nothing: every
        substep detects again before it reads them."""
        if self.self_contact and self.refreshes:  # before the first detection they hold zeros
            self.pair_count[None] = 0
            self.vertex_pair_count.fill(0)
        if self.has_body:
            self.body.state.fill(0)

    def pair_total(self) -> int:
        """Contact pairs the last detection kept (0 without self-contact or after
        :meth:`forget`); :meth:`pair_segment` reads pairs 0 .. pair_total() - 1."""
        if not self.self_contact:
            return 0
        return min(int(self.pair_count[None]), self.pair_capacity)

    @ti.func
    def mark_contacts(self, x, t, flags):
        """Set flags[i] (an (n,) i32 field) for every vertex i: ``SELF_CONTACT`` when it is one
        of the four vertices of a self-contact pair the last detection kept, ``OBJECT_CONTACT``
        when it lies within the contact radius of an object in the solve at positions ``x``
        ((n,) vec3 field, m) and time ``t`` (s); 0 otherwise. A ti.func to call at a kernel's
        top level: its loops are that kernel's (one launch gathers and draws)."""
        for i in range(self.system.particle_count):
            touching = False
            if ti.static(self.has_objects):
                p = x[i]
                if ti.static(self.has_plane):
                    touching = (p - self.plane.point[None]).dot(self.plane.normal[None]) < self.radius
                for collider in ti.static(self.obstacles):
                    for c in range(collider.count):
                        if collider.distance(c, p - collider.path.center(c, t)) < self.radius:
                            touching = True
                if ti.static(self.has_body):
                    if self.body.touching(i, x):
                        touching = True
            flags[i] = OBJECT_CONTACT if touching else 0
        if ti.static(self.self_contact):
            for s in range(ti.min(self.pair_count[None], self.pair_capacity)):
                ids = self.pair_ids[s]
                for k in ti.static(range(4)):
                    ti.atomic_or(flags[ids[k]], SELF_CONTACT)

    @ti.kernel
    def contact_vertices(self, x: ti.template(), t: float, flags: ti.template()) -> ti.i32:
        """Mark the vertices in contact (:meth:`mark_contacts`: flags[i] is a combination of
        ``SELF_CONTACT`` and ``OBJECT_CONTACT``, (n,) i32 field) at positions ``x`` ((n,) vec3
        field, m) and time ``t`` (s, where the objects are), and return how many are marked."""
        self.mark_contacts(x, t, flags)
        count = 0
        for i in range(self.system.particle_count):
            if flags[i] != 0:
                count += 1
        return count

    @ti.func
    def pair_segment(self, s, x):
        """The closest points (m) of kept pair ``s`` at positions ``x``: (on the vertex or first
        edge, on the triangle or second edge); vertex-triangle: the vertex and its closest point
        on the triangle. Their distance is the pair's gap, which the solve keeps above zero."""
        ids = self.pair_ids[s]
        kind = self.pair_kind[s]
        gap, w = self._pair_geometry(ids, kind, x)
        near = x[ids[0]]
        if kind == 1:
            near = w[0] * x[ids[0]] + w[1] * x[ids[1]]
        return near, near - gap
