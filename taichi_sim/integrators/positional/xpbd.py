"""Extended position-based dynamics: springs as compliant distance constraints."""

import math

import taichi as ti

from ... import runtime
from ...systems.base import System
from ..base import Integrator, StepReport
from ..equation import FIXED_WORK, Equation
from ..implicit.common import positive_int
from .colouring import colour_springs
from .external import ExplicitForces

FUSED_ITERATIONS = 4  # up to this many sweeps are unrolled into the one kernel of a substep
# Serial loops below this many particles plus springs (times spare threads;
# runtime.serial_loops, never on a GPU). On the 2-vCPU development machine a 20-substep step,
# serial against parallel, took 1.5 against 12.6 ms at 32 x 32, 4.6 against 21.6 ms at
# 64 x 64, 17.4 against 64.2 ms at 128 x 128 (97k springs), 69 against 204 ms at 256 x 256
# and 160 against 329 ms at 384 x 384 (1.0M springs; f32, benchmarks/bench_serial_loops.py):
# the colour loops are short and many (12 a sweep), so a parallel one is mostly hand-off.
# Larger cloths were not measured.
SERIAL_SPRINGS = 2_000_000


@ti.data_oriented
class XPBD(Integrator):
    """Extended position-based dynamics (Macklin, Mueller & Chentanez 2016, "XPBD: position-based
    simulation of compliant constrained dynamics"), with small substeps (Macklin et al. 2019,
    "Small steps in physics simulation").

    Each step of h seconds is ``substeps`` substeps of dt = h / substeps. A substep moves every
    free particle by its velocity after the explicit forces (gravity, drag, wind) act for dt,
    then runs ``iterations`` Gauss-Seidel sweeps over the constraints, and sets v = dx / dt:

    - each spring is the distance constraint C = |x_i - x_j| - r with compliance 1/k (so
      ``stiffness`` means what it means for a force spring: the constraint's potential is
      k C^2 / 2) and its dashpot the XPBD damping of C-dot with coefficient ``damping``
      (N s/m);
    - a grab is the zero-length constraint x - target with compliance 1/``grab_stiffness``.

    The springs are edge-coloured once (:func:`~.colouring.colour_springs`): the springs of one
    colour share no particle, so a colour can be projected in parallel (on a GPU; on a CPU the
    loops run on one thread below :data:`SERIAL_SPRINGS`, where that is faster). Tearing only
    kills springs, so the colouring stays valid; nothing is refactorised.

    What it converges to: with the sweeps converged, each substep is a backward Euler step of the
    springs (with the explicit forces applied first), so XPBD inherits backward Euler's
    stability at any k and h and its damping, which shrinks with dt = h / substeps. With few
    sweeps (the default: one, as Macklin et al. 2019 recommend, spending the work on substeps
    instead) the constraints are solved only partly: a stiff cloth (k large, so compliance ~ 0)
    stretches more than the exact solution would, by an amount that shrinks with more
    substeps, never by a blow-up. The method does not conserve energy; on conservative scenes
    it loses energy (docs/implicit.md, The trade, measured). First order in h.

    Args:
        system: a particle system (second order).
        substeps: substeps per step (>= 1, default 20).
        iterations: Gauss-Seidel sweeps per substep (>= 1, default 1).
    """

    name = "xpbd"
    order = 1
    requires_second_order = True
    description = "extended position-based dynamics: springs as compliant constraints, substepped"
    equation = Equation("backward_euler", FIXED_WORK, explicit_external=True,
                        advice="raise --iterations or --substeps, or lower --dt")
    tracks_solved_start = True
    stability_constant = math.inf  # the springs are compliant constraints, solved at any step
    advice_note = ("no blow-up at any step; with few substeps stiff springs stay partly stretched (k >= 1e6: "
                   "give it 50-100 substeps per 1/60 s); damping shrinks with the substep")

    @classmethod
    def scratch_bytes(cls, particles: int, springs: int, real_bytes: int, linear_solver: str = "cg") -> int:
        """Displacement and explicit force per particle; lambda and order per spring, and the
        edge colouring's Python ints on the host while it runs (about 120 bytes per spring)."""
        return 6 * real_bytes * particles + springs * (real_bytes + 4 + 120)

    def __init__(self, system: System, *, substeps: int = 20, iterations: int = 1):
        super().__init__(system)
        self.substeps = positive_int("substeps", substeps)
        self.iterations = positive_int("iterations", iterations)
        real, n = runtime.real(), system.particle_count
        self.external = ExplicitForces(system)
        self.springs = system.term("springs")
        self.grab = system.term("grab")
        self.has_springs, self.has_grab = self.springs is not None, self.grab is not None
        # The substep's displacement (m): kept apart from the positions so that v = delta / dt
        # carries no cancellation (in f32, x1 - x0 at a small dt would leave v mostly rounding).
        self.delta = ti.Vector.field(3, real, shape=n)
        self.starts: list[int] = [0]
        if self.springs is not None:
            order, self.starts = colour_springs(n, self.springs.ends_np)
            self.order = ti.field(ti.i32, shape=max(1, len(order)))
            if len(order):
                self.order.from_numpy(order)
            self.multiplier = ti.field(real, shape=max(1, self.springs.spring_count))  # lambda (N s^2)
        self.grab_multiplier = ti.Vector.field(3, real, shape=())
        self.fused = self.iterations <= FUSED_ITERATIONS
        # Below SERIAL_SPRINGS each parallel loop costs more in thread hand-off than it gains
        # (17 loops per substep): run the loops on one thread.
        springs = self.springs.spring_count if self.has_springs else 0
        self.serial = self.external.serial = runtime.serial_loops(n + springs, SERIAL_SPRINGS)

    @property
    def colour_count(self) -> int:
        """Colours of the spring graph (parallel phases of one sweep)."""
        return len(self.starts) - 1

    def step(self, state, t: float, h: float) -> StepReport:
        dt = h / self.substeps
        for k in range(self.substeps):
            if self.solved_start is not None and k == self.substeps - 1:
                self.solved_start.copy_from(state)  # what the convergence monitor measures
                self.solved_h = dt
            if self.fused:
                self._substep(state, dt, t + k * dt)
            else:
                self._begin(state, dt, t + k * dt)
                for _ in range(self.iterations):
                    self._sweep_kernel(state, dt)
                self._end(state, dt)
        return StepReport(accepted=True, h=h, next_h=h, f_evals=self.substeps,
                          linear_iterations=self.substeps * self.iterations)

    # -- kernels --------------------------------------------------------------------------------

    @ti.kernel
    def _substep(self, y: ti.template(), dt: float, t: float):
        self._predict(y, dt, t)
        for _ in ti.static(range(self.iterations)):
            self._sweep(y, dt)
        self._velocities(y, dt)

    @ti.kernel
    def _begin(self, y: ti.template(), dt: float, t: float):
        self._predict(y, dt, t)

    @ti.kernel
    def _sweep_kernel(self, y: ti.template(), dt: float):
        self._sweep(y, dt)

    @ti.kernel
    def _end(self, y: ti.template(), dt: float):
        self._velocities(y, dt)

    @ti.func
    def _predict(self, y, dt, t):
        self.external.gather(y, t)
        ti.loop_config(serialize=self.serial)
        for i in range(self.system.particle_count):  # a range-for: serialize applies
            step = ti.Vector.zero(y.x.dtype, 3)
            if self.system.free[i]:
                step = dt * (y.v[i] + dt * self.external.force[i] / self.system.mass[i])
            self.delta[i] = step
        if ti.static(self.has_springs):
            ti.loop_config(serialize=self.serial)
            for s in range(self.multiplier.shape[0]):
                self.multiplier[s] = 0.0
        if ti.static(self.has_grab):
            self.grab_multiplier[None] = ti.Vector.zero(y.x.dtype, 3)

    @ti.func
    def _sweep(self, y, dt):
        """One Gauss-Seidel sweep, colour by colour, always in the same order (alternating the
        order, symmetric Gauss-Seidel, left a 64 x 64 cloth at k = 1e6 N/m with 7 to 100 times the
        stretch energy)."""
        if ti.static(self.has_springs):
            for c in ti.static(range(self.colour_count)):
                ti.loop_config(serialize=self.serial)
                for q in range(self.starts[c], self.starts[c + 1]):
                    self._project_spring(self.order[q], y, dt)
        if ti.static(self.has_grab):
            for _ in range(1):  # one particle: a serial task
                self._project_grab(y, dt)

    @ti.func
    def _project_spring(self, s, y, dt):
        springs = self.springs
        k = springs.stiffness[s]
        if springs.is_alive(s) and k > 0.0:
            i, j = springs.ends[s][0], springs.ends[s][1]
            wi, wj = self.system.inverse_mass(i), self.system.inverse_mass(j)
            moved = self.delta[i] - self.delta[j]
            d = (y.x[i] - y.x[j]) + moved
            length = d.norm()
            if wi + wj > 0.0 and length > 0.0:
                u = d / length
                alpha = 1.0 / (k * dt * dt)  # compliance / dt^2
                gamma = springs.damping[s] / (k * dt)  # alpha * (damping dt^2) / dt
                rate = u.dot(moved)
                dl = (-(length - springs.rest[s]) - alpha * self.multiplier[s] - gamma * rate) \
                    / ((1.0 + gamma) * (wi + wj) + alpha)
                self.delta[i] += wi * dl * u
                self.delta[j] -= wj * dl * u
                self.multiplier[s] += dl

    @ti.func
    def _project_grab(self, y, dt):
        grab = self.grab
        p = grab.particle[None]
        k = grab.stiffness[None]
        if p >= 0 and k > 0.0:
            w = self.system.inverse_mass(p)
            if w > 0.0:
                alpha = 1.0 / (k * dt * dt)
                gamma = grab.damping[None] / (k * dt)
                rate = self.delta[p]
                dl = (-(y.x[p] - grab.target[None] + rate) - alpha * self.grab_multiplier[None] - gamma * rate) \
                    / ((1.0 + gamma) * w + alpha)
                self.delta[p] += w * dl
                self.grab_multiplier[None] += dl

    @ti.func
    def _velocities(self, y, dt):
        ti.loop_config(serialize=self.serial)
        for i in range(self.system.particle_count):  # a range-for: serialize applies
            if self.system.free[i]:
                y.x[i] += self.delta[i]
                y.v[i] = self.delta[i] / dt
