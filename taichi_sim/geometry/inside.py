"""Which points lie inside a scene's objects: numpy, from the npz's object keys alone.

The objects are described as a run's npz (and :attr:`Scene.arrays`) describes them:
``sphere_center`` (K, 3) and ``sphere_radius`` (K,); ``capsule_center``, ``capsule_radius`` and
``capsule_half_axis`` (K, 3: centre to end-cap centre); ``box_center`` and
``box_half_extents`` (K, 3, axis-aligned); ``plane_point`` and ``plane_normal`` (3,: the side
the normal points to is outside). A point counts as inside when it is deeper than
``tolerance`` (m), so a vertex resting on a surface is not counted. A collider mesh is not
checked (its inside is not defined for an open mesh).
"""
from __future__ import annotations

import numpy as np

KINDS = ("sphere", "capsule", "box", "plane")
# m: the depth below which a point does not count as inside. A vertex resting on a surface in
# f32 rounds to within about 1e-7 m of it at a metre from the origin.
INSIDE_TOLERANCE = 1e-6
# Points a side of the grid of points :func:`face_samples` puts on a triangle (25 points inside
# it and on its edges, the corners left out).
FACE_DIVISIONS = 6
# A face point counts as inside an object deeper than this share of the object's thinnest size.
# The objects' face pass lets a face resting on a curved surface dip 0.5 % in (its
# ALLOWED_OVERLAP); an object that passes between the vertices goes in by its whole size.
FACE_SHARE = 0.01


def inside_objects(x: np.ndarray, arrays: dict, tolerance: float = INSIDE_TOLERANCE) -> dict[str, np.ndarray]:
    """Object kind -> (N,) bool mask of the points ``x`` ((N, 3), m) inside any object of that
    kind; only the kinds ``arrays`` has."""
    x = np.asarray(x, np.float64).reshape(-1, 3)
    out = {}
    if "sphere_center" in arrays:
        centers, radii = _rows(arrays["sphere_center"]), np.ravel(arrays["sphere_radius"])
        out["sphere"] = _any(np.linalg.norm(x[:, None] - centers[None], axis=2) < radii[None] - tolerance)
    if "capsule_center" in arrays:
        centers, half = _rows(arrays["capsule_center"]), _rows(arrays["capsule_half_axis"])
        radii = np.ravel(arrays["capsule_radius"])
        depth = np.stack([_segment_distance(x, c - h, c + h) for c, h in zip(centers, half)], axis=1)
        out["capsule"] = _any(depth < radii[None] - tolerance)
    if "box_center" in arrays:
        centers, half = _rows(arrays["box_center"]), _rows(arrays["box_half_extents"])
        offset = np.abs(x[:, None] - centers[None])
        out["box"] = _any(np.all(offset < half[None] - tolerance, axis=2))
    if "plane_point" in arrays:
        point, normal = np.ravel(arrays["plane_point"]), np.ravel(arrays["plane_normal"])
        out["plane"] = (x - point) @ (normal / np.linalg.norm(normal)) < -tolerance
    return out


def _rows(a) -> np.ndarray:
    return np.asarray(a, np.float64).reshape(-1, 3)


def _any(mask: np.ndarray) -> np.ndarray:
    return mask.any(axis=1) if mask.shape[1] else np.zeros(len(mask), bool)


def _segment_distance(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) distance of each point from the segment ab."""
    ab = b - a
    length2 = float(ab @ ab)
    s = np.zeros(len(x)) if length2 == 0 else np.clip((x - a) @ ab / length2, 0.0, 1.0)
    return np.linalg.norm(x - (a + s[:, None] * ab), axis=1)


def object_depths(x: np.ndarray, arrays: dict) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Object kind -> ((N, K) how deep each point of ``x`` ((N, 3), m) lies inside each object of
    that kind (m; negative outside: minus the distance), (K,) each object's thinnest size (m):
    a sphere's or capsule's radius, a box's least half extent); spheres, capsules and boxes
    only (a flat plane is entered by a face only where a corner enters it)."""
    x = np.asarray(x, np.float64).reshape(-1, 3)
    out = {}
    if "sphere_center" in arrays:
        centers, radii = _rows(arrays["sphere_center"]), np.ravel(arrays["sphere_radius"]).astype(np.float64)
        out["sphere"] = (radii[None] - np.linalg.norm(x[:, None] - centers[None], axis=2), radii)
    if "capsule_center" in arrays:
        centers, half = _rows(arrays["capsule_center"]), _rows(arrays["capsule_half_axis"])
        radii = np.ravel(arrays["capsule_radius"]).astype(np.float64)
        distance = np.stack([_segment_distance(x, c - h, c + h) for c, h in zip(centers, half)], axis=1)
        out["capsule"] = (radii[None] - distance.reshape(len(x), len(radii)), radii)
    if "box_center" in arrays:
        centers, half = _rows(arrays["box_center"]), _rows(arrays["box_half_extents"])
        over = np.abs(x[:, None] - centers[None]) - half[None]
        outside = np.linalg.norm(np.maximum(over, 0.0), axis=2)
        inside = np.minimum(over.max(axis=2), 0.0)
        out["box"] = (-(outside + inside), half.min(axis=1))
    return out


def face_samples(x: np.ndarray, triangles: np.ndarray, divisions: int = FACE_DIVISIONS) -> np.ndarray:
    """(T, P, 3) points on each triangle ((T, 3) ids into ``x``, (n, 3) m): the barycentric grid
    of ``divisions`` steps a side, less the corners (P = (d + 1)(d + 2)/2 - 3)."""
    steps = np.arange(divisions + 1)
    grid = np.array([(i, j, divisions - i - j) for i in steps for j in steps if i + j <= divisions], float)
    grid = grid[(grid == divisions).sum(axis=1) == 0] / divisions  # the corners are the vertices' test
    return np.einsum("pk,tkd->tpd", grid, np.asarray(x, np.float64)[np.asarray(triangles)])


def face_depths(x: np.ndarray, triangles: np.ndarray, arrays: dict) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Object kind -> ((T,) share, (T,) depth in m): for each triangle ((T, 3) ids into ``x``,
    (n, 3) m), how deep the deepest point of :func:`face_samples` lies inside an object of that
    kind, as a share of that object's thinnest size and in metres (0 outside them all);
    spheres, capsules and boxes that ``arrays`` has at least one of."""
    triangles = np.asarray(triangles).reshape(-1, 3)
    points = face_samples(x, triangles)
    out = {}
    rows = np.arange(len(triangles))
    for kind, (depth, thinnest) in object_depths(points.reshape(-1, 3), arrays).items():
        if depth.shape[1] == 0:
            continue  # no object of this kind
        # (T, P x K): every sample point of a triangle against every object of the kind
        share = (depth / thinnest[None]).reshape(len(triangles), -1)
        deepest = np.argmax(share, axis=1)
        out[kind] = (np.maximum(share[rows, deepest], 0.0),
                     np.maximum(depth.reshape(len(triangles), -1)[rows, deepest], 0.0))
    return out


def faces_inside(x: np.ndarray, triangles: np.ndarray, arrays: dict, share: float = FACE_SHARE) -> dict[str, np.ndarray]:
    """Object kind -> (T,) bool mask of the triangles ((T, 3) ids into ``x``, (n, 3) m) with a
    point of :func:`face_samples` deeper inside an object of that kind than ``share`` of the
    object's thinnest size; spheres, capsules and boxes that ``arrays`` has."""
    return {kind: shares > share for kind, (shares, _) in face_depths(x, triangles, arrays).items()}
