"""Cloth against itself: a vertex-triangle contact stage after each accepted step.

What it does, per step of length h (a filter on the step's result, so it works after any
integrator, as in Bridson, Fedkiw and Anderson 2002):

1. Every intact triangle's and every edge's swept box (its corners at the start and the end of
   the step, grown by the thickness) goes into a spatial hash (:class:`~.hash_grid.PrimitiveHash`).
2. Vertex-triangle: a vertex (not one of the triangle's corners) is in contact when it ends
   closer to the triangle than ``thickness``, or when it crossed the triangle's plane during the
   step within the triangle; it must stay on the side it started on. Edge-edge: two edges (no
   shared vertex) are in contact when their closest points end closer than ``thickness``, or
   when the tetrahedron they span changed orientation during the step with the closest points
   inside both; they must stay on the side they started on.
3. A contact moves the two sides apart along the contact normal until they are ``thickness``
   apart, and removes their approaching relative normal velocity (inelastic), with Coulomb
   friction on the tangential one; the corrections are shared by inverse mass and barycentric
   weight, as impulses are, and averaged over each vertex's contacts (Jacobi). ``iterations``
   rounds, fewer when one finds none.

What it does not do (yet): exact continuous collision detection (a crossing by a primitive that
rotates within the step can be missed), and a fail-safe such as rigid impact zones. So it
reduces self-intersections, and ``taichi-sim check`` measures how far; it does not guarantee none.
"""

import math

import numpy as np
import taichi as ti

from .. import runtime
from .hash_grid import PrimitiveHash


