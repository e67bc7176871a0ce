"""Scenes held by constraint forces instead of springs (see :mod:`taichi_sim.systems.constraints`)."""
import math
from typing import Any

import numpy as np

from ..errors import ConfigError
from ..memory import Size
from ..systems.constraints import MAX_ROWS
from .builder import SceneBuilder
from .params import Param
from .preset import ScenePreset, common_params
from .scene import Scene


def feedback_params(ks: float = 100.0, kd: float = 20.0) -> tuple[Param, ...]:
    """The feedback gains; the defaults are critically damped (kd = 2 sqrt(ks))."""
    return (
        Param("ks", ks, "1/s^2", "constraint feedback stiffness k_s (C'' + kd C' + ks C = 0)", minimum=0.0),
        Param("kd", kd, "1/s", "constraint feedback damping k_d", minimum=0.0),
    )


def build_bead(preset: ScenePreset, p: dict[str, Any], seed: int) -> Scene:
    """A bead on a vertical circular wire about the origin, in the z = 0 plane."""
    r, angle = p["radius"], math.radians(p["angle"])
    x = r * np.array([math.sin(angle), -math.cos(angle), 0.0])
    v = p["initial_speed"] * np.array([math.cos(angle), math.sin(angle), 0.0])
    b = SceneBuilder()
    b.add_particles([x], p["particle_mass"], v=[v])
    b.add_circle_wire(0, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), r)
    b.set_constraint_feedback(p["ks"], p["kd"])
    return preset.finish(b, p, seed)


def pendulum_positions(lengths, angles) -> np.ndarray:
    """(k + 1, 3) positions (m) of a chain hanging from the origin: link j of length
    ``lengths[j]`` at ``angles[j]`` (rad) from straight down, in the z = 0 plane."""
    x = [np.zeros(3)]
    for length, angle in zip(lengths, angles):
        x.append(x[-1] + length * np.array([math.sin(angle), -math.cos(angle), 0.0]))
    return np.array(x)


def build_rod_pendulum(preset: ScenePreset, p: dict[str, Any], seed: int) -> Scene:
    links = p["links"]
    rows = links * (2 if p["planar"] else 1)
    if rows > MAX_ROWS:
        raise ConfigError(f"parameter links: at most {MAX_ROWS // (2 if p['planar'] else 1)} "
                          f"(the dense constraint solve holds {MAX_ROWS} rows), got {links}")
    angles = [math.radians(p["angle"])] + [math.radians(p["angle2"])] * (links - 1)
    x = pendulum_positions([p["rod_length"]] * links, angles)
    pinned = np.zeros(links + 1, bool)
    pinned[0] = True
    b = SceneBuilder()
    b.add_particles(x, p["particle_mass"], pinned=pinned)
    for j in range(links):
        b.add_rod(j, j + 1, p["rod_length"])
        if p["planar"]:
            b.add_plane_constraint(j + 1, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    b.set_constraint_feedback(p["ks"], p["kd"])
    return preset.finish(b, p, seed)


CONSTRAINT_SCENES = (
    ScenePreset("bead", "a bead on a circular wire under gravity, held by a constraint force", (
        Param("radius", 1.0, "m", "radius of the wire (a circle in the z = 0 plane about the origin)",
              minimum=0.0, exclusive=True),
        Param("angle", 90.0, "deg", "where the bead starts, from the bottom of the wire"),
        Param("initial_speed", 0.0, "m/s", "initial speed along the wire (counter-clockwise)"),
        *feedback_params(),
        *common_params(mass=0.1, damping=None),
    ), build_bead, default_dt=5e-3, default_integrator="rk4", size=lambda p: Size(1, 0)),
    ScenePreset("rod-pendulum", "a pendulum of rigid rods (links = 2: the double pendulum), "
                "held by constraint forces", (
        Param("links", 2, "", "rods in the chain (2: a double pendulum)", minimum=1),
        Param("rod_length", 1.0, "m", "length of each rod", minimum=0.0, exclusive=True),
        Param("angle", 90.0, "deg", "initial angle of the first rod from hanging down"),
        Param("angle2", 90.0, "deg", "initial angle of the other rods from hanging down"),
        Param("planar", False, "", "also constrain every bob to the z = 0 plane"),
        *feedback_params(),
        *common_params(mass=1.0, damping=None),
    ), build_rod_pendulum, default_dt=5e-3, default_integrator="rk4",
        size=lambda p: Size(p["links"] + 1, 0), size_params=("links",)),
)
