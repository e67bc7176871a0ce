"""Post-step events: applied between accepted steps, never inside f (DESIGN.md section 3).

Collision projection, tearing and emission are not smooth; inside f they would break RK order
and adaptive error estimates. Each event is called as ``event(state, t, h)`` after a step and
returns True when it changed the system itself (tearing does), not only the state.
"""
import math
from dataclasses import dataclass, replace

import numpy as np
import taichi as ti

from .. import runtime


@dataclass(frozen=True)
class SpherePath:
    """Where a sphere is at time t: ``center0 + velocity t + amplitude sin(2 pi frequency t) axis``."""

    center0: tuple
    velocity: tuple = (0.0, 0.0, 0.0)
    amplitude: float = 0.0
    frequency: float = 0.0
    axis: tuple = (1.0, 0.0, 0.0)

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(center (m), velocity (m/s)) at time t (s)."""
        w = 2 * math.pi * self.frequency
        axis = np.asarray(self.axis, float)
        center = np.asarray(self.center0, float) + np.asarray(self.velocity, float) * t \
            + self.amplitude * math.sin(w * t) * axis
        velocity = np.asarray(self.velocity, float) + self.amplitude * w * math.cos(w * t) * axis
        return center, velocity


@ti.data_oriented
class SphereColliders:
    """Spheres that particles cannot enter.

    After each accepted step, a free particle inside a sphere is projected to its surface and
    loses its inward normal velocity relative to the sphere (frictionless, as in the classic
    assignment); with friction mu > 0 its tangential relative velocity also shrinks by
    mu * |lost normal velocity| (Coulomb), never reversing. Spheres move along scripted paths.

    Args:
        paths: one :class:`SpherePath` per sphere; radii (m) and frictions alike.
        free: the system's (n,) i32 field, 1 for particles that move.
    """

    def __init__(self, paths: list[SpherePath], radii: list[float], frictions: list[float], free):
        real = runtime.real()
        self.count = K = len(paths)
        self.paths = list(paths)
        self.free = free
        self.center = ti.Vector.field(3, real, shape=K)
        self.velocity = ti.Vector.field(3, real, shape=K)
        self.radius = ti.field(real, shape=K)
        self.friction = ti.field(real, shape=K)
        self.radius.from_numpy(np.asarray(radii, runtime.np_real()))
        self.friction.from_numpy(np.asarray(frictions, runtime.np_real()))
        self.paths0 = tuple(self.paths)
        self.move_to(0.0)

    def set_speed(self, speed: float) -> None:
        """Move every sphere that travels in a straight line (drop, sweep) at ``speed`` (m/s)
        from now on, continuing from where it is (a live change must not teleport it)."""
        for k, path in enumerate(self.paths):
            v = np.asarray(path.velocity, float)
            norm = float(np.linalg.norm(v))
            if norm == 0.0:
                continue
            center, _ = path.at(self.t)
            v_new = v / norm * float(speed)
            self.paths[k] = replace(path, velocity=tuple(v_new), center0=tuple(center - v_new * self.t))

    def restore(self) -> None:
        """The paths as built (live speed changes undone), at t = 0."""
        self.paths = list(self.paths0)
        self.move_to(0.0)

    def move_to(self, t: float) -> None:
        """Place every sphere where its path puts it at time t (s)."""
        self.t = t
        centers, velocities = zip(*(p.at(t) for p in self.paths))
        self.center.from_numpy(np.asarray(centers, runtime.np_real()))
        self.velocity.from_numpy(np.asarray(velocities, runtime.np_real()))

    def centers(self) -> np.ndarray:
        return self.center.to_numpy().astype(np.float64)

    def fastest_speed(self) -> float:
        """The largest speed (m/s) any sphere's path reaches: |velocity| + 2 pi f amplitude."""
        return max(float(np.linalg.norm(p.velocity)) + 2 * math.pi * abs(p.frequency * p.amplitude)
                   for p in self.paths)

    def __call__(self, state, t: float, h: float) -> None:
        self.move_to(t)
        self._project(state)

    @ti.kernel
    def _project(self, y: ti.template()):
        for i in y.x:
            if self.free[i]:
                for k in range(self.count):
                    c = self.center[k]
                    r = self.radius[k]
                    d = y.x[i] - c
                    dist = d.norm()
                    if dist < r:
                        n = ti.Vector([0.0, 1.0, 0.0], dt=y.x.dtype)
                        if dist > 0.0:
                            n = d / dist
                        y.x[i] = c + r * n
                        rel = y.v[i] - self.velocity[k]
                        vn = rel.dot(n)
                        if vn < 0.0:
                            tangential = rel - vn * n
                            speed_t = tangential.norm()
                            scale = 1.0
                            if speed_t > 0.0:
                                scale = ti.max(0.0, 1.0 + self.friction[k] * vn / speed_t)
                            y.v[i] = self.velocity[k] + scale * tangential


