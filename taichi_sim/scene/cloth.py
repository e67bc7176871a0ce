"""Cloth grid topology, built with numpy (no Python loops over particles or springs)."""
from __future__ import annotations

from typing import Any

import numpy as np

STRUCTURAL, SHEAR, FLEX = 0, 1, 2
# The one place that maps spring kinds to stiffness: the cloth parameter of each kind, and the
# cloth family's ratios to the structural k (shear k/2, flex k/5; the defaults 500, 250, 100
# N/m) that the benches use when they sweep one k.
KIND_STIFFNESS_PARAMS = ("stiffness", "shear_stiffness", "flex_stiffness")
KIND_RATIOS = (1.0, 0.5, 0.2)


def kind_stiffness(kind: np.ndarray, per_kind) -> np.ndarray:
    """(S,) stiffness (N/m) of springs of ``kind`` (0 structural, 1 shear, 2 flex; others count
    as flex) from ``per_kind``: three values in that order, or a mapping holding the cloth's
    parameters (:data:`KIND_STIFFNESS_PARAMS`)."""
    if hasattr(per_kind, "keys"):
        per_kind = [per_kind[name] for name in KIND_STIFFNESS_PARAMS]
    return np.asarray(per_kind, float)[np.clip(np.asarray(kind, int), 0, 2)]


def swept_stiffness(k: float) -> dict[str, float]:
    """The cloth parameters for structural stiffness ``k`` (N/m) at the family's ratios."""
    return {name: k * ratio for name, ratio in zip(KIND_STIFFNESS_PARAMS, KIND_RATIOS)}


def grid_index(nx: int, ny: int) -> np.ndarray:
    """(nx, ny) array of particle ids: particle (i, j) has id i * ny + j."""
    return np.arange(nx * ny, dtype=np.int64).reshape(nx, ny)


def spring_counts(nx: int, ny: int) -> dict[int, int]:
    """Closed-form spring counts per kind for an nx x ny grid (docs/scenes.md, Force model)."""
    return {
        STRUCTURAL: (nx - 1) * ny + nx * (ny - 1),
        SHEAR: 2 * max(nx - 1, 0) * max(ny - 1, 0),
        FLEX: max(nx - 2, 0) * ny + nx * max(ny - 2, 0),
    }


