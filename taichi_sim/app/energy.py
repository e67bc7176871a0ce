"""Energy samples of a running scene, kept for the live energy plot.

A sample costs nothing extra: the blow-up guard (:mod:`taichi_sim.guard`) already reduces the
state to its :class:`~taichi_sim.systems.base.Health` (one kernel: kinetic energy, the
springs' and gravity's potential energy and the total) at each of its checks, and the
:class:`~taichi_sim.app.runner.Runner` checks at least once per frame. The runner hands each
check that passed to an :class:`EnergyTrace`, a ring buffer of the last ``capacity`` samples;
nothing is read back from the device per step.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The curves of a sample, in the order an :class:`EnergyTrace` stores them.
COMPONENTS = ("kinetic", "gravity", "spring", "total")
CAPACITY = 256  # samples kept: at one a frame, about 4 s at 60 fps; more is more to draw


@dataclass(frozen=True)
class EnergySample:
    """The energy of one state (J) at time ``t`` (s): ``kinetic`` (1/2 m v^2), ``gravity``
    (-m g . x over the free particles), ``spring`` (1/2 k (|d| - r)^2 over the springs) and
    ``total`` (every conservative term plus kinetic: with a grab its pull's energy is in the
    total and in no component)."""

    t: float
    kinetic: float
    gravity: float
    spring: float
    total: float

    @classmethod
    def from_health(cls, t: float, health) -> "EnergySample":
        """The sample a :class:`~taichi_sim.systems.base.Health` holds (its ``energy`` must not
        be None)."""
        return cls(t=float(t), kinetic=health.kinetic, gravity=health.gravity_energy,
                   spring=health.spring_energy, total=health.energy)


def sample(scene, t: float = 0.0) -> EnergySample | None:
    """The energy of ``scene``'s current state, one reduction (None: the system has no energy).
    For callers without a guard; a runner samples at its guard's checks instead."""
    health = scene.system.health(scene.state, np.zeros(3))
    return None if health.energy is None else EnergySample.from_health(t, health)


def curves_of(scene) -> tuple[str, ...]:
    """Which :data:`COMPONENTS` the scene has: gravity only with a gravity term, spring only with
    springs; () for a system without energy (the first-order circle)."""
    system = scene.system
    if not getattr(system, "second_order", False):
        return ()
    term = getattr(system, "term", lambda name: None)
    names = ["kinetic"]
    if term("gravity") is not None:
        names.append("gravity")
    if scene.springs is not None:
        names.append("spring")
    return tuple(names) + ("total",)


class EnergyTrace:
    """The last ``capacity`` :class:`EnergySample` values of a run, oldest first.

    Args:
        capacity: samples kept (>= 2); older ones are overwritten.
    """

    def __init__(self, capacity: int = CAPACITY):
        if isinstance(capacity, bool) or not isinstance(capacity, (int, np.integer)) or capacity < 2:
            raise ValueError(f"capacity must be an integer >= 2, got {capacity!r}")
        self.capacity = int(capacity)
        self._data = np.zeros((self.capacity, 1 + len(COMPONENTS)))  # columns: t, COMPONENTS
        self._head = 0  # next slot written
        self._count = 0

    def __len__(self) -> int:
        return self._count

    def clear(self) -> None:
        self._head = self._count = 0

    def add(self, s: EnergySample) -> None:
        """Keep ``s`` (a sample at a time before the last one, after a restart, clears first)."""
        if self._count and s.t < self._data[(self._head - 1) % self.capacity, 0]:
            self.clear()
        self._data[self._head] = (s.t, s.kinetic, s.gravity, s.spring, s.total)
        self._head = (self._head + 1) % self.capacity
        self._count = min(self._count + 1, self.capacity)

    def array(self) -> np.ndarray:
        """(len, 5) float64: columns t (s) and :data:`COMPONENTS` (J), oldest row first."""
        if self._count < self.capacity:
            return self._data[:self._count].copy()
        return np.roll(self._data, -self._head, axis=0)

    def times(self) -> np.ndarray:
        """(len,) sample times (s), oldest first."""
        return self.array()[:, 0]

    def values(self, name: str) -> np.ndarray:
        """(len,) one component (J), oldest first; ValueError for a name not in COMPONENTS."""
        if name not in COMPONENTS:
            raise ValueError(f"name must be one of {', '.join(COMPONENTS)}, got {name!r}")
        return self.array()[:, 1 + COMPONENTS.index(name)]

    def last(self) -> EnergySample | None:
        """The newest sample, or None when empty."""
        if not self._count:
            return None
        row = self._data[(self._head - 1) % self.capacity]
        return EnergySample(*(float(v) for v in row))
