"""Exact orientation predicates on float64 points, vectorised with numpy.

Each predicate is evaluated in floating point first; where the result is too close to zero for
its sign to be certain (a conservative forward error bound, after Shewchuk's static filters),
it is evaluated again in exact rational arithmetic (:class:`fractions.Fraction` holds every
float exactly). So the sign returned is always the sign of the exact determinant of the given
floats, whatever their round-off: ties (exact coplanarity, touching) are decided exactly.
"""
from __future__ import annotations

from fractions import Fraction

import numpy as np

# |float det - exact det| <= BOUND * permanent for the 3x3 (orient3d) and 2x2 (orient2d)
# determinants, the differences' rounding included (Shewchuk's static filters: (7 + 56 eps) eps
# and (3 + 16 eps) eps). Ours are ten times looser: the exact fallback is rare either way.
_EPS = np.finfo(np.float64).eps / 2
_BOUND3 = 80 * _EPS
_BOUND2 = 40 * _EPS


def orient3d(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Sign (+1, 0, -1) of det[b - a, c - a, d - a] for (n, 3) float64 point arrays.

    Positive when d lies on the side of plane (a, b, c) that the normal (b - a) x (c - a)
    points to; zero exactly when the four points are coplanar.
    """
    a, b, c, d = (np.asarray(p, np.float64).reshape(-1, 3) for p in (a, b, c, d))
    u, v, w = b - a, c - a, d - a
    det = (u[:, 0] * (v[:, 1] * w[:, 2] - v[:, 2] * w[:, 1])
           - u[:, 1] * (v[:, 0] * w[:, 2] - v[:, 2] * w[:, 0])
           + u[:, 2] * (v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0]))
    au, av, aw = np.abs(u), np.abs(v), np.abs(w)
    permanent = (au[:, 0] * (av[:, 1] * aw[:, 2] + av[:, 2] * aw[:, 1])
                 + au[:, 1] * (av[:, 0] * aw[:, 2] + av[:, 2] * aw[:, 0])
                 + au[:, 2] * (av[:, 0] * aw[:, 1] + av[:, 1] * aw[:, 0]))
    sign = np.sign(det).astype(np.int8)
    unsure = ~(np.abs(det) > _BOUND3 * permanent)
    # Four points with one coordinate equal lie in an axis plane: exactly coplanar (a flat cloth).
    on_axis_plane = np.any((a == b) & (a == c) & (a == d), axis=1)
    sign[unsure & on_axis_plane] = 0
    for i in np.flatnonzero(unsure & ~on_axis_plane):
        sign[i] = _orient3d_exact(a[i], b[i], c[i], d[i])
    return sign


def orient2d(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Sign (+1, 0, -1) of det[b - a, c - a] for (n, 2) float64 point arrays (+1: a, b, c
    counter-clockwise; 0 exactly when collinear)."""
    a, b, c = (np.asarray(p, np.float64).reshape(-1, 2) for p in (a, b, c))
    u, v = b - a, c - a
    det = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    permanent = np.abs(u[:, 0] * v[:, 1]) + np.abs(u[:, 1] * v[:, 0])
    sign = np.sign(det).astype(np.int8)
    unsure = ~(np.abs(det) > _BOUND2 * permanent)
    on_axis_line = np.any((a == b) & (a == c), axis=1)  # exactly collinear
    sign[unsure & on_axis_line] = 0
    for i in np.flatnonzero(unsure & ~on_axis_line):
        sign[i] = _orient2d_exact(a[i], b[i], c[i])
    return sign


def _exact(point) -> list[Fraction]:
    return [Fraction(float(x)) for x in point]


def _orient3d_exact(a, b, c, d) -> int:
    a, b, c, d = _exact(a), _exact(b), _exact(c), _exact(d)
    u = [b[k] - a[k] for k in range(3)]
    v = [c[k] - a[k] for k in range(3)]
    w = [d[k] - a[k] for k in range(3)]
    det = (u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
           + u[2] * (v[0] * w[1] - v[1] * w[0]))
    return (det > 0) - (det < 0)


def _orient2d_exact(a, b, c) -> int:
    a, b, c = _exact(a), _exact(b), _exact(c)
    det = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    return (det > 0) - (det < 0)
