"""The cloth family: a grid of structural, shear and flex springs, and the extras a cloth scene
may switch on (wind, a sphere, a capsule, a box, a mesh, a ground plane, tearing, grab)."""
import math
from typing import Any

import numpy as np

from ..errors import ConfigError
from ..forces.springs.spectrum import explicit_default_step
from ..memory import Size
from . import cloth as topo
from .builder import SceneBuilder
from .colliders import SpherePath, load_mesh_file
from .kinematic import TwistPath
from .materials import MATERIAL_PARAMS, add_membrane_cloth, finish_membrane_scene, membrane_material
from .params import Param
from .preset import ScenePreset, common_params, with_defaults
from .scene import Scene

PIN_MODES = ("corners", "edge", "pole", "sides", "border", "none")

# The default 1 m^2 cloth of 32 x 32 keeps the particles every grid cloth had before its mass
# became an area density: kg/m^2 and N s/m^3 (10.24 and 5.12)
GRID_DENSITY = topo.FIXED_PARTICLE_MASS * 32 * 32
GRID_AREA_DRAG = topo.FIXED_PARTICLE_DRAG * 32 * 32
# Presets whose default method is conditionally stable: their default step stays below this
# share of symplectic Euler's stable step at any resolution (a finer grid's particles are
# lighter: spectrum.explicit_default_step)
EXPLICIT_DEFAULTS = ("symplectic_euler",)
EXPLICIT_STEP_SHARE = 0.9

