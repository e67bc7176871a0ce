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
