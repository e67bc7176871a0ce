"""Kinematic pins: pinned particles moved along a script between steps (a post-step event).

Every integrator holds a pinned particle still within a step (its derivative is zero), so a
script cannot move it from inside f. Instead, after each accepted step ending at t, the event
puts every driven particle where the script says it is at t and gives it the script's velocity
there. Within the next step the integrators then all see the pins at x(t) (a lag of at most one
step's travel, the same for explicit, implicit and positional integrators), spring dashpots see
the pins' true velocity, and the self-contact stage, which runs after this event, sees each pin
move on a straight line from x(t - h) to x(t) over the step, as it assumes of every vertex.

The one exception: ``vbd`` with self-contact in its solve moves the pins itself, inside its
substeps and under its contact bounds, and the Stepper skips this event for it
(:mod:`taichi_sim.integrators.positional.vbd.pins`): a jump between steps would pass those
bounds.
"""

import math
from dataclasses import dataclass

import numpy as np
import taichi as ti

from .. import runtime
from ..part import MovingSource, ScenePart


def unit_axis(axis, what: str) -> tuple:
    """``axis`` normalised, as a tuple; ValueError naming ``what`` for a zero vector."""
    axis = np.asarray(axis, float)
    if not np.linalg.norm(axis) > 0:
        raise ValueError(f"{what} must be a nonzero vector")
    return tuple(axis / np.linalg.norm(axis))


@dataclass(frozen=True)
class TwistPath:
    """Particles turned about an axis, each at its own signed angular rate, for a while.

    Particle k starts at ``x0[k]`` and turns about the line through ``origin`` along ``axis`` by
    the angle ``2 pi sign[k] rate min(t, duration)`` (right-handed about ``axis``) while it slides
    along the axis by ``slide[k] min(t, duration) / duration``; after ``duration`` it stays put.

    Attributes:
        x0: (k, 3) start positions (m).
        sign: (k,) +1 or -1: the direction each particle turns.
        slide: (k,) distance (m) each particle moves along ``axis`` over the whole ``duration``.
        origin: a point on the axis (m); axis: its direction (normalised here).
        rate: turns per second (1/s, > 0); duration: seconds of turning (s, > 0).
    """

    x0: np.ndarray
    sign: np.ndarray
    slide: np.ndarray
    origin: tuple
    axis: tuple
    rate: float
    duration: float

    def __post_init__(self):
        if not (math.isfinite(self.rate) and self.rate > 0):
            raise ValueError(f"twist_rate must be a finite number > 0 (turns/s), got {self.rate!r}")
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"twist_duration must be a finite number > 0 (s), got {self.duration!r}")
        object.__setattr__(self, "axis", unit_axis(self.axis, "twist axis"))

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """((k, 3) positions (m), (k, 3) velocities (m/s)) at time t (s)."""
        a = np.asarray(self.axis)
        s = min(max(t, 0.0), self.duration)
        turning = 0.0 <= t < self.duration
        omega = 2 * math.pi * self.rate * np.asarray(self.sign, float)  # rad/s, (k,)
        angle = omega * s
        r = np.asarray(self.x0, float) - np.asarray(self.origin, float)
        along = r @ a
        radial = r - along[:, None] * a
        cross = np.cross(a, radial)
        c, sn = np.cos(angle)[:, None], np.sin(angle)[:, None]
        rotated = radial * c + cross * sn  # Rodrigues, the radial part only
        slide_rate = np.asarray(self.slide, float) / self.duration
        x = np.asarray(self.origin) + (along + slide_rate * s)[:, None] * a + rotated
        v = np.zeros_like(x)
        if turning:
            v = omega[:, None] * np.cross(a, rotated) + slide_rate[:, None] * a
        return x, v

    def fastest_speed(self) -> float:
        """The largest speed (m/s) any particle reaches: 2 pi rate r_max + the fastest slide."""
        r = np.asarray(self.x0, float) - np.asarray(self.origin, float)
        radial = r - (r @ np.asarray(self.axis))[:, None] * np.asarray(self.axis)
        r_max = float(np.linalg.norm(radial, axis=1).max()) if len(r) else 0.0
        slide = float(np.abs(self.slide).max()) / self.duration if len(r) else 0.0
        return 2 * math.pi * self.rate * r_max + slide

    def farthest_travel(self) -> float:
        """The farthest (m) any particle ever gets from its start: its circle's diameter plus its
        slide (bounds what the pins can stretch a spring by, however long the run)."""
        r = np.asarray(self.x0, float) - np.asarray(self.origin, float)
        radial = r - (r @ np.asarray(self.axis))[:, None] * np.asarray(self.axis)
        return float((2 * np.linalg.norm(radial, axis=1) + np.abs(self.slide)).max()) if len(r) else 0.0


