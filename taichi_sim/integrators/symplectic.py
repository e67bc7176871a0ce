"""Symplectic (semi-implicit) Euler: v first, then x with the new v."""

import taichi as ti

from ..forces.springs.spectrum import symplectic_euler_limit
from ..state import State, finite
from ..systems.base import System
from .base import Integrator, Status, StepReport


@ti.data_oriented
class SymplecticEuler(Integrator):
    """v_{n+1} = v_n + h a(x_n, v_n, t_n); x_{n+1} = x_n + h v_{n+1}.

    First order, one force evaluation per step, and symplectic for conservative forces: energy
    stays bounded (oscillates) below the stability limit h < 2 / omega_max.

    On a particle system the step is one kernel launch
    (:meth:`~taichi_sim.systems.ParticleSystem.symplectic_euler_step`) that reads nothing back:
    it reports ``ok``, and non-finite values are caught by the blow-up guard's next check (within
    100 steps), which every run path has; other systems count them after each step.
    """

    name = "symplectic_euler"
    plot_colour = "#2ca02c"  # in the benchmarks' plots
    order = 1
    requires_second_order = True
    takes_constraints = True
    description = "symplectic (semi-implicit) Euler, v then x"
    stability_constant = 2.0
    scratch_states = 1  # the derivative
    f_evals_per_step = 1.0

    @classmethod
    def damped_limit(cls, omega: float, gamma: float) -> float:
        """4 / (gamma + sqrt(gamma^2 + 4 omega^2)) (:func:`~taichi_sim.forces.springs.spectrum.symplectic_euler_limit`)."""
        return symplectic_euler_limit(omega, gamma)

    def __init__(self, system: System):
        super().__init__(system)
        self.derivative = system.make_state()

    def step(self, state: State, t: float, h: float) -> StepReport:
        fused = getattr(self.system, "symplectic_euler_step", None)
        if fused is not None:
            fused(state, t, h, self.derivative)
            return StepReport(accepted=True, h=h, next_h=h, f_evals=1, status=Status.OK)
        self.system.eval_f(state, t, self.derivative)
        bad = self._advance(state, h)
        return StepReport(accepted=True, h=h, next_h=h, f_evals=1,
                          status=Status.OK if bad == 0 else Status.DIVERGED)

    @ti.kernel
    def _advance(self, y: ti.template(), h: float) -> ti.i32:
        bad = 0
        for p in y.x:
            # A pinned particle has zero derivative and zero velocity, so it stays bit-identical.
            v = y.v[p] + h * self.derivative.v[p]
            x = y.x[p] + h * v
            y.v[p] = v
            y.x[p] = x
            if not (finite(x) and finite(v)):
                bad += 1
        return bad
