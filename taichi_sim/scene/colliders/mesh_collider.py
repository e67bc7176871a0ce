"""A rigid triangle mesh the cloth collides with (a table, a body), static or translating along
a scripted path: one scene part (docs/design.md, "Scene parts"; docs/collisions.md).

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
against the mesh's velocity (:func:`~taichi_sim.collide.friction.inelastic_friction`). A closed
mesh thus keeps out what starts outside it; what starts inside (deeper than ``skin``) stays.

The triangles are found through a uniform grid over the mesh in its own frame, built once with
numpy (the mesh is rigid, so it never changes): each cell lists the triangles whose box, grown
by ``skin``, reaches it. Cloth faces are not tested against the mesh's edges (the vertex test
only): a mesh edge sharper than the cloth's spacing can cut between vertices (the sphere, capsule
and box have :class:`FaceContact` for that).
"""
import os
from dataclasses import dataclass, field

import numpy as np
import taichi as ti

from ... import runtime
from ...collide.closest_points import closest_barycentric, inside
from ...collide.friction import inelastic_friction
from ...collide.objects import FAR
from ...errors import ConfigError
from ...part import MovingSource, PartSpec, ScenePart, SolidMesh
from .path import PathFields, SpherePath
from .step_start import StepStart

# Passes of "move out to skin from the nearest point" per particle and step: one settles a
# face, two an edge between two faces, three a corner of three.
MESH_PASSES = 4
# A particle this close to the skin (relative) counts as on it: one put there is, up to rounding.
SETTLED = 1.0 - 1e-6
# The grid's most cells: its cells are the mesh's median edge, or larger to stay below this.
MAX_CELLS = 32**3


