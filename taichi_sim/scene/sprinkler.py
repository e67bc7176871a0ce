"""The sprinkler: particles sprayed from a nozzle, bouncing on the ground, dying of old age."""
import math
from typing import Any

from ..memory import Size
from .builder import SceneBuilder
from .cloth_scenes import sphere_path
from .events import EmitterSpec
from .params import Param
from .preset import ScenePreset, common_params
from .scene import Scene

SPRINKLER_PARAMS: tuple[Param, ...] = (
    Param("rate", 400.0, "1/s", "particles emitted per second", minimum=0.0),
    Param("speed", 3.5, "m/s", "launch speed", minimum=0.0),
    Param("spread", 12.0, "deg", "half-angle of the spray cone", minimum=0.0),
    Param("tilt", 25.0, "deg", "nozzle tilt from vertical toward +x"),
    Param("nozzle_height", 0.1, "m", "nozzle height above the ground plane"),
    Param("lifetime", 3.0, "s", "how long a particle lives", minimum=0.0, exclusive=True),
    Param("capacity", 1500, "", "ring-buffer size (the oldest particles are recycled)", minimum=1),
    *common_params(mass=0.001, drag=0.0002, damping=None),
    Param("restitution", 0.5, "", "ground bounce: normal speed kept after impact (0..1)", minimum=0.0),
    Param("plane_friction", 0.2, "", "Coulomb friction coefficient on the ground", minimum=0.0),
    Param("sphere", False, "", "a sphere the spray bounces off"),
    Param("sphere_radius", 0.25, "m", "sphere radius", minimum=0.0, exclusive=True),
    Param("sphere_x", 0.8, "m", "sphere centre x"),
    Param("sphere_y", 0.25, "m", "sphere centre y"),
    Param("sphere_z", 0.0, "m", "sphere centre z"),
    Param("sphere_friction", 0.0, "", "Coulomb friction coefficient on the sphere", minimum=0.0),
)


def build_sprinkler(preset: ScenePreset, p: dict[str, Any], seed: int) -> Scene:
    tilt = math.radians(p["tilt"])
    b = SceneBuilder()
    b.set_emitter(EmitterSpec(position=(0.0, p["nozzle_height"], 0.0),
                              direction=(math.sin(tilt), math.cos(tilt), 0.0), rate=p["rate"],
                              speed=p["speed"], spread=p["spread"], lifetime=p["lifetime"],
                              capacity=p["capacity"]), p["particle_mass"])
    b.set_plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), min(p["restitution"], 1.0), p["plane_friction"])
    if p["sphere"]:
        b.add_sphere(sphere_path(p | {"sphere_motion": "static"}), p["sphere_radius"], p["sphere_friction"])
    return preset.finish(b, p, seed)


SPRINKLER = ScenePreset("sprinkler", "a sprinkler spraying particles over a ground plane",
                        SPRINKLER_PARAMS, build_sprinkler, default_dt=2e-3,
                        default_integrator="symplectic_euler",
                        size=lambda p: Size(p["capacity"], 0), size_params=("capacity",))
