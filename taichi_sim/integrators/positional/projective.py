"""Projective dynamics for mass-spring systems: local projections and one constant matrix."""

import math
import time
from typing import Annotated

import numpy as np
import taichi as ti

from ... import runtime
from ...errors import ConfigError
from ...systems.base import System
from ..base import Integrator, Status, StepReport
from ..equation import FIXED_WORK, Equation
from ..options import Option
from .chebyshev import chebyshev_weight
from .external import ExplicitForces
from .global_matrix import GlobalMatrix


@ti.data_oriented
class ProjectiveDynamics(Integrator):
    """Projective dynamics (Liu, Bargteil, O'Brien & Kavan 2013, "Fast simulation of mass-spring
    systems"; Bouaziz et al. 2014): backward Euler on the springs by local/global iterations.

    A step of h seconds minimises over the new positions x

        g(x) = |x - y|_M^2 / (2 h^2) + sum_s k_s |x_i - x_j - d_s|^2 / 2
               + sum_s c_s |(x_i - x_j) - (x0_i - x0_j)|^2 / (2 h) + grab terms,

    y = x0 + h v0 + h^2 M^-1 f_ext (gravity, drag, wind, taken explicitly at the step's start),
    over x and the spring directions d_s (|d_s| = rest length). Starting from whichever of y
    and the drift x0 + h v0 has the lower g (see below), it alternates the *local* step (each
    d_s = r_s (x_i - x_j) / |x_i - x_j|, one kernel that also gathers the right-hand side) and the *global* step, a linear solve with the constant
    matrix A = M / h^2 + L_k + L_c / h (+ the grab's k + c/h on its particle), L_k and L_c the
    spring graph's Laplacians weighted by stiffness and damping. A is the same for x, y and z
    (an n x n matrix, not 3n x 3n) and is factorised (:class:`~.global_matrix.GlobalMatrix`:
    SuperLU, symmetric, solving x, y and z in one call) once per topology and step size:
    again only when a spring tears, a grab starts or ends, the step size or a spring's
    stiffness or damping changes, or :meth:`refactorise` is called. Then v = (x - x0) / h.

    Where it starts: y is the usual start, and the better one for soft springs. But y moves
    every free particle by h^2 f_ext / m while the pins stay, and on a stiff cloth the springs
    this stretches hold more energy than the whole cloth (k = 1e8 N/m, 64 x 64, 1/60 s:
    gravity's 2.7 mm a step on a 16 mm spring); a few iterations do not undo it, and the run
    gained energy step after step (highest rise 310 J over its 401 J in 2 s at 10 iterations,
    f64; none from the drift). Starting from the lower of g(y) and g(x0 + h v0), every
    iteration lowering g, the step ends with g no higher than at either, for one extra pass
    over the springs a step. Against the exact backward Euler step (64 x 64, 0.5 s) the error
    was the same or lower than from y alone at k = 1e2 to 1e6, and 2-3 % higher at k = 1e8,
    where both were 0.8 m off (docs/implicit.md, Position-level methods).

    What it converges to: every iteration lowers g, and g's minimiser is the backward Euler
    step of the springs with spring forces exact; so with enough ``iterations`` (or a
    ``tolerance``) PD approaches :class:`~taichi_sim.integrators.ImplicitEuler`'s step on a
    scene whose other forces are constant (gravity), and it is unconditionally stable like it.
    What it damps: backward Euler's artificial damping, plus, with few iterations, a stiff
    cloth left partly unsolved (it stretches and swings more softly than the exact step).
    Unlike the force springs' dashpots, which act only along each spring, PD's dashpots damp
    the whole relative velocity of the two ends (isotropic, so A stays one scalar matrix): a
    different model, which on a 16 x 16 cloth with the default damping (0.05 N s/m) leaves PD
    4-6 cm from the reference however small the step (``taichi-sim bench stiff-cloth``); set
    ``damping`` to 0 to compare like with like. ``chebyshev_rho`` > 0 turns on Chebyshev semi-iterative acceleration (Wang
    2015, "A Chebyshev semi-iterative approach for accelerating projective and position-based
    dynamics") with that estimated spectral radius; a rho above the true one can make the
    iterations oscillate, which is why it is off by default.

    Args:
        system: a particle system (second order).
        iterations: local/global iterations per step (>= 1, default 10); the most, when a
            ``tolerance`` is given.
        tolerance: None (run all ``iterations``), or stop once the largest position change of
            an iteration is below ``tolerance`` times the largest displacement of the step.
        chebyshev_rho: 0 (off) or the spectral radius estimate in (0, 1) for Chebyshev
            acceleration.
    """

    name = "projective_dynamics"
    plot_colour = "#7f7f7f"  # in the benchmarks' plots
    takes_elastic_models = False  # its solve holds springs only (Integrator.takes_elastic_models)
    order = 1
    requires_second_order = True
    description = "projective dynamics: local/global backward Euler with one prefactorised matrix"
    equation = Equation("backward_euler", FIXED_WORK, explicit_external=True, isotropic_dashpots=True,
                        advice="raise --iterations, set --pd-tolerance, or lower --dt")
    work_option, work_cap = "iterations", 160  # 16 times the default, under a --tolerance
    # The springs are solved implicitly at any step (gravity, drag and wind are not stiff).
    stability_constant = math.inf
    advice_note = ("no blow-up at any step (each iteration lowers backward Euler's objective, "
                   "from the lower of two starts: energy did not rise up to k = 1e8); with few "
                   "iterations a stiff cloth is left unsolved (k >= 1e6: it hardly moves, "
                   "0.6-1 m from backward Euler after 0.5 s); damps like backward Euler")

    @classmethod
    def scratch_bytes(cls, particles: int, springs: int, real_bytes: int, linear_solver: str = "cg") -> int:
        """vec3s per particle; the matrix's triplets and its SuperLU factors, L and U together:
        7.8 and 10.9 times the matrix's n + 2 S entries on 64 x 64 and 128 x 128 cloths (the
        fill grows slowly with n), taken as 12."""
        return (18 * real_bytes * particles + (particles + 4 * springs) * (real_bytes + 8)
                + 12 * (particles + 2 * springs) * (real_bytes + 4))

    def __init__(self, system: System, *,
                 iterations: Annotated[int, Option("local/global iterations per step", flag=True, at_least=1)] = 10,
                 tolerance: Annotated[float | None, Option(
                     "stop iterating once an iteration moves no particle by more than this fraction of the "
                     "step's largest displacement", flag="--pd-tolerance", above=0, below=1,
                     default_text="off: all iterations")] = None,
                 chebyshev_rho: Annotated[float, Option(
                     "Chebyshev acceleration: the spectral radius estimate (0: off)", flag=True, at_least=0,
                     below=1)] = 0.0):
        super().__init__(system)
        self.iterations = int(iterations)
        self.tolerance = None if tolerance is None else float(tolerance)
        self.chebyshev_rho = float(chebyshev_rho)
        coupled = system.term("springs") is not None or system.term("grab") is not None
        if coupled and runtime.backend() not in ("x64", "arm64"):
            raise ConfigError(f"projective_dynamics runs on the CPU backend only (its kernels share the "
                              f"global solve's arrays in place; this run uses {runtime.backend()}); use xpbd")
        real, n = runtime.real(), system.particle_count
        self.external = ExplicitForces(system)
        self.external.serial = system.serial_loops
        self.springs = system.term("springs")
        self.grab = system.term("grab")
        self.has_springs, self.has_grab = self.springs is not None, self.grab is not None
        self.start = ti.Vector.field(3, real, shape=n)  # x0 (m)
        self.inertial = ti.Vector.field(3, real, shape=n)  # y (m)
        self.earlier = ti.Vector.field(3, real, shape=n)  # the iterate before last (Chebyshev)
        self.drifted = ti.Vector.field(3, real, shape=n)  # x0 + h v0 (m), the other start
        # The global step's right-hand side (N), (n, 3): a numpy array the kernels write in place.
        self.rhs = np.zeros((n, 3), GlobalMatrix.dtype)  # f64 always (see GlobalMatrix)
        self.factored_key = None
        self.matrix = None
        if self.springs is not None or self.grab is not None:
            springs = self.springs.spring_count if self.springs is not None else 0
            self.matrix = GlobalMatrix(n, n + 4 * springs)
        self.factorisations = 0
        self.factorise_seconds = 0.0
        self.total_iterations = 0
        self.drift_starts = 0  # steps started from x0 + h v0 rather than y

    def reset(self) -> None:
        """Nothing to forget: the matrix follows the step size, the springs' topology and
        parameters (``Springs.set_parameters``) and the grabbed particle by itself, so a grab
        target that moves every frame costs no refactorisation. Call :meth:`refactorise` after
        changing which particles are pinned."""

    def refactorise(self) -> None:
        """Factorise again before the next step (the pins changed)."""
        self.factored_key = None

    def step(self, state, t: float, h: float) -> StepReport:
        inertial_objective, drift_objective = self._begin(state, h, t)
        if self.matrix is None:  # nothing coupled or solved: x = y
            self._finish(state, h)
            return StepReport(accepted=True, h=h, next_h=h, f_evals=1)
        self._factorise_if_needed(h)
        if not self.matrix.factorised:
            return StepReport(accepted=False, h=0.0, next_h=h, f_evals=1, status=Status.DIVERGED,
                              message="projective dynamics: the global matrix is not positive definite")
        if drift_objective < inertial_objective:
            self._start_from_drift(state)
            self.drift_starts += 1
        omega = 1.0
        iterations = 0
        self._local_step(state, h, self.rhs)
        for k in range(self.iterations):
            iterations += 1
            solved = self.matrix.solve(self.rhs)
            if self.chebyshev_rho > 0.0:
                omega = chebyshev_weight(self.chebyshev_rho ** 2, k, omega)
            last = k == self.iterations - 1
            # One launch per iteration: the solution is accepted and, unless this was the last
            # iteration, the next local step runs in the same kernel.
            change, displacement = self._accept(state, solved, omega, h, self.rhs, not last)
            if not last and self.tolerance is not None \
                    and change <= self.tolerance * max(displacement, 1e-300):
                break
        self._finish(state, h)
        self.total_iterations += iterations
        return StepReport(accepted=True, h=h, next_h=h, f_evals=1, linear_iterations=iterations)

    # -- the constant matrix --------------------------------------------------------------------

    def _factorise_if_needed(self, h: float) -> None:
        springs = (self.springs.topology_version, self.springs.parameters_version) if self.has_springs else ()
        grabbed = int(self.grab.particle[None]) if self.has_grab else -1
        key = (h, springs, grabbed)
        if key == self.factored_key and self.matrix.factorised:
            return
        start = time.perf_counter()
        self.matrix.vals.fill(0)
        self._assemble(self.matrix.rows, self.matrix.cols, self.matrix.vals, h)
        self.factored_key = key if self.matrix.factorise() else None
        self.factorisations += 1
        self.factorise_seconds += time.perf_counter() - start

    @ti.kernel
    def _assemble(self, rows: ti.types.ndarray(ndim=1), cols: ti.types.ndarray(ndim=1),
                  vals: ti.types.ndarray(ndim=1), h: float):
        """COO triplets of A: triplet i is particle i's diagonal, triplets n + 4 s .. n + 4 s + 3
        spring s's four entries (left 0 where an end is pinned or the spring torn)."""
        n = self.system.particle_count
        for i in range(n):
            diagonal = ti.cast(1.0, self.start.dtype)
            if self.system.free[i]:
                diagonal = self.system.mass[i] / (h * h)
                if ti.static(self.has_grab):
                    if i == self.grab.particle[None]:
                        diagonal += self.grab.stiffness[None] + self.grab.damping[None] / h
            rows[i], cols[i], vals[i] = i, i, diagonal
        if ti.static(self.has_springs):
            springs = self.springs
            for s in range(springs.spring_count):
                i, j = springs.ends[s][0], springs.ends[s][1]
                first = n + 4 * s
                rows[first], cols[first] = i, i
                rows[first + 1], cols[first + 1] = j, j
                rows[first + 2], cols[first + 2] = i, j
                rows[first + 3], cols[first + 3] = j, i
                if springs.is_alive(s):
                    weight = springs.stiffness[s] + springs.damping[s] / h
                    if self.system.free[i]:
                        vals[first] = weight
                    if self.system.free[j]:
                        vals[first + 1] = weight
                    if self.system.free[i] and self.system.free[j]:
                        vals[first + 2] = -weight
                        vals[first + 3] = -weight

    # -- kernels --------------------------------------------------------------------------------

    @ti.kernel
    def _begin(self, y: ti.template(), h: float, t: float) -> (float, float):
        """Start the step at y, keeping x0; returns (g(y), g(x0 + h v0)) in J, up to the same
        constant (g as in the class doc), for the choice of start."""
        self.external.gather(y, t)
        ti.loop_config(serialize=self.system.serial_loops)
        for i in range(self.system.particle_count):
            self.start[i] = y.x[i]
            target = y.x[i]
            if self.system.free[i]:
                target += h * y.v[i] + h * h * self.external.force[i] / self.system.mass[i]
            self.inertial[i] = target
            self.drifted[i] = y.x[i] + h * y.v[i] if self.system.free[i] else y.x[i]
            self.earlier[i] = target
            y.x[i] = target
        inertial = 0.0
        drift = 0.0
        if ti.static(self.has_springs or self.has_grab):  # else nothing is solved: no choice to make
            ti.loop_config(serialize=self.system.serial_loops)
            for i in range(self.system.particle_count):
                if self.system.free[i]:
                    drift += 0.5 * self.system.mass[i] / (h * h) \
                        * (self.drifted[i] - self.inertial[i]).norm_sqr()
                if ti.static(self.has_grab):
                    if i == self.grab.particle[None]:
                        k, c, target = self.grab.stiffness[None], self.grab.damping[None], self.grab.target[None]
                        for drifting in ti.static((False, True)):
                            x = self.drifted[i] if ti.static(drifting) else self.inertial[i]
                            g = 0.5 * k * (x - target).norm_sqr() + 0.5 * c / h * (x - self.start[i]).norm_sqr()
                            if ti.static(drifting):
                                drift += g
                            else:
                                inertial += g
            if ti.static(self.has_springs):
                springs = self.springs
                ti.loop_config(serialize=self.system.serial_loops)
                for s in range(springs.spring_count):
                    if springs.is_alive(s):
                        i, j = springs.ends[s][0], springs.ends[s][1]
                        k, c, rest = springs.stiffness[s], springs.damping[s], springs.rest[s]
                        d0 = self.start[i] - self.start[j]
                        for drifting in ti.static((False, True)):
                            d = self.drifted[i] - self.drifted[j] if ti.static(drifting) else self.inertial[i] - self.inertial[j]
                            g = 0.5 * k * (d.norm() - rest) ** 2 + 0.5 * c / h * (d - d0).norm_sqr()
                            if ti.static(drifting):
                                drift += g
                            else:
                                inertial += g
        return inertial, drift

    @ti.kernel
    def _start_from_drift(self, y: ti.template()):
        ti.loop_config(serialize=self.system.serial_loops)
        for i in range(self.system.particle_count):
            self.earlier[i] = self.drifted[i]
            y.x[i] = self.drifted[i]

    @ti.func
    def _project_and_gather(self, y, h, rhs: ti.template()):
        """Project every spring at the iterate ``y.x`` and gather the global step's right-hand
        side (N) into ``rhs`` (n, 3): per particle, a pass over its own springs (no atomics)."""
        ti.loop_config(serialize=self.system.serial_loops)
        for i in range(self.system.particle_count):
            b = self.start[i]  # a pinned particle's row is the identity
            if self.system.free[i]:
                b = self.system.mass[i] / (h * h) * self.inertial[i]
                if ti.static(self.has_grab):
                    if i == self.grab.particle[None]:
                        b += self.grab.stiffness[None] * self.grab.target[None] \
                            + self.grab.damping[None] / h * self.start[i]
                if ti.static(self.has_springs):
                    springs = self.springs
                    for e in range(springs.offsets[i], springs.offsets[i + 1]):
                        s = springs.incident[e]
                        if springs.is_alive(s):
                            j = springs.other[e]
                            d = y.x[i] - y.x[j]
                            length = d.norm()
                            k, c = springs.stiffness[s], springs.damping[s]
                            if length > 0.0:
                                b += k * springs.rest[s] / length * d
                            b += c / h * (self.start[i] - self.start[j])
                            if not self.system.free[j]:  # its column moved to the right-hand side
                                b += (k + c / h) * self.start[j]
            for a in ti.static(range(3)):
                rhs[i, a] = b[a]

    @ti.kernel
    def _local_step(self, y: ti.template(), h: float, rhs: ti.types.ndarray(ndim=2)):
        self._project_and_gather(y, h, rhs)

    @ti.kernel
    def _accept(self, y: ti.template(), solved: ti.types.ndarray(ndim=2), omega: float, h: float,
                rhs: ti.types.ndarray(ndim=2), then_local: ti.template()) -> (float, float):
        """x <- omega (solution - earlier) + earlier (Chebyshev; omega = 1: the solution), keeping
        the iterate before as ``earlier``, then (``then_local``) the next local step into
        ``rhs``; returns (largest change of this iteration, largest displacement from the step's
        start) in m."""
        change = 0.0
        displacement = 0.0
        ti.loop_config(serialize=self.system.serial_loops)
        for i in range(self.system.particle_count):
            if self.system.free[i]:
                solution = ti.Vector([solved[i, 0], solved[i, 1], solved[i, 2]], y.x.dtype)
                new = omega * (solution - self.earlier[i]) + self.earlier[i]
                ti.atomic_max(change, (new - y.x[i]).norm())
                ti.atomic_max(displacement, (new - self.start[i]).norm())
                self.earlier[i] = y.x[i]
                y.x[i] = new
        if ti.static(then_local):
            self._project_and_gather(y, h, rhs)
        return change, displacement

    @ti.kernel
    def _finish(self, y: ti.template(), h: float):
        ti.loop_config(serialize=self.system.serial_loops)
        for i in range(self.system.particle_count):
            if self.system.free[i]:
                y.v[i] = (y.x[i] - self.start[i]) / h
