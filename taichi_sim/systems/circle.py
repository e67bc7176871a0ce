"""The circle ODE: dx/dt = -y, dy/dt = x, dz/dt = 0 (exact solution: rotation at 1 rad/s)."""

import taichi as ti

from .. import runtime
from ..state import State, finite
from .base import Health, System


@ti.data_oriented
class CircleSystem(System):
    """First-order system: each of ``particle_count`` points rotates about the z axis.

    The invariant ``energy`` is 0.5 * (x^2 + y^2 + z^2) summed over points (it is conserved by the
    exact flow, so its drift shows an integrator's error).
    """

    second_order = False
    has_jacobian_product = True

    def __init__(self, particle_count: int = 1):
        self.particle_count = int(particle_count)
        self.serial_loops = runtime.serial_loops(self.particle_count)

    def eval_f(self, y: State, t: float, out: State) -> None:
        self._eval_f(y, out)

    @ti.kernel
    def _eval_f(self, y: ti.template(), out: ti.template()):
        ti.loop_config(serialize=self.serial_loops)  # each point its own
        for i in range(self.particle_count):
            p = y.x[i]
            out.x[i] = ti.Vector([-p[1], p[0], 0.0])

    def jacobian_product(self, y: State, t: float, w: State, out: State) -> None:
        # f(y) = S y is linear (S the rotation generator about z): its Jacobian is S itself.
        self._eval_f(w, out)

    def energy(self, y: State) -> float:
        return float(self._half_norm2(y))

    def health(self, y: State, center) -> Health:
        nonfinite, farthest2, energy = self._health(y, float(center[0]), float(center[1]), float(center[2]))
        return Health(nonfinite=int(nonfinite), farthest=float(farthest2) ** 0.5, energy=float(energy))

    @ti.kernel
    def _health(self, y: ti.template(), cx: float, cy: float, cz: float) -> (ti.i32, float, float):
        bad = 0
        farthest2 = 0.0
        total = 0.0
        c = ti.Vector([cx, cy, cz])
        for i in y.x:
            p = y.x[i]
            if finite(p):
                ti.atomic_max(farthest2, (p - c).norm_sqr())
                total += 0.5 * p.norm_sqr()
            else:
                bad += 1
        return bad, farthest2, total

    @ti.kernel
    def _half_norm2(self, y: ti.template()) -> float:
        total = 0.0
        for i in y.x:
            total += 0.5 * y.x[i].norm_sqr()
        return total