def grid_springs(nx: int, ny: int, *, structural: bool = True, shear: bool = True,
                 flex: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Springs of an nx x ny cloth grid.

    Structural springs join horizontal and vertical neighbours, shear springs both diagonals of
    every cell, flex springs particles two apart horizontally and vertically.

    Returns:
        ends: (S, 2) int64 particle ids.
        kind: (S,) int8, 0 structural, 1 shear, 2 flex.
    """
    idx = grid_index(nx, ny)
    pairs: list[tuple[np.ndarray, np.ndarray, int]] = []
    if structural:
        pairs += [(idx[:-1, :], idx[1:, :], STRUCTURAL), (idx[:, :-1], idx[:, 1:], STRUCTURAL)]
    if shear:
        pairs += [(idx[:-1, :-1], idx[1:, 1:], SHEAR), (idx[1:, :-1], idx[:-1, 1:], SHEAR)]
    if flex:
        pairs += [(idx[:-2, :], idx[2:, :], FLEX), (idx[:, :-2], idx[:, 2:], FLEX)]
    if not pairs:
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int8)
    ends = np.concatenate([np.stack([a.ravel(), b.ravel()], axis=1) for a, b, _ in pairs])
    kind = np.concatenate([np.full(a.size, k, np.int8) for a, _, k in pairs])
    return ends, kind


def grid_positions(nx: int, ny: int, size_x: float, size_y: float, origin, u_axis, v_axis) -> np.ndarray:
    """(nx*ny, 3) positions: origin + (i / (nx-1)) size_x u_axis + (j / (ny-1)) size_y v_axis."""
    s = np.linspace(0.0, size_x, nx)[:, None, None] * np.asarray(u_axis, float)
    t = np.linspace(0.0, size_y, ny)[None, :, None] * np.asarray(v_axis, float)
    return (np.asarray(origin, float) + s + t).reshape(nx * ny, 3)


def grid_triangles(nx: int, ny: int) -> np.ndarray:
    """(2 (nx-1)(ny-1), 3) triangles, two per cell along the (i, j)-(i+1, j+1) diagonal (a shear
    spring), wound so that their normals point along u x v of :func:`grid_positions`."""
    idx = grid_index(nx, ny)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    first = np.stack([a, b, d], axis=-1).reshape(-1, 3)
    second = np.stack([a, d, c], axis=-1).reshape(-1, 3)
    return np.concatenate([first, second])


def turned_grid(m: int) -> tuple[np.ndarray, np.ndarray]:
    """The unit square meshed by the grid's triangles turned 45 degrees to its sides.

    The vertices are the lattice points (i, j) / (2m), 0 <= i, j <= 2m, with i + j even: the
    grid of :func:`grid_triangles` turned 45 degrees, its spacing 1 / (m sqrt 2), clipped to the
    square. Each diamond (the cell around a point with i + j odd) is split along its diagonal
    parallel to the square's first axis into two right isosceles triangles, the grid's shape;
    a diamond cut by the square's side keeps its inner half, one such triangle. So every edge
    of the grid's triangles runs at 45 degrees to the sides (the diagonals, along the sides),
    and the sides hold m + 1 vertices each, corners included. For an n x n grid's spacing
    take m = round((n - 1) / sqrt 2).

    Args:
        m: segments along each side, >= 1.

    Returns:
        uv: (k, 2) float64 vertex coordinates in [0, 1]^2, k = ((2m + 1)^2 + 1) / 2.
        triangles: (4 m^2, 3) int64 vertex ids, counter-clockwise in (u, v).
    """
    if m < 1:
        raise ValueError(f"turned_grid: m must be >= 1, got {m}")
    side = 2 * m + 1
    i, j = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    even = (i + j) % 2 == 0
    ids = np.full((side, side), -1, np.int64)
    ids[even] = np.arange(int(even.sum()))
    uv = np.stack([i[even], j[even]], axis=1) / (2.0 * m)
    ci, cj = i[~even], j[~even]  # diamond centres
    triangles = []
    for below in (True, False):  # the half under the diagonal (j - 1), then the half over it (j + 1)
        tip = cj - 1 if below else cj + 1
        inside = (tip >= 0) & (tip < side) & (ci > 0) & (ci < side - 1)
        clip = np.clip(ci, 1, side - 2)
        left, right, apex = ids[clip - 1, cj], ids[clip + 1, cj], ids[ci, np.clip(tip, 0, side - 1)]
        order = [left, apex, right] if below else [left, right, apex]
        triangles.append(np.stack(order, axis=1)[inside])
    # diamonds on the sides u = 0 and u = 1 have no diagonal along u: their inner half is one
    # triangle (the centre's neighbours along v and the one inward)
    for edge, inward in ((0, 1), (side - 1, side - 2)):
        on = (ci == edge)
        low, high, apex = ids[edge, cj[on] - 1], ids[edge, cj[on] + 1], ids[inward, cj[on]]
        triangles.append(np.stack([low, apex, high] if edge == 0 else [low, high, apex], axis=1))
    return uv, np.concatenate(triangles).astype(np.int64)


def grid_particle_area(p: dict[str, Any]) -> float:
    """Each particle's share (m^2) of the grid cloth of parameters ``p``: size^2 / (nx ny)."""
    return p["size"] ** 2 / (p["nx"] * p["ny"])


def grid_particle_mass(p: dict[str, Any]) -> float:
    """Each particle's mass (kg): the area density times its share of the area, so the cloth
    weighs the same at any resolution."""
    return p["density"] * grid_particle_area(p)


def grid_particle_drag(p: dict[str, Any]) -> float:
    """Each particle's drag coefficient (N s/m): ``area_drag`` times its share of the area."""
    return p["area_drag"] * grid_particle_area(p)


def per_particle(nx: int, ny: int, mass: float, drag: float = 0.0, size: float = 1.0) -> dict[str, float]:
    """The grid cloth parameters (``density``, ``area_drag``) that give each particle of an
    nx x ny cloth of side ``size`` (m) this ``mass`` (kg) and ``drag`` (N s/m): the way to build
    a cloth of fixed particles (a study defined on them, or a figure taken before the grid's mass
    became an area density: :func:`fixed_particle_cloth`)."""
    area = size * size / (nx * ny)
    return {"density": mass / area, "area_drag": drag / area}


FIXED_PARTICLE_MASS = 0.01  # kg: a grid cloth's particle at every size before the mass became per area
FIXED_PARTICLE_DRAG = 0.005  # N s/m: its drag then


def fixed_particle_cloth(nx: int, ny: int) -> dict[str, float]:
    """:func:`per_particle` of FIXED_PARTICLE_MASS and FIXED_PARTICLE_DRAG: the nx x ny cloth of
    the studies and figures defined on fixed particles (the 32 x 32 default's at every size)."""
    return per_particle(nx, ny, FIXED_PARTICLE_MASS, FIXED_PARTICLE_DRAG)
