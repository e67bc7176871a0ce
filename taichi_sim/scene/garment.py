"""A garment of our own: a skirt sewn from flat gores (trapezoid panels), and the ``garment``
scene that drapes it on a body of capsules and a sphere (docs/meshes.md).

Each gore is a flat isosceles trapezoid, triangulated as a grid; sewn side to side the gores
close into a ten-sided cone (a frustum), each gore lying flat in its own plane, so the cloth
starts at rest: its rest lengths are the flat panels' lengths. examples/garments/make_skirt.py
writes it as an OBJ.
"""
from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from .builder import SceneBuilder
from .colliders import SpherePath
from .mesh_cloth import MESH_CLOTH_PARAMS, add_mesh_cloth, finish_mesh_cloth, mesh_size
from .mesh_import import ClothMesh
from .params import Param
from .preset import ScenePreset, with_defaults
from .scene import Scene

SKIRT_DEFAULTS = dict(gores=10, gore_columns=10, rows=50, waist_radius=0.15, hem_radius=0.32,
                      length=0.55, waist_height=1.0)


def skirt_panels(gores: int, gore_columns: int, rows: int, waist_radius: float, hem_radius: float,
                 length: float) -> tuple[np.ndarray, np.ndarray]:
    """The flat pattern: one gore, a trapezoid ``waist`` chord wide at the top and ``hem`` chord
    wide at the bottom (the chords of the waist and hem circles over 1/``gores`` of a turn), its
    slant height that of the cone, as a grid of ``rows`` x (``gore_columns`` + 1) points.

    Returns:
        uv: (rows, gore_columns + 1, 2) flat coordinates (m): u across, v down from the waist.
        corners: (4, 3) the gore's corners in 3-D for gore 0 (waist left, waist right, hem
            left, hem right), for :func:`skirt_mesh` to place.
    """
    half = math.pi / gores
    top, bottom = 2 * waist_radius * math.sin(half), 2 * hem_radius * math.sin(half)
    inset = (hem_radius - waist_radius) * math.cos(half)  # how far the hem's chord lies outside
    slant = math.hypot(length, inset)
    t = np.linspace(0.0, 1.0, rows)[:, None]
    s = np.linspace(-0.5, 0.5, gore_columns + 1)[None, :]
    uv = np.stack(np.broadcast_arrays(s * (top + t * (bottom - top)), t * slant), axis=-1)
    ring = lambda r, a: (r * math.sin(a), 0.0, r * math.cos(a))  # noqa: E731
    corners = np.asarray([ring(waist_radius, -half), ring(waist_radius, half),
                          ring(hem_radius, -half), ring(hem_radius, half)])
    corners[2:, 1] -= length
    return uv, corners


@functools.lru_cache(maxsize=4)
def skirt_mesh(gores: int = 10, gore_columns: int = 10, rows: int = 50, waist_radius: float = 0.15,
               hem_radius: float = 0.32, length: float = 0.55, waist_height: float = 1.0) -> ClothMesh:
    """The skirt: ``gores`` panels of :func:`skirt_panels` sewn into a cone about the y axis, the
    waist at ``waist_height`` (m). rows x gores x gore_columns vertices (5 000 by default);
    groups ``waist`` (the top row), ``hem`` (the bottom row) and ``gore0``... ``goreN``."""
    uv, corners = skirt_panels(gores, gore_columns, rows, waist_radius, hem_radius, length)
    t = np.linspace(0.0, 1.0, rows)[:, None, None]
    s = np.linspace(0.0, 1.0, gore_columns + 1)[None, :, None]
    left = corners[0] + t * (corners[2] - corners[0])
    right = corners[1] + t * (corners[3] - corners[1])
    gore0 = left + s * (right - left)  # (rows, columns + 1, 3): the flat gore in its own plane
    around = gores * gore_columns
    x = np.empty((rows, around, 3))
    for k in range(gores):
        angle = 2 * math.pi * k / gores  # gore k turned about +y from gore 0
        c, sn = math.cos(angle), math.sin(angle)
        turn = np.array([[c, 0.0, sn], [0.0, 1.0, 0.0], [-sn, 0.0, c]])  # about +y
        x[:, k * gore_columns:(k + 1) * gore_columns] = gore0[:, :-1] @ turn.T
    x[..., 1] += waist_height
    ids = np.arange(rows * around).reshape(rows, around)
    nxt = np.roll(ids, -1, axis=1)  # the seam: the last column of a gore is the next gore's first
    a, b, c_, d = ids[:-1], nxt[:-1], ids[1:], nxt[1:]
    triangles = np.concatenate([np.stack([a, c_, d], -1).reshape(-1, 3),
                                np.stack([a, d, b], -1).reshape(-1, 3)])
    groups = {"waist": ids[0], "hem": ids[-1]}
    for k in range(gores):
        seam = ids[:, [(k + 1) * gore_columns % around]]
        groups[f"gore{k}"] = np.concatenate([ids[:, k * gore_columns:(k + 1) * gore_columns], seam], 1).ravel()
    return ClothMesh(x.reshape(-1, 3), triangles.astype(np.int64), groups, "skirt")


