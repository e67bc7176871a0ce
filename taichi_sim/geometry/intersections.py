"""Which triangles of a mesh intersect each other: an exact check, independent of any solver.

It answers "did the cloth pass through itself (or is it inside itself) in this frame?" from
positions alone, for tests and for anyone checking a saved run (``x_history`` and
``triangles`` in a run's npz). Triangles are closed sets: touching counts as intersecting.
Pairs that share a vertex (neighbours in the mesh) are not checked, as is usual for cloth: they
meet by construction.

Broad phase: a uniform grid of cells (numpy); each pair of triangles whose bounding boxes share
a cell comes out once, from one cell, and goes on if the closed boxes overlap. Narrow phase:
orientation signs from :mod:`.predicates`, exact for the given floats, so nothing is missed or
invented by round-off however close the triangles are.
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
        candidates: pairs the broad phase passed to the exact test: those whose closed bounding
            boxes overlap and that share no vertex (degenerate and torn triangles left out).
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
    """(P, 2) index pairs (i < j) into ``corners`` whose closed boxes overlap and share no vertex.

    Every such pair and nothing else, each once (so ``candidates`` is their number, whatever the
    grid). Boxes are binned in a uniform grid of cells; a pair is emitted only from the one cell
    holding the componentwise max of the two lower corners, which both boxes cover when they
    overlap: no dedup is needed. Triangles spanning more than ``_MAX_SPAN`` cells along an axis are tested
    against all others instead.
    """
    n = len(corners)
    if n < 2:
        return np.zeros((0, 2), np.int64)
    # column-wise minima and maxima: numpy's reductions over a short axis are several times slower
    lo = np.minimum(np.minimum(corners[:, 0], corners[:, 1]), corners[:, 2])
    hi = np.maximum(np.maximum(corners[:, 0], corners[:, 1]), corners[:, 2])
    origin = lo.min(axis=0)
    with np.errstate(over="ignore"):  # an infinite spread is handled below
        ext = hi - lo
        spread = float((hi.max(axis=0) - origin).max())
    extent = np.maximum(np.maximum(ext[:, 0], ext[:, 1]), ext[:, 2])
    # Cells the size of the median box's longest side: on a folding cloth 0.6x or 1.6x that is
    # slower (larger cells hold more pairs to reject, smaller ones more entries). Never under
    # spread / 2^20, so that each cell coordinate fits 21 bits of one int64 key.
    cell = max(float(np.partition(extent, n // 2)[n // 2]), spread / 2**20)
    a = b = np.zeros(0, np.int64)
    wide = np.ones(n, bool)  # no grid where coordinates are too far apart to subtract
    if np.isfinite(spread) and cell > 0:
        c_lo = np.floor((lo - origin) / cell).astype(np.int64)
        c_hi = np.floor((hi - origin) / cell).astype(np.int64)
        if c_hi.max() < 2**21:  # (subnormal coordinates could round past 2^20)
            span = c_hi - c_lo + 1
            wide = (span > _MAX_SPAN).any(axis=1)
            a, b = _pairs_sharing_cells(np.flatnonzero(~wide), c_lo, span)
    # closed boxes overlap (floor is monotone, so boxes that meet share a cell: none missed)
    for lo_k, hi_k in zip(lo.T.copy(), hi.T.copy()):  # (columns: 1-d gathers are faster)
        keep = (lo_k[a] <= hi_k[b]) & (lo_k[b] <= hi_k[a])
        a, b = a[keep], b[keep]
    if wide.any():
        wa, wb = _pairs_with_wide(lo, hi, wide)
        a, b = np.concatenate([a, wa]), np.concatenate([b, wb])
    ta, tb = tris[a], tris[b]
    shared = np.zeros(len(a), bool)
    for u in range(3):
        for v in range(3):
            shared |= ta[:, u] == tb[:, v]
    a, b = a[~shared], b[~shared]
    return np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)


_MAX_SPAN = 4  # cells along one axis; a triangle spanning more is paired by brute force


def _runs(counts: np.ndarray) -> np.ndarray:
    """0, 1, ..., c - 1 for each c of ``counts``, concatenated."""
    return np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)


def _pairs_sharing_cells(ids: np.ndarray, c_lo: np.ndarray, span: np.ndarray):
    """(a, b): pairs of ``ids`` whose cell ranges (``c_lo`` to ``c_lo + span - 1``) overlap,
    each once, from the cell that is the componentwise max of their lower cells."""
    sp = span[ids]
    counts = sp[:, 0] * sp[:, 1] * sp[:, 2]
    owner = np.repeat(ids, counts)
    sy, sz = np.repeat(sp[:, 1], counts), np.repeat(sp[:, 2], counts)
    ox, rest = np.divmod(_runs(counts), sy * sz)
    oy, oz = np.divmod(rest, sz)
    cl = c_lo[owner]
    key = ((cl[:, 0] + ox) << 42) | ((cl[:, 1] + oy) << 21) | (cl[:, 2] + oz)
    # tag: the triangle << 3, with bit k set where this cell is the triangle's lowest along axis
    # k. A cell that both of two triangles cover is the max of their lower cells iff on each
    # axis it is the lower cell of one of them: the pair is kept from that cell alone.
    tag = (owner << 3) | (ox == 0) | ((oy == 0) << 1) | ((oz == 0) << 2)
    order = np.argsort(key)
    key, tag = key[order], tag[order]
    # every pair of entries within a run of equal keys: entry i with i + 1, ..., its run's end - 1
    bounds = np.concatenate([[0], np.flatnonzero(key[1:] != key[:-1]) + 1, [len(key)]])
    after = np.repeat(bounds[1:], np.diff(bounds)) - np.arange(len(key)) - 1
    ti = np.repeat(tag, after)
    tj = tag[np.repeat(np.arange(1, len(key) + 1), after) + _runs(after)]
    own = ((ti | tj) & 7) == 7
    return ti[own] >> 3, tj[own] >> 3


def _pairs_with_wide(lo: np.ndarray, hi: np.ndarray, wide: np.ndarray):
    """(a, b): pairs with at least one ``wide`` triangle whose closed boxes overlap, each once
    (a wide one against every narrow one and every later wide one), in blocks of bounded size."""
    n = len(lo)
    wide_ids = np.flatnonzero(wide)
    out_a, out_b = [], []
    step = max(1, 2**22 // n)
    for s in range(0, len(wide_ids), step):
        w = wide_ids[s:s + step]
        meet = np.ones((len(w), n), bool)
        for k in range(3):
            meet &= (lo[w, k][:, None] <= hi[None, :, k]) & (lo[None, :, k] <= hi[w, k][:, None])
        meet &= ~wide[None, :] | (np.arange(n)[None, :] > w[:, None])
        r, c = np.nonzero(meet)
        out_a.append(w[r])
        out_b.append(c)
    return np.concatenate(out_a), np.concatenate(out_b)


def _triangles_intersect(t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """(P,) bool: closed triangles t1[i] and t2[i] ((P, 3, 3) corners, none degenerate) meet.

    Each test runs only on the pairs that earlier ones left open (most candidates are apart by
    the first plane's signs): the predicates are row by row, so the answers are the same.
    """
    n = len(t1)
    result = np.zeros(n, bool)
    s1 = np.stack([orient3d(t1[:, 0], t1[:, 1], t1[:, 2], t2[:, k]) for k in range(3)], axis=1)
    open_ = np.flatnonzero(~(np.all(s1 > 0, axis=1) | np.all(s1 < 0, axis=1)))
    if not len(open_):
        return result
    u1, u2, s1 = t1[open_], t2[open_], s1[open_]
    s2 = np.stack([orient3d(u2[:, 0], u2[:, 1], u2[:, 2], u1[:, k]) for k in range(3)], axis=1)
    apart = np.all(s2 > 0, axis=1) | np.all(s2 < 0, axis=1)
    coplanar = np.all(s1 == 0, axis=1)
    solid = np.flatnonzero(~apart & ~coplanar)
    if len(solid):
        # Two non-coplanar triangles meet iff an edge of one meets the other: the six edges'
        # tests in one batch, only for the edges that reach the other's plane.
        rows, tests = [], []
        for tri, other, signs in ((u1, u2, s2), (u2, u1, s1)):
            for i, j in ((0, 1), (1, 2), (2, 0)):
                si, sj = signs[solid, i], signs[solid, j]
                r = np.flatnonzero((si * sj <= 0) & ~((si == 0) & (sj == 0)))  # reaches the plane
                t = solid[r]
                rows.append(r)
                tests.append((tri[t, i], tri[t, j], other[t]))
        hit = np.zeros(len(solid), bool)
        meets = _crossing_segment_meets_triangle(*(np.concatenate(column) for column in zip(*tests)))
        hit[np.concatenate(rows)[meets]] = True
        result[open_[solid]] = hit
    flat = np.flatnonzero(~apart & coplanar)
    if len(flat):
        result[open_[flat]] = _coplanar_triangles_meet(u1[flat], u2[flat])
    return result


def _crossing_segment_meets_triangle(p, q, tri) -> np.ndarray:
    """Closed segment pq, which reaches the plane of closed triangle tri without lying in it (its
    ends' signs against the plane differ or one is zero: the caller's test), meets tri."""
    e = [orient3d(p, q, tri[:, k], tri[:, (k + 1) % 3]) for k in range(3)]
    e = np.stack(e, axis=1)
    return np.all(e >= 0, axis=1) | np.all(e <= 0, axis=1)


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
