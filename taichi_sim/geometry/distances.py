"""Exact closest distances between points, segments and triangles (numpy, float64): what the
self-contact stage's input check measures and what `check` measures depths inside a collider
mesh with."""
from __future__ import annotations

import numpy as np


def point_triangle_distance(p, a, b, c) -> np.ndarray:
    """(P,) distances (m) from points p to triangles abc, all (P, 3) m (a triangle of zero area
    is measured by its sides)."""
    n = np.cross(b - a, c - a)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = n / np.where(length > 0, length, 1.0)
    height = np.einsum("ij,ij->i", p - a, n)
    q = p - height[:, None] * n  # the projection onto the triangle's plane
    inside = length[:, 0] > 0
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(v - u, q - u), n) >= 0
    edge = np.minimum.reduce([segment_point_distance(p, a, b), segment_point_distance(p, b, c), segment_point_distance(p, c, a)])
    return np.where(inside, np.abs(height), edge)


def segment_point_distance(p, a, b) -> np.ndarray:
    """(P,) distances (m) from points p to segments ab, all (P, 3) m."""
    d = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * d), axis=1)


def segment_distance(p1, q1, p2, q2) -> np.ndarray:
    """(P,) closest distances between segments p1q1 and p2q2 (Ericson, Real-Time Collision
    Detection, 5.1.9), parallel segments included."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.einsum("ij,ij->i", d1, d1)
    e = np.einsum("ij,ij->i", d2, d2)
    f = np.einsum("ij,ij->i", d2, r)
    c = np.einsum("ij,ij->i", d1, r)
    b = np.einsum("ij,ij->i", d1, d2)
    denom = a * e - b * b
    s = np.where(denom > 1e-14 * a * e, np.clip((b * f - c * e) / np.where(denom > 0, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e
    s = np.where(t < 0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    # the three candidate end-point distances cover the cases the clamping above resolves
    best = np.linalg.norm((p1 + s[:, None] * d1) - (p2 + t[:, None] * d2), axis=1)
    for pt, sa, sb in ((p1, p2, q2), (q1, p2, q2)):
        best = np.minimum(best, segment_point_distance(pt, sa, sb))
    for pt, sa, sb in ((p2, p1, q1), (q2, p1, q1)):
        best = np.minimum(best, segment_point_distance(pt, sa, sb))
    return best
