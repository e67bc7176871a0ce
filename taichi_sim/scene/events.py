"""Post-step events: applied between accepted steps, never inside f (docs/design.md, Contracts).

The object colliders live in :mod:`taichi_sim.scene.colliders`; tearing and emission here.

Collision projection, tearing and emission are not smooth; inside f they would break RK order
and adaptive error estimates. Each event is called as ``event(state, t, h)`` after a step and
returns True when it changed the system itself (tearing does), not only the state.
"""
import math
from dataclasses import dataclass

import numpy as np
import taichi as ti

from .. import runtime
from ..part import LaunchSource, ScenePart
from .visual import Emitter as EmitterVisual


class Tearing(ScenePart):
    """Breaks over-strained springs after each accepted step (see Springs.tear)."""

    name = "tearing"
    order = 40

    def __init__(self, springs):
        self.springs = springs
        self.torn_total = 0

    def __call__(self, state, t: float, h: float) -> bool:
        torn = self.springs.tear(state)
        self.torn_total += torn
        return torn > 0

    def restore(self) -> None:
        """Every spring intact again, as built."""
        self.springs.restore()
        self.torn_total = 0


@dataclass(frozen=True)
class EmitterSpec:
    """A sprinkler nozzle.

    Attributes:
        position: nozzle position (m); direction: spray axis (normalised here).
        rate: particles per second; speed: launch speed (m/s); spread: half-angle of the spray
        cone (degrees); lifetime: seconds a particle lives; capacity: ring-buffer size.
    """

    position: tuple
    direction: tuple
    rate: float
    speed: float
    spread: float
    lifetime: float
    capacity: int


@ti.data_oriented
class Emitter(ScenePart):
    """A particle emitter over a fixed-capacity ring buffer of the system's particles.

    Live particles are exactly those with ``alive`` = 1 (and ``free`` = 1, so the integrator
    moves them); a dead slot is frozen at the nozzle with zero velocity. After each step every
    live particle ages by h and dies past ``lifetime``; then ``rate * h`` new particles (the
    fraction carried over) are launched into the oldest slots, spread over the step as if
    emitted continuously. Directions are uniform in the cone; the stream of random numbers
    comes from ``seed``, so the same seed and steps give identical particles.
    """

    name = "emitter"
    order = 50

    def __init__(self, spec: EmitterSpec, first: int, free, seed: int, particle_mass: float = 0.0):
        real = runtime.real()
        self.particle_mass = float(particle_mass)  # kg, each launched particle's
        self.spec = spec
        self.first = first
        self.capacity = spec.capacity
        self.free = free
        self.seed = seed
        self.rng = np.random.default_rng(seed)
        self._slots_free0 = free.to_numpy()[first:first + spec.capacity].copy()
        self.alive = ti.field(ti.i32, shape=spec.capacity)
        self.age = ti.field(real, shape=spec.capacity)
        self.live_count = ti.field(ti.i32, shape=())
        self.next_slot = 0
        self.carry = 0.0
        self.emitted = 0  # particles launched since t = 0
        self.spec0 = spec
        # A :class:`~taichi_sim.curves.Spline` of the rate (1/s) over time, set by a curve
        # driver; None: the constant ``spec.rate``.
        self.rate_curve = None
        axis = np.asarray(spec.direction, float)
        self.axis = axis / np.linalg.norm(axis)
        helper = np.array([1.0, 0.0, 0.0]) if abs(self.axis[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
        self.u = np.cross(self.axis, helper)
        self.u /= np.linalg.norm(self.u)
        self.w = np.cross(self.axis, self.u)

    def __call__(self, state, t: float, h: float) -> None:
        self._age_and_expire(state, h, self.spec.lifetime)
        # A rate curve gives its exact integral over the step; the fraction of a particle
        # carries over, so after any steps emitted == floor(total) (capacity permitting).
        due = self.rate_curve.integral(t - h, t) if self.rate_curve is not None else self.spec.rate * h
        self.carry += max(due, 0.0)
        count = min(int(self.carry), self.capacity)
        self.carry -= int(self.carry)
        if count:
            self._launch(state, count, h)
            self.emitted += count

    def _launch(self, state, count: int, h: float) -> None:
        spec, npr = self.spec, runtime.np_real()
        cos_max = math.cos(math.radians(spec.spread))
        cos_t = self.rng.uniform(cos_max, 1.0, count)
        sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t**2))
        phi = self.rng.uniform(0.0, 2 * math.pi, count)
        dirs = (cos_t[:, None] * self.axis + sin_t[:, None] * (np.cos(phi)[:, None] * self.u
                                                               + np.sin(phi)[:, None] * self.w))
        v = spec.speed * dirs
        flight = self.rng.uniform(0.0, h, count)  # time since launch within this step
        x = np.asarray(spec.position, float) + v * flight[:, None]
        slots = (self.next_slot + np.arange(count)) % self.capacity
        self.next_slot = int((self.next_slot + count) % self.capacity)
        self._spawn(state, slots.astype(np.int32), x.astype(npr), v.astype(npr), flight.astype(npr))

    @ti.kernel
    def _age_and_expire(self, y: ti.template(), h: float, lifetime: float):
        for k in range(self.capacity):
            if self.alive[k]:
                age = self.age[k] + h
                self.age[k] = age
                if age > lifetime:
                    self._kill(y, k)

    @ti.func
    def _kill(self, y, k):
        i = self.first + k
        self.alive[k] = 0
        self.free[i] = 0
        self.age[k] = 0.0
        y.v[i] = ti.Vector.zero(y.x.dtype, 3)
        y.x[i] = ti.Vector(self.spec.position, dt=y.x.dtype)
        self.live_count[None] -= 1

    @ti.kernel
    def _spawn(self, y: ti.template(), slots: ti.types.ndarray(), x: ti.types.ndarray(),
               v: ti.types.ndarray(), age: ti.types.ndarray()):
        for m in range(slots.shape[0]):
            k = slots[m]
            i = self.first + k
            if self.alive[k]:  # the ring wrapped: the oldest particle makes room
                self._kill(y, k)
            for c in ti.static(range(3)):
                y.x[i][c] = x[m, c]
                y.v[i][c] = v[m, c]
            self.age[k] = age[m]
            self.alive[k] = 1
            self.free[i] = 1
            self.live_count[None] += 1

    def restore(self) -> None:
        """No particle emitted yet and the random stream from its start, as built: the same
        seed and steps then give the same particles again."""
        self.alive.fill(0)
        self.age.fill(0)
        self.live_count[None] = 0
        self.next_slot = 0
        self.carry = 0.0
        self.emitted = 0
        self.spec = self.spec0
        self.rng = np.random.default_rng(self.seed)
        free = self.free.to_numpy()
        free[self.first:self.first + self.capacity] = self._slots_free0
        self.free.from_numpy(free)

    def features(self) -> dict:
        return {"emitter": self.capacity}

    def visuals(self) -> list:
        return [EmitterVisual(alive=self.alive, age=self.age, lifetime=float(self.spec.lifetime), first=int(self.first),
                              capacity=int(self.capacity), lifetime_now=lambda: float(self.spec.lifetime),
                              spec=self.spec)]

    def energy_sources(self) -> list:
        spec = self.spec
        return [LaunchSource("emitter", spec.capacity, self.particle_mass, spec.speed, float(spec.position[1]),
                             spec.lifetime)]

    def arrays(self) -> dict:
        return {"alive": self.alive.to_numpy().astype(bool), "age": self.age.to_numpy().astype(np.float64),
                "lifetime": np.float64(self.spec.lifetime), "emitted": np.int64(self.emitted)}