CLOTH_PARAMS: tuple[Param, ...] = (
    Param("nx", 32, "", "particles along the grid's i axis (world x)", minimum=2),
    Param("ny", 32, "", "particles along the grid's j axis (world z, or y when vertical)", minimum=2),
    Param("size", 1.0, "m", "side length of the square cloth", minimum=0.0, exclusive=True),
    Param("height", 1.0, "m", "height (y) of the flat cloth, or of its top edge when vertical"),
    Param("orientation", "horizontal", "", "horizontal (in the x-z plane) or vertical (x-y plane)",
          choices=("horizontal", "vertical")),
    Param("stiffness", 500.0, "N/m", "structural spring stiffness", minimum=0.0),
    Param("shear_stiffness", 250.0, "N/m", "shear (diagonal) spring stiffness", minimum=0.0),
    Param("flex_stiffness", 100.0, "N/m", "flex (two-apart) spring stiffness", minimum=0.0),
    Param("structural", True, "", "include structural springs"),
    Param("shear", True, "", "include shear springs"),
    Param("flex", True, "", "include flex springs"),
    *MATERIAL_PARAMS,
    Param("pin", "corners", "", "pinned particles: corners (both ends of the edge j = ny-1), edge "
          "(that whole edge), pole (the edge i = 0), sides (edges i = 0 and i = nx-1), border (all four "
          "edges) or none",
          choices=PIN_MODES),
    Param("jitter", 0.0, "m", "std. dev. of seeded random noise added to initial positions",
          minimum=0.0),
    Param("density", GRID_DENSITY, "kg/m^2", "area density: the cloth weighs density x size^2 at any nx, ny, "
          "shared equally by its particles", minimum=0.0, exclusive=True),
    Param("area_drag", GRID_AREA_DRAG, "N s/m^3", "viscous drag per m^2 of cloth: each particle feels "
          "-area_drag x its share of the area x v (the same decay at any nx, ny)", minimum=0.0),
    *(q for q in common_params(mass=topo.FIXED_PARTICLE_MASS, drag=topo.FIXED_PARTICLE_DRAG, damping=0.05) if q.name not in ("particle_mass", "drag")),
    # wind
    Param("wind", False, "", "aerodynamic gusting wind on the cloth triangles"),
    Param("wind_speed", 6.0, "m/s", "mean wind speed", minimum=0.0),
    Param("wind_heading", 0.0, "deg", "wind direction in the x-z plane, from +x toward +z"),
    Param("wind_gust", 0.6, "", "relative strength of the gusts", minimum=0.0),
    Param("wind_gust_frequency", 0.7, "Hz", "typical gust frequency", minimum=0.0, exclusive=True),
    Param("wind_drag", 0.6, "kg/m^3", "aerodynamic coefficient rho*C_d/2 (air, C_d = 1: 0.6)",
          minimum=0.0),
    # sphere
    Param("sphere", False, "", "a sphere the cloth collides with"),
    Param("sphere_radius", 0.3, "m", "sphere radius", minimum=0.0, exclusive=True),
    Param("sphere_x", 0.0, "m", "sphere centre x at t = 0"),
    Param("sphere_y", 0.45, "m", "sphere centre y at t = 0"),
    Param("sphere_z", 0.0, "m", "sphere centre z at t = 0"),
    Param("sphere_motion", "static", "", "static, drop (down at sphere_speed), sweep (along +x at "
          "sphere_speed) or oscillate (up and down, sphere_amplitude at sphere_frequency)",
          choices=("static", "drop", "sweep", "oscillate")),
    Param("sphere_speed", 0.5, "m/s", "speed of a dropping or sweeping sphere", minimum=0.0),
    Param("sphere_amplitude", 0.2, "m", "amplitude of an oscillating sphere", minimum=0.0),
    Param("sphere_frequency", 0.5, "Hz", "frequency of an oscillating sphere", minimum=0.0),
    Param("sphere_friction", 0.0, "", "Coulomb friction coefficient on the sphere", minimum=0.0),
    Param("sphere_spin", 0.0, "rad/s", "the sphere's spin about the vertical axis through its centre "
          "(friction drags what lies on it)"),
    Param("object_faces", True, "", "test the cloth's triangles against spheres, capsules and boxes "
          "too, not only its vertices (an object smaller than the spacing cannot pass between them)"),
    # capsule (axis along x) and axis-aligned box
    Param("capsule", False, "", "a capsule (axis along x) the cloth collides with"),
    Param("capsule_radius", 0.1, "m", "capsule radius", minimum=0.0, exclusive=True),
    Param("capsule_length", 0.6, "m", "length of the capsule's axis (end-cap centre to centre)",
          minimum=0.0, exclusive=True),
    Param("capsule_x", 0.0, "m", "capsule centre x"),
    Param("capsule_y", 0.4, "m", "capsule centre y"),
    Param("capsule_z", 0.0, "m", "capsule centre z"),
    Param("capsule_friction", 0.3, "", "Coulomb friction coefficient on the capsule", minimum=0.0),
    Param("box", False, "", "an axis-aligned box the cloth collides with"),
    Param("box_half_x", 0.2, "m", "box half extent along x", minimum=0.0, exclusive=True),
    Param("box_half_y", 0.2, "m", "box half extent along y", minimum=0.0, exclusive=True),
    Param("box_half_z", 0.2, "m", "box half extent along z", minimum=0.0, exclusive=True),
    Param("box_x", 0.0, "m", "box centre x"),
    Param("box_y", 0.2, "m", "box centre y"),
    Param("box_z", 0.0, "m", "box centre z"),
    Param("box_friction", 0.3, "", "Coulomb friction coefficient on the box", minimum=0.0),
    # a triangle mesh (a table, a body) from a file
    Param("collider_mesh", "", "path", "a mesh file (OBJ, STL, PLY, GLB, ...: whatever trimesh reads) the cloth "
          "collides with, in its own coordinates (m), or a pattern of numbered files (body_*.obj) played as "
          "frames at collider_mesh_fps; empty for none"),
    Param("collider_mesh_fps", 30.0, "1/s", "frames per second of a collider mesh sequence (the last frame is held)",
          minimum=0.0, exclusive=True),
    Param("collider_mesh_friction", 0.3, "", "Coulomb friction coefficient on the collider mesh", minimum=0.0),
    Param("collider_mesh_skin", 0.005, "m", "distance the cloth's vertices keep from the collider mesh",
          minimum=0.0, exclusive=True),
    # ground plane
    Param("plane", False, "", "a ground plane the cloth collides with"),
    Param("plane_height", 0.0, "m", "height (y) of the ground plane"),
    Param("restitution", 0.3, "", "ground bounce: normal speed kept after impact (0..1)", minimum=0.0),
    Param("plane_friction", 0.5, "", "Coulomb friction coefficient on the ground", minimum=0.0),
    # tearing
    Param("tear", False, "", "springs break when over-stretched"),
    Param("tear_strain", 0.3, "", "strain |d|/r - 1 at which a structural spring breaks (inf: never)",
          minimum=0.0, exclusive=True, allow_infinite=True),
    Param("tear_shear_factor", 1.5, "", "shear springs break at this multiple of tear_strain",
          minimum=0.0, exclusive=True),
    Param("tear_flex_factor", 2.0, "", "flex springs break at this multiple of tear_strain",
          minimum=0.0, exclusive=True),
    Param("tear_i_factor", 1.0, "", "multiplier for springs along the i axis (anisotropic fabric)",
          minimum=0.0, exclusive=True),
    Param("tear_j_factor", 1.0, "", "multiplier for springs along the j axis", minimum=0.0, exclusive=True),
    Param("tear_seam", "none", "", "a weakened seam: across-i (splits the i axis in half), across-j, "
          "or none", choices=("none", "across-i", "across-j")),
    Param("tear_seam_factor", 0.4, "", "threshold multiplier of springs crossing the seam",
          minimum=0.0, exclusive=True),
    Param("tear_noise", 0.0, "", "relative amplitude of a seeded smooth noise map on thresholds (0..1)",
          minimum=0.0),
    # the cloth against itself
    Param("self_collision", False, "", "keep the cloth from passing through itself (contacts, "
          "continuous detection and rigid impact zones after each step)"),
    Param("thickness", 0.01, "m", "distance a vertex keeps from the cloth's other triangles",
          minimum=0.0, exclusive=True),
    Param("self_friction", 0.2, "", "Coulomb friction coefficient between layers of the cloth", minimum=0.0),
    Param("collision_iterations", 4, "", "rounds of contact resolution per step before the impact "
          "zones", minimum=1),
    # twist: the held sides i = 0 and i = nx-1 turned about the line between them
    Param("twist", False, "", "turn the two held sides (pin=sides) in opposite directions about the "
          "line between them, wringing the cloth"),
    Param("twist_rate", 0.5, "turns/s", "how fast each held side turns (the other turns the other "
          "way)", minimum=0.0, exclusive=True),
    Param("twist_duration", 3.0, "s", "how long the sides turn; then they hold still", minimum=0.0,
          exclusive=True),
    Param("twist_approach", 0.3, "", "fraction of the width by which the sides close in while they "
          "turn (slack for the folds; 0 to < 1)", minimum=0.0),
    # grab
    Param("grab", False, "", "allow pulling a particle with the mouse (a stiff spring)"),
    Param("grab_stiffness", 200.0, "N/m", "stiffness of the grab spring", minimum=0.0),
)


