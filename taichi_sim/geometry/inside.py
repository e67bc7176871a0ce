"""What `check` and the start warning measure points and faces against objects with (numpy):
the tolerances and the points sampled on each triangle. Each collider kind measures how deep a
point lies inside its objects in its own file, from the npz's keys
(:class:`~taichi_sim.scene.colliders.shape.Shape`); the loops over the kinds are
:mod:`taichi_sim.scene.colliders.shape`'s.
"""
from __future__ import annotations

import numpy as np

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


def face_samples(x: np.ndarray, triangles: np.ndarray, divisions: int = FACE_DIVISIONS) -> np.ndarray:
    """(T, P, 3) points on each triangle ((T, 3) ids into ``x``, (n, 3) m): the barycentric grid
    of ``divisions`` steps a side, less the corners (P = (d + 1)(d + 2)/2 - 3)."""
    steps = np.arange(divisions + 1)
    grid = np.array([(i, j, divisions - i - j) for i in steps for j in steps if i + j <= divisions], float)
    grid = grid[(grid == divisions).sum(axis=1) == 0] / divisions  # the corners are the vertices' test
    return np.einsum("pk,tkd->tpd", grid, np.asarray(x, np.float64)[np.asarray(triangles)])
