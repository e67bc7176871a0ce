"""Any triangle mesh as cloth: stretch springs on its edges, bending springs across its interior
edges, masses from its area, pins from a spec string (docs/meshes.md)."""
from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import ConfigError
from ..memory import Size
from . import cloth as topo
from .builder import SceneBuilder
from .cloth_scenes import EXPLICIT_STEP_SHARE, EXTRA_PARAM_NAMES, add_cloth_extras, cloth_params
from .kinematic import TranslatePath
from .materials import MATERIAL_PARAMS, finish_membrane_scene, membrane_bending, membrane_material, refuse_springs_only
from .mesh_import import ClothMesh
from .params import Param
from .preset import common_params, with_defaults


def vertex_masses(x, triangles, density: float) -> np.ndarray:
    """(n,) mass (kg) of each vertex: a third of the area (m^2) of each triangle it belongs to,
    times the area ``density`` (kg/m^2). The masses sum to density times the mesh's area."""
    x = np.asarray(x, float)
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    a, b, c = (x[triangles[:, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    mass = np.zeros(len(x))
    np.add.at(mass, triangles.ravel(), np.repeat(density * area / 3.0, 3))
    return mass


def mesh_edges(triangles) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's edges and, for each, how many triangles share it.

    Returns:
        edges: (E, 2) int64 vertex ids, lower id first, sorted.
        counts: (E,) 1 on the boundary, 2 inside, more where the mesh is non-manifold.
    """
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    edges = np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(edges, axis=0, return_counts=True)


def bending_pairs(triangles) -> np.ndarray:
    """(B, 2) int64: for each interior edge shared by exactly two triangles, the two vertices
    opposite it (the flex spring across the edge; a fold along the edge stretches or squeezes
    it). Non-manifold edges get none."""
    triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
    edges = np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    opposite = triangles[:, [2, 0, 1]].reshape(-1)
    _, inverse, counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    interior = counts[inverse] == 2
    order = np.argsort(inverse[interior], kind="stable")
    across = opposite[interior][order].reshape(-1, 2)
    across = across[across[:, 0] != across[:, 1]]
    return np.sort(across, axis=1)


def mesh_springs(triangles, *, bending: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Springs of a mesh cloth: one structural (kind 0) along every edge, and (``bending``) one
    flex (kind 2) across every interior edge.

    Returns:
        ends: (S, 2) int64 vertex ids.
        kind: (S,) int8.
    """
    edges, _ = mesh_edges(triangles)
    parts = [(edges, topo.STRUCTURAL)]
    if bending:
        parts.append((bending_pairs(triangles), topo.FLEX))
    ends = np.concatenate([e for e, _ in parts]).reshape(-1, 2)
    kind = np.concatenate([np.full(len(e), k, np.int8) for e, k in parts])
    return ends, kind


def square_sheet(n: int, *, turned: bool = False, size: float = 1.0, height: float = 1.0) -> ClothMesh:
    """A square sheet of side ``size`` (m) hanging in the x-y plane from its top edge at
    ``height`` (m), as the vertical grid cloth does: the n x n grid's triangles
    (:func:`~taichi_sim.scene.cloth.grid_triangles`), or (``turned``) the same triangles turned
    45 degrees to the sides at about the same spacing
    (:func:`~taichi_sim.scene.cloth.turned_grid` with m = round((n - 1) / sqrt 2)). Write it
    with :func:`~taichi_sim.scene.garment.write_obj` for the ``mesh`` scene; ``pin=top:1e-3``
    then holds its top edge."""
    if turned:
        uv, triangles = topo.turned_grid(max(1, round((n - 1) / np.sqrt(2.0))))
    else:
        uv = topo.grid_positions(n, n, 1.0, 1.0, origin=(0, 0, 0), u_axis=(1, 0, 0), v_axis=(0, 1, 0))[:, :2]
        triangles = topo.grid_triangles(n, n)
    x = np.stack([size * (uv[:, 0] - 0.5), height - size * (1.0 - uv[:, 1]), np.zeros(len(uv))], axis=1)
    return ClothMesh(x, triangles, {}, f"{'turned ' if turned else ''}square sheet {n}")


def select_pins(spec: str, mesh: ClothMesh) -> np.ndarray:
    """(n,) bool: the vertices the ``pin`` spec holds (see :data:`PIN_HELP`). ConfigError for a
    spec that does not parse, or that selects no vertex or every vertex."""
    spec = spec.strip()
    x, n = mesh.x, mesh.vertex_count
    kind, _, arg = spec.partition(":")
    kind = kind.strip().lower()
    pinned = np.zeros(n, bool)
    if kind == "none" and not arg:
        return pinned
    try:
        if kind == "ids":
            ids = np.asarray([int(t) for t in arg.split(",") if t.strip()], np.int64)
            if len(ids) == 0:
                raise ValueError
            bad = ids[(ids < 0) | (ids >= n)]
            if len(bad):
                raise ConfigError(f"parameter pin: vertex id {bad[0]} is not in 0..{n - 1} (the mesh "
                                  f"{mesh.source} has {n} vertices)")
            pinned[ids] = True
        elif kind == "box":
            bounds = np.asarray([float(t) for t in arg.split(",")], float)
            if bounds.shape != (6,) or not np.isfinite(bounds).all():
                raise ValueError
            low, high = np.minimum(bounds[:3], bounds[3:]), np.maximum(bounds[:3], bounds[3:])
            pinned = np.all((x >= low) & (x <= high), axis=1)
        elif kind in ("top", "bottom"):
            reach = float(arg)
            if not (reach >= 0 and np.isfinite(reach)):
                raise ValueError
            y = x[:, 1]
            pinned = y >= y.max() - reach if kind == "top" else y <= y.min() + reach
        elif kind == "group":
            if arg not in mesh.groups:
                known = ", ".join(sorted(mesh.groups)) or "none"
                raise ConfigError(f"parameter pin: the mesh {mesh.source} has no group {arg!r} (its groups: "
                                  f"{known})")
            pinned[mesh.groups[arg]] = True
        else:
            raise ValueError
    except ConfigError:
        raise
    except ValueError:
        raise ConfigError(f"parameter pin: cannot read {spec!r}; give {PIN_HELP}") from None
    if not pinned.any():
        raise ConfigError(f"parameter pin: {spec!r} selects no vertex of the mesh {mesh.source} "
                          "(pin=none pins nothing on purpose)")
    if pinned.all():
        raise ConfigError(f"parameter pin: {spec!r} selects every vertex of the mesh {mesh.source}; "
                          "nothing would move")
    return pinned


PIN_HELP = ("none, ids:3,17,42 (vertex ids), box:x0,y0,z0,x1,y1,z1 (m), top:D or bottom:D (vertices "
            "within D m of the highest or lowest y) or group:NAME (an OBJ o/g group, a glTF node)")


def add_mesh_cloth(b: SceneBuilder, p: dict[str, Any], seed: int, mesh: ClothMesh, *,
                   mass: np.ndarray | None = None, pinned: np.ndarray | None = None,
                   default_thickness: float | None = None) -> None:
    """Add ``mesh`` to ``b`` as cloth with the parameters ``p`` (those of :data:`MESH_CLOTH_PARAMS`),
    rest lengths as the mesh is: its vertices (``mass``, kg, default :func:`vertex_masses` at
    ``density``; ``pinned``, default from the ``pin`` spec), its springs, its triangles, seeded
    jitter, tearing and every extra (:func:`~taichi_sim.scene.cloth_scenes.add_cloth_extras`).
    ``default_thickness`` (m): the scene's default ``thickness``; where ``p`` keeps it (the user
    gave none), self-contact takes a thickness that fits the mesh, at most that
    (:meth:`SceneBuilder.enable_self_collision`'s ``fit``)."""
    if mass is None:
        mass = vertex_masses(mesh.x, mesh.triangles, p["density"])
    if pinned is None:
        pinned = select_pins(p["pin"], mesh)
    material = membrane_material(p)
    if material is not None:  # a membrane resting in the mesh as loaded, each triangle flattened
        b.set_membrane(material, **membrane_bending(p, None if p["bending"] else 0.0))
        refuse_springs_only(p)
        ends = ()
        b.add_particles(mesh.x, mass, pinned=pinned)
        b.add_triangles(mesh.triangles)
    else:
        b.add_particles(mesh.x, mass, pinned=pinned)
    if p["pin_motion"] != "static" and pinned.any():
        b.add_kinematic(np.flatnonzero(pinned), pin_path(p, mesh.x[pinned]))
    if material is None:
        ends, kind = mesh_springs(mesh.triangles, bending=p["bending"])
        stiffness = np.where(kind == topo.FLEX, p["flex_stiffness"], p["stiffness"])
        b.add_springs(ends, stiffness=stiffness, damping=p["damping"], kind=kind)
        b.add_triangles(mesh.triangles)
    if p["jitter"] > 0:  # after the springs: the rest lengths stay those of the mesh as loaded
        b.displace(np.random.default_rng(seed).normal(scale=p["jitter"], size=mesh.x.shape))
    if p["tear"] and len(ends):
        strain = np.full(len(ends), p["tear_strain"], float)
        strain[kind == topo.FLEX] *= p["tear_flex_factor"]
        b.set_tearing(strain)
    # a thickness equal to the default counts as not given: a scene file or the launcher may
    # hand on every default, and the default is the ceiling of the fitted thickness anyway
    add_cloth_extras(b, p, seed, float(np.mean(mass)),
                     fit_thickness=default_thickness is not None and p["thickness"] == default_thickness)


def finish_mesh_cloth(preset, b: SceneBuilder, p: dict[str, Any], seed: int):
    """``preset.finish`` for a mesh cloth. With a collider mesh, an ``xpbd`` default becomes
    ``vbd``: xpbd meets the mesh only after each step, vertex by vertex, so a body that moves
    passes through the garment, where vbd meets it inside its solve (docs/meshes.md, "On a
    moving body"). Then a membrane's method and steps (a positional default becomes the
    membrane's: see :func:`~taichi_sim.scene.materials.finish_membrane_scene`)."""
    scene = preset.finish(b, p, seed)
    if p.get("collider_mesh") and scene.default_integrator == "xpbd":
        scene.default_integrator = "vbd"
    material = membrane_material(p)
    if material is not None:
        bending = p["bending_stiffness"] if p["bending"] else 0.0
        finish_membrane_scene(scene, preset, dict(p, bending_stiffness=bending), material, (), EXPLICIT_STEP_SHARE)
    return scene


PIN_MOTIONS = ("static", "lift", "sweep", "oscillate")


def pin_path(p: dict[str, Any], x0: np.ndarray) -> TranslatePath:
    """Where the pinned vertices (starting at ``x0``, (k, 3) m) go: ``lift`` up (+y) and
    ``sweep`` along +x at ``pin_speed`` for ``pin_duration``, ``oscillate`` up and down by
    ``pin_amplitude`` at ``pin_frequency``."""
    motion = p["pin_motion"]
    if motion == "oscillate":
        return TranslatePath(x0, amplitude=p["pin_amplitude"], frequency=p["pin_frequency"])
    direction = (0.0, 1.0, 0.0) if motion == "lift" else (1.0, 0.0, 0.0)
    return TranslatePath(x0, velocity=tuple(p["pin_speed"] * np.asarray(direction)), duration=p["pin_duration"])


def mesh_size(mesh: ClothMesh, bending: bool, material: str = "springs") -> Size:
    """Particles, springs and triangles a mesh cloth allocates (counted with numpy only)."""
    if material != "springs":
        return Size(mesh.vertex_count, 0, len(mesh.triangles))
    edges, counts = mesh_edges(mesh.triangles)
    springs = len(edges)
    if bending:
        springs += len(bending_pairs(mesh.triangles))
    return Size(mesh.vertex_count, springs, len(mesh.triangles))


#: What every mesh cloth (a file or a garment) reads: the spring model, mass, pins and extras.
MESH_CLOTH_PARAMS: tuple[Param, ...] = (
    Param("pin", "top:0.02", "", f"pinned vertices: {PIN_HELP}"),
    Param("pin_motion", "static", "", "how the pinned vertices move: static, lift (up at pin_speed), sweep "
          "(along +x at pin_speed), both for pin_duration, or oscillate (up and down, pin_amplitude at "
          "pin_frequency)", choices=PIN_MOTIONS),
    Param("pin_speed", 0.3, "m/s", "speed of lifted or swept pins", minimum=0.0),
    Param("pin_duration", 1.0, "s", "how long lifted or swept pins move", minimum=0.0),
    Param("pin_amplitude", 0.1, "m", "amplitude of oscillating pins", minimum=0.0),
    Param("pin_frequency", 1.0, "Hz", "frequency of oscillating pins", minimum=0.0),
    Param("density", 0.2, "kg/m^2", "area density of the cloth: each vertex gets a third of the area of "
          "each of its triangles times this", minimum=0.0, exclusive=True),
    Param("stiffness", 500.0, "N/m", "stiffness of the stretch springs along the mesh edges", minimum=0.0),
    Param("bending", True, "", "a flex spring across each interior edge, between the two vertices "
          "opposite it"),
    Param("flex_stiffness", 20.0, "N/m", "stiffness of the bending springs", minimum=0.0),
    # a membrane instead (material=stvk or neohookean): bending is then bending_stiffness across
    # the interior edges, off with bending=0
    *MATERIAL_PARAMS,
    # drag and the dashpot act per vertex and per spring here: the grid's defaults at 32 x 32
    # (for 0.01 kg particles) would hold back vertices of a few grams per m^2 like honey, and
    # make an explicit step unstable (c / m above 2 / h); these suit vertices of about 3e-5 kg
    *cloth_params("jitter", "gravity"),
    *(q for q in common_params(mass=1.0, drag=2e-5) if q.name == "drag"),
    *with_defaults(cloth_params("damping", "tear", "tear_strain", "tear_flex_factor"), damping=1e-4),
    *cloth_params(*EXTRA_PARAM_NAMES),
)
