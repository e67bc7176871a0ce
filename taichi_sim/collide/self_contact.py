"""Cloth against itself: a contact stage after each accepted step (Bridson, Fedkiw and Anderson 2002).

What it does, per step of length h, as a filter on the step's result, so it works after any
integrator. Every vertex is taken to move on a straight line from its start to its end position.

1. Broad phase: every intact triangle's and every edge's swept box (its corners at the start and
   the end of the step, grown by half the thickness) goes into a spatial hash
   (:class:`~.hash_grid.PrimitiveHash`); overlapping vertex-triangle and edge-edge pairs (no shared
   vertex) are listed once per step.
2. Contact rounds (``iterations``, Jacobi): a pair is in contact when it ends closer than
   ``thickness``, or when it touches at some moment of the step (continuous detection, exact up to
   round-off: the coplanarity cubic of :mod:`.ccd`). A contact moves the two sides apart along the
   contact normal until they are ``thickness`` apart on the side they were on before, and removes
   their approaching relative normal velocity (inelastic), with Coulomb friction on the tangential
   one; corrections are shared by inverse mass and barycentric weight, as impulses are, and
   averaged over each vertex's contacts. The rounds stop early when one closes too little of
   the overlap the round before left (``STALLED_ROUND``): the fail-safe finishes.
3. Fail-safe (:class:`~.impact_zones.ImpactZones`): while some pair still touches during the step,
   the vertices of touching pairs are merged into zones that move rigidly, which no touch inside
   a zone survives. So a cloth that starts a step free of self-intersections ends it free of them;
   ``unresolved_total`` counts the touches left if the fail-safe ever runs out of rounds.
"""

import math

import numpy as np
import taichi as ti

from .. import field_io, runtime
from ..part import ScenePart
from .candidates import CandidatePairs, PairList
from .ccd import (
    edge_edge_hit,
    edge_edge_hit_between,
    point_triangle_distance,
    vertex_triangle_hit,
    vertex_triangle_hit_between,
)
from .closest_points import closest_barycentric, segment_parameters
from .hash_grid import PrimitiveHash
from .impact_zones import ImpactZones
from .objects import KeepsOutOfObjects

DELTA_FRACTION = 1e-3  # a touch: closer than this fraction of the thickness at some moment of the step
# Fail-safe rounds per step before the whole cloth moves as one zone. A 64 x 64 fold at 1/60 s
# needs up to about 60: at 32, 10-14 of 60 steps fell back to moving the whole cloth rigidly
# (which stops the fold's motion for that step); at 64, none, for 2 % (implicit Euler) to 22 %
# (projective dynamics) more time a step.
MAX_ZONE_ROUNDS = 64
# A contact round whose contacts still overlap by more than this share of the summed overlap the
# round before found (the gaps its pushes must close, m; contacts that pins, the floor or objects
# block are left out: no push closes them) has stalled: the rounds stop and the fail-safe
# finishes. On a 64 x 64 fold at 1/60 s the overlap falls by 7-16 % a round (965, 811, 685, 590 m
# summed over 125 000 contacts), the contacts' count by 0-5 %, and a round is a pass over
# 600 000 pairs.
STALLED_ROUND = 0.9
PAIRS_PER_PRIMITIVE = 64  # the pair lists' first room, per vertex and per edge; they grow when full
TOUCHES_PER_VERTEX = 4  # the fail-safe's first room for touching pairs; it grows when full
TouchList = ti.types.ndarray(dtype=ti.math.ivec4, ndim=1)


