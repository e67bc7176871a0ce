"""Triangle meshes over particles (cloth): incidence, intactness under tearing, index buffers."""
import numpy as np
import taichi as ti

from .forces.springs import incidence_of


def edge_springs(triangles: np.ndarray, spring_ends: np.ndarray, particle_count: int) -> np.ndarray:
    """(T, 3) id of the spring along each triangle edge (v0v1, v1v2, v2v0), or -1 where none."""
    a = np.minimum(spring_ends[:, 0], spring_ends[:, 1]).astype(np.int64)
    b = np.maximum(spring_ends[:, 0], spring_ends[:, 1]).astype(np.int64)
    keys = a * particle_count + b
    order = np.argsort(keys)
    sorted_keys = keys[order]
    result = np.full((len(triangles), 3), -1, np.int64)
    for k, (p, q) in enumerate(((0, 1), (1, 2), (2, 0))):
        u, v = triangles[:, p].astype(np.int64), triangles[:, q].astype(np.int64)
        edge = np.minimum(u, v) * particle_count + np.maximum(u, v)
        pos = np.clip(np.searchsorted(sorted_keys, edge), 0, max(len(keys) - 1, 0))
        found = len(keys) > 0 and sorted_keys[pos] == edge
        result[:, k] = np.where(found, order[pos], -1) if len(keys) else -1
    return result


@ti.data_oriented
class TriangleMesh:
    """Triangles (T, 3) of particle ids, with the spring (if any) along each edge.

    A triangle is intact while every spring along its edges is alive; a torn triangle exerts no
    wind force and is dropped from the index buffer, so holes and ragged edges show.

    Args:
        particle_count: n.
        triangles: (T, 3) int particle ids, counter-clockwise seen from the front.
        springs: the scene's :class:`~taichi_sim.forces.Springs` term, or None.
    """

    def __init__(self, particle_count: int, triangles: np.ndarray, springs=None):
        triangles = np.asarray(triangles, np.int32).reshape(-1, 3)
        self.triangle_count = T = len(triangles)
        self.triangles_np = triangles
        self.springs = springs
        self.tearable = springs is not None and springs.tearable
        self.triangles = ti.Vector.field(3, ti.i32, shape=T)
        self._indices = None
        edges = np.full((T, 3), -1, np.int32)
        if self.tearable:
            self.edge_springs = ti.Vector.field(3, ti.i32, shape=T)
            edges = edge_springs(triangles, springs.ends_np, particle_count).astype(np.int32)
        offsets, incident, _ = incidence_of(particle_count, triangles)
        self.offsets = ti.field(ti.i32, shape=particle_count + 1)
        self.incident = ti.field(ti.i32, shape=max(len(incident), 1))
        self._upload(triangles, edges, offsets, incident)

    @ti.kernel
    def _upload(self, triangles: ti.types.ndarray(dtype=ti.i32, ndim=2),
                edges: ti.types.ndarray(dtype=ti.i32, ndim=2),
                offsets: ti.types.ndarray(dtype=ti.i32, ndim=1),
                incident: ti.types.ndarray(dtype=ti.i32, ndim=1)):
        for tri in range(self.triangle_count):
            self.triangles[tri] = ti.Vector([triangles[tri, 0], triangles[tri, 1], triangles[tri, 2]])
            if ti.static(self.tearable):
                self.edge_springs[tri] = ti.Vector([edges[tri, 0], edges[tri, 1], edges[tri, 2]])
        for i in range(offsets.shape[0]):
            self.offsets[i] = offsets[i]
        for e in range(incident.shape[0]):
            self.incident[e] = incident[e]

    @ti.func
    def is_intact(self, tri):
        intact = True
        if ti.static(self.tearable):
            for k in ti.static(range(3)):
                s = self.edge_springs[tri][k]
                if s >= 0 and self.springs.alive[s] == 0:
                    intact = False
        return intact

    @ti.kernel
    def fill_index_buffer(self, out: ti.template()):
        """Write 3T vertex indices into the 1-D i32 field ``out``; a torn triangle becomes the
        degenerate (v0, v0, v0), which draws nothing."""
        for tri in range(self.triangle_count):
            v = self.triangles[tri]
            if self.is_intact(tri):
                for k in ti.static(range(3)):
                    out[3 * tri + k] = v[k]
            else:
                for k in ti.static(range(3)):
                    out[3 * tri + k] = v[0]

    def index_buffer(self) -> np.ndarray:
        """(T, 3) int32 numpy index buffer (torn triangles degenerate)."""
        if self._indices is None:  # allocated once: a field per call would exhaust Taichi's trees
            self._indices = ti.field(ti.i32, shape=3 * self.triangle_count)
        self.fill_index_buffer(self._indices)
        return self._indices.to_numpy().reshape(-1, 3)

    @ti.func
    def area_normal(self, y, tri):
        """Twice the area times the unit normal of triangle ``tri`` at state ``y`` (a 3-vector)."""
        v = self.triangles[tri]
        return (y.x[v[1]] - y.x[v[0]]).cross(y.x[v[2]] - y.x[v[0]])
