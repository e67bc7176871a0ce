"""What the self-contact stage needs of its input mesh, checked once before anything is allocated.

The stage keeps every vertex ``thickness`` away from the triangles it is not a corner of, and
every edge that far from the edges it shares no vertex with. So a mesh that, as built, already
has such a pair closer than the thickness would be pushed apart at rest: the cloth would inflate
or buckle before anything touched it. Coincident vertices are the limit of that (distance 0),
and a triangle of zero area has no normal for a contact to push along. :func:`check_contact_mesh`
refuses all of these with a :class:`~taichi_sim.errors.ConfigError` (a ValueError) that names the
parameter and the limit; it does not clamp the thickness, since a silently thinner cloth would
let layers come closer than the user asked for, which is a different simulation.

The distances are exact closest distances between primitives (numpy, float64), found through a
uniform grid of boxes grown by the thickness, so only pairs that could be closer than it are
measured: the check costs about as much as one broad phase.

A thickness nobody chose is different: :func:`contact_thickness` with ``fit`` takes one that fits
the mesh, ``FIT_SHARE`` of that smallest distance (so the resting cloth keeps a margin of the
same size to its contacts), no more than the thickness asked for (the scene's default) and no
less than ``THICKNESS_FLOOR``. A mesh cloth whose user gave no thickness runs with it
(docs/meshes.md).
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError
from ..geometry.distances import point_triangle_distance as _point_triangle_distance
from ..geometry.distances import segment_distance as _segment_distance
from ..geometry.intersections import self_intersections

#: The share of the rest shape's smallest distance between non-adjacent parts that a fitted
#: thickness takes: half, so that the cloth at rest is as far from its contacts as they are thick.
FIT_SHARE = 0.5
#: m: the thinnest thickness fitted without being asked. The stage decides a touch at a
#: thousandth of the thickness (its ``delta``), and f32 holds a vertex a metre from the origin to
#: about 1e-7 m: below half a millimetre that decision nears round-off. A mesh whose parts come
#: closer than this at rest needs a thickness given by hand (or a coarser or cleaner mesh).
THICKNESS_FLOOR = 5e-4


def check_contact_mesh(x0: np.ndarray, triangles: np.ndarray, thickness: float, *,
                       rest: np.ndarray | None = None, name: str = "thickness") -> float:
    """Check that the self-contact stage can run on this mesh as built.

    Args:
        x0: (N, 3) positions (m) the cloth starts from.
        triangles: (F, 3) vertex ids (a row with a negative id, a torn triangle, is left out).
        thickness: the distance (m) the stage keeps between non-adjacent primitives.
        rest: (N, 3) positions (m) of the shape the cloth rests in (default ``x0``; a builder
            passes the grid before its seeded jitter).
    Returns:
        The smallest distance (m) in ``rest`` between a vertex and a triangle it is not a
        corner of, or between two edges sharing no vertex, over the pairs whose boxes, grown by
        ``thickness``, overlap (so exact whenever it is below ``thickness``, which is refused);
        inf when no pair comes that near. On return it is always above ``thickness``.
    Raises:
        ConfigError (a ValueError): naming ``thickness`` when it is not a finite number > 0 or is
        at least that smallest distance (with the limit); naming ``triangles`` for a triangle
        with a repeated vertex or of zero area; naming ``x`` for non-finite positions or for
        non-adjacent parts that touch at the start (coincident points) or a start whose
        triangles intersect.
    """
    return contact_thickness(x0, triangles, thickness, rest=rest, name=name)[1]


def contact_thickness(x0: np.ndarray, triangles: np.ndarray, thickness: float, *,
                      rest: np.ndarray | None = None, fit: bool = False,
                      name: str = "thickness") -> tuple[float, float]:
    """The thickness (m) the self-contact stage runs this mesh with, checked as
    :func:`check_contact_mesh` checks one.

    Args:
        x0, triangles, rest, name: as for :func:`check_contact_mesh`.
        thickness: the distance (m) asked for; with ``fit``, the most that is taken.
        fit: take ``FIT_SHARE`` of the rest shape's smallest distance between non-adjacent parts
            where that is less than ``thickness``, and no less than ``THICKNESS_FLOOR`` (for a
            thickness the user did not give: the scene's default as the ceiling).
    Returns:
        (the thickness taken (m): ``thickness`` itself without ``fit``; the smallest distance
        (m) as :func:`check_contact_mesh` returns it, exact whenever the fitted thickness was
        decided by it).
    Raises:
        ConfigError (a ValueError): as :func:`check_contact_mesh`; with ``fit``, naming ``name``
        when the rest shape's parts come within ``THICKNESS_FLOOR`` of each other.
    """
    if isinstance(thickness, bool) or not isinstance(thickness, (int, float, np.floating)) \
            or not np.isfinite(thickness) or thickness <= 0:
        raise ConfigError(f"{name} must be a finite number > 0 (m), got {thickness!r}")
    thickness = float(thickness)
    x = _positions(x0)
    rest = x if rest is None else _positions(rest)
    if rest.shape != x.shape:
        raise ConfigError(f"x: rest positions {rest.shape} and start positions {x.shape} differ in shape")
    tris = np.asarray(triangles, np.int64).reshape(-1, 3)
    tris = tris[np.all(tris >= 0, axis=1)]
    if len(tris) == 0:
        return thickness, np.inf
    if tris.max() >= len(x):
        raise ConfigError(f"triangles refers to vertex {tris.max()} but there are {len(x)} particles")
    repeated = np.flatnonzero((tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2]))
    if len(repeated):
        k = int(repeated[0])
        raise ConfigError(f"triangles: triangle {k} {tris[k].tolist()} repeats a vertex "
                          f"({len(repeated)} such triangle(s)); self_collision needs proper triangles")
    edges = _edges(tris)
    for shape in (x, rest) if rest is not x else (x,):
        _refuse_flat(shape, tris)
    # coincident points at the start: no direction to push them apart along
    scale = float(np.median(np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)))
    tiny = 1e-9 * scale
    if min(_vertex_triangle(x, tris, tiny), _edge_edge(x, edges, tiny)) <= tiny:
        raise ConfigError("x: non-adjacent parts of the cloth touch as built (coincident particles?); "
                          "self_collision needs a start free of contact")
    # a start that already crosses itself (a jitter large against the spacing, a mesh file that
    # passes through itself): contact would keep those crossings for the whole run
    crossing = self_intersections(x, tris).count
    if crossing:
        raise ConfigError(f"x: the cloth starts passing through itself ({crossing} pair(s) of intersecting "
                          f"triangles; a jitter too large for the spacing?); contact keeps a start's "
                          f"crossings, it cannot undo them")
    # fitting, the distance must be exact up to the ceiling over the share: the pairs measured
    # are those whose boxes, grown by the reach, overlap
    reach = thickness / FIT_SHARE if fit else thickness
    smallest = min(_vertex_triangle(rest, tris, reach), _edge_edge(rest, edges, reach))
    if fit:
        if smallest <= THICKNESS_FLOOR:
            raise ConfigError(f"{name}: non-adjacent parts of the cloth come within {smallest:.6g} m of each other "
                              f"at rest, closer than the thinnest {name} taken without being asked "
                              f"({THICKNESS_FLOOR:g} m); give a {name} below {smallest:.6g} m, or weld or "
                              f"coarsen the mesh")
        thickness = min(thickness, max(THICKNESS_FLOOR, FIT_SHARE * smallest))
    if smallest <= thickness:
        raise ConfigError(f"{name} {thickness:g} m must be below {smallest:.6g} m, the smallest distance "
                          f"between non-adjacent parts of the cloth at rest (contacts closer than the {name} "
                          f"would push the resting cloth apart); use a smaller {name} or a coarser grid")
    return thickness, smallest


def _positions(x) -> np.ndarray:
    x = np.asarray(x, np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ConfigError(f"x must be an (N, 3) array of positions, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ConfigError(f"x: {int((~np.isfinite(x)).any(axis=1).sum())} particle(s) have non-finite positions")
    return x


def _refuse_flat(x: np.ndarray, tris: np.ndarray) -> None:
    corners = x[tris]
    doubled_area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    # zero area up to round-off: the height over the longest side is below 1e-9 of that side
    flat = np.flatnonzero(doubled_area <= 1e-9 * longest**2)
    if len(flat):
        k = int(flat[0])
        raise ConfigError(f"triangles: triangle {k} {tris[k].tolist()} has zero area as built (its corners "
                          f"coincide or are collinear; {len(flat)} such triangle(s)); self_collision needs "
                          f"triangles with a normal")


def _edges(tris: np.ndarray) -> np.ndarray:
    both = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    return np.unique(np.sort(both, axis=1), axis=0)


def _box_pairs(lo_a, hi_a, lo_b, hi_b, cell: float) -> np.ndarray:
    """(P, 2) ids (a, b) whose closed boxes overlap, each pair once; every box spans at most 2
    cells per axis."""
    origin = np.minimum(lo_a.min(axis=0), lo_b.min(axis=0))

    def cells(lo, hi):
        c_lo = np.floor((lo - origin) / cell).astype(np.int64)
        span = np.minimum(np.floor((hi - origin) / cell).astype(np.int64) - c_lo + 1, 2)
        out_id, out_cell = [], []
        for dx in range(2):
            for dy in range(2):
                for dz in range(2):
                    use = (dx < span[:, 0]) & (dy < span[:, 1]) & (dz < span[:, 2])
                    out_id.append(np.flatnonzero(use))
                    out_cell.append(c_lo[use] + np.array([dx, dy, dz]))
        return np.concatenate(out_id), np.concatenate(out_cell), c_lo, c_lo + span - 1

    id_a, cell_a, first_a, last_a = cells(lo_a, hi_a)
    id_b, cell_b, first_b, last_b = cells(lo_b, hi_b)
    key_lo = np.minimum(cell_a.min(axis=0), cell_b.min(axis=0))
    dims = np.maximum(cell_a.max(axis=0), cell_b.max(axis=0)) - key_lo + 1
    key_a = np.ravel_multi_index((cell_a - key_lo).T, dims)
    key_b = np.ravel_multi_index((cell_b - key_lo).T, dims)
    order = np.argsort(key_b, kind="stable")
    key_b, id_b = key_b[order], id_b[order]
    start, stop = np.searchsorted(key_b, key_a, "left"), np.searchsorted(key_b, key_a, "right")
    counts = stop - start
    a = np.repeat(id_a, counts)
    b = id_b[np.repeat(start, counts) + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)]
    key = np.repeat(key_a, counts)
    keep = np.all((lo_a[a] <= hi_b[b]) & (lo_b[b] <= hi_a[a]), axis=1)
    a, b, key = a[keep], b[keep], key[keep]
    # A pair met in several shared cells is kept in one: the cell of its overlap's lowest corner
    # (within both boxes' cells), so nothing needs sorting out afterwards.
    corner = np.floor((np.maximum(lo_a[a], lo_b[b]) - origin) / cell).astype(np.int64)
    corner = np.clip(corner, np.maximum(first_a[a], first_b[b]), np.minimum(last_a[a], last_b[b]))
    once = np.ravel_multi_index((corner - key_lo).T, dims) == key
    return np.stack([a[once], b[once]], axis=1)


def _vertex_triangle(x: np.ndarray, tris: np.ndarray, reach: float) -> float:
    corners = x[tris]
    lo, hi = corners.min(axis=1) - reach, corners.max(axis=1) + reach
    cell = max(float((hi - lo).max()), 1e-12)
    pairs = _box_pairs(x, x, lo, hi, cell)
    pairs = pairs[~(tris[pairs[:, 1]] == pairs[:, [0]]).any(axis=1)]
    if len(pairs) == 0:
        return np.inf
    c = corners[pairs[:, 1]]
    return float(_point_triangle_distance(x[pairs[:, 0]], c[:, 0], c[:, 1], c[:, 2]).min())


def _edge_edge(x: np.ndarray, edges: np.ndarray, reach: float) -> float:
    ends = x[edges]
    lo, hi = ends.min(axis=1) - 0.5 * reach, ends.max(axis=1) + 0.5 * reach
    cell = max(float((hi - lo).max()), 1e-12)
    pairs = _box_pairs(lo, hi, lo, hi, cell)
    pairs = pairs[pairs[:, 0] < pairs[:, 1]]
    e, f = edges[pairs[:, 0]], edges[pairs[:, 1]]
    pairs = pairs[(e[:, :, None] != f[:, None, :]).all(axis=(1, 2))]
    if len(pairs) == 0:
        return np.inf
    a, b = ends[pairs[:, 0]], ends[pairs[:, 1]]
    return float(_segment_distance(a[:, 0], a[:, 1], b[:, 0], b[:, 1]).min())
