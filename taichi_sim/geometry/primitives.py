"""Triangle meshes of simple solids (numpy): what the scene's colliders and the renderer's
props are drawn with. Each returns vertices (m, 3) (m), unit outward normals (m, 3) and
triangles (t, 3), wound counter-clockwise seen from outside."""
import numpy as np


def unit_sphere(rings: int = 16, segments: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """A latitude-longitude unit sphere: vertices (m, 3) (also its normals) and triangles
    (t, 3), wound counter-clockwise seen from outside."""
    theta = np.linspace(0.0, np.pi, rings + 1)[:, None]
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)[None, :]
    verts = np.stack(np.broadcast_arrays(np.sin(theta) * np.cos(phi), np.cos(theta),
                                         -np.sin(theta) * np.sin(phi)), axis=-1).reshape(-1, 3)
    idx = np.arange((rings + 1) * (segments + 1)).reshape(rings + 1, segments + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    tris = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([c, b, d], -1).reshape(-1, 3)])
    return verts, tris


def capsule(half_axis: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A capsule about the origin: a cylinder along +-``half_axis`` (m) and a sphere of
    ``radius`` (m) at each end; vertices, normals, triangles as :func:`rod`."""
    segments = 16
    cyl_v, cyl_n, cyl_t = rod(-half_axis, half_axis, radius, segments)
    # the side only: its end caps would lie inside the end spheres
    cyl_v, cyl_n, cyl_t = cyl_v[:2 * segments], cyl_n[:2 * segments], cyl_t[:2 * segments]
    unit, sphere_t = unit_sphere(8, 16)
    verts, normals, tris = [cyl_v], [cyl_n], [cyl_t]
    count = len(cyl_v)
    for end in (-half_axis, half_axis):
        verts.append(end + radius * unit)
        normals.append(unit)
        tris.append(sphere_t + count)
        count += len(unit)
    return np.concatenate(verts), np.concatenate(normals), np.concatenate(tris)


def box(half: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An axis-aligned box of half extents ``half`` (m) about the origin, four vertices per face
    (flat normals); vertices, normals, triangles as :func:`rod`."""
    verts, normals, tris = [], [], []
    for axis in range(3):
        u, w = (axis + 1) % 3, (axis + 2) % 3
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            corners = []
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                c = np.zeros(3)
                c[axis], c[u], c[w] = sign * half[axis], a * half[u], b * half[w]
                corners.append(c)
            base = len(verts) * 4
            order = [[0, 1, 2], [0, 2, 3]] if sign > 0 else [[0, 2, 1], [0, 3, 2]]
            verts.append(np.asarray(corners))
            normals.append(np.tile(n, (4, 1)))
            tris.append(np.asarray(order) + base)
    return np.concatenate(verts), np.concatenate(normals), np.concatenate(tris)


def rod(bottom: np.ndarray, top: np.ndarray, radius: float,
         segments: int = 16) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A closed cylinder from ``bottom`` to ``top`` (m) of ``radius`` (m): vertices (m, 3),
    normals (m, 3) and triangles (t, 3), wound counter-clockwise seen from outside."""
    axis = top - bottom
    axis = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    w = np.cross(axis, u)
    phi = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    ring = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * w  # (segments, 3) outward normals
    # side rings (normals outward), then each cap's ring and centre (normals along the axis)
    verts = np.concatenate([bottom + radius * ring, top + radius * ring,
                            top + radius * ring, top[None], bottom + radius * ring, bottom[None]])
    normals = np.concatenate([ring, ring, np.tile(axis, (segments + 1, 1)), np.tile(-axis, (segments + 1, 1))])
    k = np.arange(segments)
    nxt = (k + 1) % segments
    s = segments
    side = np.concatenate([np.stack([k, nxt, s + k], -1), np.stack([nxt, s + nxt, s + k], -1)])
    top_cap = np.stack([np.full(s, 3 * s), 2 * s + k, 2 * s + nxt], -1)
    bottom_cap = np.stack([np.full(s, 4 * s + 1), 3 * s + 1 + nxt, 3 * s + 1 + k], -1)
    return verts, normals, np.concatenate([side, top_cap, bottom_cap])
