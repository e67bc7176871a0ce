import taichi as ti

from .. import field_io, runtime
from .base import ForceTerm


@ti.data_oriented
class Drag(ForceTerm):
    """Viscous drag -k_drag * v_i (k_drag in N s/m, a 0-D field so it can change at run time)."""

    name = "drag"
    reads_other_particles = False
    has_jacobian = True  # df_i/dv_i = -k_drag I; nothing depends on x or on other particles

    def __init__(self, k_drag: float):
        self.k = ti.field(runtime.real(), shape=())
        self.set(k_drag)

    def set(self, k_drag: float) -> None:
        field_io.write((self.k, float(k_drag)))  # the kernel every part's values go through

    def get(self) -> float:
        return float(field_io.read(self.k)[0])

    def anchored_fields(self) -> tuple:
        return (self.k,)

    @ti.func
    def force(self, i, y, mass_i, t):
        return -self.k[None] * y.v[i]

    @ti.func
    def dissipation_at(self, i, y, free_i):
        rate = ti.cast(0.0, y.x.dtype)
        if free_i:
            rate = 0.5 * self.k[None] * y.v[i].norm_sqr()
        return rate

    def dissipation(self, y) -> float:
        """R = k_drag/2 sum |v_i|^2 (W); pinned particles have zero velocity in a consistent state."""
        return float(self._dissipation(y))

    @ti.kernel
    def _dissipation(self, y: ti.template()) -> float:
        total = 0.0
        for i in y.v:
            total += 0.5 * self.k[None] * y.v[i].norm_sqr()
        return total

    @ti.func
    def jacobian_product(self, i, y, p, a, b, t):
        return -a * self.k[None] * p[i]

    @ti.func
    def jacobian_diagonal_block(self, i, y, a, b, t):
        return -a * self.k[None] * ti.Matrix.identity(y.x.dtype, 3)
