"""Each particle's position at the start of the step, for tests over the step's motion."""
import taichi as ti

from ... import runtime


@ti.data_oriented
class StepStart:
    """(n, 3) positions (m) where the last step began.

    A collider runs after the step, so it sees only the end positions. The start is kept from
    the collider's own last call when the new step follows it (t - h equals the last t), else
    estimated as x - h v (exact for symplectic Euler) after a reset, a jump or the first step.
    What later events move after this collider (the plane, self-contact) is not in the kept
    start; they move particles by a thickness, not by a step's travel.
    """

    def __init__(self, n: int):
        self.x = ti.Vector.field(3, runtime.real(), shape=n)
        self.serial = runtime.serial_loops(n)  # two loads and a store a particle
        self.t_end = None

    def restore(self) -> None:
        self.t_end = None

    def begin(self, state, t: float, h: float) -> None:
        """Make ``self.x`` the start of the step that ended at t (s) and was h (s) long."""
        if self.t_end is None or abs((t - h) - self.t_end) > 1e-9 * max(1.0, abs(t)):
            self._estimate(state, h)

    def end(self, state, t: float) -> None:
        """Keep the corrected end positions as the next step's start."""
        self._keep(state)
        self.t_end = t

    @ti.kernel
    def _estimate(self, y: ti.template(), h: float):
        ti.loop_config(serialize=self.serial)
        for i in range(y.x.shape[0]):  # a range-for: serialize applies
            self.x[i] = y.x[i] - h * y.v[i]

    @ti.kernel
    def _keep(self, y: ti.template()):
        ti.loop_config(serialize=self.serial)
        for i in range(y.x.shape[0]):  # a range-for: serialize applies
            self.x[i] = y.x[i]