def load_mesh_file(path: str) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64 m, triangles (T, 3) int64) of the mesh file ``path`` (any format
    trimesh reads: OBJ, STL, PLY, GLB, ...); ConfigError naming ``collider_mesh`` otherwise."""
    if not os.path.isfile(path):
        raise ConfigError(f"parameter collider_mesh: no such file {path!r}")
    import trimesh

    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:  # trimesh raises many kinds on a bad file
        raise ConfigError(f"parameter collider_mesh: cannot read {path!r} as a mesh ({exc})") from None
    if not hasattr(mesh, "faces") or len(mesh.faces) == 0:
        raise ConfigError(f"parameter collider_mesh: {path!r} holds no triangles")
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)


@dataclass(frozen=True, eq=False)
class MeshObstacle(PartSpec):
    """A triangle mesh collider: ``vertices`` (V, 3) (m, in its own frame, whose origin moves
    along ``path``), ``triangles`` (T, 3) vertex ids, Coulomb ``friction`` (>= 0) and ``skin``
    (m, > 0), the distance particles keep from it."""

    vertices: np.ndarray
    triangles: np.ndarray
    path: SpherePath = field(default_factory=lambda: SpherePath((0.0, 0.0, 0.0)))
    friction: float = 0.0
    skin: float = 0.005

    def __post_init__(self):
        v = np.asarray(self.vertices, float)
        t = np.asarray(self.triangles)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3 or not np.isfinite(v).all():
            raise ValueError("collider_mesh: vertices must be (V, 3) finite values, V >= 3")
        if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0 or t.min() < 0 or t.max() >= len(v):
            raise ValueError("collider_mesh: triangles must be (T, 3) ids of its vertices, T >= 1")
        area = np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1)
        if not np.all(area > 1e-12 * max(float(np.ptp(v, axis=0).max()), 1e-12) ** 2):
            raise ValueError(f"collider_mesh: {int((area <= 0).sum() or 1)} triangle(s) of zero area")
        if not self.skin > 0:
            raise ValueError("collider_mesh_skin must be > 0")
        if not self.friction >= 0:
            raise ValueError("collider_mesh_friction must be >= 0")


def triangle_grid(vertices: np.ndarray, triangles: np.ndarray, margin: float):
    """A uniform grid over the mesh grown by ``margin`` (m): (origin (3,), cell (m), dims (3,),
    cell_start (cells + 1,), cell_triangles) in CSR form, a triangle in every cell its box grown
    by ``margin`` reaches."""
    lo = vertices.min(axis=0) - margin
    hi = vertices.max(axis=0) + margin
    extent = hi - lo
    corners = vertices[triangles]
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
    cell = max(float(np.median(edges)), float(np.prod(extent) / MAX_CELLS) ** (1 / 3), 1e-6)
    dims = np.maximum(1, np.ceil(extent / cell).astype(np.int64))
    while np.prod(dims) > MAX_CELLS:  # a flat mesh: the volume rule above allows too many
        cell *= 1.25
        dims = np.maximum(1, np.ceil(extent / cell).astype(np.int64))
    first = np.clip(np.floor((corners.min(axis=1) - margin - lo) / cell).astype(np.int64), 0, dims - 1)
    last = np.clip(np.floor((corners.max(axis=1) + margin - lo) / cell).astype(np.int64), 0, dims - 1)
    span = last - first + 1
    counts = span.prod(axis=1)
    owner = np.repeat(np.arange(len(triangles)), counts)
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    sy, sz = span[owner, 1], span[owner, 2]
    ix = first[owner, 0] + local // (sy * sz)
    iy = first[owner, 1] + (local // sz) % sy
    iz = first[owner, 2] + local % sz
    cells = (ix * dims[1] + iy) * dims[2] + iz
    order = np.argsort(cells, kind="stable")
    start = np.zeros(int(np.prod(dims)) + 1, np.int64)
    np.cumsum(np.bincount(cells, minlength=int(np.prod(dims))), out=start[1:])
    return lo, cell, dims, start, owner[order]


@ti.data_oriented
class MeshCollider(ScenePart):
    """The scene's triangle-mesh collider (module docstring); also an obstacle the self-contact
    stage keeps the cloth out of (``nearest_surface``)."""

    name = "collider_mesh"
    order = 13
    is_obstacle = True

    def __init__(self, spec: MeshObstacle, free):
        real, npr = runtime.real(), runtime.np_real()
        self.spec = spec
        self.free = free
        self.vertices_np = np.asarray(spec.vertices, np.float64)
        self.triangles_np = np.asarray(spec.triangles, np.int64)
        self.skin = float(spec.skin)
        self.count = 1
        self.path = PathFields(1)
        self.path.upload([spec.path])
        lo, cell, dims, start, listed = triangle_grid(self.vertices_np, self.triangles_np, self.skin)
        self.grid_origin = tuple(float(c) for c in lo)  # compile-time constants of the kernels
        self.cell = float(cell)
        self.dims = tuple(int(d) for d in dims)
        T = len(self.triangles_np)
        self.corner = ti.Vector.field(3, real, shape=(T, 3))
        self.face_normal = ti.Vector.field(3, real, shape=T)
        self.cell_start = ti.field(ti.i32, shape=len(start))
        self.cell_triangles = ti.field(ti.i32, shape=max(1, len(listed)))
        corners = self.vertices_np[self.triangles_np]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        self.normals_np = normals
        self.corner.from_numpy(corners.astype(npr))
        self.face_normal.from_numpy(normals.astype(npr))
        self.cell_start.from_numpy(start.astype(np.int32))
        self.cell_triangles.from_numpy(np.asarray(listed if len(listed) else [0], np.int32))
        self.start = StepStart(free.shape[0])
        self.contacts = ti.field(ti.i64, shape=())
        self.t = 0.0

    @classmethod
    def from_specs(cls, specs: list[MeshObstacle], context) -> "MeshCollider":
        if len(specs) > 1:
            raise ValueError("a scene has at most one collider mesh (join the meshes into one)")
        return cls(specs[0], context.system.free)

    # -- the part protocol ----------------------------------------------------------------------

    def __call__(self, state, t: float, h: float) -> None:
        self.start.begin(state, t, h)
        self.t = t
        self._collide(state, self.start.x, t, h, self.spec.friction)
        self.start.end(state, t)

    def reset(self) -> None:
        self.t = 0.0

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

    def features(self) -> dict:
        return {"collider_mesh": len(self.triangles_np)}

    def arrays(self) -> dict:
        return {"collider_mesh_vertices": self.vertices_np, "collider_mesh_triangles": self.triangles_np,
                "collider_mesh_center": self.center(), "collider_mesh_skin": np.float64(self.skin)}

    def visuals(self) -> list:
        # flat-shaded: each triangle its own three vertices with its normal
        corners = self.vertices_np[self.triangles_np].reshape(-1, 3)
        reach = np.maximum(np.abs(self.vertices_np.min(axis=0)), np.abs(self.vertices_np.max(axis=0)))
        return [SolidMesh(vertices=corners, normals=np.repeat(self.normals_np, 3, axis=0),
                          triangles=np.arange(len(corners)).reshape(-1, 3), place=self.center, reach=reach)]

    def energy_sources(self) -> list:
        return [MovingSource("moving collider mesh", self.spec.path.fastest_speed())]

    def summary(self) -> str:
        return f"collider mesh: {self.contacts_total} particle contacts"

    # -- geometry -----------------------------------------------------------------------------

    @ti.func
    def _cells(self, lo, hi):
        """The grid's cell range (first, last, each an int vector) that the box [lo, hi] (mesh
        frame) reaches; first > last on some axis when it lies outside the grid."""
        origin = ti.Vector(self.grid_origin)
        dims = ti.Vector(self.dims)
        first = ti.cast(ti.floor((lo - origin) / self.cell), ti.i32)
        last = ti.cast(ti.floor((hi - origin) / self.cell), ti.i32)
        return ti.max(first, 0), ti.min(last, dims - 1)

    @ti.func
    def _cell_id(self, first, span, k):
        """The grid index of the k-th cell of the block of ``span`` cells from ``first``."""
        ix = first[0] + k // (span[1] * span[2])
        iy = first[1] + (k // span[2]) % span[1]
        iz = first[2] + k % span[2]
        return (ix * self.dims[1] + iy) * self.dims[2] + iz

    @ti.func
    def _crossing(self, a, b):
        """The earliest s in [0, 1] at which a + s (b - a) crosses a triangle (2 when none), and
        that triangle's unit normal on a's side."""
        best, normal = 2.0, 0.0 * a
        normal[1] = 1.0
        first, last = self._cells(ti.min(a, b), ti.max(a, b))
        span = ti.max(last - first + 1, 0)
        for k in range(span[0] * span[1] * span[2]):  # one loop over the cells: less to compile
            c = self._cell_id(first, span, k)
            for e in range(self.cell_start[c], self.cell_start[c + 1]):
                f = self.cell_triangles[e]
                n = self.face_normal[f]
                p0 = self.corner[f, 0]
                ha, hb = (a - p0).dot(n), (b - p0).dot(n)
                if ha * hb < 0.0 or (hb == 0.0 and ha != 0.0):
                    s = ha / (ha - hb)
                    if s < best and inside(a + s * (b - a), p0, self.corner[f, 1], self.corner[f, 2]):
                        best = s
                        normal = n if ha > 0.0 else -n
        return best, normal

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
        return dist, normal, self.path.velocity(0, t)

    @ti.kernel
    def _collide(self, y: ti.template(), x_start: ti.template(), t: float, h: float, friction: float):
        for i in y.x:
            if self.free[i]:
                center = self.path.center(0, t)
                a = x_start[i] - self.path.center(0, t - h)
                b = y.x[i] - center
                first, last = self._cells(ti.min(a, b) - self.skin, ti.max(a, b) + self.skin)
                if all(first <= last):  # the motion reaches the grid
                    q = b
                    hit = False
                    n = 0.0 * b
                    n[1] = 1.0
                    s, crossed = self._crossing(a, b)
                    side = a
                    if s <= 1.0:  # back to the crossing, on by the motion along the surface
                        hit = True
                        met = a + s * (b - a)
                        rest = b - met
                        q = met + rest - ti.min(rest.dot(crossed), 0.0) * crossed
                        n = crossed
                        side = met + self.skin * crossed
                    for _ in range(MESH_PASSES):
                        d, p, face = self._nearest(q, self.skin)
                        if face < 0 or d >= SETTLED * self.skin:  # (one put there last pass or step)
                            break
                        out = self._away(q, p, face, side)
                        q = p + self.skin * out
                        side = q
                        n = out
                        hit = True
                    if hit:
                        y.x[i] = center + q
                        y.v[i] = inelastic_friction(y.v[i], self.path.velocity(0, t), n, friction)
                        self.contacts[None] += 1


MeshObstacle.part_class = MeshCollider
