
import numpy as np
import taichi as ti

from .. import field_io, runtime
from .base import ForceTerm, ZeroJacobian


@ti.data_oriented
class Gravity(ZeroJacobian, ForceTerm):
    """Uniform gravity: force m_i * g on every particle; potential energy -m_i g . x_i summed
    over the particles that move (pinned or inactive ones would add a constant).

    ``g`` (m/s^2, a 3-vector, e.g. (0, -9.8, 0)) lives in a 0-D field, so it may change while a
    simulation runs without recompiling.
    """

    name = "gravity"
    reads_other_particles = False

    def __init__(self, g, mass_field, free_field):
        self.g = ti.Vector.field(3, runtime.real(), shape=())
        self.mass = mass_field
        self.free = free_field
        self.set(g)

    def set(self, g) -> None:
        field_io.write((self.g, np.asarray(g, dtype=float).reshape(3)))  # one kernel, not one per component

    def get(self) -> np.ndarray:
        return np.asarray(field_io.read(self.g)[0], dtype=float)  # one kernel, not one per component

    def anchored_fields(self) -> tuple:
        return (self.g,)

    @ti.func
    def force(self, i, y, mass_i, t):
        return mass_i * self.g[None]

    @ti.func
    def energy_at(self, i, y, free_i):
        energy = ti.cast(0.0, y.x.dtype)
        if free_i:
            energy = -self.mass[i] * self.g[None].dot(y.x[i])
        return energy


    def energy(self, y) -> float:
        return float(self._energy(y))

    @ti.kernel
    def _energy(self, y: ti.template()) -> float:
        total = 0.0
        for i in y.x:
            if self.free[i]:
                total -= self.mass[i] * self.g[None].dot(y.x[i])
        return total
