import numpy as np
import taichi as ti

from .. import runtime
from .base import ForceTerm


@ti.data_oriented
class GrabSpring(ForceTerm):
    """A stiff zero-length spring pulling one grabbed particle toward a target point.

    Force on the grabbed particle: ``stiffness * (target - x) - damping * v`` (N); nothing on the
    others, and nothing when no particle is grabbed (``particle`` = -1). All values are 0-D
    fields, changed by :class:`taichi_sim.scene.grab.Grabber` while the simulation runs.
    The pull is a smooth force inside f, so every integrator (and adaptive error control)
    handles it; the target moves only between steps.
    """

    name = "grab"
    reads_other_particles = False
    has_jacobian = True  # on the grabbed particle: df/dx = -stiffness I, df/dv = -damping I

    def __init__(self, stiffness: float, damping: float):
        real = runtime.real()
        self.particle = ti.field(ti.i32, shape=())
        self.target = ti.Vector.field(3, real, shape=())
        self.stiffness = ti.field(real, shape=())
        self.damping = ti.field(real, shape=())
        self.particle[None] = -1
        self.stiffness[None] = float(stiffness)
        self.damping[None] = float(damping)

    def hold(self, particle: int, target) -> None:
        self.particle[None] = int(particle)
        self.target[None] = np.asarray(target, float).reshape(3).tolist()

    def release(self) -> None:
        self.particle[None] = -1

    @ti.func
    def force(self, i, y, mass_i, t):
        f = ti.Vector.zero(y.x.dtype, 3)
        if i == self.particle[None]:
            f = self.stiffness[None] * (self.target[None] - y.x[i]) - self.damping[None] * y.v[i]
        return f

    def energy(self, y) -> float:
        """Potential energy of the pull (J): stiffness/2 |target - x|^2 of the grabbed particle (0
        when none is). While the target stays put the pull is conservative; moving it is work done
        from outside (the launcher re-bases its blow-up guard then)."""
        return float(self._energy(y))

    def dissipation(self, y) -> float:
        """Rayleigh dissipation of the pull's damper (W): damping/2 |v|^2 of the grabbed particle."""
        return float(self._dissipation(y))

    @ti.func
    def energy_at(self, i, y, free_i):
        energy = ti.cast(0.0, y.x.dtype)
        if i == self.particle[None]:
            energy = 0.5 * self.stiffness[None] * (self.target[None] - y.x[i]).norm_sqr()
        return energy

    @ti.func
    def dissipation_at(self, i, y, free_i):
        rate = ti.cast(0.0, y.x.dtype)
        if i == self.particle[None]:
            rate = 0.5 * self.damping[None] * y.v[i].norm_sqr()
        return rate

    @ti.kernel
    def _energy(self, y: ti.template()) -> float:
        total = 0.0
        i = self.particle[None]
        if i >= 0:
            total = 0.5 * self.stiffness[None] * (self.target[None] - y.x[i]).norm_sqr()
        return total

    @ti.kernel
    def _dissipation(self, y: ti.template()) -> float:
        total = 0.0
        i = self.particle[None]
        if i >= 0:
            total = 0.5 * self.damping[None] * y.v[i].norm_sqr()
        return total

    @ti.func
    def jacobian_product(self, i, y, p, a, b, t):
        out = ti.Vector.zero(y.x.dtype, 3)
        if i == self.particle[None]:
            out = -(a * self.damping[None] + b * self.stiffness[None]) * p[i]
        return out

    @ti.func
    def jacobian_diagonal_block(self, i, y, a, b, t):
        block = ti.Matrix.zero(y.x.dtype, 3, 3)
        if i == self.particle[None]:
            block = -(a * self.damping[None] + b * self.stiffness[None]) * ti.Matrix.identity(y.x.dtype, 3)
        return block
