"""The scene registry: small recipes over the builder, each with its parameters."""
import math
from typing import Any

import numpy as np

from ..errors import ConfigError, unknown_name
from ..memory import Size, check_size
from ..systems.circle import CircleSystem
from .builder import SceneBuilder
from .cloth_scenes import CLOTH_SCENES
from .constraint_scenes import CONSTRAINT_SCENES
from .garment import GARMENT
from .mesh_scenes import MESH
from .params import Param, resolve
from .preset import ScenePreset, common_params
from .scene import Scene
from .sprinkler import SPRINKLER, SPRINKLER_FIRE, SPRINKLER_SMOKE


def build_simple(preset: ScenePreset, p: dict[str, Any], seed: int) -> Scene:
    system = CircleSystem(1)
    x0 = np.array([[p["radius"], 0.0, 0.0]])
    scene = Scene(name=preset.name, system=system, state=system.make_state(), x0=x0, v0=None,
                  params=p, features={"particles": 1}, seed=seed,
                  static_arrays={"mass": np.ones(1), "pinned": np.zeros(1, bool),
                                 "gravity": np.zeros(3), "drag": np.float64(0.0)},
                  default_dt=preset.default_dt, default_integrator=preset.default_integrator)
    scene.reset()
    return scene


def build_spring(preset: ScenePreset, p: dict[str, Any], seed: int) -> Scene:
    b = SceneBuilder()
    b.add_particles([[0.0, 0.0, 0.0]], p["particle_mass"], pinned=[True])
    b.add_particles([[0.0, -(p["rest_length"] + p["stretch"]), 0.0]], p["particle_mass"])
    b.add_springs([[0, 1]], stiffness=p["stiffness"], damping=p["damping"],
                  rest_length=p["rest_length"])
    return preset.finish(b, p, seed)


def build_pendulum(preset: ScenePreset, p: dict[str, Any], seed: int) -> Scene:
    n = p["particle_count"]
    angle = math.radians(p["angle"])
    direction = np.array([math.sin(angle), -math.cos(angle), 0.0])
    b = SceneBuilder()
    pinned = np.zeros(n, bool)
    pinned[0] = True
    b.add_particles(np.arange(n)[:, None] * p["segment_length"] * direction, p["particle_mass"],
                    pinned=pinned)
    b.add_springs(np.stack([np.arange(n - 1), np.arange(1, n)], axis=1),
                  stiffness=p["stiffness"], damping=p["damping"])
    if p["grab"]:  # critically damped pull, as on the cloth
        b.enable_grab(p["grab_stiffness"], damping=2 * math.sqrt(p["grab_stiffness"] * p["particle_mass"]))
    return preset.finish(b, p, seed)


SCENES: dict[str, ScenePreset] = {s.name: s for s in (
    ScenePreset("simple", "circle ODE dx/dt = (-y, x, 0); exact solution: rotation at 1 rad/s", (
        Param("radius", 1.0, "m", "initial distance from the origin", minimum=0.0, exclusive=True),
    ), build_simple, default_dt=0.01, default_integrator="rk4"),
    ScenePreset("spring", "one particle hanging from a fixed one on a spring", (
        Param("stiffness", 10.0, "N/m", "spring stiffness", minimum=0.0),
        Param("rest_length", 1.0, "m", "spring rest length", minimum=0.0, exclusive=True),
        Param("stretch", 0.5, "m", "initial extension beyond the rest length"),
        *common_params(mass=1.0),
    ), build_spring, default_dt=0.01, default_integrator="symplectic_euler", size=lambda p: Size(2, 1)),
    ScenePreset("pendulum", "a chain of particles joined by springs, the top one pinned", (
        Param("particle_count", 5, "", "particles in the chain (the first is pinned)", minimum=2),
        Param("stiffness", 1000.0, "N/m", "stiffness of each link", minimum=0.0),
        Param("segment_length", 0.25, "m", "rest length of each link", minimum=0.0, exclusive=True),
        Param("angle", 90.0, "deg", "initial angle of the straight chain from hanging down"),
        *common_params(mass=0.1),
        Param("grab", False, "", "allow pulling a particle with the mouse (a stiff spring)"),
        Param("grab_stiffness", 50.0, "N/m", "stiffness of the grab spring", minimum=0.0),
    ), build_pendulum, default_dt=1e-3, default_integrator="symplectic_euler",
        size=lambda p: Size(p["particle_count"], p["particle_count"] - 1), size_params=("particle_count",)),
    *CLOTH_SCENES,
    MESH,
    GARMENT,
    SPRINKLER,
    SPRINKLER_FIRE,
    SPRINKLER_SMOKE,
    *CONSTRAINT_SCENES,
)}


def scene_preset(name: str) -> ScenePreset:
    try:
        return SCENES[name]
    except KeyError:
        raise ConfigError(unknown_name("unknown scene", name, SCENES)) from None


def check_scene_memory(preset: ScenePreset, values: dict[str, Any], *, precision: str,
                       integrators: tuple = (), linear_solver: str = "cg", copies: int = 1) -> int:
    """Refuse (ConfigError naming the size parameters) a scene too large for the available
    memory, before anything is allocated (see :mod:`taichi_sim.memory` for the estimate's
    basis). ``values`` are resolved parameters; ``integrators``: the classes that will step
    it (their scratch; none when the caller does not know yet). Returns the estimate in bytes."""
    culprits = ", ".join(f"{k} = {values[k]}" for k in preset.size_params) or f"of scene {preset.name!r}"
    return check_size(preset.size(values), culprits, precision=precision,
                      integrators=integrators, linear_solver=linear_solver,
                      copies=copies)


def build_scene(name: str, params: dict[str, Any] | None = None, *, seed: int = 0) -> Scene:
    """Build the preset ``name`` with ``params`` overriding its defaults.

    Values may be Python values or command-line strings. Raises ConfigError (a ValueError)
    naming the offending scene or parameter, also when the scene would need more memory than is
    available (estimated with the scratch of its default integrator). Call
    :func:`taichi_sim.init` first.
    """
    from .. import runtime

    preset = scene_preset(name)
    values = resolve(preset.params, name, dict(params or {}))
    check_scene_memory(preset, values, precision=runtime.precision())
    scene = preset.build(preset, values, int(seed))
    if preset.default_tolerance is not None:
        scene.default_tolerance = preset.default_tolerance
    return scene