@ti.data_oriented
class SelfCollision:
    """The post-step self-contact stage of a cloth (call it as ``stage(state, t, h)``).

    Args:
        system: the scene's ParticleSystem (masses, which particles are free).
        mesh: the cloth's :class:`~taichi_sim.mesh.TriangleMesh`.
        x0: (n, 3) initial positions (m): sizes the hash's cells by the longest triangle edge.
        thickness: the distance (m) a vertex keeps from any triangle it is not a corner of.
        friction: Coulomb coefficient between cloth layers (>= 0).
        iterations: rounds of contact resolution per step (>= 1).
    Raises:
        ValueError: naming ``thickness``, ``friction`` or ``iterations``.
    """

    def __init__(self, system, mesh, x0: np.ndarray, *, thickness: float, friction: float = 0.0,
                 iterations: int = 4):
        if not (isinstance(thickness, (int, float)) and math.isfinite(thickness) and thickness > 0):
            raise ValueError(f"thickness must be a finite number > 0 (m), got {thickness!r}")
        if not (isinstance(friction, (int, float)) and math.isfinite(friction) and friction >= 0):
            raise ValueError(f"self_friction must be a finite number >= 0, got {friction!r}")
        if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
            raise ValueError(f"collision_iterations must be an integer >= 1, got {iterations!r}")
        real = runtime.real()
        n = system.particle_count
        self.system, self.mesh = system, mesh
        self.iterations = iterations
        tris = mesh.triangles_np.astype(np.int64)
        corners = np.asarray(x0, float)[tris]
        lengths = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
        cell = max(float(lengths.max()) if lengths.size else 0.0, 2.0 * thickness, 1e-6)
        edges = np.unique(np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1),
                          axis=0)
        self.edge_count = len(edges)
        self.edges = ti.Vector.field(2, ti.i32, shape=max(len(edges), 1))
        self.edges.from_numpy(edges.astype(np.int32) if len(edges) else np.zeros((1, 2), np.int32))
        self.edge_alive = ti.field(ti.i32, shape=max(len(edges), 1))
        self.edge_alive.fill(1)
        self.triangle_alive = ti.field(ti.i32, shape=max(mesh.triangle_count, 1))
        # Boxes grown by half the thickness each: two boxes overlap when their primitives could
        # be closer than the thickness (grown by all of it on both sides, twice the pairs).
        self.triangle_grid = PrimitiveHash(mesh.triangle_count, 3, cell, 0.5 * thickness)
        self.edge_grid = PrimitiveHash(len(edges), 2, cell, 0.5 * thickness)
        self.x_start = ti.Vector.field(3, real, shape=n)
        self.dx = ti.Vector.field(3, real, shape=n)
        self.dv = ti.Vector.field(3, real, shape=n)
        self.hits = ti.field(ti.i32, shape=n)
        # candidate pairs of a step: (vertex, triangle) and (edge, edge); beyond these lengths
        # pairs are dropped and counted as overflow
        self.vt_pairs = ti.Vector.field(2, ti.i32, shape=192 * n)
        self.ee_pairs = ti.Vector.field(2, ti.i32, shape=160 * max(len(edges), 1))
        self.pair_count = ti.field(ti.i32, shape=2)
        self.thickness = ti.field(real, shape=())
        self.friction = ti.field(real, shape=())
        self.contacts = ti.field(ti.i32, shape=())
        self.thickness[None], self.friction[None] = float(thickness), float(friction)
        self.t_end = None  # the time the last stage ended at, None before the first
        self.contacts_total = 0
        self.overflow_total = 0

    def restore(self) -> None:
        """Forget the last step (the scene went back to its start)."""
        self.t_end = None
        self.contacts_total = self.overflow_total = 0

    def __call__(self, state, t: float, h: float) -> bool:
        # The step's start: kept from the last stage when this step follows it, else estimated
        # as x - h v (exact for symplectic Euler) after a reset, a jump or the first step.
        if self.t_end is None or abs((t - h) - self.t_end) > 1e-9 * max(1.0, abs(t)):
            self._estimate_start(state, h)
        self._mark_intact()
        self.triangle_grid.build(self.x_start, state.x, self.mesh.triangles, self.triangle_alive)
        self.edge_grid.build(self.x_start, state.x, self.edges, self.edge_alive)
        self._collect(state)
        vt, ee = self.pair_count.to_numpy()
        self.overflow_total += (self.triangle_grid.overflowed() + self.edge_grid.overflowed()
                                + max(0, vt - self.vt_pairs.shape[0]) + max(0, ee - self.ee_pairs.shape[0]))
        for _ in range(self.iterations):
            found = self._resolve(state)
            self.contacts_total += found
            if found == 0:
                break
        self._keep_end(state)
        self.t_end = t
        return False  # the state changed, the system did not

    @ti.kernel
    def _estimate_start(self, y: ti.template(), h: float):
        for i in y.x:
            self.x_start[i] = y.x[i] - h * y.v[i]

    @ti.kernel
    def _mark_intact(self):
        for t in range(self.mesh.triangle_count):
            self.triangle_alive[t] = 1 if self.mesh.is_intact(t) else 0

    @ti.kernel
    def _keep_end(self, y: ti.template()):
        for i in y.x:
            self.x_start[i] = y.x[i]

    @ti.func
    def _inverse_mass(self, i):
        inv = ti.cast(0.0, self.dx.dtype)
        if self.system.free[i]:
            inv = 1.0 / self.system.mass[i]
        return inv

    @ti.kernel
    def _collect(self, y: ti.template()):
        """The broad phase, once per step: every vertex-triangle and edge-edge pair whose swept
        boxes overlap (each pair once), into the pair lists the rounds go through."""
        self.pair_count[0], self.pair_count[1] = 0, 0
        thick = self.thickness[None]
        for i in y.x:
            p0, p1 = self.x_start[i], y.x[i]
            lo, hi = ti.min(p0, p1) - 0.5 * thick, ti.max(p0, p1) + 0.5 * thick
            c_lo, c_hi, clipped = self.triangle_grid.box_cells(lo, hi)
            if clipped:
                ti.atomic_add(self.triangle_grid.overflow[None], 1)
            for ci, cj, ck in ti.ndrange((c_lo[0], c_hi[0] + 1), (c_lo[1], c_hi[1] + 1), (c_lo[2], c_hi[2] + 1)):
                cell = ti.Vector([ci, cj, ck])
                first_entry, end_entry = self.triangle_grid.entries(self.triangle_grid.bucket(cell))
                for e in range(first_entry, end_entry):
                    t = self.triangle_grid.items[e]
                    tri = self.mesh.triangles[t]
                    if (tri[0] != i and tri[1] != i and tri[2] != i and all(lo <= self.triangle_grid.hi[t])
                            and all(self.triangle_grid.lo[t] <= hi)
                            and self.triangle_grid.first_shared_cell(cell, c_lo, c_hi, t)):
                        k = ti.atomic_add(self.pair_count[0], 1)
                        if k < self.vt_pairs.shape[0]:
                            self.vt_pairs[k] = ti.Vector([i, t])
        for a in range(self.edge_count):
            if self.edge_alive[a]:
                ea = self.edges[a]
                lo, hi = self.edge_grid.lo[a], self.edge_grid.hi[a]
                c_lo, c_hi = self.edge_grid.cell_lo[a], self.edge_grid.cell_hi[a]
                for ci, cj, ck in ti.ndrange((c_lo[0], c_hi[0] + 1), (c_lo[1], c_hi[1] + 1), (c_lo[2], c_hi[2] + 1)):
                    cell = ti.Vector([ci, cj, ck])
                    first_entry, end_entry = self.edge_grid.entries(self.edge_grid.bucket(cell))
                    for e in range(first_entry, end_entry):
                        b = self.edge_grid.items[e]
                        eb = self.edges[b]
                        if (b > a and ea[0] != eb[0] and ea[0] != eb[1] and ea[1] != eb[0] and ea[1] != eb[1]
                                and all(lo <= self.edge_grid.hi[b]) and all(self.edge_grid.lo[b] <= hi)
                                and self.edge_grid.first_shared_cell(cell, c_lo, c_hi, b)):
                            k = ti.atomic_add(self.pair_count[1], 1)
                            if k < self.ee_pairs.shape[0]:
                                self.ee_pairs[k] = ti.Vector([a, b])

    @ti.kernel
    def _resolve(self, y: ti.template()) -> ti.i32:
        """One Jacobi round over the collected pairs; returns the contacts found."""
        for i in self.dx:
            self.dx[i] = ti.Vector.zero(self.dx.dtype, 3)
            self.dv[i] = ti.Vector.zero(self.dx.dtype, 3)
            self.hits[i] = 0
        self.contacts[None] = 0
        for k in range(ti.min(self.pair_count[0], self.vt_pairs.shape[0])):
            pair = self.vt_pairs[k]
            self._vertex_triangle(y, pair[0], self.mesh.triangles[pair[1]])
        for k in range(ti.min(self.pair_count[1], self.ee_pairs.shape[0])):
            pair = self.ee_pairs[k]
            self._edge_edge(y, self.edges[pair[0]], self.edges[pair[1]])
        for i in y.x:
            if self.hits[i] > 0:
                y.x[i] += self.dx[i] / self.hits[i]
                y.v[i] += self.dv[i] / self.hits[i]
        return self.contacts[None]

    @ti.func
    def _vertex_triangle(self, y, i, tri):
        thick = self.thickness[None]
        a0, b0, c0 = self.x_start[tri[0]], self.x_start[tri[1]], self.x_start[tri[2]]
        a1, b1, c1 = y.x[tri[0]], y.x[tri[1]], y.x[tri[2]]
        p0, p1 = self.x_start[i], y.x[i]
        n1 = (b1 - a1).cross(c1 - a1)
        n0 = (b0 - a0).cross(c0 - a0)
        area1, area0 = n1.norm(), n0.norm()
        if area1 > 1e-12 and area0 > 1e-12:
            n1 /= area1
            n0 /= area0
            s0 = (p0 - a0).dot(n0)
            s1 = (p1 - a1).dot(n1)
            side = 1.0
            if s0 < 0.0 or (s0 == 0.0 and s1 < 0.0):
                side = -1.0
            w = _closest_barycentric(p1, a1, b1, c1)
            q1 = w[0] * a1 + w[1] * b1 + w[2] * c1
            near = (p1 - q1).norm() < thick
            crossed = s0 * s1 < 0.0 and (_inside(p1 - s1 * n1, a1, b1, c1) or _inside(p0 - s0 * n0, a0, b0, c0))
            gap = thick - side * s1
            if (near or crossed) and gap > 0.0:
                self._push_apart(y, ti.Vector([i, tri[0], tri[1], tri[2]]),
                                 ti.Vector([1.0, -w[0], -w[1], -w[2]]), side * n1, gap)

    @ti.func
    def _edge_edge(self, y, ea, eb):
        thick = self.thickness[None]
        p0, q0, r0, s0 = self.x_start[ea[0]], self.x_start[ea[1]], self.x_start[eb[0]], self.x_start[eb[1]]
        p1, q1, r1, s1 = y.x[ea[0]], y.x[ea[1]], y.x[eb[0]], y.x[eb[1]]
        u1, u0 = _segment_parameters(p1, q1, r1, s1), _segment_parameters(p0, q0, r0, s0)
        d1 = (p1 + u1[0] * (q1 - p1)) - (r1 + u1[1] * (s1 - r1))  # from edge b's closest point to a's
        d0 = (p0 + u0[0] * (q0 - p0)) - (r0 + u0[1] * (s0 - r0))
        vol0 = (q0 - p0).cross(s0 - r0).dot(r0 - p0)
        vol1 = (q1 - p1).cross(s1 - r1).dot(r1 - p1)
        interior = u1[0] > 0.0 and u1[0] < 1.0 and u1[1] > 0.0 and u1[1] < 1.0
        crossed = vol0 * vol1 < 0.0 and interior
        dist0 = d0.norm()
        if dist0 > 1e-12 and (crossed or d1.norm() < thick):
            n = d0 / dist0  # the side a started on, seen from b
            gap = thick - d1.dot(n)
            if gap > 0.0:
                self._push_apart(y, ti.Vector([ea[0], ea[1], eb[0], eb[1]]),
                                 ti.Vector([1.0 - u1[0], u1[0], -(1.0 - u1[1]), -u1[1]]), n, gap)

    @ti.func
    def _push_apart(self, y, ids, w, n, gap):
        """Separate two sides of a contact by ``gap`` along unit ``n`` and stop their approach:
        vertex ``ids[k]`` moves with weight ``w[k]`` (positive on the side ``n`` points to)."""
        inv = ti.Vector([self._inverse_mass(ids[0]), self._inverse_mass(ids[1]),
                         self._inverse_mass(ids[2]), self._inverse_mass(ids[3])])
        denom = (w * w * inv).sum()
        if denom > 0.0:
            ti.atomic_add(self.contacts[None], 1)
            rel = ti.Vector.zero(self.dx.dtype, 3)
            for k in ti.static(range(4)):
                rel += w[k] * y.v[ids[k]]
            vn = rel.dot(n)
            jv = ti.max(0.0, -vn) / denom  # inelastic: the approach stops
            vt = rel - vn * n
            speed_t = vt.norm()
            jt = ti.Vector.zero(self.dx.dtype, 3)
            if speed_t > 0.0:  # Coulomb: at most friction x the normal change, never reversing
                jt = -ti.min(self.friction[None] * ti.max(0.0, -vn), speed_t) / denom * vt / speed_t
            jx = gap / denom
            for k in ti.static(range(4)):
                self._share(ids[k], inv[k], w[k], n * jx, n * jv + jt)

    @ti.func
    def _share(self, j, inv, weight, dx, dv):
        if inv > 0.0:
            ti.atomic_add(self.dx[j], weight * inv * dx)
            ti.atomic_add(self.dv[j], weight * inv * dv)
            ti.atomic_add(self.hits[j], 1)


