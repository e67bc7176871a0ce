"""vbd's energy cap: an unconverged substep of a closed scene never ends with more energy than
it started with.

Backward Euler's exact step loses energy on a closed scene (convex potential: E1 + 1/2 |v1 -
v0|_M^2 <= E0), but a step its sweeps stop short of need not: every sweep lowers the
incremental potential G, and a point of lower G than the start can still hold more energy
(docs/vbd.md). The cap moves such a substep's end back along its own displacement, x = x0 +
a (x - x0) and v = a (x - x0) / dt, to an a in [0, 1) where E(a) <= E0, found by bisection
between a = 0 (staying put: E = U(x0) <= E0) and a = 1, so that a small excess costs a small
shortening.

A scene is closed when nothing in it can add energy within a substep: no wind, no turbulence,
no part that launches particles and no part that moves at a speed above zero (a moving
collider, kinematic pins), as the guard counts them (the scene says so:
:attr:`~taichi_sim.scene.handoff.ContactInputs.closed`). Elsewhere the cap is off; so it is with
contact in the solve (the contact penalty's energy is not in E: a vertex pushed out of a
contact would read as a gain) and with ``energy_cap=False``.
"""
import taichi as ti

from .... import runtime

CAP_BISECTIONS = 8  # the shortened substep's a is within 2^-8 of a point where E = E0
CAP_TOLERANCE = 1e3  # machine epsilons of the energy's scale (sum of |U_i| and K_i): round-off


@ti.data_oriented
class EnergyCap:
    """The cap of :class:`~.solver.VBD` on a closed scene (module docstring): :meth:`apply` at a
    substep's end; ``capped`` counts the substeps it shortened.

    Args:
        system: the particle system (``particle_count``, ``free``, ``mass``,
            ``potential_and_dissipation_at``).
    """

    def __init__(self, system):
        self.system = system
        self.capped = ti.field(ti.i32, shape=())  # substeps the cap shortened
        self.tolerance = CAP_TOLERANCE * runtime.machine_epsilon()

    def warning(self, accuracy_judged: bool = False) -> str:
        """The run's line for the substeps the cap shortened ("" for none): they stopped short
        of the solved step, unless ``accuracy_judged`` (the error estimate measured them against
        their solution and warns itself where they are off)."""
        capped = int(self.capped[None])
        if not capped or accuracy_judged:
            return ""
        return (f"vbd: {capped} substep(s) would have ended with more energy than they started with and were "
                "shortened toward their start (energy_cap); many mean the sweeps stop short: raise --iterations "
                "or --substeps, or lower --dt")

    @ti.func
    def apply(self, y, point, start_x, delta, dt, serial: ti.template()):
        """Shorten the substep of dt seconds toward its start ``y`` (still x0, v0) until its
        energy is at most the start's: ``delta`` (x - x0, m) is scaled in place; ``point`` (the
        iterate, a state) and ``start_x`` (x0, m) as the solve keeps them. With ``serial`` (the
        sweeps run on one thread: a small cloth on a CPU) so does this; else E0 and E(1) are
        parallel loops and the bisection (rare) runs on one thread."""
        if ti.static(serial):
            ti.loop_config(serialize=True)
            for _ in range(1):
                self._shorten(y, point, start_x, delta, dt)
        else:
            self._shorten(y, point, start_x, delta, dt)

    @ti.func
    def _energy_at(self, alpha, point, start_x, delta, dt):
        """E at x0 + alpha (x - x0), v = alpha (x - x0) / dt (J), the iterate ``point`` put there;
        a top-level loop where called at a kernel's top level, else serial."""
        e = ti.cast(0.0, delta.dtype)
        for i in range(self.system.particle_count):
            if self.system.free[i]:
                point.x[i] = start_x[i] + alpha * delta[i]
                point.v[i] = alpha * delta[i] / dt
        for i in range(self.system.particle_count):
            u, r = self.system.potential_and_dissipation_at(i, point)
            e += u
            if self.system.free[i]:
                e += 0.5 * self.system.mass[i] * point.v[i].norm_sqr()
        return e

    @ti.func
    def _shorten(self, y, point, start_x, delta, dt):
        e0 = ti.cast(0.0, delta.dtype)
        scale = ti.cast(0.0, delta.dtype)
        for i in range(self.system.particle_count):
            u0, r0 = self.system.potential_and_dissipation_at(i, y)
            k0 = ti.cast(0.0, delta.dtype)
            if self.system.free[i]:
                k0 = 0.5 * self.system.mass[i] * y.v[i].norm_sqr()
            e0 += u0 + k0
            scale += ti.abs(u0) + k0
        bound = e0 + ti.static(self.tolerance) * scale
        e1 = self._energy_at(1.0, point, start_x, delta, dt)
        if e1 > bound:
            # bisect [low, high] with E(low) <= bound < E(high); E(0) = U(x0) <= E0
            low = ti.cast(0.0, delta.dtype)
            high = ti.cast(1.0, delta.dtype)
            for _ in range(CAP_BISECTIONS):
                alpha = 0.5 * (low + high)
                if self._energy_at(alpha, point, start_x, delta, dt) <= bound:
                    low = alpha
                else:
                    high = alpha
            self.capped[None] += 1
            for i in range(self.system.particle_count):
                delta[i] = low * delta[i]
