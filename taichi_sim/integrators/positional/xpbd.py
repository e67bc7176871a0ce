"""Extended position-based dynamics: springs as compliant distance constraints."""

import math
from typing import Annotated

import numpy as np
import taichi as ti

from ... import runtime
from ...loops import anchor
from ...systems.base import System
from ..base import Integrator, StepReport
from ..equation import FIXED_WORK, Equation
from ..options import Option
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
    kills springs, so the colouring stays valid; nothing is refactorised. At the start of each
    step the springs are copied in colour order with their compliance terms for that step's dt
    (live stiffness, damping and rest length changes and torn springs are seen at the next
    step) and the update's denominator, and each particle's inverse mass is stored, so a
    projection reads its spring's data in sequence and divides only once (by its length).

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
    plot_colour = "#000000"  # in the benchmarks' plots
    takes_elastic_models = False  # its solve holds springs only (Integrator.takes_elastic_models)
    order = 1
    requires_second_order = True
    description = "extended position-based dynamics: springs as compliant constraints, substepped"
    equation = Equation("backward_euler", FIXED_WORK, explicit_external=True,
                        advice="raise --iterations or --substeps, or lower --dt")
    work_option, work_cap = "substeps", 320  # 16 times the default, under a --tolerance
    tracks_solved_start = True
    stability_constant = math.inf  # the springs are compliant constraints, solved at any step
    advice_note = ("no blow-up at any step; with few substeps stiff springs stay partly stretched (k >= 1e6: "
                   "give it 50-100 substeps per 1/60 s); damping shrinks with the substep")

    @classmethod
    def scratch_bytes(cls, particles: int, springs: int, real_bytes: int, linear_solver: str = "cg") -> int:
        """Per particle the substep's record (8 reals), the explicit force and the inverse mass;
        per spring lambda, its place in colour order and the colour-ordered copy (ends and six
        reals), and the edge colouring's Python ints on the host while it runs (about 120 bytes
        per spring)."""
        return 12 * real_bytes * particles + springs * (7 * real_bytes + 12 + 120)

    def __init__(self, system: System, *,
                 substeps: Annotated[int, Option("substeps per step", flag=True, at_least=1)] = 20,
                 iterations: Annotated[int, Option("Gauss-Seidel sweeps per substep", flag=True, at_least=1)] = 1):
        super().__init__(system)
        self.substeps, self.iterations = substeps, iterations
        real, n = runtime.real(), system.particle_count
        self.external = ExplicitForces(system)
        self.springs = system.term("springs")
        self.grab = system.term("grab")
        self.has_springs, self.has_grab = self.springs is not None, self.grab is not None
        # Each particle's substep as one record (x, 0, delta, 0): its position at the substep's
        # start and its displacement (m), so a projection reads both ends in one cache line each
        # and works on 4-wide vectors (the zero lanes stay zero). The displacement is kept apart
        # from the position so that v = delta / dt carries no cancellation (in f32, x1 - x0 at
        # a small dt would leave v mostly rounding).
        self.record = ti.Vector.field(8, real, shape=n)
        self.w = ti.field(real, shape=n)  # inverse mass (1/kg) for this step; 0 on a particle that does not move
        self.starts: list[int] = [0]
        if self.springs is not None:
            order, self.starts = colour_springs(n, self.springs.ends_np)
            self.colour_order = ti.field(ti.i32, shape=max(1, len(order)))
            if len(order):
                self.colour_order.from_numpy(order)
            # The springs in colour order (index q = place in colour_order), their terms refreshed
            # each step by _prepare: the sweep reads them in sequence instead of through colour_order.
            size = max(1, len(order))
            self.ends = ti.Vector.field(2, ti.i32, shape=size)  # fixed: tearing only kills springs
            if len(order):
                self.ends.from_numpy(self.springs.ends_np[order].astype(np.int32))
            # (rest length, alpha = 1/(k dt^2), gamma = damping/(k dt), 1 / the update's
            # denominator, w_i, w_j): all fixed through a step. alpha < 0 marks a spring that is
            # skipped (torn, k <= 0, or both ends fixed)
            self.terms = ti.Vector.field(6, real, shape=size)
            self.multiplier = ti.field(real, shape=size)  # lambda (N s^2), in colour order
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
        self._prepare(dt)
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
    def _prepare(self, dt: float):
        ti.loop_config(serialize=self.serial)
        for i in range(self.system.particle_count):  # a range-for: serialize applies
            self.w[i] = self.system.inverse_mass(i)
        if ti.static(self.has_springs):
            springs = self.springs
            ti.loop_config(serialize=self.serial)
            for q in range(self.colour_order.shape[0]):
                s = self.colour_order[q]
                k = springs.stiffness[s]
                i, j = springs.ends[s][0], springs.ends[s][1]
                wi, wj = self.w[i], self.w[j]
                terms = ti.Vector([springs.rest[s], -1.0, 0.0, 0.0, wi, wj], dt=self.terms.dtype)
                if springs.is_alive(s) and k > 0.0 and wi + wj > 0.0:
                    alpha = 1.0 / (k * dt * dt)  # compliance / dt^2
                    gamma = springs.damping[s] / (k * dt)  # alpha * (damping dt^2) / dt
                    terms[1], terms[2] = alpha, gamma
                    terms[3] = 1.0 / ((1.0 + gamma) * (wi + wj) + alpha)
                self.terms[q] = terms

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
        if ti.static(self.serial):  # one serial task, anchored (taichi_sim/loops.py): about 5% of a step
            ti.loop_config(serialize=True)
            for _ in range(1):
                for field in ti.static((y.x, y.v, self.record, self.w, self.external.force, self.system.free)):
                    anchor(field)
                for i in range(self.system.particle_count):
                    self._predict_particle(i, y, dt)
                if ti.static(self.has_springs):
                    anchor(self.multiplier)
                    for q in range(self.multiplier.shape[0]):
                        self.multiplier[q] = 0.0
        else:
            for i in range(self.system.particle_count):
                self._predict_particle(i, y, dt)
            if ti.static(self.has_springs):
                for q in range(self.multiplier.shape[0]):
                    self.multiplier[q] = 0.0
        if ti.static(self.has_grab):
            self.grab_multiplier[None] = ti.Vector.zero(y.x.dtype, 3)

    @ti.func
    def _predict_particle(self, i, y, dt):
        step = ti.Vector.zero(y.x.dtype, 3)
        if self.system.free[i]:
            step = dt * (y.v[i] + dt * self.external.force[i] * self.w[i])
        self.record[i] = ti.Vector([y.x[i][0], y.x[i][1], y.x[i][2], 0.0, step[0], step[1], step[2], 0.0])

    @ti.func
    def _sweep(self, y, dt):
        """One Gauss-Seidel sweep, colour by colour, always in the same order (alternating the
        order, symmetric Gauss-Seidel, left a 64 x 64 cloth at k = 1e6 N/m with 7 to 100 times the
        stretch energy)."""
        if ti.static(self.has_springs and self.serial):
            # One thread: the colours in turn are one loop over the colour order. In one serial
            # task the anchors keep the fields' base addresses in registers (taichi_sim/loops.py).
            ti.loop_config(serialize=True)
            for _ in range(1):
                for field in ti.static((self.record, self.ends, self.terms, self.multiplier)):
                    anchor(field)
                for q in range(self.starts[-1]):
                    self._project_spring(q)
        elif ti.static(self.has_springs):
            for c in ti.static(range(self.colour_count)):
                for q in range(self.starts[c], self.starts[c + 1]):
                    self._project_spring(q)
        if ti.static(self.has_grab):
            for _ in range(1):  # one particle: a serial task
                self._project_grab(y, dt)

    @ti.func
    def _project_spring(self, q):
        """Spring q of the colour order (its data as :meth:`_prepare` left it)."""
        terms = self.terms[q]
        alpha = terms[1]
        if alpha >= 0.0:
            i, j = self.ends[q][0], self.ends[q][1]
            wi, wj = terms[4], terms[5]
            ri, rj = self.record[i], self.record[j]
            moved = ti.Vector([ri[4] - rj[4], ri[5] - rj[5], ri[6] - rj[6], ri[7] - rj[7]])
            d = ti.Vector([ri[0] - rj[0], ri[1] - rj[1], ri[2] - rj[2], ri[3] - rj[3]]) + moved
            length = d.norm()
            if length > 0.0:
                u = d * (1.0 / length)
                rate = u.dot(moved)
                # dl = (-C - alpha lambda - gamma C-dot dt) / ((1 + gamma)(w_i + w_j) + alpha)
                dl = (-(length - terms[0]) - alpha * self.multiplier[q] - terms[2] * rate) * terms[3]
                for a in ti.static(range(4)):
                    self.record[i][4 + a] = ri[4 + a] + wi * dl * u[a]
                    self.record[j][4 + a] = rj[4 + a] - wj * dl * u[a]
                self.multiplier[q] += dl

    @ti.func
    def _project_grab(self, y, dt):
        grab = self.grab
        p = grab.particle[None]
        k = grab.stiffness[None]
        if p >= 0 and k > 0.0:
            w = self.w[p]
            if w > 0.0:
                alpha = 1.0 / (k * dt * dt)
                gamma = grab.damping[None] / (k * dt)
                rate = self._delta(p)
                dl = (-(y.x[p] - grab.target[None] + rate) - alpha * self.grab_multiplier[None] - gamma * rate) \
                    / ((1.0 + gamma) * w + alpha)
                for a in ti.static(range(3)):
                    self.record[p][4 + a] += w * dl[a]
                self.grab_multiplier[None] += dl

    @ti.func
    def _velocities(self, y, dt):
        if ti.static(self.serial):
            ti.loop_config(serialize=True)
            for _ in range(1):
                for field in ti.static((y.x, y.v, self.record, self.system.free)):
                    anchor(field)
                for i in range(self.system.particle_count):
                    self._move_particle(i, y, dt)
        else:
            for i in range(self.system.particle_count):
                self._move_particle(i, y, dt)

    @ti.func
    def _move_particle(self, i, y, dt):
        if self.system.free[i]:
            delta = self._delta(i)
            y.x[i] += delta
            y.v[i] = delta / dt

    @ti.func
    def _delta(self, i):
        """Particle i's displacement in this substep (m)."""
        return ti.Vector([self.record[i][4], self.record[i][5], self.record[i][6]])