def cloth_pins(nx: int, ny: int, mode: str) -> np.ndarray:
    """(nx*ny,) bool: which particles a cloth pins (see the ``pin`` parameter)."""
    pinned = np.zeros((nx, ny), bool)
    if mode == "corners":
        pinned[0, -1] = pinned[-1, -1] = True
    elif mode == "edge":
        pinned[:, -1] = True
    elif mode == "pole":
        pinned[0, :] = True
    elif mode == "sides":
        pinned[0, :] = pinned[-1, :] = True
    elif mode == "border":
        pinned[0, :] = pinned[-1, :] = pinned[:, 0] = pinned[:, -1] = True
    return pinned.ravel()


def tear_thresholds(p: dict[str, Any], ends: np.ndarray, kind: np.ndarray, seed: int) -> np.ndarray:
    """Per-spring breaking strains: tear_strain, scaled by kind, grid direction, seam and noise."""
    nx, ny = p["nx"], p["ny"]
    i, j = ends // ny, ends % ny
    strain = np.full(len(ends), p["tear_strain"], float)
    strain[kind == topo.SHEAR] *= p["tear_shear_factor"]
    strain[kind == topo.FLEX] *= p["tear_flex_factor"]
    strain[j[:, 0] == j[:, 1]] *= p["tear_i_factor"]  # springs along the i axis
    strain[i[:, 0] == i[:, 1]] *= p["tear_j_factor"]
    if p["tear_seam"] != "none":
        coord, n = (i, nx) if p["tear_seam"] == "across-i" else (j, ny)
        middle = (n - 1) / 2
        crosses = (np.minimum(coord[:, 0], coord[:, 1]) < middle) & (np.maximum(coord[:, 0], coord[:, 1]) > middle)
        strain[crosses] *= p["tear_seam_factor"]
    if p["tear_noise"] > 0:
        # Smooth value noise: a seeded 6x6 lattice, bilinear at each spring's midpoint.
        lattice = np.random.default_rng(seed).uniform(-1.0, 1.0, (6, 6))
        u = (i.mean(axis=1) / max(nx - 1, 1)) * 5
        w = (j.mean(axis=1) / max(ny - 1, 1)) * 5
        u0, w0 = np.minimum(u.astype(int), 4), np.minimum(w.astype(int), 4)
        fu, fw = u - u0, w - w0
        noise = (lattice[u0, w0] * (1 - fu) * (1 - fw) + lattice[u0 + 1, w0] * fu * (1 - fw)
                 + lattice[u0, w0 + 1] * (1 - fu) * fw + lattice[u0 + 1, w0 + 1] * fu * fw)
        strain *= np.maximum(1.0 + p["tear_noise"] * noise, 0.05)
    return strain


