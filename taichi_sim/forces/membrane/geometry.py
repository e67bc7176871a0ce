"""The rest shape of a triangle membrane, in numpy (built once, never in a step): each
triangle flattened to its own 2D frame, vertex masses from areas, the bending stencils of the
interior edges, and a bound on the highest frequency for an explicit step."""
from __future__ import annotations

import numpy as np

from ...errors import ConfigError

#: A rest triangle whose area is below this share of its longest edge squared counts as zero.
DEGENERATE_SHARE = 1e-10


def rest_frames(x, triangles) -> tuple[np.ndarray, np.ndarray]:
    """Each triangle's rest shape in a 2D frame of its own.

    For triangle (a, b, c) with edges e1 = x_b - x_a, e2 = x_c - x_a, the frame's first axis
    is e1 and its second lies in the triangle's plane, so Dm = [[|e1|, e2.u], [0, e2.w]]
    (2x2, m) holds the edges as columns and F = Ds Dm^-1 (3x2, Ds = [x_b - x_a, x_c - x_a])
    is an isometry at rest whatever the triangle's place or turn in 3D: a curved mesh rests
    flattened triangle by triangle.

    Args:
        x: (n, 3) rest positions (m).
        triangles: (T, 3) vertex ids.

    Returns:
        inverse: (T, 2, 2) Dm^-1 (1/m).
        area: (T,) rest area (m^2).

    Raises ConfigError naming the first triangle with a non-finite vertex or zero area.
    """
    x = np.asarray(x, float)
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    corners = x[triangles]  # (T, 3, 3)
    bad = ~np.isfinite(corners).all(axis=(1, 2))
    if bad.any():
        t = int(np.flatnonzero(bad)[0])
        raise ConfigError(f"membrane: triangle {t} (vertices {triangles[t].tolist()}) has a non-finite rest position")
    e1 = corners[:, 1] - corners[:, 0]
    e2 = corners[:, 2] - corners[:, 0]
    normal = np.cross(e1, e2)
    double_area = np.linalg.norm(normal, axis=1)
    longest2 = np.max([np.einsum("ij,ij->i", e, e) for e in (e1, e2, e2 - e1)], axis=0)
    flat = ~(double_area > DEGENERATE_SHARE * longest2)
    if flat.any():
        t = int(np.flatnonzero(flat)[0])
        raise ConfigError(f"membrane: rest triangle {t} (vertices {triangles[t].tolist()}) has zero area; "
                          f"{int(flat.sum())} such triangle(s): remove them or weld their vertices")
    length1 = np.linalg.norm(e1, axis=1)
    u = e1 / length1[:, None]
    w = np.cross(normal / double_area[:, None], u)
    dm = np.zeros((len(triangles), 2, 2))
    dm[:, 0, 0] = length1
    dm[:, 0, 1] = np.einsum("ij,ij->i", e2, u)
    dm[:, 1, 1] = np.einsum("ij,ij->i", e2, w)
    return np.linalg.inv(dm), 0.5 * double_area


def shape_gradients(inverse) -> np.ndarray:
    """(T, 3, 2) each triangle's shape gradients g_a (1/m), vertex a's row: F = sum_a x_a g_a^T
    for the rest frames' Dm^-1 ``inverse`` (T, 2, 2) of :func:`rest_frames`; g_0 = -g_1 - g_2."""
    inverse = np.asarray(inverse, float)
    g = np.empty((len(inverse), 3, 2))
    g[:, 1], g[:, 2] = inverse[:, 0, :], inverse[:, 1, :]
    g[:, 0] = -g[:, 1] - g[:, 2]
    return g


def lumped_masses(particle_count: int, triangles, area, density: float) -> np.ndarray:
    """(n,) mass (kg) of each vertex: a third of each of its triangles' ``area`` (m^2) times the
    area ``density`` (kg/m^2); they sum to density times the total area. A vertex in no
    triangle gets 0."""
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    share = np.repeat(density * np.asarray(area, float) / 3.0, 3)
    return np.bincount(triangles.ravel(), share, minlength=particle_count)


def _cot(a, b):
    """Cotangent of the angle between the rows of a and b."""
    return np.einsum("ij,ij->i", a, b) / np.linalg.norm(np.cross(a, b), axis=1)


