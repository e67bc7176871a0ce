"""A triangle mesh the cloth collides with (a table, a body): rigid, static or translating along
a scripted path, or animated by a sequence of frames (a body that moves); one scene part
(docs/design.md, "Scene parts"; docs/collisions.md).

The mesh is a two-sided shell of thickness ``skin``: a free particle keeps at least ``skin``
from every triangle, on the side it came from. After each step, in the mesh's frame a particle
goes from a = p0 - c(t - h) to b = p1 - c(t) (p0 from :class:`StepStart`). If that segment
crosses a triangle (however fast it moves: the exact segment-plane crossing, tested against
every triangle whose cells the segment's box reaches), the particle goes back to the earliest
crossing and on by the rest of its motion along the triangle's plane (the motion into it is
dropped, so a resting particle still slides); then, up to ``MESH_PASSES`` times, a particle
within ``skin`` of the mesh moves out to ``skin`` along the way from its nearest mesh point (the
triangle's normal on its side when it lies on the surface), which rounds a convex edge and
settles a concave corner. A particle moved gets the inelastic, Coulomb-friction response
against the mesh's velocity there (:func:`~taichi_sim.collide.friction.inelastic_friction`).
A closed mesh thus keeps out what starts outside it; what starts inside (deeper than ``skin``)
stays.

An animated mesh (:class:`~.mesh_frames.FramePlayer`) is posed at the end of each step. Each
triangle is then tested in its own moving frame: the particle's start is shifted by the
triangle's centroid move over the step, which is exact for a triangle that translates and
leaves out its turn and stretch within the step (each corner's move about the centroid). Its surface
velocity, for friction, is the centroid's.

The triangles are found through a uniform grid over every frame of the mesh in its own frame
(:class:`~.mesh_grid.TriangleGrid`): each cell lists the triangles whose box over the current
frame segment, grown by ``skin``, reaches it, refilled with numpy when the segment changes (a
rigid mesh: once). Cloth faces are not tested against the mesh's edges (the vertex test only):
a mesh edge sharper than the cloth's spacing can cut between vertices (the sphere, capsule and
box have :class:`FaceContact` for that; vbd's solve, which replaces this pass, keeps the cloth's
triangles off the mesh's sharp edges: integrators/positional/vbd/mesh_faces.py).
"""
from dataclasses import dataclass, field

import numpy as np
import taichi as ti

from ... import runtime
from ...collide.closest_points import closest_barycentric, inside
from ...collide.friction import inelastic_friction
from ...collide.objects import FAR
from ...part import MovingSource, PartSpec, ScenePart, SolidMesh
from .mesh_frames import FramePlayer
from .mesh_grid import TriangleGrid, cell_id, cells
from .path import PathFields, SpherePath
from .step_start import StepStart

# Passes of "move out to skin from the nearest point" per particle and step: one settles a
# face, two an edge between two faces, three a corner of three.
MESH_PASSES = 4
# A particle's test walks the grid's cells and their triangles, far more work than a system
# loop's per particle, so the loop pays its threads' hand-off from a few thousand on. The
# collider's loop alone on cloth-on-table, f32, 2 vCPUs, serial against parallel: 0.19 against
# 0.21-0.29 ms at 32 x 32, 0.55 against 0.42-0.48 ms at 64 x 64 (runtime.serial_loops' items).
SERIAL_MESH_PARTICLES = 2_000
# A particle this close to the skin (relative) counts as on it: one put there is, up to rounding.
SETTLED = 1.0 - 1e-6


