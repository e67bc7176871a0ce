"""The forces a position-level solver treats explicitly: every force term of a particle system
but the ones it solves itself (the springs, the grab)."""

import taichi as ti

from ... import runtime
from ...systems.base import System

SOLVED_TERMS = ("springs", "grab")  # terms the positional solvers treat implicitly, as constraints


@ti.data_oriented
class ExplicitForces:
    """Sum of a particle system's force terms other than ``SOLVED_TERMS`` (gravity, drag, wind),
    evaluated at a state into ``self.force`` ((n,) vec3, N); zero on particles that do not move.
    Only the terms the scene has are compiled in."""

    def __init__(self, system: System):
        self.system = system
        self.terms = [term for term in system.terms if term.name not in SOLVED_TERMS]
        self.serial = False  # run the gather on one thread (small systems: see XPBD)
        self.force = ti.Vector.field(3, runtime.real(), shape=system.particle_count)

    @ti.func
    def gather(self, y, t):
        """Fill ``self.force`` at state ``y`` and time ``t`` (s): a top-level parallel loop, so
        call it at a kernel's outermost scope."""
        ti.loop_config(serialize=self.serial)
        for i in range(self.system.particle_count):  # a range-for: serialize applies
            f = ti.Vector.zero(y.x.dtype, 3)
            if self.system.free[i]:
                for term in ti.static(self.terms):
                    f += term.force(i, y, self.system.mass[i], t)
            self.force[i] = f
