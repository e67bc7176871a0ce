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