def sphere_path(p: dict[str, Any]) -> SpherePath:
    center = (p["sphere_x"], p["sphere_y"], p["sphere_z"])
    motion, spin = p["sphere_motion"], float(p.get("sphere_spin", 0.0))
    if motion == "drop":
        return SpherePath(center, velocity=(0.0, -p["sphere_speed"], 0.0), spin=spin)
    if motion == "sweep":
        return SpherePath(center, velocity=(p["sphere_speed"], 0.0, 0.0), spin=spin)
    if motion == "oscillate":
        return SpherePath(center, amplitude=p["sphere_amplitude"], frequency=p["sphere_frequency"],
                          axis=(0.0, 1.0, 0.0), spin=spin)
    return SpherePath(center, spin=spin)


def add_twist(b: SceneBuilder, p: dict[str, Any], x: np.ndarray) -> None:
    """Drive the pinned sides i = 0 and i = nx-1 (pin=sides) about the grid's i axis through the
    cloth's middle: side 0 turns right-handed about +x, the other side the other way, and both
    slide toward the middle by ``twist_approach`` / 2 of the width over ``twist_duration``."""
    if p["pin"] != "sides":
        raise ConfigError(f"parameter twist: turns the sides held by pin=sides, got pin={p['pin']!r}")
    if not p["twist_approach"] < 1.0:
        raise ConfigError(f"parameter twist_approach: must be < 1 (the sides would cross), "
                          f"got {p['twist_approach']}")
    nx, ny = p["nx"], p["ny"]
    ids = topo.grid_index(nx, ny)[[0, -1], :].ravel()
    sign = np.repeat([1.0, -1.0], ny)
    slide = sign * 0.5 * p["twist_approach"] * p["size"]
    origin = x[ids].mean(axis=0)
    b.add_kinematic(ids, TwistPath(x[ids], sign, slide, tuple(origin), (1.0, 0.0, 0.0),
                                   p["twist_rate"], p["twist_duration"]))


