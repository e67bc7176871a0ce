"""How deep points lie inside a closed triangle mesh (a collider mesh), numpy only: what `check`
judges a run's frames against a collider mesh with.

A point is inside when a ray from it crosses the mesh an odd number of times (the mesh must be
closed: a collider mesh is, or the scene refuses it). The ray runs along a fixed direction of
no special alignment (``RAY``), so that rays through the vertices and edges of a mesh built on
round numbers (a box, a grid) are the exception, and the test whether the ray meets a triangle
is made consistent along shared edges: each edge's side test is computed once from its lower
vertex id to its higher, for both triangles that share it, and a point exactly on the edge's
line is given to one side. So a ray through a shared edge meets exactly one of its two
triangles and the parity is right. Triangles are found through a uniform grid over the plane
across the ray. The depth of a point inside is its exact distance to the nearest triangle
(:func:`~taichi_sim.geometry.distances.point_triangle_distance`), found with a k-d tree of the
triangles' centroids (scipy): the nearest centroid's triangle bounds the distance, and only
triangles whose centroid lies within that bound plus the largest centroid-to-corner reach can
be nearer.
"""
from __future__ import annotations

import numpy as np

from .distances import point_triangle_distance

# The ray's direction, as a rotation taking it to +x: the unit vector (3, 5, 7) / |(3, 5, 7)| turned
# by a further 0.3 rad about itself (no axis, diagonal or simple ratio of one).
_AXIS = np.array([3.0, 5.0, 7.0]) / np.sqrt(83.0)
# points a chunk: the ray tests hold about (points x triangles a cell) pairs at once
_CHUNK = 20_000
# cells a side of the grid across the ray, at most
_MAX_CELLS = 256


def _rotation() -> np.ndarray:
    """(3, 3) the rotation taking ``_AXIS`` to +x (rows: the new axes in old coordinates)."""
    x = _AXIS
    helper = np.array([0.0, 0.0, 1.0])
    y = np.cross(helper, x)
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    c, s = np.cos(0.3), np.sin(0.3)
    return np.stack([x, c * y + s * z, -s * y + c * z])


RAY = _rotation()


