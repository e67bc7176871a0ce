"""One generic explicit Runge-Kutta step driven by a Butcher tableau."""

import taichi as ti

from ..state import State, finite
from ..systems.base import System
from .base import Integrator, Status, StepReport
from .tableau import EULER, MIDPOINT, RK4, TRAPEZOID, ButcherTableau


@ti.data_oriented
class ExplicitRK(Integrator):
    """Explicit RK over a tableau. Subclasses set ``tableau`` (and ``name``, ``description``).

    The tableau's coefficients are compile-time constants: each stage's combination
    y + h sum_j a_ij k_j is one kernel in which zero coefficients vanish, and the final update
    also counts non-finite particles so divergence is caught without an extra pass.
    """

    tableau: ButcherTableau

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        cls.order = cls.tableau.order

    def __init__(self, system: System):
        super().__init__(system)
        self.stages = [system.make_state() for _ in range(self.tableau.stage_count)]
        self.stage_input = system.make_state() if self.tableau.stage_count > 1 else None

    def step(self, state: State, t: float, h: float) -> StepReport:
        tab = self.tableau
        for i in range(tab.stage_count):
            if i == 0:
                self.system.eval_f(state, t, self.stages[0])
            else:
                self._stage_input(state, i, h)
                self.system.eval_f(self.stage_input, t + tab.c[i] * h, self.stages[i])
        bad = self._advance(state, h)
        status = Status.OK if bad == 0 else Status.DIVERGED
        return StepReport(accepted=True, h=h, next_h=h, f_evals=tab.stage_count, status=status)

    @ti.kernel
    def _stage_input(self, y: ti.template(), i: ti.template(), h: float):
        for p in y.x:
            dx = ti.Vector.zero(y.x.dtype, 3)
            for j in ti.static(range(i)):
                if ti.static(self.tableau.a[i][j] != 0.0):
                    dx += self.tableau.a[i][j] * self.stages[j].x[p]
            self.stage_input.x[p] = y.x[p] + h * dx
            if ti.static(y.second_order):
                dv = ti.Vector.zero(y.x.dtype, 3)
                for j in ti.static(range(i)):
                    if ti.static(self.tableau.a[i][j] != 0.0):
                        dv += self.tableau.a[i][j] * self.stages[j].v[p]
                self.stage_input.v[p] = y.v[p] + h * dv

    @ti.kernel
    def _advance(self, y: ti.template(), h: float) -> ti.i32:
        bad = 0
        for p in y.x:
            dx = ti.Vector.zero(y.x.dtype, 3)
            for j in ti.static(range(self.tableau.stage_count)):
                if ti.static(self.tableau.b[j] != 0.0):
                    dx += self.tableau.b[j] * self.stages[j].x[p]
            x = y.x[p] + h * dx
            y.x[p] = x
            ok = finite(x)
            if ti.static(y.second_order):
                dv = ti.Vector.zero(y.x.dtype, 3)
                for j in ti.static(range(self.tableau.stage_count)):
                    if ti.static(self.tableau.b[j] != 0.0):
                        dv += self.tableau.b[j] * self.stages[j].v[p]
                v = y.v[p] + h * dv
                y.v[p] = v
                ok = ok and finite(v)
            if not ok:
                bad += 1
        return bad


class Euler(ExplicitRK):
    name = "euler"
    tableau = EULER
    description = "explicit (forward) Euler"


class Midpoint(ExplicitRK):
    name = "midpoint"
    tableau = MIDPOINT
    description = "explicit midpoint rule"


class Trapezoid(ExplicitRK):
    name = "trapezoid"
    tableau = TRAPEZOID
    description = "explicit trapezoid rule (Heun): f0=f(X), f1=f(X+h f0), X+=h/2 (f0+f1)"


class RK4(ExplicitRK):
    name = "rk4"
    tableau = RK4
    description = "classical fourth-order Runge-Kutta"
