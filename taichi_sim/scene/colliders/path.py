"""Scripted rigid motion of a collider: where its centre is, how fast it moves and spins."""
import math
from dataclasses import dataclass

import numpy as np
import taichi as ti

from ... import field_io, runtime


@dataclass(frozen=True)
class SpherePath:
    """Where a collider's centre is at time t: ``center0 + velocity t + amplitude sin(2 pi
    frequency t) axis``; it may also spin at ``spin`` (rad/s, right-handed) about ``spin_axis``
    through its centre. Only a sphere uses the spin (a spinning sphere keeps its shape, so the
    spin only changes the surface velocity that friction sees); capsules and boxes translate.
    """

    center0: tuple
    velocity: tuple = (0.0, 0.0, 0.0)
    amplitude: float = 0.0
    frequency: float = 0.0
    axis: tuple = (1.0, 0.0, 0.0)
    spin: float = 0.0
    spin_axis: tuple = (0.0, 1.0, 0.0)

    def __post_init__(self):
        if self.spin != 0.0 and not np.linalg.norm(np.asarray(self.spin_axis, float)) > 0.0:
            raise ValueError("spin_axis must be a nonzero vector")

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(center (m), velocity (m/s)) at time t (s)."""
        w = 2 * math.pi * self.frequency
        axis = np.asarray(self.axis, float)
        center = np.asarray(self.center0, float) + np.asarray(self.velocity, float) * t \
            + self.amplitude * math.sin(w * t) * axis
        velocity = np.asarray(self.velocity, float) + self.amplitude * w * math.cos(w * t) * axis
        return center, velocity

    def angular_velocity(self) -> np.ndarray:
        """(3,) rad/s: the spin vector, zero when the collider does not spin."""
        if self.spin == 0.0:
            return np.zeros(3)
        axis = np.asarray(self.spin_axis, float)
        return self.spin * axis / np.linalg.norm(axis)

    def fastest_speed(self) -> float:
        """The largest speed (m/s) of the centre: |velocity| + 2 pi f amplitude."""
        return float(np.linalg.norm(self.velocity)) + 2 * math.pi * abs(self.frequency * self.amplitude)


@ti.data_oriented
class PathFields:
    """K paths as fields, so kernels place colliders at any t themselves (uploading centres
    every step would cost a field copy per step, more than the collision test)."""

    def __init__(self, count: int):
        real = runtime.real()
        self.center0 = ti.Vector.field(3, real, shape=count)
        self.linear = ti.Vector.field(3, real, shape=count)
        self.axis = ti.Vector.field(3, real, shape=count)
        self.amplitude = ti.field(real, shape=count)
        self.angular_frequency = ti.field(real, shape=count)
        self.omega = ti.Vector.field(3, real, shape=count)

    def values(self, paths) -> list:
        """(field, values) pairs that place ``paths`` in these fields, for :func:`field_io.write`
        (an owner writes them with its own fields, in one kernel)."""
        return [(self.center0, [p.center0 for p in paths]), (self.linear, [p.velocity for p in paths]),
                (self.axis, [p.axis for p in paths]), (self.amplitude, [p.amplitude for p in paths]),
                (self.angular_frequency, [2 * math.pi * p.frequency for p in paths]),
                (self.omega, [p.angular_velocity() for p in paths])]

    def upload(self, paths) -> None:
        field_io.write(*self.values(paths))

    @ti.func
    def center(self, k, t):
        """Collider k's centre (m) at time t (s), as :meth:`SpherePath.at`."""
        return self.center0[k] + self.linear[k] * t \
            + self.amplitude[k] * ti.sin(self.angular_frequency[k] * t) * self.axis[k]

    @ti.func
    def velocity(self, k, t):
        w = self.angular_frequency[k]
        return self.linear[k] + self.amplitude[k] * w * ti.cos(w * t) * self.axis[k]
