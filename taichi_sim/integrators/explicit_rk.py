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
    fuse_stages = True  # one launch per stage where the system offers it (see _staged_step)
    takes_constraints = True

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        cls.order = cls.tableau.order

    def __init__(self, system: System):
        super().__init__(system)
        self.stages = [system.make_state() for _ in range(self.tableau.stage_count)]
        self.stage_input = system.make_state() if self.tableau.stage_count > 1 else None

    def step(self, state: State, t: float, h: float) -> StepReport:
        tab = self.tableau
        if self.fuse_stages and hasattr(self.system, "eval_f_staged"):
            return self._staged_step(state, t, h)
        for i in range(tab.stage_count):
            if i == 0:
                self.system.eval_f(state, t, self.stages[0])
            else:
                self._stage_input(state, i, h)
                self.system.eval_f(self.stage_input, t + tab.c[i] * h, self.stages[i])
        bad = self._advance(state, h)
        status = Status.OK if bad == 0 else Status.DIVERGED
        return StepReport(accepted=True, h=h, next_h=h, f_evals=tab.stage_count, status=status)

    def _staged_step(self, state: State, t: float, h: float) -> StepReport:
        """The step with each stage's input and the final update folded into the force
        evaluations' kernels (:meth:`~taichi_sim.systems.ParticleSystem.eval_f_staged`): one
        launch of two loops per stage. As each particle's k_i is computed, the same thread
        writes its entry of the next stage's input y + h sum_j a_(i+1)j k_j (into the other of
        two buffers, so that no particle's input changes while a neighbour may read it), and
        in the last stage its final update. Nothing is read back: non-finite values are left
        to the blow-up guard's next check, as for symplectic Euler."""
        tab = self.tableau
        count = tab.stage_count
        combine = self._combinations(state)
        # The last stage reads the stage input, so it may update the state as it goes; a
        # single stage reads the state itself, which only local terms make safe.
        fused_final = count > 1 or self.system.sums_locally()
        for i in range(count):
            y = state if i == 0 else self._buffers[i % 2]
            after = combine[i] if (i < count - 1 or fused_final) else None
            self.system.eval_f_staged(y, t + tab.c[i] * h, self.stages[i], h, after=after)
        if not fused_final:
            self._advance(state, h)
        return StepReport(accepted=True, h=h, next_h=h, f_evals=count, status=Status.OK)

    def _combinations(self, state: State) -> list:
        """What each stage's kernel writes after k_i: the next stage's input, or (last) the new
        state. Kept for the last state seen: each is a kernel's template argument, so a new one
        compiles new kernels."""
        if getattr(self, "_combined_for", None) is not state:
            tab = self.tableau
            if not hasattr(self, "_buffers"):  # stage inputs alternate between two states
                second = self.system.make_state() if tab.stage_count > 2 else self.stage_input
                self._buffers = (second, self.stage_input)
            self._stage_combinations = [
                StageCombination(state, self.stages, tab.a[i + 1], self._buffers[(i + 1) % 2])
                for i in range(tab.stage_count - 1)] + [StageCombination(state, self.stages, tab.b, state)]
            self._combined_for = state
        return self._stage_combinations

    @ti.kernel
    def _stage_input(self, y: ti.template(), i: ti.template(), h: float):
        for p in y.x:
            for part in ti.static(range(len(state_parts(y)))):
                ti.static(state_parts(self.stage_input)[part])[p] = (
                    ti.static(state_parts(y)[part])[p]
                    + h * weighted_stages(self.stages, self.tableau.a[i], part, p))

    @ti.kernel
    def _advance(self, y: ti.template(), h: float) -> ti.i32:
        bad = 0
        for p in y.x:
            ok = True
            for part in ti.static(range(len(state_parts(y)))):
                value = ti.static(state_parts(y)[part])[p] + h * weighted_stages(self.stages, self.tableau.b, part, p)
                ti.static(state_parts(y)[part])[p] = value
                ok = ok and finite(value)
            if not ok:
                bad += 1
        return bad


@ti.data_oriented
class StageCombination:
    """target = y + h sum_j w_j k_j, one particle at a time (``apply(p, h)``), with the weights
    w as compile-time constants (the stages with zero weight, not yet computed, are not read).
    ``target`` may be ``y`` itself (the final update): each particle reads its own entries
    before writing them."""

    def __init__(self, y: State, stages: list, weights: tuple, target: State):
        self.y, self.stages, self.weights, self.target = y, stages, tuple(weights), target

    @ti.func
    def apply(self, p, h):
        for part in ti.static(range(len(state_parts(self.y)))):
            ti.static(state_parts(self.target)[part])[p] = (
                ti.static(state_parts(self.y)[part])[p] + h * weighted_stages(self.stages, self.weights, part, p))


def state_parts(state: State) -> tuple:
    """The fields that make up ``state``: (x,) for a first-order system, (x, v) otherwise."""
    return (state.x, state.v) if state.second_order else (state.x,)


@ti.func
def weighted_stages(stages: ti.template(), weights: ti.template(), part: ti.template(), p):
    """sum_j weights[j] k_j for part ``part`` (0: x, 1: v) of particle p; the weights are
    compile-time constants, so zero weights compile away."""
    total = ti.Vector.zero(stages[0].x.dtype, 3)
    for j in ti.static(range(len(weights))):
        if ti.static(weights[j] != 0.0):
            total += weights[j] * ti.static(state_parts(stages[j])[part])[p]
    return total


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