def mesh_depths(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(N,) how deep (m) each of ``points`` ((N, 3), m) lies inside the closed mesh of
    ``vertices`` ((V, 3), m) and ``triangles`` ((T, 3) ids): the distance to the mesh for a
    point inside, 0 for a point outside (its distance is not measured)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    vertices = np.asarray(vertices, np.float64).reshape(-1, 3)
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    depth = np.zeros(len(points))
    if len(points) == 0 or len(triangles) == 0:
        return depth
    lo, hi = vertices[triangles].min(axis=(0, 1)), vertices[triangles].max(axis=(0, 1))
    near = np.flatnonzero(np.all((points >= lo) & (points <= hi), axis=1))  # inside lies in the box
    if len(near) == 0:
        return depth
    p = points[near] @ RAY.T
    v = vertices @ RAY.T
    grid = _Grid(v, triangles)
    inside = np.zeros(len(near), bool)
    for start in range(0, len(near), _CHUNK):
        inside[start:start + _CHUNK] = grid.odd_crossings(p[start:start + _CHUNK])
    if inside.any():
        depth[near[inside]] = _distances(points[near[inside]], vertices, triangles)
    return depth


class _Grid:
    """The triangles (rotated so that the ray runs along +x) listed by the cells of a uniform
    grid over the (y, z) plane that their boxes reach."""

    def __init__(self, v: np.ndarray, triangles: np.ndarray):
        self.v, self.triangles = v, triangles
        yz = v[triangles][:, :, 1:]  # (T, 3, 2)
        lo, hi = yz.min(axis=1), yz.max(axis=1)
        self.origin = lo.min(axis=0)
        extent = float((hi.max(axis=0) - self.origin).max())
        # cells about a triangle wide (the median box), no more than _MAX_CELLS a side
        self.cell = max(float(np.median((hi - lo).max(axis=1))), extent / _MAX_CELLS, 1e-12)
        self.dims = np.floor((hi.max(axis=0) - self.origin) / self.cell).astype(np.int64) + 1
        first = self._cell(lo)
        span = self._cell(hi) - first + 1
        counts = span[:, 0] * span[:, 1]
        tri = np.repeat(np.arange(len(triangles)), counts)
        k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)  # k-th cell of its box
        rows = np.repeat(span[:, 1], counts)
        cells = np.repeat(first, counts, axis=0) + np.stack([k // rows, k % rows], axis=1)
        key = cells[:, 0] * self.dims[1] + cells[:, 1]
        order = np.argsort(key, kind="stable")
        self.listed = tri[order]
        self.starts = np.searchsorted(key[order], np.arange(self.dims[0] * self.dims[1] + 1))
        self.lo, self.hi = lo, hi

    def _cell(self, yz: np.ndarray) -> np.ndarray:
        return np.clip(np.floor((yz - self.origin) / self.cell).astype(np.int64), 0, self.dims - 1)

    def odd_crossings(self, p: np.ndarray) -> np.ndarray:
        """(P,) whether the ray from each point (rotated, (P, 3)) along +x crosses an odd number
        of triangles."""
        c = self._cell(p[:, 1:])
        key = c[:, 0] * self.dims[1] + c[:, 1]
        outside = np.any((p[:, 1:] < self.origin) | (p[:, 1:] > self.origin + self.dims * self.cell), axis=1)
        first, last = self.starts[key], self.starts[key + 1]
        counts = np.where(outside, 0, last - first)
        point = np.repeat(np.arange(len(p)), counts)
        k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        tri = self.listed[np.repeat(first, counts) + k]
        q = p[point]
        # the cell's triangles whose box holds the point's (y, z) and reaches beyond it along x
        keep = np.all((self.lo[tri] <= q[:, 1:]) & (q[:, 1:] <= self.hi[tri]), axis=1)
        keep &= self.v[self.triangles[tri]][:, :, 0].max(axis=1) > q[:, 0]
        point, tri, q = point[keep], tri[keep], q[keep]
        crossed = _crosses(q, self.v, self.triangles[tri])
        return np.bincount(point[crossed], minlength=len(p)) % 2 == 1


def _crosses(q: np.ndarray, v: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(P,) whether the ray from q ((P, 3)) along +x meets the triangle of vertex ids
    ``corners`` ((P, 3)), at a point beyond q."""
    sides = []
    for i, j in ((0, 1), (1, 2), (2, 0)):
        u, w = corners[:, i], corners[:, j]
        low, high = np.minimum(u, w), np.maximum(u, w)
        a, b = v[low, 1:] - q[:, 1:], v[high, 1:] - q[:, 1:]
        side = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]  # the same numbers for both triangles of the edge
        # on the edge's line: given to the side of the edge taken from its lower id, for both
        side = np.where(side == 0.0, np.finfo(np.float64).tiny, side)
        sides.append(np.where(u == low, side, -side))
    sides = np.stack(sides, axis=1)  # (P, 3): opposite the corners 2, 0, 1
    meets = np.all(sides > 0, axis=1) | np.all(sides < 0, axis=1)
    weight = sides[:, [1, 2, 0]]  # the barycentric weight of corners 0, 1, 2
    total = weight.sum(axis=1)
    x = np.einsum("pk,pk->p", weight, v[corners][:, :, 0]) / np.where(total != 0.0, total, 1.0)
    return meets & (x > q[:, 0])


def _distances(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(P,) the exact distance (m) of each point to the nearest triangle of the mesh."""
    from scipy.spatial import cKDTree

    corners = vertices[triangles]
    centroid = corners.mean(axis=1)
    reach = float(np.linalg.norm(corners - centroid[:, None], axis=2).max())
    tree = cKDTree(centroid)
    _, nearest = tree.query(points)
    c = corners[nearest]
    bound = point_triangle_distance(points, c[:, 0], c[:, 1], c[:, 2])
    # a triangle nearer than the bound has its centroid within the bound plus its reach
    found = tree.query_ball_point(points, bound + reach)
    counts = np.array([len(f) for f in found])
    point = np.repeat(np.arange(len(points)), counts)
    tri = np.concatenate([np.asarray(f, np.int64) for f in found]) if counts.sum() else np.zeros(0, np.int64)
    c = corners[tri]
    d = point_triangle_distance(points[point], c[:, 0], c[:, 1], c[:, 2])
    out = bound.copy()
    np.minimum.at(out, point, d)
    return out
