"""Which triangles of a mesh intersect each other: an exact check, independent of any solver.

It answers "did the cloth pass through itself (or is it inside itself) in this frame?" from
positions alone, for tests and for anyone checking a saved run (``x_history`` and
``triangles`` in a run's npz). Triangles are closed sets: touching counts as intersecting.
Pairs that share a vertex (neighbours in the mesh) are not checked, as is usual for cloth: they
meet by construction.

Broad phase: a uniform grid of cells (numpy), pairs of triangles whose bounding boxes share a
cell. Narrow phase: orientation signs from :mod:`.predicates`, exact for the given floats, so
nothing is missed or invented by round-off however close the triangles are.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .predicates import orient2d, orient3d


@dataclass
class IntersectionReport:
    """What :func:`self_intersections` found in one frame.

    Attributes:
        pairs: (P, 2) int64 triangle indices (i < j) of the intersecting pairs, sorted.
        candidates: pairs the broad phase passed to the exact test.
        degenerate: (D,) indices of zero-area triangles (collinear corners), left out.
    """

    pairs: np.ndarray
    candidates: int
    degenerate: np.ndarray

    @property
    def count(self) -> int:
        return len(self.pairs)


def self_intersections(x: np.ndarray, triangles: np.ndarray) -> IntersectionReport:
    """Every pair of non-adjacent triangles of one mesh that intersect.

    Args:
        x: (N, 3) vertex positions (m); must be finite.
        triangles: (F, 3) vertex indices; a row with a negative index (a torn triangle) is left
            out.
    Raises:
        ValueError: naming ``x`` or ``triangles`` when shapes, indices or values are unusable.
    """
    x = np.asarray(x, np.float64)
    tris = np.asarray(triangles)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"x must be an (N, 3) array of positions, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("x holds non-finite positions")
    if tris.ndim != 2 or tris.shape[1] != 3 or not np.issubdtype(tris.dtype, np.integer):
        raise ValueError(f"triangles must be an (F, 3) integer array, got {tris.dtype} {tris.shape}")
    if tris.size and tris.max() >= len(x):
        raise ValueError(f"triangles refers to vertex {tris.max()} but x has {len(x)}")
    ids = np.flatnonzero(np.all(tris >= 0, axis=1))
    corners = x[tris[ids].astype(np.int64)]  # (F', 3, 3)
    flat = _degenerate(corners)
    degenerate, ids, corners = ids[flat], ids[~flat], corners[~flat]
    pairs = _broad_phase(corners, tris[ids].astype(np.int64))
    hit = _triangles_intersect(corners[pairs[:, 0]], corners[pairs[:, 1]]) if len(pairs) else np.zeros(0, bool)
    found = np.sort(ids[pairs[hit]], axis=1) if len(pairs) else np.zeros((0, 2), np.int64)
    order = np.lexsort((found[:, 1], found[:, 0])) if len(found) else np.zeros(0, np.int64)
    return IntersectionReport(pairs=found[order].astype(np.int64), candidates=len(pairs),
                              degenerate=degenerate.astype(np.int64))


def _degenerate(corners: np.ndarray) -> np.ndarray:
    """Exactly zero-area triangles: collinear corners in all three coordinate projections."""
    flat = np.ones(len(corners), bool)
    for drop in range(3):
        keep = [k for k in range(3) if k != drop]
        p = corners[:, :, keep]
        flat &= orient2d(p[:, 0], p[:, 1], p[:, 2]) == 0
    return flat


def _broad_phase(corners: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(P, 2) index pairs into ``corners`` whose closed boxes overlap and share no vertex."""
    if len(corners) < 2:
        return np.zeros((0, 2), np.int64)
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    extent = (hi - lo).max(axis=1)
    cell = max(float(np.quantile(extent, 0.9)), 1e-12 * max(1.0, float(np.abs(corners).max())))
    origin = lo.min(axis=0)
    c_lo = np.floor((lo - origin) / cell).astype(np.int64)
    c_hi = np.floor((hi - origin) / cell).astype(np.int64)
    span = c_hi - c_lo + 1
    # A stretched triangle covers many cells; beyond 4^3 of them, coarsen its cells instead.
    span = np.minimum(span, 4)
    c_hi = c_lo + span - 1
    counts = span.prod(axis=1)
    owner = np.repeat(np.arange(len(corners)), counts)
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    sy, sz = span[owner, 1], span[owner, 2]
    offset = np.stack([local // (sy * sz), (local // sz) % sy, local % sz], axis=1)
    cells = c_lo[owner] + offset
    # coarsened triangles: their box may reach past their cells; catch them by also binning the
    # box's far corner cell (a looser but still complete test follows on the boxes themselves)
    wide = np.flatnonzero((np.floor((hi - origin) / cell).astype(np.int64) > c_hi).any(axis=1))
    pairs = [_pairs_sharing_cells(owner, cells)]
    if len(wide):
        others = np.arange(len(corners))
        w = np.repeat(wide, len(others))
        pairs.append(np.stack([w, np.tile(others, len(wide))], axis=1))
    p = np.concatenate(pairs)
    p = p[p[:, 0] != p[:, 1]]
    # each pair once: unique on one int64 key (np.unique on rows sorts them as records, ~8x slower)
    key = np.unique(p.min(axis=1) * len(corners) + p.max(axis=1))
    p = np.stack([key // len(corners), key % len(corners)], axis=1)
    a, b = p[:, 0], p[:, 1]
    boxes = np.all((lo[a] <= hi[b]) & (lo[b] <= hi[a]), axis=1)
    shared = (tris[a][:, :, None] == tris[b][:, None, :]).any(axis=(1, 2))
    return p[boxes & ~shared]


def _pairs_sharing_cells(owner: np.ndarray, cells: np.ndarray) -> np.ndarray:
    key_lo = cells.min(axis=0)
    dims = cells.max(axis=0) - key_lo + 1
    key = np.ravel_multi_index((cells - key_lo).T, dims)
    order = np.argsort(key, kind="stable")
    key, owner = key[order], owner[order]
    out = []
    d = 1
    while d < len(key):
        same = key[:-d] == key[d:]
        if not same.any():
            break
        out.append(np.stack([owner[:-d][same], owner[d:][same]], axis=1))
        d += 1
    return np.concatenate(out) if out else np.zeros((0, 2), np.int64)


def _triangles_intersect(t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """(P,) bool: closed triangles t1[i] and t2[i] ((P, 3, 3) corners, none degenerate) meet."""
    n = len(t1)
    s1 = np.stack([orient3d(t1[:, 0], t1[:, 1], t1[:, 2], t2[:, k]) for k in range(3)], axis=1)
    s2 = np.stack([orient3d(t2[:, 0], t2[:, 1], t2[:, 2], t1[:, k]) for k in range(3)], axis=1)
    apart = (np.all(s1 > 0, axis=1) | np.all(s1 < 0, axis=1) | np.all(s2 > 0, axis=1)
             | np.all(s2 < 0, axis=1))
    coplanar = np.all(s1 == 0, axis=1)
    result = np.zeros(n, bool)
    solid = np.flatnonzero(~apart & ~coplanar)
    if len(solid):
        # Two non-coplanar triangles meet iff an edge of one meets the other.
        hit = np.zeros(len(solid), bool)
        for tri, other, signs in ((t1, t2, s2), (t2, t1, s1)):
            for i, j in ((0, 1), (1, 2), (2, 0)):
                hit |= _segment_meets_triangle(tri[solid, i], tri[solid, j], signs[solid, i],
                                               signs[solid, j], other[solid])
        result[solid] = hit
    flat = np.flatnonzero(~apart & coplanar)
    if len(flat):
        result[flat] = _coplanar_triangles_meet(t1[flat], t2[flat])
    return result


def _segment_meets_triangle(p, q, sp, sq, tri) -> np.ndarray:
    """Closed segment pq meets closed triangle tri, given the signs of p and q against its plane
    (segments lying in the plane are the coplanar case's, not this test's)."""
    crosses = ((sp * sq) <= 0) & ~((sp == 0) & (sq == 0))
    e = [orient3d(p, q, tri[:, k], tri[:, (k + 1) % 3]) for k in range(3)]
    e = np.stack(e, axis=1)
    inside = np.all(e >= 0, axis=1) | np.all(e <= 0, axis=1)
    return crosses & inside


def _coplanar_triangles_meet(t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """Closed coplanar triangles meet: compared in the coordinate plane their normal faces most
    (dropping a coordinate is exact, and keeps every orientation sign up to one flip)."""
    normal = np.cross(t1[:, 1] - t1[:, 0], t1[:, 2] - t1[:, 0])
    drop = np.abs(normal).argmax(axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[drop]
    rows = np.arange(len(t1))[:, None]
    a = np.stack([t1[rows, k, keep] for k in range(3)], axis=1)  # (P, 3, 2)
    b = np.stack([t2[rows, k, keep] for k in range(3)], axis=1)
    hit = np.zeros(len(t1), bool)
    for i in range(3):
        for j in range(3):
            hit |= _segments_meet_2d(a[:, i], a[:, (i + 1) % 3], b[:, j], b[:, (j + 1) % 3])
    hit |= _point_in_triangle_2d(a[:, 0], b) | _point_in_triangle_2d(b[:, 0], a)
    return hit


def _segments_meet_2d(p1, q1, p2, q2) -> np.ndarray:
    o1, o2 = orient2d(p1, q1, p2), orient2d(p1, q1, q2)
    o3, o4 = orient2d(p2, q2, p1), orient2d(p2, q2, q1)
    proper = (o1 * o2 <= 0) & (o3 * o4 <= 0)
    collinear = (o1 == 0) & (o2 == 0)
    # all four collinear: the segments meet iff their extents overlap on both axes
    overlap = np.all((np.minimum(p1, q1) <= np.maximum(p2, q2)) & (np.minimum(p2, q2) <= np.maximum(p1, q1)),
                     axis=1)
    return np.where(collinear, overlap, proper)


def _point_in_triangle_2d(p, tri) -> np.ndarray:
    e = np.stack([orient2d(tri[:, k], tri[:, (k + 1) % 3], p) for k in range(3)], axis=1)
    return np.all(e >= 0, axis=1) | np.all(e <= 0, axis=1)
