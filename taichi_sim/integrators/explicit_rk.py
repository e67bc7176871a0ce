"""One generic explicit Runge-Kutta step driven by a Butcher tableau."""

import math

import numpy as np
import taichi as ti

from ..loops import anchor
from ..state import State, finite
from ..systems.base import System
from .base import Integrator, Status, StepReport
from .tableau import EULER, MIDPOINT, RK4, TRAPEZOID, ButcherTableau


@ti.data_oriented
class ExplicitRK(Integrator):
    """Explicit RK over a tableau. Subclasses set ``tableau`` (and ``name``, ``description``).

    The tableau's coefficients are compile-time constants, so zero ones vanish. On a system
    that offers :meth:`~taichi_sim.systems.ParticleSystem.eval_f_stages` (particles) the whole
    step is one kernel launch (:class:`StagePlan`); otherwise each stage's input and the final
    update are kernels of their own, the update also counting non-finite particles.
    """

    tableau: ButcherTableau
    fuse_stages = True  # one launch per step where the system offers it (see _staged_step)
    takes_constraints = True

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        cls.order = cls.tableau.order
        count = cls.tableau.stage_count
        cls.scratch_states = count + (1 if count > 1 else 0)  # the stages and one stage input
        cls.f_evals_per_step = float(count)

    @classmethod
    def amplification_squared(cls, theta: float) -> float:
        """|R(i theta)|^2 from the tableau's stability polynomial R(z) = sum_k gamma_k z^k."""
        return float(abs(np.polyval(cls.tableau.stability_polynomial()[::-1], 1j * theta)) ** 2)

    @classmethod
    def damped_limit(cls, omega: float, gamma: float) -> float | None:
        """The largest h with |R(h lambda)| <= 1 for both roots lambda of
        lambda^2 + gamma lambda + omega^2 = 0 at every step up to h (scanned in 2000 steps of
        the undamped limit's 1/1000, then bisected); None for a method with no undamped limit
        (C = 0 or inf)."""
        c = cls.stability_constant
        if not c or math.isinf(c):
            return None
        if omega <= 0 and gamma <= 0:
            return math.inf
        roots = np.roots([1.0, gamma, omega * omega]).astype(complex)
        poly = cls.tableau.stability_polynomial()[::-1]

        def stable(h):
            return bool(np.all(np.abs(np.polyval(poly, h * roots)) <= 1.0 + 1e-12))

        unit = (c / omega if omega > 0 else 2.0 / gamma) / 1000.0
        hs = unit * np.arange(1, 2001)
        growth = np.abs(np.polyval(poly, np.outer(hs, roots)))
        bad = np.nonzero(np.any(growth > 1.0 + 1e-12, axis=1))[0]
        if not len(bad):
            return float(hs[-1])
        hi = float(hs[bad[0]])
        lo = float(hs[bad[0] - 1]) if bad[0] > 0 else 0.0
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if stable(mid) else (lo, mid)
        return lo

    def __init__(self, system: System):
        super().__init__(system)
        count = self.tableau.stage_count
        self.stages = [system.make_state() for _ in range(count)]
        self.stage_input = system.make_state() if count > 1 else None
        self._plans = {}

    def step(self, state: State, t: float, h: float) -> StepReport:
        tab = self.tableau
        if self.fuse_stages and hasattr(self.system, "eval_f_stages"):
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
        """The whole step in one kernel launch
        (:meth:`~taichi_sim.systems.ParticleSystem.eval_f_stages`, run on a :class:`StagePlan`).
        Nothing is read back: non-finite values are left to the blow-up guard's next check, as
        for symplectic Euler."""
        plan = self._plans.get(id(state))
        if plan is None:
            # a kernel compiles per plan (per state stepped); keep the state alive with it
            plan = self._plans[id(state)] = (StagePlan(self, state), state)
        self.system.eval_f_stages(plan[0], t, h)
        return StepReport(accepted=True, h=h, next_h=h, f_evals=self.tableau.stage_count, status=Status.OK)

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
class StagePlan:
    """What :meth:`~taichi_sim.systems.ParticleSystem.eval_f_stages` runs for one step of
    ``rk`` on ``y`` (a particle system's state): stage 0 at ``y``, the later stages at
    ``rk.stage_input``, each stage's accelerations a_s (the v part of its derivative k_s) into
    ``rk.stages[s].v``; after stage s (:meth:`after`) a loop of its own writes
    y + h sum_j w_j k_j into the stage input (w_j = a_(s+1)j) or, after the last stage
    (w_j = b_j), into ``y`` (each particle reads its own entries before writing them).

    The x part of k_j, the velocity of stage j's input, is not stored: that input's velocity
    was y.v + h sum_l a_jl a_l, so sum_j w_j k_j.x = (sum_j w_j) y.v + h sum_l (w^T A)_l a_l
    for a free particle and 0 for a pinned one. The same sum up to rounding, with a third less
    memory traffic in the loops (rk4 at 512 x 512: 4.25-4.43 symplectic steps against
    4.52). Every weight is a compile-time constant, so stages with a zero weight are not read."""

    def __init__(self, rk: "ExplicitRK", y: State):
        tab = rk.tableau
        self.y, self.derivatives, self.free = y, tuple(rk.stages), rk.system.free
        self.inputs = (y,) + (rk.stage_input,) * (tab.stage_count - 1)
        self.outputs = self.derivatives
        self.c = tuple(tab.c)
        self.targets = self.inputs[1:] + (y,)
        self.weights = tuple(tuple(row) for row in tab.a[1:]) + (tuple(tab.b),)
        matrix = tab.matrix()
        self.velocity_weights = tuple(float(sum(w)) for w in self.weights)
        self.acceleration_weights = tuple(
            tuple(float(sum(w[j] * matrix[j, k] for j in range(len(w)))) for k in range(tab.stage_count))
            for w in self.weights)
        self.particle_count = y.particle_count
        self.serial = rk.system.serial_loops
        inputs = tuple(dict.fromkeys(self.inputs))
        self.fields = sum(((state.x, state.v) for state in inputs), ()) + tuple(k.v for k in self.derivatives) + (self.free,)

    @ti.func
    def after(self, s: ti.template(), h):
        """The combination after stage s. On a CPU it is a serial loop with every memory tree
        anchored (:mod:`taichi_sim.loops`), which vectorises it: fused into the derivative
        loop, as they once were, the combinations stayed scalar and took a third of an rk4
        step."""
        if ti.static(self.serial):
            ti.loop_config(serialize=True)
            for _ in range(1):
                for field in ti.static(self.fields):
                    anchor(field)
                for p in range(self.particle_count):
                    self._combine(s, p, h)
        else:
            for p in range(self.particle_count):
                self._combine(s, p, h)

    @ti.func
    def _combine(self, s: ti.template(), p, h):
        velocity = self.y.v[p]
        change = ti.Vector.zero(self.y.x.dtype, 3)  # h sum_k (w^T A)_k a_k
        for k in ti.static(range(len(self.derivatives))):
            if ti.static(self.acceleration_weights[s][k] != 0.0):
                change += self.acceleration_weights[s][k] * self.derivatives[k].v[p]
        mean_velocity = self.velocity_weights[s] * velocity + h * change
        ti.static(self.targets[s].x)[p] = self.y.x[p] + h * ti.select(
            self.free[p] != 0, mean_velocity, ti.Vector.zero(self.y.x.dtype, 3))
        ti.static(self.targets[s].v)[p] = velocity + h * weighted_stages(self.derivatives, self.weights[s], 1, p)


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
    plot_colour = "#d62728"  # in the benchmarks' plots
    tableau = EULER
    stability_constant = 0.0  # |1 + i theta| > 1 for every theta > 0
    description = "explicit (forward) Euler"


class Midpoint(ExplicitRK):
    name = "midpoint"
    plot_colour = "#bcbd22"  # in the benchmarks' plots
    tableau = MIDPOINT
    stability_constant = 0.0  # |R(i theta)|^2 = 1 + theta^4 / 4
    description = "explicit midpoint rule"


class Trapezoid(ExplicitRK):
    name = "trapezoid"
    plot_colour = "#ff7f0e"  # in the benchmarks' plots
    tableau = TRAPEZOID
    stability_constant = 0.0  # |R(i theta)|^2 = 1 + theta^4 / 4
    description = "explicit trapezoid rule (Heun): f0=f(X), f1=f(X+h f0), X+=h/2 (f0+f1)"


class RK4(ExplicitRK):
    name = "rk4"
    plot_colour = "#1f77b4"  # in the benchmarks' plots
    tableau = RK4
    stability_constant = 2.0 * math.sqrt(2.0)
    description = "classical fourth-order Runge-Kutta"