def write_obj(mesh: ClothMesh, path) -> None:
    """``mesh`` as a Wavefront OBJ: its vertices, then one ``g`` group per named vertex set
    (faces whose three vertices all lie in it), and the rest."""
    lines = [f"# {mesh.source}: {mesh.vertex_count} vertices, {len(mesh.triangles)} triangles (m, y up)"]
    lines += [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in mesh.x]
    owner = np.full(len(mesh.triangles), -1)
    names = [n for n in mesh.groups if n.startswith("gore")]
    for k, name in enumerate(names):
        inside = np.zeros(mesh.vertex_count, bool)
        inside[mesh.groups[name]] = True
        owner[(owner < 0) & inside[mesh.triangles].all(axis=1)] = k
    for k, name in enumerate(names + ["rest"]):
        chosen = mesh.triangles[owner == (k if k < len(names) else -1)]
        if len(chosen):
            lines.append(f"g {name}")
            lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in chosen]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


GARMENT_PARAMS: tuple[Param, ...] = (
    Param("gores", 10, "", "panels sewn around the skirt", minimum=3),
    Param("gore_columns", 10, "", "vertices across each panel (one seam's shared)", minimum=1),
    Param("rows", 50, "", "vertices down each panel, waist to hem", minimum=2),
    Param("waist_radius", 0.15, "m", "radius of the waist circle", minimum=0.0, exclusive=True),
    Param("hem_radius", 0.32, "m", "radius of the hem circle", minimum=0.0, exclusive=True),
    Param("length", 0.55, "m", "height of the skirt, waist to hem", minimum=0.0, exclusive=True),
    Param("body", True, "", "the body the skirt drapes on: a torso, hips and two legs (capsules)"),
    Param("body_friction", 0.5, "", "Coulomb friction coefficient on the body", minimum=0.0),
    *with_defaults(MESH_CLOTH_PARAMS, pin="group:waist", plane=True, restitution=0.0, thickness=0.004,
                   flex_stiffness=5.0),
)

#: The body: (centre (m), half axis (m), radius (m)) of each capsule; the waist is at 1 m.
BODY = (((0.0, 1.2, 0.0), (0.0, 0.17, 0.0), 0.12),     # torso, inside the waist ring
        ((0.0, 0.87, 0.0), (0.05, 0.0, 0.0), 0.11),     # hips, across
        ((-0.085, 0.45, 0.0), (0.0, 0.36, 0.0), 0.07),  # legs
        ((0.085, 0.45, 0.0), (0.0, 0.36, 0.0), 0.07))


def garment_mesh(p: dict[str, Any]) -> ClothMesh:
    return skirt_mesh(p["gores"], p["gore_columns"], p["rows"], p["waist_radius"], p["hem_radius"],
                      p["length"], SKIRT_DEFAULTS["waist_height"])


def build_garment(preset: ScenePreset, p: dict[str, Any], seed: int) -> Scene:
    b = SceneBuilder()
    add_mesh_cloth(b, p, seed, garment_mesh(p), default_thickness=preset.param("thickness").default)
    if p["body"]:
        for centre, half_axis, radius in BODY:
            b.add_capsule(SpherePath(centre), radius, half_axis, p["body_friction"])
    return finish_mesh_cloth(preset, b, p, seed)


GARMENT = ScenePreset(
    "garment", "a skirt sewn from ten flat panels, pinned at the waist and draping over hips and "
    "legs made of capsules", GARMENT_PARAMS, build_garment, default_dt=1 / 60,
    default_integrator="xpbd", size=lambda p: mesh_size(garment_mesh(p), p["bending"], p["material"]),
    size_params=("gores", "gore_columns", "rows"))

