"""The rest geometry of hinge bending, in numpy (built once, never in a step): the interior
edges as hinges with their rest dihedral angles, and the stiffness each bending element puts
on its hinges' angles: one hinge alone (``dihedral``, discrete shells) or a triangle's three
(``shape_operator``, a curvature tensor per triangle). docs/materials.md, "Bending"."""
from __future__ import annotations

import numpy as np

from ...errors import ConfigError

BENDING_MODELS = ("isometric", "dihedral", "shape_operator")

#: A length or area below this share of the hinge's scale is taken as zero (no division by it).
_TINY = 1e-30


def check_bending_model(value) -> str:
    """One of :data:`BENDING_MODELS`, else ConfigError naming the parameter."""
    if value not in BENDING_MODELS:
        raise ConfigError(f"parameter bending_model: must be one of {', '.join(BENDING_MODELS)}, got {value!r}")
    return value


def hinge_topology(triangles) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The interior edges shared by exactly two triangles, as hinges.

    Returns:
        vertices: (H, 4) int64 (x0, x1, x2, x3): the edge x0 -> x1 as the first triangle
            runs it, x2 the first triangle's vertex opposite it, x3 the second's.
        faces: (H, 2) int64 the two triangles.
        face_hinges: (T, 3) int64 the hinge on each triangle's edge k (its vertices k, k+1),
            -1 on a boundary (or non-manifold) edge.
    """
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    edges = triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    opposite = triangles[:, [2, 0, 1]].reshape(-1)
    face_hinges = np.full(len(edges), -1, np.int64)
    _, inverse, counts = np.unique(np.sort(edges, axis=1), axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    interior = np.flatnonzero(counts[inverse] == 2)
    pairs = interior[np.argsort(inverse[interior], kind="stable")].reshape(-1, 2)
    pairs = pairs[opposite[pairs[:, 0]] != opposite[pairs[:, 1]]]
    first, second = pairs[:, 0], pairs[:, 1]
    vertices = np.stack([edges[first, 0], edges[first, 1], opposite[first], opposite[second]], axis=1)
    face_hinges[first] = face_hinges[second] = np.arange(len(pairs))
    return vertices, np.stack([first // 3, second // 3], axis=1), face_hinges.reshape(-1, 3)


def hinge_angles(x, vertices) -> tuple[np.ndarray, np.ndarray]:
    """Signed dihedral angles and their gradients at positions ``x`` ((n, 3) m).

    theta = atan2((n1 x n2) . e_hat, n1 . n2) for the normals n1 of (x0, x1, x2) and n2 of
    (x0, x3, x1) (both sides' x2 and x3 on opposite sides of the edge give n1 = n2 when flat,
    whatever the triangles' orientation); 0 flat, positive when x2 and x3 fold towards -n1.

    Returns:
        theta: (H,) rad in (-pi, pi].
        gradient: (H, 4, 3) d theta / d x_k (1/m): x2, x3 along their normals over their
            heights above the edge, x0 and x1 what keeps the sum and the moment zero
            (Bridson et al. 2003).
    """
    p = np.asarray(x, float)[np.asarray(vertices, np.int64)]  # (H, 4, 3)
    e = p[:, 1] - p[:, 0]
    n1 = np.cross(e, p[:, 2] - p[:, 0])
    n2 = np.cross(p[:, 3] - p[:, 0], e)
    length2 = np.maximum(np.einsum("hi,hi->h", e, e), _TINY)
    length = np.sqrt(length2)
    a1 = np.maximum(np.einsum("hi,hi->h", n1, n1), _TINY)
    a2 = np.maximum(np.einsum("hi,hi->h", n2, n2), _TINY)
    u1, u2 = n1 / np.sqrt(a1)[:, None], n2 / np.sqrt(a2)[:, None]
    theta = np.arctan2(np.einsum("hi,hi->h", np.cross(u1, u2), e) / length, np.einsum("hi,hi->h", u1, u2))
    g2 = -(length / a1)[:, None] * n1
    g3 = -(length / a2)[:, None] * n2
    s2 = np.einsum("hi,hi->h", p[:, 2] - p[:, 0], e) / length2
    s3 = np.einsum("hi,hi->h", p[:, 3] - p[:, 0], e) / length2
    g0 = -(1 - s2)[:, None] * g2 - (1 - s3)[:, None] * g3
    g1 = -s2[:, None] * g2 - s3[:, None] * g3
    return theta, np.stack([g0, g1, g2, g3], axis=1)


def dihedral_moduli(x, vertices, faces, triangles, stiffness: float) -> np.ndarray:
    """(H,) k_e = D |e|^2 / (A0 + A1) (N m) of each hinge at rest, its energy k_e/2 (theta -
    theta_rest)^2: a flat grid rolled about either axis into curvature kappa stores (D/2) kappa^2
    per m^2 (the hinge across each cell's column turns by kappa h)."""
    x = np.asarray(x, float)
    tri = np.asarray(triangles, np.int64)[np.asarray(faces, np.int64)]  # (H, 2, 3)
    corners = x[tri]
    area = 0.5 * np.linalg.norm(np.cross(corners[:, :, 1] - corners[:, :, 0],
                                         corners[:, :, 2] - corners[:, :, 0]), axis=2).sum(axis=1)
    e = x[vertices[:, 1]] - x[vertices[:, 0]]
    return stiffness * np.einsum("hi,hi->h", e, e) / area


def plate_weights(poisson: float) -> np.ndarray:
    """W (3x3) with (1 - nu) tr(M^2) + nu (tr M)^2 = m^T W m for m = (M_xx, M_yy, M_xy)."""
    return (1 - poisson) * np.diag([1.0, 1.0, 2.0]) + poisson * np.outer([1.0, 1, 0], [1.0, 1, 0])


def shape_operator_moduli(x, triangles, vertices, face_hinges, stiffness: float,
                          poisson: float = 0.0) -> np.ndarray:
    """(T, 3, 3) Q_t (N m) of each triangle: its energy is (1/2) d^T Q_t d for d its three hinges'
    theta - theta_rest (a boundary edge's taken as 0), the plate's A (D/2) [(1 - nu) tr(M^2) +
    nu (tr M)^2] of the shape operator M = sum_i d_i B_i.

    The B_i are fitted at rest so that M is exact for any uniform curvature: in the
    triangle's plane (centroid origin, axes u, w, normal n), the three unit curvatures K_j move
    each vertex of the triangle and its neighbours by (p^T K_j p / 2) n, p the vertex's
    projection on the plane; the hinges' rest gradients turn that into their angles' change,
    L (3x3, d = L k for k = (K_xx, K_yy, K_xy)), and M's components are L^-1 d. A boundary
    edge is given a mirror neighbour for the fit (the opposite vertex reflected through the
    edge's midpoint), so a triangle's L is always the full 3x3; with its angle held at 0 the
    free edge carries no bending moment across it (nu = 0). Raises ConfigError naming the first
    triangle whose hinges do not determine a curvature (L singular: a neighbour folded onto it)."""
    x = np.asarray(x, float)
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    T = len(triangles)
    corners = x[triangles]  # (T, 3, 3)
    centre = corners.mean(axis=1)
    e1 = corners[:, 1] - corners[:, 0]
    normal = np.cross(e1, corners[:, 2] - corners[:, 0])
    double_area = np.linalg.norm(normal, axis=1)
    normal /= double_area[:, None]
    u = e1 / np.linalg.norm(e1, axis=1)[:, None]
    w = np.cross(normal, u)
    # each triangle's three hinges as the term measures them (a boundary edge: a parallelogram)
    stencil = np.empty((T, 3, 4, 3))
    for k in range(3):
        a, b, c = corners[:, k], corners[:, (k + 1) % 3], corners[:, (k + 2) % 3]
        stencil[:, k] = np.stack([a, b, c, a + b - c], axis=1)
        hinge = face_hinges[:, k]
        inside = hinge >= 0
        stencil[inside, k] = x[vertices[hinge[inside]]]
    flat = stencil.reshape(-1, 4, 3)
    _, gradient = hinge_angles(flat.reshape(-1, 3), np.arange(len(flat) * 4).reshape(-1, 4))
    gradient = gradient.reshape(T, 3, 4, 3)
    rel = stencil - centre[:, None, None, :]
    pu = np.einsum("tkvi,ti->tkv", rel, u)
    pw = np.einsum("tkvi,ti->tkv", rel, w)
    along = np.einsum("tkvi,ti->tkv", gradient, normal)  # d theta_k / d (normal offset of v)
    fields = np.stack([0.5 * pu * pu, 0.5 * pw * pw, pu * pw], axis=-1)  # (T, 3, 4, 3): z of K_xx, K_yy, K_xy
    lift = np.einsum("tkv,tkvj->tkj", along, fields)  # (T, 3 hinges, 3 curvatures)
    scale = np.abs(lift).max(axis=(1, 2))
    singular = ~(np.abs(np.linalg.det(lift)) > 1e-9 * scale ** 3)
    if singular.any():
        t = int(np.flatnonzero(singular)[0])
        raise ConfigError(f"parameter bending_model: shape_operator cannot fit triangle {t} (vertices "
                          f"{triangles[t].tolist()}): its three hinges do not determine a curvature")
    inverse = np.linalg.inv(lift)
    q = 0.5 * double_area[:, None, None] * stiffness * np.einsum(
        "tji,jk,tkl->til", inverse, plate_weights(poisson), inverse)
    missing = face_hinges < 0
    q[np.repeat(missing[:, :, None], 3, axis=2)] = 0.0
    q[np.repeat(missing[:, None, :], 3, axis=1)] = 0.0
    return q


def element_stencils(vertices, elements, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Each element's distinct vertices, padded with -1 to ``width``: (E, width) int64, and where
    each of its hinges' four vertices sits among them, (E, 3, 4) int64 (0 for a missing hinge)."""
    stencil = np.full((len(elements), width), -1, np.int64)
    local = np.zeros((len(elements), 3, 4), np.int64)
    for e, hinges in enumerate(elements):
        seen: list[int] = []
        for k, h in enumerate(hinges):
            if h < 0:
                continue
            for r, v in enumerate(vertices[h]):
                if v not in seen:
                    seen.append(int(v))
                local[e, k, r] = seen.index(int(v))
        stencil[e, :len(seen)] = seen
    return stencil, local


def bound_weights(x, vertices, elements, moduli, width: int, stiffness: float) -> tuple[np.ndarray, np.ndarray]:
    """(stencils (E, width) int64, weights (E, width) 1/m) with |K_rs| <= D w_r w_s for each
    element's rest Hessian K = sum_kl Q_kl g_kr g_ls^T (Cauchy-Schwarz: w_r = sqrt(|Q|_2 / D)
    times the norm over k of |g_kr|), the form :func:`~taichi_sim.forces.membrane.omega_max_bound`
    bounds a frequency with; a padded slot is the element's first vertex with weight 0."""
    stencil, local = element_stencils(vertices, elements, width)
    _, gradient = hinge_angles(x, vertices)
    size = np.linalg.norm(gradient, axis=2)  # (H, 4)
    per_slot = np.zeros((len(elements), 3, width))
    for k in range(3):
        rows = np.flatnonzero(elements[:, k] >= 0)
        for r in range(4):
            np.add.at(per_slot, (rows, k, local[rows, k, r]), size[elements[rows, k], r])
    norm = np.linalg.norm(moduli, ord=2, axis=(1, 2))
    weights = np.sqrt(norm / max(stiffness, 1e-300))[:, None] * np.linalg.norm(per_slot, axis=1)
    return np.where(stencil >= 0, stencil, stencil[:, :1]), weights


def check_poisson(value) -> float:
    """A bending Poisson's ratio in [0, 0.5), else ConfigError naming it."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (0.0 <= value < 0.5):
        raise ConfigError(f"parameter bending_poisson_ratio: must be in [0, 0.5), got {value!r}")
    return float(value)


def normal_stiffness(x, arrays, axis: int = 1):
    """The hinge bending's rest Hessian in the deflections along coordinate ``axis`` of a flat
    rest shape normal to it: sum_e J_e^T Q_e J_e (scipy CSR, n x n, N/m), J_e its hinges'
    gradients' ``axis`` components, for the ``arrays`` of
    :func:`~taichi_sim.forces.membrane.hinge_term.hinge_elements`. Exact at rest (every d is 0),
    so it gives the small-deflection equilibrium K w = load (docs/materials.md, "Bending against
    a beam"). Uses scipy."""
    from scipy.sparse import csr_matrix

    vertices, elements, moduli = arrays["hinge_vertices"], arrays["bending_elements"], arrays["bending_moduli"]
    _, gradient = hinge_angles(x, vertices)
    H, n = len(vertices), len(x)
    normal = csr_matrix((gradient[:, :, axis].ravel(), (np.repeat(np.arange(H), 4), vertices.ravel())), shape=(H, n))
    k, c = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    rows, cols = elements[:, k.ravel()], elements[:, c.ravel()]
    present = (rows >= 0) & (cols >= 0)
    coupling = csr_matrix((moduli.reshape(-1, 9)[present], (rows[present], cols[present])), shape=(H, H))
    return (normal.T @ coupling @ normal).tocsr()