@dataclass(frozen=True, eq=False)
class MeshObstacle(PartSpec):
    """A triangle mesh collider: ``vertices`` (V, 3) m, or (F, V, 3) for a sequence of F
    frames played at ``fps`` (frames per second; linear between frames, the last held), in
    its own frame, whose origin moves along ``path``; ``triangles`` (T, 3) vertex ids, shared
    by every frame; Coulomb ``friction`` (>= 0) and ``skin`` (m, > 0), the distance particles
    keep from it."""

    vertices: np.ndarray
    triangles: np.ndarray
    path: SpherePath = field(default_factory=lambda: SpherePath((0.0, 0.0, 0.0)))
    friction: float = 0.0
    skin: float = 0.005
    fps: float = 30.0

    def __post_init__(self):
        v = np.asarray(self.vertices, float)
        t = np.asarray(self.triangles)
        frames = v[None] if v.ndim == 2 else v
        if frames.ndim != 3 or frames.shape[2] != 3 or frames.shape[1] < 3 or not np.isfinite(frames).all():
            raise ValueError("collider_mesh: vertices must be (V, 3) or (F, V, 3) finite values, V >= 3")
        if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0 or t.min() < 0 or t.max() >= frames.shape[1]:
            raise ValueError("collider_mesh: triangles must be (T, 3) ids of its vertices, T >= 1")
        corners = frames[:, t]
        area = np.linalg.norm(np.cross(corners[:, :, 1] - corners[:, :, 0], corners[:, :, 2] - corners[:, :, 0]),
                              axis=2)
        flat = area <= 1e-12 * max(float(np.ptp(frames, axis=(0, 1)).max()), 1e-12) ** 2
        if flat.any():
            frame = int(np.flatnonzero(flat.any(axis=1))[0])
            where = f" in frame {frame}" if len(frames) > 1 else ""
            raise ValueError(f"collider_mesh: {int(flat[frame].sum())} triangle(s) of zero area{where}")
        if not self.skin > 0:
            raise ValueError("collider_mesh_skin must be > 0")
        if not self.friction >= 0:
            raise ValueError("collider_mesh_friction must be >= 0")
        if not (self.fps > 0 and np.isfinite(self.fps)):
            raise ValueError("collider_mesh_fps must be > 0")

    @property
    def frames(self) -> np.ndarray:
        """(F, V, 3) m: every frame (F = 1 for a rigid mesh)."""
        v = np.asarray(self.vertices, np.float64)
        return v[None] if v.ndim == 2 else v


