"""The sprinkler: particles sprayed from a nozzle, bouncing on the ground, dying of old age.

Its ``effect`` (water, fire, smoke) says how the renderer draws the particles
(:mod:`taichi_sim.render.effects`); the fire and smoke presets also change the physics: hot gas
rises (``buoyancy``) and is stirred (``turbulence``), slowed by drag.
"""
import math
from typing import Any

from ..memory import Size
from .builder import SceneBuilder
from .cloth_scenes import sphere_path
from .events import EmitterSpec
from .params import Param
from .preset import ScenePreset, common_params, with_defaults
from .scene import Scene

#: The looks :mod:`taichi_sim.render.effects` draws (listed here, so the scene layer does not
#: import the renderer).
EFFECTS = ("water", "fire", "smoke")

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
    Param("effect", "water", "", "how the particles are drawn over their life: water, fire or smoke",
          choices=EFFECTS),
    Param("buoyancy", 0.0, "m/s^2", "upward acceleration of every particle (hot gas rising)"),
    Param("turbulence", 0.0, "m/s^2", "largest acceleration of a seeded random eddy field", minimum=0.0),
    Param("turbulence_scale", 0.3, "m", "size of the turbulent eddies", minimum=0.0, exclusive=True),
    Param("turbulence_frequency", 1.0, "Hz", "how fast the eddies change", minimum=0.0),
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
    b.set_turbulence(amplitude=p["turbulence"], scale=p["turbulence_scale"], frequency=p["turbulence_frequency"])
    return preset.finish(b, p, seed, gravity=p["gravity"] - p["buoyancy"])


def _sprinkler(name: str, description: str, **defaults) -> ScenePreset:
    return ScenePreset(name, description, with_defaults(SPRINKLER_PARAMS, **defaults), build_sprinkler,
                       default_dt=2e-3, default_integrator="symplectic_euler",
                       size=lambda p: Size(p["capacity"], 0), size_params=("capacity",))


SPRINKLER = _sprinkler("sprinkler", "a sprinkler spraying particles over a ground plane")
# Hot gas: buoyancy lifts it against gravity and drag caps its climb (terminal speed
# m (buoyancy - g) / drag: 1.2 m/s for fire, 0.35 m/s for smoke), turbulence makes it flicker.
SPRINKLER_FIRE = _sprinkler("sprinkler-fire", "a burner: short-lived flames rising, flickering, cooling",
                            effect="fire", rate=1200.0, speed=0.8, spread=40.0, tilt=0.0, lifetime=0.8,
                            capacity=1200, drag=0.005, buoyancy=15.8, turbulence=8.0, turbulence_scale=0.15,
                            turbulence_frequency=3.0)
SPRINKLER_SMOKE = _sprinkler("sprinkler-smoke", "a smoke plume: slow puffs rising, spreading and thinning",
                             effect="smoke", rate=150.0, speed=0.4, spread=35.0, tilt=0.0, lifetime=4.5,
                             capacity=700, drag=0.005, buoyancy=11.55, turbulence=2.5, turbulence_scale=0.35,
                             turbulence_frequency=0.6)
