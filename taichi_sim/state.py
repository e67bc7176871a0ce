"""Simulation state: Taichi fields owned by the caller (a Scene or an integrator's scratch)."""

import numpy as np
import taichi as ti

from . import field_io, runtime


@ti.data_oriented
class State:
    """Positions and, for second-order systems, velocities of ``particle_count`` particles.

    Attributes:
        x: ``ti.Vector.field(3)`` of shape (n,), positions in m (or the ODE variable).
        v: same shape, velocities in m/s; ``None`` for a first-order system.
        second_order: whether ``v`` exists (a Python bool, read with ``ti.static``).
    """

    def __init__(self, particle_count: int, second_order: bool):
        if particle_count < 1:
            raise ValueError(f"particle_count must be >= 1, got {particle_count}")
        self.particle_count = int(particle_count)
        self.second_order = bool(second_order)
        dtype = runtime.real()
        self.x = ti.Vector.field(3, dtype, shape=self.particle_count)
        self.v = ti.Vector.field(3, dtype, shape=self.particle_count) if second_order else None

    def like(self) -> "State":
        """A new, zeroed state of the same shape."""
        return State(self.particle_count, self.second_order)

    def to_numpy(self) -> tuple[np.ndarray, np.ndarray | None]:
        """(x, v) as float arrays of shape (n, 3); v is None for a first-order state."""
        if self.second_order:
            return field_io.read(self.x, self.v)  # one kernel for both
        return self.x.to_numpy(), None

    def from_numpy(self, x: np.ndarray, v: np.ndarray | None = None) -> None:
        """Set positions (and velocities; default zero) from (n, 3) arrays."""
        dtype = runtime.np_real()
        x = np.ascontiguousarray(x, dtype=dtype).reshape(self.particle_count, 3)
        if self.second_order:
            v = np.zeros_like(x) if v is None else np.ascontiguousarray(v, dtype=dtype).reshape(x.shape)
        self._upload(x, x if v is None else v)

    @ti.kernel
    def _upload(self, x: ti.types.ndarray(ndim=2), v: ti.types.ndarray(ndim=2)):
        # One kernel for both fields: Field.from_numpy would compile one kernel per field.
        for i in range(self.particle_count):
            for k in ti.static(range(3)):
                self.x[i][k] = x[i, k]
                if ti.static(self.second_order):
                    self.v[i][k] = v[i, k]

    def copy_from(self, other: "State") -> None:
        """Set this state to ``other`` (of the same shape). The kernel is a closure over the
        pair, made once: a kernel with a template argument costs about 100 us of Python per
        call on the development machine, as much as the copy of a 64 x 64 cloth itself."""
        copiers = self.__dict__.setdefault("_copiers", {})
        copy = copiers.get(id(other))
        if copy is None:
            copy = copiers[id(other)] = (self._bind_copy(other), other)
        copy[0]()

    def _bind_copy(self, other):
        target = self
        serial = runtime.serial_loops(self.particle_count)

        @ti.kernel
        def copy():
            ti.loop_config(serialize=serial)
            for i in range(target.particle_count):
                target.x[i] = other.x[i]
                if ti.static(target.second_order):
                    target.v[i] = other.v[i]

        return copy

    @ti.kernel
    def nonfinite_count(self) -> ti.i32:
        """Number of particles whose position or velocity has a NaN or infinite component."""
        bad = 0
        for i in self.x:
            if not finite(self.x[i]):
                bad += 1
            elif ti.static(self.second_order):
                if not finite(self.v[i]):
                    bad += 1
        return bad


@ti.func
def finite(u):
    """True when every component of the 3-vector ``u`` is finite."""
    ok = True
    for k in ti.static(range(3)):
        if ti.math.isnan(u[k]) or ti.math.isinf(u[k]):
            ok = False
    return ok

