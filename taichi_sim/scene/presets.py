"""Scene presets: small functions over the builder, with their parameters."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ..errors import ConfigError
from ..systems.circle import CircleSystem
from . import cloth as topo
from .builder import SceneBuilder
from .params import Param, resolve
from .scene import Scene


def _common(*, mass: float, gravity: float = 9.8, drag: float = 0.0, damping: float = 0.0) -> tuple[Param, ...]:
    return (
        Param("particle_mass", mass, "kg", "mass of each particle", minimum=0.0, exclusive=True),
        Param("gravity", gravity, "m/s^2", "gravitational acceleration (pointing -y)"),
        Param("drag", drag, "N s/m", "viscous drag coefficient, force -drag * v", minimum=0.0),
        Param("damping", damping, "N s/m", "spring dashpot coefficient along the spring", minimum=0.0),
    )


@dataclass(frozen=True)
class ScenePreset:
    name: str
    description: str
    params: tuple[Param, ...]
    build: Callable[[dict[str, Any], int], Scene]
    default_dt: float
    default_integrator: str

    def param(self, name: str) -> Param:
        return next(p for p in self.params if p.name == name)


def _simple(p: dict[str, Any], seed: int) -> Scene:
    system = CircleSystem(1)
    x0 = np.array([[p["radius"], 0.0, 0.0]])
    scene = Scene(name="simple", system=system, state=system.make_state(), x0=x0, v0=None,
                  params=p, features={"particles": 1}, seed=seed,
                  arrays={"mass": np.ones(1), "pinned": np.zeros(1, bool),
                          "gravity": np.zeros(3), "drag": np.float64(0.0)},
                  default_dt=SCENES["simple"].default_dt, default_integrator="rk4")
    scene.reset()
    return scene


def _spring(p: dict[str, Any], seed: int) -> Scene:
    b = SceneBuilder()
    b.add_particles([[0.0, 0.0, 0.0]], p["particle_mass"], pinned=[True])
    b.add_particles([[0.0, -(p["rest_length"] + p["stretch"]), 0.0]], p["particle_mass"])
    b.add_springs([[0, 1]], stiffness=p["stiffness"], damping=p["damping"],
                  rest_length=p["rest_length"])
    return _finish(b, "spring", p, seed)


def _pendulum(p: dict[str, Any], seed: int) -> Scene:
    n = p["particle_count"]
    angle = math.radians(p["angle"])
    direction = np.array([math.sin(angle), -math.cos(angle), 0.0])
    x = np.arange(n)[:, None] * p["segment_length"] * direction
    b = SceneBuilder()
    pinned = np.zeros(n, bool)
    pinned[0] = True
    b.add_particles(x, p["particle_mass"], pinned=pinned)
    b.add_springs(np.stack([np.arange(n - 1), np.arange(1, n)], axis=1),
                  stiffness=p["stiffness"], damping=p["damping"])
    return _finish(b, "pendulum", p, seed)


def cloth_pins(nx: int, ny: int, mode: str) -> np.ndarray:
    """(nx*ny,) bool: which particles a cloth pins (``corners``: the two corners of the edge
    j = ny-1; ``edge``: that whole edge; ``none``)."""
    pinned = np.zeros((nx, ny), bool)
    if mode == "corners":
        pinned[0, -1] = pinned[-1, -1] = True
    elif mode == "edge":
        pinned[:, -1] = True
    return pinned.ravel()


def _cloth(p: dict[str, Any], seed: int) -> Scene:
    nx, ny, size = p["nx"], p["ny"], p["size"]
    x = topo.grid_positions(nx, ny, size, size, origin=(-size / 2, p["height"], -size / 2),
                            u_axis=(1, 0, 0), v_axis=(0, 0, 1))
    b = SceneBuilder()
    b.add_particles(x, p["particle_mass"], pinned=cloth_pins(nx, ny, p["pin"]))
    ends, kind = topo.grid_springs(nx, ny, structural=p["structural"], shear=p["shear"], flex=p["flex"])
    stiffness = np.choose(kind, [p["stiffness"], p["shear_stiffness"], p["flex_stiffness"]]) \
        if len(kind) else np.zeros(0)
    b.add_springs(ends, stiffness=stiffness, damping=p["damping"], kind=kind)
    scene = _finish(b, "cloth", p, seed)
    if p["jitter"] > 0:
        rng = np.random.default_rng(seed)
        free = ~scene.arrays["pinned"]
        scene.x0 = scene.x0.copy()
        scene.x0[free] += rng.normal(scale=p["jitter"], size=(int(free.sum()), 3))
        scene.reset()
    return scene


def _finish(b: SceneBuilder, name: str, p: dict[str, Any], seed: int) -> Scene:
    b.set_gravity(p["gravity"])
    b.set_drag(p["drag"])
    preset = SCENES[name]
    return b.finalize(name=name, params=p, default_dt=preset.default_dt,
                      default_integrator=preset.default_integrator, seed=seed)


SCENES: dict[str, ScenePreset] = {s.name: s for s in (
    ScenePreset("simple", "circle ODE dx/dt = (-y, x, 0); exact solution: rotation at 1 rad/s", (
        Param("radius", 1.0, "m", "initial distance from the origin", minimum=0.0, exclusive=True),
    ), _simple, default_dt=0.01, default_integrator="rk4"),
    ScenePreset("spring", "one particle hanging from a fixed one on a spring", (
        Param("stiffness", 10.0, "N/m", "spring stiffness", minimum=0.0),
        Param("rest_length", 1.0, "m", "spring rest length", minimum=0.0, exclusive=True),
        Param("stretch", 0.5, "m", "initial extension beyond the rest length"),
        *_common(mass=1.0),
    ), _spring, default_dt=0.01, default_integrator="symplectic_euler"),
    ScenePreset("pendulum", "a chain of particles joined by springs, the top one pinned", (
        Param("particle_count", 5, "", "particles in the chain (the first is pinned)", minimum=2),
        Param("stiffness", 1000.0, "N/m", "stiffness of each link", minimum=0.0),
        Param("segment_length", 0.25, "m", "rest length of each link", minimum=0.0, exclusive=True),
        Param("angle", 90.0, "deg", "initial angle of the straight chain from hanging down"),
        *_common(mass=0.1),
    ), _pendulum, default_dt=1e-3, default_integrator="symplectic_euler"),
    ScenePreset("cloth", "an nx x ny cloth of structural, shear and flex springs, starting flat", (
        Param("nx", 32, "", "particles along x", minimum=2),
        Param("ny", 32, "", "particles along z", minimum=2),
        Param("size", 1.0, "m", "side length of the square cloth", minimum=0.0, exclusive=True),
        Param("height", 1.0, "m", "initial height (y) of the flat cloth"),
        Param("stiffness", 500.0, "N/m", "structural spring stiffness", minimum=0.0),
        Param("shear_stiffness", 250.0, "N/m", "shear (diagonal) spring stiffness", minimum=0.0),
        Param("flex_stiffness", 100.0, "N/m", "flex (two-apart) spring stiffness", minimum=0.0),
        Param("structural", True, "", "include structural springs"),
        Param("shear", True, "", "include shear springs"),
        Param("flex", True, "", "include flex springs"),
        Param("pin", "corners", "", "pinned particles: corners (two corners of the far edge), "
              "edge (that whole edge) or none", choices=("corners", "edge", "none")),
        Param("jitter", 0.0, "m", "std. dev. of seeded random noise added to initial positions",
              minimum=0.0),
        *_common(mass=0.01, drag=0.005, damping=0.05),
    ), _cloth, default_dt=1e-3, default_integrator="symplectic_euler"),
)}


def scene_preset(name: str) -> ScenePreset:
    try:
        return SCENES[name]
    except KeyError:
        raise ConfigError(f"unknown scene {name!r} (choose from {', '.join(SCENES)})") from None


def build_scene(name: str, params: dict[str, Any] | None = None, *, seed: int = 0) -> Scene:
    """Build the preset ``name`` with ``params`` overriding its defaults.

    Values may be Python values or command-line strings. Raises ConfigError (a ValueError)
    naming the offending scene or parameter. Call :func:`taichi_sim.init` first.
    """
    preset = scene_preset(name)
    values = resolve(preset.params, name, dict(params or {}))
    return preset.build(values, int(seed))