@dataclass(frozen=True)
class TranslatePath:
    """Particles moved together, without turning: each one's offset from its start is
    ``velocity min(t, duration) + amplitude sin(2 pi frequency t) axis`` (the sine keeps going
    after ``duration``; it stays within +-amplitude).

    Attributes:
        x0: (k, 3) start positions (m).
        velocity: (3,) m/s while ``duration`` lasts; duration: s (>= 0).
        amplitude: m (>= 0); frequency: Hz (>= 0); axis: (3,) the oscillation's direction.
    """

    x0: np.ndarray
    velocity: tuple = (0.0, 0.0, 0.0)
    duration: float = 0.0
    amplitude: float = 0.0
    frequency: float = 0.0
    axis: tuple = (0.0, 1.0, 0.0)

    def __post_init__(self):
        for name in ("duration", "amplitude", "frequency"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"pin_{name} must be a finite number >= 0, got {value!r}")
        object.__setattr__(self, "axis", unit_axis(self.axis, "the pins' axis"))

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """((k, 3) positions (m), (k, 3) velocities (m/s)) at time t (s)."""
        w = 2 * math.pi * self.frequency
        velocity = np.asarray(self.velocity, float)
        moving = 0.0 <= t < self.duration
        offset = velocity * min(max(t, 0.0), self.duration) + self.amplitude * math.sin(w * t) * np.asarray(self.axis)
        rate = (velocity if moving else 0.0) + self.amplitude * w * math.cos(w * t) * np.asarray(self.axis)
        x0 = np.asarray(self.x0, float)
        return x0 + offset, np.broadcast_to(rate, x0.shape).copy()

    def fastest_speed(self) -> float:
        return float(np.linalg.norm(self.velocity)) + 2 * math.pi * self.frequency * self.amplitude

    def farthest_travel(self) -> float:
        return float(np.linalg.norm(self.velocity)) * self.duration + self.amplitude


@ti.data_oriented
class KinematicPins(ScenePart):
    """The post-step event that moves pinned particles ``ids`` along ``path`` (a
    :class:`TwistPath`, or anything with ``at(t) -> (x, v)``, ``fastest_speed()`` and
    ``farthest_travel()``). ``x0`` of the path must be where the particles start."""

    name = "kinematic"
    order = 0  # first: colliders and self-contact see the pins' motion

    def __init__(self, ids: np.ndarray, path):
        self.ids_np = np.asarray(ids, np.int32).reshape(-1)
        self.path = path
        self.count = len(self.ids_np)
        self.ids = ti.field(ti.i32, shape=max(self.count, 1))
        self.ids.from_numpy(self.ids_np if self.count else np.zeros(1, np.int32))

    def __call__(self, state, t: float, h: float) -> None:
        x, v = self.path.at(t)
        npr = runtime.np_real()
        self._place(state, x.astype(npr), v.astype(npr))

    def fastest_speed(self) -> float:
        return self.path.fastest_speed()

    def farthest_travel(self) -> float:
        return self.path.farthest_travel()

    def features(self) -> dict:
        return {"kinematic": self.count}

    def energy_sources(self) -> list:
        return [MovingSource("kinematic pins", self.fastest_speed(), self.farthest_travel())]

    @ti.kernel
    def _place(self, y: ti.template(), x: ti.types.ndarray(), v: ti.types.ndarray()):
        for k in range(self.count):
            i = self.ids[k]
            for c in ti.static(range(3)):
                y.x[i][c] = x[k, c]
                y.v[i][c] = v[k, c]