def build_cloth(preset: ScenePreset, p: dict[str, Any], seed: int) -> Scene:
    nx, ny, size = p["nx"], p["ny"], p["size"]
    if p["orientation"] == "horizontal":
        x = topo.grid_positions(nx, ny, size, size, origin=(-size / 2, p["height"], -size / 2),
                                u_axis=(1, 0, 0), v_axis=(0, 0, 1))
    else:  # j runs down from the top edge at `height`, so the edge j = ny-1 is at the bottom
        x = topo.grid_positions(nx, ny, size, size, origin=(-size / 2, p["height"], 0.0),
                                u_axis=(1, 0, 0), v_axis=(0, -1, 0))
    b = SceneBuilder()
    material = membrane_material(p)
    if material is not None:  # a membrane: masses lumped from the triangles' areas, no springs
        masses = add_membrane_cloth(b, p, x, topo.grid_triangles(nx, ny), cloth_pins(nx, ny, p["pin"]), material)
        mass = float(np.mean(masses))
        ends = ()
    else:
        mass = topo.grid_particle_mass(p)
        b.add_particles(x, mass, pinned=cloth_pins(nx, ny, p["pin"]))
        b.declare_grid(0, nx, ny)
        ends, kind = topo.grid_springs(nx, ny, structural=p["structural"], shear=p["shear"], flex=p["flex"])
        stiffness = topo.kind_stiffness(kind, p)
        b.add_springs(ends, stiffness=stiffness, damping=p["damping"], kind=kind)
        b.add_triangles(topo.grid_triangles(nx, ny))
    if p["jitter"] > 0:  # after the springs, so rest lengths stay those of the flat grid
        b.displace(np.random.default_rng(seed).normal(scale=p["jitter"], size=(nx * ny, 3)))
    if p["tear"] and len(ends):
        b.set_tearing(tear_thresholds(p, ends, kind, seed))
    if p["twist"]:
        add_twist(b, p, x)
    add_cloth_extras(b, p, seed, mass)
    scene = preset.finish(b, p, seed, drag=topo.grid_particle_drag(p))
    if material is not None:
        return finish_membrane_scene(scene, preset, p, material, EXPLICIT_DEFAULTS, EXPLICIT_STEP_SHARE)
    if preset.default_integrator in EXPLICIT_DEFAULTS:
        # a finer grid has lighter particles and a shorter stable step (omega_max ~ n, the
        # dashpots' gamma_max ~ n^2)
        scene.default_dt = explicit_default_step(scene.arrays, scene.x0, scene.default_dt, EXPLICIT_STEP_SHARE)
        scene.explicit_dt = scene.default_dt
    elif preset.explicit_dt is not None:  # the same for an explicit method asked for by name
        scene.explicit_dt = explicit_default_step(scene.arrays, scene.x0, preset.explicit_dt, EXPLICIT_STEP_SHARE)
    return scene


def add_cloth_extras(b: SceneBuilder, p: dict[str, Any], seed: int, grab_mass: float, *,
                     fit_thickness: bool = False) -> None:
    """The extras any cloth (a grid or a mesh) switches on with its parameters: wind, spheres,
    capsules, boxes, the ground, self-collision and grab (its dashpot critically damped for a
    particle of ``grab_mass``, kg). Wants the cloth's particles, springs and triangles added.
    ``fit_thickness``: self-collision fits its thickness to the cloth's rest shape, ``thickness``
    at most (:meth:`~taichi_sim.scene.builder.SceneBuilder.enable_self_collision`)."""
    if p["wind"]:
        b.set_wind(speed=p["wind_speed"], heading=p["wind_heading"], gust=p["wind_gust"],
                   gust_frequency=p["wind_gust_frequency"], drag_coefficient=p["wind_drag"], seed=seed)
    b.set_object_faces(p["object_faces"])
    if p["sphere"]:
        b.add_sphere(sphere_path(p), p["sphere_radius"], p["sphere_friction"])
    if p["capsule"]:
        b.add_capsule(SpherePath((p["capsule_x"], p["capsule_y"], p["capsule_z"])), p["capsule_radius"],
                      (p["capsule_length"] / 2, 0.0, 0.0), p["capsule_friction"])
    if p["box"]:
        b.add_box(SpherePath((p["box_x"], p["box_y"], p["box_z"])),
                  (p["box_half_x"], p["box_half_y"], p["box_half_z"]), p["box_friction"])
    if p["collider_mesh"]:
        vertices, triangles = load_mesh_file(p["collider_mesh"])
        b.add_mesh_collider(vertices, triangles, friction=p["collider_mesh_friction"], skin=p["collider_mesh_skin"],
                            fps=p["collider_mesh_fps"])
    if p["plane"]:
        b.set_plane((0.0, p["plane_height"], 0.0), (0.0, 1.0, 0.0), min(p["restitution"], 1.0),
                    p["plane_friction"])
    if p["self_collision"]:
        b.enable_self_collision(p["thickness"], p["self_friction"], int(p["collision_iterations"]),
                                fit=fit_thickness)
    if p["grab"]:
        b.enable_grab(p["grab_stiffness"], damping=2 * math.sqrt(p["grab_stiffness"] * grab_mass))