@ti.data_oriented
class MeshCollider(ScenePart):
    """The scene's triangle-mesh collider (module docstring); also an obstacle the self-contact
    stage keeps the cloth out of (``nearest_surface``)."""

    name = "collider_mesh"
    order = 13
    is_obstacle = True

    def __init__(self, spec: MeshObstacle, free):
        real = runtime.real()
        self.spec = spec
        self.free = free
        self.player = FramePlayer(spec.frames, spec.fps)
        self.triangles_np = np.asarray(spec.triangles, np.int64)
        self.skin = float(spec.skin)
        self.count = 1
        self.path = PathFields(1)
        self.path.upload([spec.path])
        # one grid over every frame (its geometry is compiled into the kernels); each frame
        # segment lists the triangles by their boxes over the segment
        self.grid = TriangleGrid.covering(self.player.frames, self.triangles_np, self.skin)
        capacity = max(self.grid.entries(*self._grown(k)) for k in range(self.player.segment_count))
        self.grid_origin, self.cell, self.dims = self.grid.origin, self.grid.cell, self.grid.dims
        T = len(self.triangles_np)
        self.corner = ti.Vector.field(3, real, shape=(T, 3))
        self.face_normal = ti.Vector.field(3, real, shape=T)
        # each triangle's centroid: its move over the last step (m) and its velocity now (m/s)
        self.face_shift = ti.Vector.field(3, real, shape=T)
        self.face_velocity = ti.Vector.field(3, real, shape=T)
        self.cell_start = ti.field(ti.i32, shape=self.grid.cell_count + 1)
        self.cell_triangles = ti.field(ti.i32, shape=max(1, capacity))
        self.start = StepStart(free.shape[0])
        self.serial = runtime.serial_loops(free.shape[0], SERIAL_MESH_PARTICLES)
        self.contacts = ti.field(ti.i64, shape=())
        self.listed_segment = -1
        self.normals_np = np.zeros((T, 3))
        self.largest_shift = 0.0
        self.t = 0.0
        self.t_posed = None
        self._pose(0.0, 0.0)

    def _grown(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.player.segment_boxes(self.triangles_np, k)
        return lo - self.skin, hi + self.skin

    def _pose(self, t: float, h: float) -> None:
        """Put the triangles where the frames have them at t (s), with their move since t - h."""
        if self.t_posed is not None and not self.player.animated:
            return  # a rigid mesh stays as built
        self.list_segment(self.player.segment(t)[0])
        npr = runtime.np_real()
        now = self.follow(t)
        corners = now[self.triangles_np]
        shift = (now - self.player.vertices(t - h))[self.triangles_np].mean(axis=1)
        velocity = self.player.velocities(t)[self.triangles_np].mean(axis=1)
        self.corner.from_numpy(corners.astype(npr))
        self.face_normal.from_numpy(self.normals_np.astype(npr))
        self.face_shift.from_numpy(shift.astype(npr))
        self.face_velocity.from_numpy(velocity.astype(npr))
        self.largest_shift = float(np.linalg.norm(shift, axis=1).max())
        self.t_posed = t

    def list_segment(self, segment: int) -> None:
        """Fill the grid's cell lists (``cell_start``, ``cell_triangles``) with the triangles'
        boxes over frame segment ``segment``, grown by the skin (a no-op when listed already):
        any pose within the segment is found through them."""
        if segment != self.listed_segment:
            start, listed = self.grid.lists(*self._grown(segment))
            self.cell_start.from_numpy(start.astype(np.int32))
            self.cell_triangles.from_numpy(np.pad(listed, (0, self.cell_triangles.shape[0] - len(listed)))
                                           .astype(np.int32))
            self.listed_segment = segment

    def follow(self, t: float) -> np.ndarray:
        """Take the pose at t (s) on the host only (what the npz, `check` and a viewer read:
        ``t``, ``vertices_np``, ``normals_np``) and return its vertices (V, 3) m, mesh frame;
        where vbd's solve meets the mesh (its post-step pass does not run) the solve calls it."""
        self.t = t
        if self.t_posed is not None and not self.player.animated:
            return self.vertices_np
        now = self.player.vertices(t)
        corners = now[self.triangles_np]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        # a triangle passing through zero area between two frames keeps its last normal
        self.normals_np = np.where(length > 0, normals / np.where(length > 0, length, 1.0), self.normals_np)
        self.vertices_np = now
        return now

    @classmethod
    def from_specs(cls, specs: list[MeshObstacle], context) -> "MeshCollider":
        if len(specs) > 1:
            raise ValueError("a scene has at most one collider mesh (join the meshes into one)")
        return cls(specs[0], context.system.free)

    # -- the part protocol ----------------------------------------------------------------------

    def __call__(self, state, t: float, h: float) -> None:
        self.start.begin(state, t, h)
        self.t = t
        self._pose(t, h)
        self._collide(state, self.start.x, t, h, self.spec.friction, self.largest_shift)
        self.start.end(state, t)

    def reset(self) -> None:
        self.t = 0.0
        self._pose(0.0, 0.0)

    def restore(self) -> None:
        self.start.restore()
        self.contacts[None] = 0

    @property
    def contacts_total(self) -> int:
        """Particle contacts since the scene was built or restored (read back only when asked:
        a read each step would wait for the kernel)."""
        return int(self.contacts[None])

    def center(self) -> np.ndarray:
        """(3,) float64: where the mesh's origin is now (m)."""
        return np.asarray(self.spec.path.at(self.t)[0], np.float64)

    def centers_at(self, t: float) -> dict[str, np.ndarray]:
        """Where the mesh is at time t (s), as the npz's keys (a run keeps them with its saved
        frames, ``..._history``, for `check` to judge the frames against): its origin on the
        path, ``collider_mesh_center`` (3,) m, and for a sequence of frames its vertices then,
        ``collider_mesh_vertices`` (V, 3) m in its own frame (a rigid mesh's stay as built)."""
        out = {"collider_mesh_center": np.asarray(self.spec.path.at(t)[0], np.float64)}
        if self.player.animated:
            out["collider_mesh_vertices"] = self.player.vertices(t)
        return out

    def features(self) -> dict:
        return {"collider_mesh": len(self.triangles_np)}

    def arrays(self) -> dict:
        return {"collider_mesh_vertices": self.vertices_np.copy(), "collider_mesh_triangles": self.triangles_np,
                "collider_mesh_center": self.center(), "collider_mesh_skin": np.float64(self.skin)}

    def _flat_shaded(self) -> tuple[np.ndarray, np.ndarray]:
        """Each triangle its own three vertices (about the origin, m) with its normal."""
        return self.vertices_np[self.triangles_np].reshape(-1, 3), np.repeat(self.normals_np, 3, axis=0)

    def visuals(self) -> list:
        corners, normals = self._flat_shaded()
        frames = self.player.frames
        reach = np.maximum(np.abs(frames.min(axis=(0, 1))), np.abs(frames.max(axis=(0, 1))))
        return [SolidMesh(vertices=corners, normals=normals, triangles=np.arange(len(corners)).reshape(-1, 3),
                          place=self.center, reach=reach,
                          pose=self._flat_shaded if self.player.animated else None)]

    def energy_sources(self) -> list:
        return [MovingSource("moving collider mesh", self.spec.path.fastest_speed() + self.player.fastest_speed())]

    def summary(self) -> str:
        return f"collider mesh: {self.contacts_total} particle contacts"

    # -- geometry -----------------------------------------------------------------------------

    @ti.func
    def _cells(self, lo, hi):
        """The grid's cell range (first, last, each an int vector) that the box [lo, hi] (mesh
        frame) reaches; first > last on some axis when it lies outside the grid."""
        return cells(self.grid, lo, hi)

    @ti.func
    def _cell_id(self, first, span, k):
        """The grid index of the k-th cell of the block of ``span`` cells from ``first``."""
        return cell_id(self.grid, first, span, k)

    @ti.func
    def _crossing(self, a, b, reach):
        """The earliest s in [0, 1] at which the particle moving from a to b (mesh frame)
        crosses a triangle (2 when none), that triangle's unit normal on the particle's side,
        the triangle and where the particle meets it. Each triangle is tested in its own
        moving frame: the particle starts at a plus the triangle's move over the step (at most
        ``reach``, m), as the rigid path's move is already taken out of a."""
        best, normal, face, met = 2.0, 0.0 * a, -1, a
        normal[1] = 1.0
        first, last = self._cells(ti.min(a, b) - reach, ti.max(a, b) + reach)
        span = ti.max(last - first + 1, 0)
        for k in range(span[0] * span[1] * span[2]):  # one loop over the cells: less to compile
            c = self._cell_id(first, span, k)
            for e in range(self.cell_start[c], self.cell_start[c + 1]):
                f = self.cell_triangles[e]
                n = self.face_normal[f]
                p0 = self.corner[f, 0]
                af = a + self.face_shift[f]
                ha, hb = (af - p0).dot(n), (b - p0).dot(n)
                if ha * hb < 0.0 or (hb == 0.0 and ha != 0.0):
                    s = ha / (ha - hb)
                    m = af + s * (b - af)
                    if s < best and inside(m, p0, self.corner[f, 1], self.corner[f, 2]):
                        best, face, met = s, f, m
                        normal = n if ha > 0.0 else -n
        return best, normal, face, met

    @ti.func
    def _nearest(self, q, radius):
        """(distance (m), nearest point, its triangle) of the mesh within ``radius`` of q; FAR
        and -1 when none is."""
        best, point, face = FAR * 1.0, q, -1
        first, last = self._cells(q - radius, q + radius)
        span = ti.max(last - first + 1, 0)
        for k in range(span[0] * span[1] * span[2]):  # one loop over the cells: less to compile
            c = self._cell_id(first, span, k)
            for e in range(self.cell_start[c], self.cell_start[c + 1]):
                f = self.cell_triangles[e]
                p0 = self.corner[f, 0]
                # the plane's distance first: most triangles of a cell are farther
                if ti.abs((q - p0).dot(self.face_normal[f])) < ti.min(best, radius):
                    p1, p2 = self.corner[f, 1], self.corner[f, 2]
                    w = closest_barycentric(q, p0, p1, p2)
                    p = w[0] * p0 + w[1] * p1 + w[2] * p2
                    d = (q - p).norm()
                    if d < best and d <= radius:
                        best, point, face = d, p, f
        return best, point, face

    @ti.func
    def _away(self, q, p, face, side):
        """The unit direction out of the mesh at q from its nearest point p on ``face``; on the
        surface itself, the face's normal on the side of ``side`` (a point known to be there)."""
        d = (q - p).norm()
        n = self.face_normal[face]
        out = n
        if d > 1e-9 * self.skin:
            out = (q - p) / d
        elif (side - p).dot(n) < 0.0:
            out = -n
        return out

    @ti.func
    def nearest_surface(self, x, t, reach):
        """The :class:`~.obstacle.Obstacle` question: (signed distance to the shell's outside
        (m), outward unit normal, surface velocity (m/s)) at x (m) at time t (s); FAR farther
        than ``reach`` (m) outside the skin."""
        q = x - self.path.center(0, t)
        d, p, face = self._nearest(q, self.skin + reach)
        dist, normal = FAR * 1.0, ti.Vector([0.0, 1.0, 0.0])
        if face >= 0:
            dist = d - self.skin
            normal = self._away(q, p, face, q + self.face_normal[face])
        velocity = self.path.velocity(0, t)
        if face >= 0:
            velocity += self.face_velocity[face]
        return dist, normal, velocity

    @ti.kernel
    def _collide(self, y: ti.template(), x_start: ti.template(), t: float, h: float, friction: float,
                 reach: float):
        ti.loop_config(serialize=self.serial)
        for i in range(y.x.shape[0]):  # a range-for: serialize applies
            if self.free[i]:
                center = self.path.center(0, t)
                a = x_start[i] - self.path.center(0, t - h)
                b = y.x[i] - center
                first, last = self._cells(ti.min(a, b) - self.skin - reach, ti.max(a, b) + self.skin + reach)
                if all(first <= last):  # the motion reaches the grid
                    q = b
                    hit = False
                    n = 0.0 * b
                    n[1] = 1.0
                    touched = -1
                    s, crossed, face, met = self._crossing(a, b, reach)
                    side = a
                    if s <= 1.0:  # back to the crossing, on by the motion along the surface
                        hit = True
                        rest = b - met
                        q = met + rest - ti.min(rest.dot(crossed), 0.0) * crossed
                        n = crossed
                        side = met + self.skin * crossed
                        touched = face
                    for _ in range(MESH_PASSES):
                        d, p, nearest = self._nearest(q, self.skin)
                        if nearest < 0 or d >= SETTLED * self.skin:  # (one put there last pass or step)
                            break
                        out = self._away(q, p, nearest, side)
                        q = p + self.skin * out
                        side = q
                        n = out
                        hit = True
                        touched = nearest
                    if hit:
                        surface = self.path.velocity(0, t) + self.face_velocity[ti.max(touched, 0)]
                        y.x[i] = center + q
                        y.v[i] = inelastic_friction(y.v[i], surface, n, friction)
                        self.contacts[None] += 1


MeshObstacle.part_class = MeshCollider