@ti.data_oriented
class SelfCollision(CandidatePairs, KeepsOutOfObjects, ScenePart):
    """The post-step self-contact stage of a cloth (call it as ``stage(state, t, h)``; a scene
    part: :class:`~taichi_sim.part.ScenePart`).

    Args:
        system: the scene's ParticleSystem (masses, which particles are free).
        mesh: the cloth's :class:`~taichi_sim.mesh.TriangleMesh`.
        x0: (n, 3) initial positions (m): sizes the hash's cells by the longest triangle edge.
        thickness: the distance (m) a vertex keeps from any triangle it is not a corner of.
        friction: Coulomb coefficient between cloth layers (>= 0).
        iterations: rounds of contact resolution per step (>= 1).
        floor: ``(point, unit normal)`` of the scene's ground plane, or None. Contacts do not push
            a vertex near it into it, a vertex the contact rounds left below it is lifted back
            onto it, and a zone that would end below it is moved up: the stage does not undo the
            plane's work.
        obstacles: the scene's object colliders (its parts with ``is_obstacle``; see
            :mod:`.objects`): the same rules as the floor's keep the stage's pushes and zones
            from moving the cloth into them.
    Raises:
        ValueError: naming ``thickness``, ``friction`` or ``iterations``.
    """

    def __init__(self, system, mesh, x0: np.ndarray, *, thickness: float, friction: float = 0.0,
                 iterations: int = 4, floor=None, obstacles=()):
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
        self.edge_alive = ti.field(ti.i32, shape=max(len(edges), 1))
        self.triangle_alive = ti.field(ti.i32, shape=max(mesh.triangle_count, 1))
        # Boxes grown by half the thickness each: two boxes overlap when their primitives could
        # be closer than the thickness (grown by all of it on both sides, twice the pairs).
        self.base_cell = cell  # the cells' side unless a box this step is longer (see _fit_cells)
        self.triangle_grid = PrimitiveHash(mesh.triangle_count, 3, cell, 0.5 * thickness)
        self.edge_grid = PrimitiveHash(len(edges), 2, cell, 0.5 * thickness)
        self.x_start = ti.Vector.field(3, real, shape=n)
        self.dx = ti.Vector.field(3, real, shape=n)
        self.dv = ti.Vector.field(3, real, shape=n)
        self.hits = ti.field(ti.i32, shape=n)
        # moved by the last contact round: a pair none of whose vertices moved cannot have come
        # into contact since that round found it out of contact
        self.moved = ti.field(ti.i32, shape=n)
        # candidate pairs of a step: (vertex, triangle) and (edge, edge), in arrays passed to the
        # kernels, so that a list that fills up is replaced by a longer one without compiling
        self.vt_pairs = ti.Vector.ndarray(2, ti.i32, shape=PAIRS_PER_PRIMITIVE * n)
        self.ee_pairs = ti.Vector.ndarray(2, ti.i32, shape=PAIRS_PER_PRIMITIVE * max(len(edges), 1))
        self.pair_count = ti.field(ti.i32, shape=2)
        self.thickness = ti.field(real, shape=())
        self.friction = ti.field(real, shape=())
        self.contacts = ti.field(ti.i32, shape=())
        self.overlap = ti.field(real, shape=())  # the round's summed gaps (m) that a push can close
        # a touch is a moment closer than this: small beside the thickness the contacts keep,
        # large beside the round-off of a root's time
        self.delta = ti.field(real, shape=())
        self.x_collected = ti.Vector.field(3, real, shape=n)  # the end positions the pairs came from
        self.moved_count = ti.field(ti.i32, shape=())
        # the fail-safe's touching pairs (four vertex ids); longer when a round finds more
        self.collided = ti.Vector.ndarray(4, ti.i32, shape=TOUCHES_PER_VERTEX * n)
        self.collided_count = ti.field(ti.i32, shape=())
        self.obstacles = tuple(obstacles)
        self.time = ti.field(real, shape=())  # the step's end (s): where the objects are
        self.zones = ImpactZones(*field_io.read(system.mass, system.free), floor=floor,
                                 push_out=self._push_zone_out if self.obstacles else None)
        self.floor_point = ti.Vector.field(3, real, shape=())
        self.floor_normal = ti.Vector.field(3, real, shape=())  # zero: no floor
        self.floor_count = ti.field(ti.i32, shape=())
        self.blocked = ti.field(ti.i32, shape=())  # contacts no push could resolve this step
        # the fail-safe's later rounds re-collect only around the vertices its zones moved
        self.changed = ti.field(ti.i32, shape=n)
        self.vertex_grid = PrimitiveHash(n, 1, cell, 0.5 * thickness)
        self.vertex_ids = ti.Vector.field(1, ti.i32, shape=n)
        self.vertex_alive = ti.field(ti.i32, shape=n)
        # every value the stage starts from in one kernel: from Python each of these fields (and
        # each component of a vector) compiles a kernel of its own, 13 where this is one
        floor_values = () if floor is None else ((self.floor_point, np.asarray(floor[0], float)),
                                                 (self.floor_normal, np.asarray(floor[1], float)))
        field_io.write((self.edges, edges if len(edges) else np.zeros((1, 2))),
                       (self.edge_alive, np.ones(self.edges.shape[0])),
                       (self.vertex_ids, np.arange(n)[:, None]), (self.vertex_alive, np.ones(n)),
                       (self.thickness, float(thickness)), (self.friction, float(friction)),
                       (self.delta, DELTA_FRACTION * float(thickness)), *floor_values)
        self.t_end = None  # the time the last stage ended at, None before the first
        self.restore()

    def restore(self) -> None:
        """Forget the last step (the scene went back to its start)."""
        self.t_end = None
        self.contacts_total = self.overflow_total = 0
        self.zone_steps = 0  # steps that needed the fail-safe
        self.zone_rounds = 0  # its rounds (detect, merge, move rigidly), over all steps
        self.zone_fallbacks = 0  # steps in which it ran out of rounds and moved the whole cloth rigidly
        self.unresolved_total = 0  # touches the fail-safe left (0 unless it ran out of rounds)

    name = "self_collision"
    order = 30  # after every other position change, so that nothing moves the cloth after it

    def features(self) -> dict:
        return {"self_collision": True}

    def summary(self) -> str:
        """One line on the run so far: contacts and the fail-safe's use."""
        line = (f"self-contact: {self.contacts_total} contacts, impact zones in {self.zone_steps} step(s) "
                f"({self.zone_rounds} rounds)")
        if self.zone_fallbacks:
            line += f", the whole cloth rigid in {self.zone_fallbacks} step(s) (out of rounds)"
        return line

    def warning(self) -> str:
        """What could have left an intersection ('' when nothing): touches the fail-safe left
        unresolved, candidate pairs dropped for lack of room in the lists or the hash."""
        if not (self.unresolved_total or self.overflow_total):
            return ""
        return (f"self-contact: {self.unresolved_total} touch(es) left unresolved, {self.overflow_total} candidate "
                f"pair(s) dropped: the cloth may intersect itself (taichi-sim check FILE.npz tells)")

    def __call__(self, state, t: float, h: float) -> bool:
        # The stage's kernels are large and branchy: Taichi's whole-kernel CFG pass was half
        # of their compile and bought no speed (runtime.without_cfg_optimisation).
        with runtime.without_cfg_optimisation():
            self._stage(state, t, h)
        return False  # the state changed, the system did not

    def _stage(self, state, t: float, h: float) -> None:
        # The step's start: kept from the last stage when this step follows it, else estimated
        # as x - h v (exact for symplectic Euler) after a reset, a jump or the first step.
        if self.t_end is None or abs((t - h) - self.t_end) > 1e-9 * max(1.0, abs(t)):
            self._estimate_start(state, h)
        self._mark_intact()
        self.time[None] = t
        self.blocked[None] = 0
        self._broad_phase(state)
        found, overlap = 0, 0.0
        for round_ in range(self.iterations):
            found = self._resolve(state, int(round_ == 0), self.vt_pairs, self.ee_pairs)
            self.contacts_total += found
            left = float(self.overlap[None])
            if found == 0 or (round_ > 0 and left > STALLED_ROUND * overlap):
                break  # none left, or Jacobi rounds no longer settle them: the fail-safe's turn
            overlap = left
        lifted = self._lift_to_floor(state)
        if self.obstacles:
            lifted += self._lift_out_of_obstacles(state)
        clean = found == 0 and lifted == 0 and self.blocked[None] == 0
        self._fail_safe(state, h, rounds_clean=clean)
        self._keep_end(state)
        self.t_end = t

    def _fail_safe(self, state, h: float, rounds_clean: bool) -> None:
        """Rigid impact zones (Provot 1997; Bridson et al. 2002, section 7.4): while some pair
        still touches during the step, the vertices of touching pairs are merged into zones and
        each zone moves rigidly over the step. A rigid (indeed any affine) motion keeps four
        points of one zone from becoming coplanar, so touches inside a zone vanish; touches
        between zones merge them. After MAX_ZONE_ROUNDS rounds the whole cloth moves as one
        zone for the step (counted in ``zone_fallbacks``).

        ``rounds_clean``: the last contact round found no contact (none closer than the thickness
        or touching), so none touches unless the pair lists have gone stale."""
        self.zones.clear()
        spare = 0.5 * (self.thickness[None] - self.delta[None])
        for round_ in range(MAX_ZONE_ROUNDS):
            if round_ == 0:
                # the pairs stay valid while no vertex has moved by more than the boxes' spare
                # margin since they were collected
                stale = self._mark_moved_since_collect(state, spare) > 0
                if rounds_clean and not stale:
                    return
                if stale:  # the vertices that moved further: their pairs are added to the lists
                    self._broad_phase(state, only_changed=True, append=True)
                touching = self._touches(state)
            else:
                # only the zones' vertices moved: only pairs holding one can touch anew, and the
                # lists are refilled with just those (the rounds are over: nothing else reads them)
                self._broad_phase(state, only_changed=True)
                touching = self._touches(state)
            if touching == 0:
                return
            if round_ == 0:
                self.zone_steps += 1
            self.zone_rounds += 1
            ids = self.collided.to_numpy()[:touching]
            self._move_zones_rigidly(state, ids, h)
        # Out of rounds: the whole cloth moves rigidly for this step (it kills the step's relative
        # motion, but no touch survives it); what still touches is counted, never hidden.
        self.zone_fallbacks += 1
        self.zones.merge_all()
        self._move_zones_rigidly(state, np.zeros((0, 4), np.int64), h)
        self._broad_phase(state)
        self.unresolved_total += self._touches(state)

    def _touches(self, state) -> int:
        """How many listed pairs touch during the step, all of them in ``collided``: a touch left
        out of the zones would not be looked at again (later rounds list only the pairs of
        vertices the zones moved), so a list too short is replaced and the detection repeated."""
        touching = self._detect(state, self.vt_pairs, self.ee_pairs, self.collided)
        if touching > self.collided.shape[0]:
            self.collided = ti.Vector.ndarray(4, ti.i32, shape=touching + touching // 2)
            touching = self._detect(state, self.vt_pairs, self.ee_pairs, self.collided)
        return touching

    def _move_zones_rigidly(self, state, touches: np.ndarray, h: float) -> None:
        """Merge ``touches`` into the zones, move the zones they reached rigidly over the step,
        and mark the vertices that moved, and those of the touches, as ``changed``."""
        x_before = state.x.to_numpy()
        x1, v1 = self.zones.rigidify(touches, self.x_start.to_numpy(), x_before, state.v.to_numpy(), h)
        x1 = x1.astype(runtime.np_real())
        state.x.from_numpy(x1)
        state.v.from_numpy(v1.astype(runtime.np_real()))
        changed = (x1 != x_before).any(axis=1)
        # a touch whose zone did not move it (its fit came out the same: pins on scripted paths
        # that no rigid motion follows) still touches, and the next round must see it again
        changed[np.asarray(touches, np.int64).ravel()] = True
        self.changed.from_numpy(changed.astype(np.int32))

    @ti.kernel
    def _lift_to_floor(self, y: ti.template()) -> ti.i32:
        """Put every free vertex below the floor back onto it, without its velocity into it;
        returns how many (then the fail-safe's first round looks at every listed pair, after
        collecting again those of vertices that moved beyond the boxes' margin)."""
        self.floor_count[None] = 0
        n = self.floor_normal[None]
        for i in y.x:
            if self.system.free[i]:
                depth = (y.x[i] - self.floor_point[None]).dot(n)
                if depth < 0.0:
                    y.x[i] -= depth * n
                    y.v[i] -= ti.min(0.0, y.v[i].dot(n)) * n
                    ti.atomic_add(self.floor_count[None], 1)
        return self.floor_count[None]

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

    @ti.kernel
    def _mark_moved_since_collect(self, y: ti.template(), spare: float) -> ti.i32:
        """Mark as ``changed`` the vertices that have moved further than ``spare`` (m) since the
        pair lists were collected; returns how many."""
        self.moved_count[None] = 0
        for i in y.x:
            far = (y.x[i] - self.x_collected[i]).norm() > spare
            self.changed[i] = 1 if far else 0
            if far:
                ti.atomic_add(self.moved_count[None], 1)
        return self.moved_count[None]

    @ti.kernel
    def _detect(self, y: ti.template(), vt: PairList, ee: PairList, touched: TouchList) -> ti.i32:
        """Every listed pair that touches during the step (continuous detection only), into
        ``touched`` as four vertex ids; returns how many touch."""
        self.collided_count[None] = 0
        delta = self.delta[None]
        for k in range(ti.min(self.pair_count[0], vt.shape[0])):
            i, tri = vt[k][0], self.mesh.triangles[vt[k][1]]
            t_hit, _ = vertex_triangle_hit(self.x_start[i], y.x[i], self.x_start[tri[0]], y.x[tri[0]],
                                           self.x_start[tri[1]], y.x[tri[1]], self.x_start[tri[2]], y.x[tri[2]],
                                           delta, True)
            if t_hit >= 0.0:
                self._record_touch(touched, ti.Vector([i, tri[0], tri[1], tri[2]]))
        for k in range(ti.min(self.pair_count[1], ee.shape[0])):
            ea, eb = self.edges[ee[k][0]], self.edges[ee[k][1]]
            t_hit, _ = edge_edge_hit(self.x_start[ea[0]], y.x[ea[0]], self.x_start[ea[1]], y.x[ea[1]],
                                     self.x_start[eb[0]], y.x[eb[0]], self.x_start[eb[1]], y.x[eb[1]], delta, True)
            if t_hit >= 0.0:
                self._record_touch(touched, ti.Vector([ea[0], ea[1], eb[0], eb[1]]))
        return self.collided_count[None]

    @ti.func
    def _record_touch(self, touched: ti.template(), ids):
        slot = ti.atomic_add(self.collided_count[None], 1)
        if slot < touched.shape[0]:
            touched[slot] = ids

    @ti.kernel
    def _resolve(self, y: ti.template(), first_round: ti.i32, vt: PairList, ee: PairList) -> ti.i32:
        """One Jacobi round over the collected pairs; returns the contacts found. After the
        first round only pairs with a vertex the previous round moved are looked at: the others
        were out of contact then and nothing they depend on has changed."""
        for i in self.dx:
            self.moved[i] = 1 if first_round or self.hits[i] > 0 else 0
            self.dx[i] = ti.Vector.zero(self.dx.dtype, 3)
            self.dv[i] = ti.Vector.zero(self.dx.dtype, 3)
            self.hits[i] = 0
        self.contacts[None] = 0
        self.overlap[None] = 0.0
        for k in range(ti.min(self.pair_count[0], vt.shape[0])):
            pair = vt[k]
            tri = self.mesh.triangles[pair[1]]
            if self.moved[pair[0]] or self.moved[tri[0]] or self.moved[tri[1]] or self.moved[tri[2]]:
                self._vertex_triangle(y, pair[0], tri)
        for k in range(ti.min(self.pair_count[1], ee.shape[0])):
            pair = ee[k]
            ea, eb = self.edges[pair[0]], self.edges[pair[1]]
            if self.moved[ea[0]] or self.moved[ea[1]] or self.moved[eb[0]] or self.moved[eb[1]]:
                self._edge_edge(y, ea, eb)
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
            w = closest_barycentric(p1, a1, b1, c1)
            q1 = w[0] * a1 + w[1] * b1 + w[2] * c1
            end = (p1 - q1).norm()
            t_hit, side = vertex_triangle_hit_between(p0, p1, a0, a1, b0, b1, c0, c1,
                                                      point_triangle_distance(p0, a0, b0, c0), end,
                                                      self.delta[None], False)
            if t_hit < 0.0:  # no touch during the step: the side is where it started
                s0 = (p0 - a0).dot(n0)
                side = 1.0
                if s0 < 0.0 or (s0 == 0.0 and (p1 - a1).dot(n1) < 0.0):
                    side = -1.0
            s1 = (p1 - a1).dot(n1)
            near = end < thick
            gap = thick - side * s1
            if (near or t_hit >= 0.0) and gap > 0.0:
                self._push_apart(y, ti.Vector([i, tri[0], tri[1], tri[2]]),
                                 ti.Vector([1.0, -w[0], -w[1], -w[2]]), side * n1, gap)

    @ti.func
    def _edge_edge(self, y, ea, eb):
        thick = self.thickness[None]
        p0, q0, r0, s0 = self.x_start[ea[0]], self.x_start[ea[1]], self.x_start[eb[0]], self.x_start[eb[1]]
        p1, q1, r1, s1 = y.x[ea[0]], y.x[ea[1]], y.x[eb[0]], y.x[eb[1]]
        u1, u0 = segment_parameters(p1, q1, r1, s1), segment_parameters(p0, q0, r0, s0)
        d1 = (p1 + u1[0] * (q1 - p1)) - (r1 + u1[1] * (s1 - r1))  # from edge b's closest point to a's
        d0 = (p0 + u0[0] * (q0 - p0)) - (r0 + u0[1] * (s0 - r0))
        dist0, dist1 = d0.norm(), d1.norm()
        t_hit, side = edge_edge_hit_between(p0, p1, q0, q1, r0, r1, s0, s1, dist0, dist1, self.delta[None], False)
        n = d0 / ti.max(dist0, 1e-30)  # the side a started on, seen from b
        valid = dist0 > 1e-12
        if t_hit >= 0.0:
            # they met: the side before the touch is the tetrahedron's sign, along the edges'
            # common normal (b was on its side ``side``, so a is on ``-side``)
            cross = (q1 - p1).cross(s1 - r1)
            length = cross.norm()
            if length > 1e-6 * (q1 - p1).norm() * (s1 - r1).norm():
                n = -side * cross / length
                valid = True
        if valid and (t_hit >= 0.0 or dist1 < thick):
            gap = thick - d1.dot(n)
            if gap > 0.0:
                self._push_apart(y, ti.Vector([ea[0], ea[1], eb[0], eb[1]]),
                                 ti.Vector([1.0 - u1[0], u1[0], -(1.0 - u1[1]), -u1[1]]), n, gap)

    @ti.func
    def _push_apart(self, y, ids, w, n, gap):
        """Separate two sides of a contact by ``gap`` along unit ``n`` and stop their approach:
        vertex ``ids[k]`` moves with weight ``w[k]`` (positive on the side ``n`` points to)."""
        inv = ti.Vector([self.system.inverse_mass(ids[0]), self.system.inverse_mass(ids[1]),
                         self.system.inverse_mass(ids[2]), self.system.inverse_mass(ids[3])])
        # a vertex within the thickness of the floor is not pushed towards it: it stays, and the
        # other side moves the whole gap (else the layers' contacts would press it through). Only
        # the positions: the velocity impulses keep the true masses, so that momentum is kept
        # and no kinetic energy is added (a floor vertex moving up must not throw the other side)
        inv_x = inv
        up = self.floor_normal[None]
        for k in ti.static(range(4)):
            if w[k] * n.dot(up) < 0.0 and (y.x[ids[k]] - self.floor_point[None]).dot(up) < self.thickness[None]:
                inv_x[k] = 0.0
            if self._held_by_obstacle(y.x[ids[k]], w[k] * n):  # the same for objects
                inv_x[k] = 0.0
        denom = (w * w * inv).sum()
        denom_x = (w * w * inv_x).sum()
        if denom > 0.0:
            ti.atomic_add(self.contacts[None], 1)
            if denom_x == 0.0:  # pins, the floor or objects hold both sides: left to the fail-safe
                ti.atomic_add(self.blocked[None], 1)
            else:
                ti.atomic_add(self.overlap[None], gap)
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
            jx = gap / ti.max(denom_x, 1e-30)
            for k in ti.static(range(4)):
                self._share(ids[k], inv_x[k], inv[k], w[k], n * jx, n * jv + jt)

    @ti.func
    def _share(self, j, inv_x, inv, weight, dx, dv):
        if inv > 0.0:
            ti.atomic_add(self.dx[j], weight * inv_x * dx)
            ti.atomic_add(self.dv[j], weight * inv * dv)
            ti.atomic_add(self.hits[j], 1)