def cloth_params(*names: str) -> tuple[Param, ...]:
    """The cloth parameters ``names`` (in that order), for other cloth families to share."""
    by_name = {p.name: p for p in CLOTH_PARAMS}
    return tuple(by_name[name] for name in names)


#: The parameters :func:`add_cloth_extras` reads.
EXTRA_PARAM_NAMES = tuple(p.name for p in CLOTH_PARAMS if p.name.split("_")[0] in (
    "wind", "sphere", "object", "capsule", "box", "plane", "restitution", "self", "thickness",
    "collision", "grab", "collider"))


def cloth_size(p: dict[str, Any]) -> Size:
    """Particles, springs and triangles of a cloth, in closed form (nothing allocated)."""
    nx, ny = p["nx"], p["ny"]
    if p["material"] != "springs":
        return Size(nx * ny, 0, 2 * (nx - 1) * (ny - 1))
    counts = topo.spring_counts(nx, ny)
    springs = sum(counts[kind] for kind, on in ((topo.STRUCTURAL, p["structural"]), (topo.SHEAR, p["shear"]),
                                                (topo.FLEX, p["flex"])) if on)
    return Size(nx * ny, springs, 2 * (nx - 1) * (ny - 1))


_CLOTH_SIZE = dict(size=cloth_size, size_params=("nx", "ny"))