def bending_stencils(x, triangles) -> tuple[np.ndarray, np.ndarray]:
    """The quadratic bending model's stencil on every interior edge (Bergou et al. 2006).

    For an edge (x0, x1) shared by triangles (x0, x1, x2) and (x0, x1, x3), the discrete
    mean-curvature vector across it is sum_k K_k x_k with the cotangent weights
    K = (c03 + c04, c01 + c02, -c01 - c03, -c02 - c04) of the rest angles (c01, c02 at x0,
    c03, c04 at x1, in the first and second triangle); it vanishes on any flat shape and on
    rigid motions. The edge's energy is (D/2) |sum_k K_k x_k|^2 / (A0 + A1) for a bending
    stiffness D (N m). Bergou et al. scale by 3 / (A0 + A1); with 1 / (A0 + A1) a grid cloth
    rolled into a cylinder of curvature k about either grid axis stores (D/2) k^2 per m^2, a
    plate's energy (measured: tests/test_membrane.py; across the cells' diagonals about three
    times as much, the per-edge model's anisotropy on that mesh).

    Args:
        x: (n, 3) rest positions (m); the rest shape is taken as flat, whatever x's curvature.
        triangles: (T, 3) vertex ids.

    Returns:
        vertices: (B, 4) int64 (x0, x1, x2, x3) of each interior edge shared by exactly two
            triangles (non-manifold edges get none).
        weights: (B, 4) float64 K / sqrt(A0 + A1) (1/m): the edge's energy is
            (D/2) |sum_k weights_k x_k|^2.
    """
    x = np.asarray(x, float)
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    edges = triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    opposite = triangles[:, [2, 0, 1]].reshape(-1)
    key = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    interior = np.flatnonzero(counts[inverse] == 2)
    order = interior[np.argsort(inverse[interior], kind="stable")].reshape(-1, 2)
    if len(order) == 0:
        return np.zeros((0, 4), np.int64), np.zeros((0, 4))
    first, second = order[:, 0], order[:, 1]
    v0, v1 = edges[first, 0], edges[first, 1]
    v2, v3 = opposite[first], opposite[second]
    keep = v2 != v3
    v0, v1, v2, v3 = v0[keep], v1[keep], v2[keep], v3[keep]
    e0, e1, e2 = x[v1] - x[v0], x[v2] - x[v0], x[v3] - x[v0]
    e3, e4 = x[v2] - x[v1], x[v3] - x[v1]
    c01, c02 = _cot(e0, e1), _cot(e0, e2)
    c03, c04 = _cot(-e0, e3), _cot(-e0, e4)
    area = 0.5 * (np.linalg.norm(np.cross(e0, e1), axis=1) + np.linalg.norm(np.cross(e0, e2), axis=1))
    k = np.stack([c03 + c04, c01 + c02, -c01 - c03, -c02 - c04], axis=1)
    return np.stack([v0, v1, v2, v3], axis=1), k / np.sqrt(area)[:, None]


def omega_max_bound(mass, pinned, triangles, inverse, area, mu: float, lam: float,
                    stencil_vertices=None, stencil_weights=None, bending: float = 0.0) -> float:
    """An upper bound (rad/s) on the highest frequency of the membrane (and bending) near rest:
    Gershgorin's bound on M^-1 K over the free vertices, with the element stiffness at rest
    bounded blockwise by |K_ab| <= A (2 mu + |lambda|) |g_a| |g_b| (g_a the gradient of vertex
    a's shape function, 1/m) and the bending's by D |w_a| |w_b|."""
    mass = np.asarray(mass, float)
    n = len(mass)
    row = np.zeros(n)
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    if len(triangles):
        size = np.linalg.norm(shape_gradients(inverse), axis=2)  # (T, 3)
        per = (np.asarray(area) * (2 * mu + abs(lam)))[:, None] * size * size.sum(axis=1, keepdims=True)
        row += np.bincount(triangles.ravel(), per.ravel(), minlength=n)
    if bending > 0 and stencil_vertices is not None and len(stencil_vertices):
        w = np.abs(stencil_weights)
        per = bending * w * w.sum(axis=1, keepdims=True)
        row += np.bincount(np.asarray(stencil_vertices).ravel(), per.ravel(), minlength=n)
    free = ~np.asarray(pinned, bool)
    if not free.any():
        return 0.0
    return float(np.sqrt(np.max(row[free] / mass[free])))