@ti.data_oriented
class PlaneCollider:
    """A ground plane: a free particle below it is projected onto it, and its normal velocity
    is reflected and scaled by ``restitution`` (0: it stops, 1: elastic bounce); ``friction``
    mu scales the tangential velocity down by mu * (1 + e) |v_n| (Coulomb), never reversing it.

    Args:
        point: a point on the plane (m); normal: its upward normal (normalised here).
    """

    def __init__(self, point, normal, restitution: float, friction: float, free):
        real = runtime.real()
        normal = np.asarray(normal, float)
        self.point_np = np.asarray(point, float)
        self.normal_np = normal / np.linalg.norm(normal)
        self.free = free
        self.point = ti.Vector.field(3, real, shape=())
        self.normal = ti.Vector.field(3, real, shape=())
        self.restitution = ti.field(real, shape=())
        self.friction = ti.field(real, shape=())
        self.point[None] = self.point_np.tolist()
        self.normal[None] = self.normal_np.tolist()
        self.restitution[None] = float(restitution)
        self.friction[None] = float(friction)

    def __call__(self, state, t: float, h: float) -> None:
        self._project(state)

    @ti.kernel
    def _project(self, y: ti.template()):
        n = self.normal[None]
        for i in y.x:
            if self.free[i]:
                depth = (y.x[i] - self.point[None]).dot(n)
                if depth < 0.0:
                    y.x[i] -= depth * n
                    vn = y.v[i].dot(n)
                    if vn < 0.0:
                        tangential = y.v[i] - vn * n
                        speed_t = tangential.norm()
                        scale = 1.0
                        if speed_t > 0.0:
                            scale = ti.max(0.0, 1.0 + self.friction[None] * (1.0 + self.restitution[None]) * vn / speed_t)
                        y.v[i] = scale * tangential - self.restitution[None] * vn * n


class Tearing:
    """Breaks over-strained springs after each accepted step (see Springs.tear)."""

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
class Emitter:
    """A particle emitter over a fixed-capacity ring buffer of the system's particles.

    Live particles are exactly those with ``alive`` = 1 (and ``free`` = 1, so the integrator
    moves them); a dead slot is frozen at the nozzle with zero velocity. After each step every
    live particle ages by h and dies past ``lifetime``; then ``rate * h`` new particles (the
    fraction carried over) are launched into the oldest slots, spread over the step as if
    emitted continuously. Directions are uniform in the cone; the stream of random numbers
    comes from ``seed``, so the same seed and steps give identical particles.
    """

    def __init__(self, spec: EmitterSpec, first: int, free, seed: int):
        real = runtime.real()
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

    def arrays(self) -> dict:
        return {"alive": self.alive.to_numpy().astype(bool), "age": self.age.to_numpy().astype(np.float64),
                "lifetime": np.float64(self.spec.lifetime), "emitted": np.int64(self.emitted)}