CLOTH_SCENES = (
    ScenePreset("cloth", "an nx x ny cloth of structural, shear and flex springs, starting flat; "
                "--set wind/sphere/plane/tear/grab=1 add the extras", CLOTH_PARAMS, build_cloth,
                default_dt=1e-3, default_integrator="symplectic_euler", **_CLOTH_SIZE),
    ScenePreset("cloth-sphere", "a cloth falling onto a sphere above the ground",
                with_defaults(CLOTH_PARAMS, pin="none", sphere=True, plane=True, sphere_friction=0.3),
                build_cloth, default_dt=1e-3, default_integrator="symplectic_euler", **_CLOTH_SIZE),
    ScenePreset("cloth-spin", "a cloth dropped onto a sphere spinning about the vertical axis: "
                "friction drags it round until it slides off (self-collision on)",
                with_defaults(CLOTH_PARAMS, pin="none", sphere=True, plane=True, sphere_friction=1.0,
                              sphere_spin=10.0, sphere_x=0.15, plane_friction=0.3, restitution=0.0,
                              self_collision=True),
                # vbd at one step a frame, in pieces while the sphere flings the cloth: it slides
                # off as with symplectic Euler, in half the wall time (docs/lab/vbd.md, "The fold's pace").
                build_cloth, default_dt=1 / 60, default_integrator="vbd", explicit_dt=1e-3, **_CLOTH_SIZE),
    ScenePreset("cloth-tear", "a cloth held at two sides, torn by a sphere dropping through it",
                with_defaults(CLOTH_PARAMS, pin="sides", sphere=True, sphere_y=1.5, sphere_radius=0.2,
                              sphere_motion="drop", sphere_speed=0.6, tear=True, tear_strain=0.3,
                              tear_noise=0.3, plane=True, stiffness=1500.0, shear_stiffness=750.0,
                              flex_stiffness=300.0),
                build_cloth, default_dt=1e-3, default_integrator="symplectic_euler", **_CLOTH_SIZE),
    ScenePreset("cloth-wind", "a flag pinned to a pole, fluttering in gusty wind",
                with_defaults(CLOTH_PARAMS, orientation="vertical", pin="pole", height=1.5, wind=True,
                              wind_speed=8.0, wind_heading=15.0, density=0.4096, stiffness=40.0,
                              shear_stiffness=20.0, flex_stiffness=8.0, jitter=0.002),
                build_cloth, default_dt=1e-3, default_integrator="symplectic_euler", **_CLOTH_SIZE),
    ScenePreset("cloth-fold", "a cloth dropped edge-first onto the ground, piling up in folds on "
                "itself (self-collision on)",
                with_defaults(CLOTH_PARAMS, orientation="vertical", pin="none", height=1.1, plane=True,
                              plane_friction=0.6, restitution=0.0, self_collision=True, jitter=0.002,
                              flex_stiffness=20.0),
                # vbd at one step a frame, its substeps cut into pieces while the cloth collapses:
                # the pace of the explicit step at a fraction of its wall time (64 x 64: the 5 s
                # in 42 s, symplectic Euler's first second in 65 s; docs/lab/vbd.md, "The fold's pace").
                build_cloth, default_dt=1 / 60, default_integrator="vbd", explicit_dt=1e-3, **_CLOTH_SIZE,
                # A pile of layers a thickness (1 cm) apart: positions within half of it draw the
                # same pile; held to 1 mm the fold takes 1.6 times the sweeps (docs/integrators.md,
                # "--tolerance").
                default_tolerance=5e-3),
    # vbd at one step a frame: it moves the turning pins inside its solve, under its contact
    # bounds, and no frame intersects, in a quarter of symplectic Euler's wall time (docs/vbd.md).
    ScenePreset("cloth-twist", "a cloth held at two sides that turn in opposite directions, wringing "
                "it into folds against itself (self-collision on)",
                with_defaults(CLOTH_PARAMS, pin="sides", twist=True, self_collision=True, jitter=0.002,
                              flex_stiffness=20.0),
                build_cloth, default_dt=1 / 60, default_integrator="vbd", explicit_dt=1e-3, **_CLOTH_SIZE),
    # Nearly inextensible cloth at one step per 60 Hz frame: symplectic Euler would need about
    # 2000 steps per frame here (h < 2 / omega_max), XPBD takes one step of 50 substeps: with
    # XPBD's own 20 the fall ends 5 cm from the motion at 64 x 64, with 50 within 2 cm
    # (docs/lab/vbd.md, "cloth-stiff's default").
    # The cloth as a material: the default 1 m^2 cloth's weight as a Neo-Hookean membrane of
    # E t = 1000 N/m with bending, at one implicit Euler step per 60 Hz frame.
    ScenePreset("cloth-membrane", "a cloth as a material: a Neo-Hookean membrane (E t = 1000 N/m, nu = 0.3) "
                "with bending across its edges, the same cloth at any nx, ny, one implicit step a frame",
                with_defaults(CLOTH_PARAMS, material="neohookean", bending_stiffness=1e-3, membrane_damping=0.01),
                build_cloth, default_dt=1 / 60, default_integrator="implicit_euler", explicit_dt=1e-3,
                **_CLOTH_SIZE),
    ScenePreset("cloth-stiff", "a nearly inextensible cloth (k = 1e6 N/m) at one 1/60 s step per "
                "frame with XPBD",
                with_defaults(CLOTH_PARAMS, stiffness=1e6, shear_stiffness=5e5, flex_stiffness=2e5),
                build_cloth, default_dt=1 / 60, default_integrator="xpbd", **_CLOTH_SIZE,
                integrator_options={"xpbd": {"substeps": 50}}),
)