@ti.func
def _inside(p, a, b, c):
    """Whether p's projection onto the plane of (a, b, c) falls inside the triangle (with a
    relative tolerance of 1e-6, so a vertex crossing exactly at an edge counts)."""
    n = (b - a).cross(c - a)
    nn = n.norm_sqr()
    u = (b - p).cross(c - p).dot(n) / nn
    v = (c - p).cross(a - p).dot(n) / nn
    w = 1.0 - u - v
    return u >= -1e-6 and v >= -1e-6 and w >= -1e-6


@ti.func
def _closest_barycentric(p, a, b, c):
    """Barycentric weights of the point of triangle (a, b, c) nearest p (Ericson, Real-Time
    Collision Detection, 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab.dot(ap), ac.dot(ap)
    w = ti.Vector([1.0, 0.0, 0.0])
    bp = p - b
    d3, d4 = ab.dot(bp), ac.dot(bp)
    cp = p - c
    d5, d6 = ab.dot(cp), ac.dot(cp)
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    if d1 <= 0.0 and d2 <= 0.0:
        w = ti.Vector([1.0, 0.0, 0.0])
    elif d3 >= 0.0 and d4 <= d3:
        w = ti.Vector([0.0, 1.0, 0.0])
    elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        w = ti.Vector([1.0 - t, t, 0.0])
    elif d6 >= 0.0 and d5 <= d6:
        w = ti.Vector([0.0, 0.0, 1.0])
    elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        w = ti.Vector([1.0 - t, 0.0, t])
    elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        w = ti.Vector([0.0, 1.0 - t, t])
    else:
        denom = 1.0 / (va + vb + vc)
        v = vb * denom
        u = vc * denom
        w = ti.Vector([1.0 - v - u, v, u])
    return w


@ti.func
def _segment_parameters(p, q, r, s):
    """Parameters (a, b) in [0, 1] of the closest points p + a (q - p) and r + b (s - r) of two
    segments (Ericson, Real-Time Collision Detection, 5.1.9)."""
    d1, d2, rr = q - p, s - r, p - r
    a_, e, f = d1.dot(d1), d2.dot(d2), d2.dot(rr)
    sa, tb = 0.0, 0.0
    if a_ <= 1e-20 and e <= 1e-20:
        sa, tb = 0.0, 0.0
    elif a_ <= 1e-20:
        sa, tb = 0.0, ti.min(ti.max(f / e, 0.0), 1.0)
    else:
        c = d1.dot(rr)
        if e <= 1e-20:
            sa, tb = ti.min(ti.max(-c / a_, 0.0), 1.0), 0.0
        else:
            b_ = d1.dot(d2)
            denom = a_ * e - b_ * b_
            if denom > 1e-20 * a_ * e:
                sa = ti.min(ti.max((b_ * f - c * e) / denom, 0.0), 1.0)
            tb = (b_ * sa + f) / e
            if tb < 0.0:
                tb = 0.0
                sa = ti.min(ti.max(-c / a_, 0.0), 1.0)
            elif tb > 1.0:
                tb = 1.0
                sa = ti.min(ti.max((b_ - c) / a_, 0.0), 1.0)
    return ti.Vector([sa, tb])
