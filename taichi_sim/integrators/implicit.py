"""Implicit integrators: backward Euler (Baraff-Witkin) and the implicit midpoint rule.

Both methods solve one implicit stage and extrapolate from it. With tau = theta h, the stage
is the state Y with

    Y = y0 + tau f(Y, t + tau),        then  y1 = y0 + (Y - y0) / theta.

theta = 1 is backward Euler (y1 = Y); theta = 1/2 is the implicit midpoint rule (Y is the
midpoint state, y1 = 2 Y - y0), which conserves every quadratic invariant: the energy of linear
springs, the radius of the circle ODE.

The stage equations are solved by Newton's method in one of two ways, picked by the system's
capability flags (never by its class):

* ``system.supports_jacobian`` (particle systems whose force terms all provide Jacobians): the
  velocity form of Baraff & Witkin (1998). With X = x0 + tau V, the unknown is V and the residual
  is g(V) = M (V - v0) - tau f(X, V); each Newton iteration solves A dV = -g with
  A = M - tau df/dv - tau^2 df/dx and analytic force Jacobians. A is kept symmetric positive
  definite, so CG and Cholesky apply: a compressed spring's stiffness block drops its transverse
  term (the factor 1 - r/|d| is clamped at 0; the exact, negative factor would make A indefinite
  for stiff springs at large steps), and the dashpots' non-symmetric dependence on positions is
  left out, as Baraff & Witkin do (see :class:`taichi_sim.forces.Springs`). Only the Jacobian is
  approximated, never the force, so iterated Newton still solves the exact equations. The first
  iteration linearises f about the current state (x0, v0) instead of (x0 + tau v0, v0), which
  gives Baraff & Witkin's step exactly: A dV = tau (f0 + tau df/dx v0). Pinned particles are
  filtered out of the solve (identity rows) and keep their position bit for bit. For conjugate
  gradients, each Newton iteration caches A once (every spring's 3x3 block, the diagonal
  blocks and their inverses) and the whole solve runs in one kernel, preconditioned by block
  SSOR on CPU backends (block Jacobi on GPUs), warm-started from the last steps' velocity
  changes (see :class:`_ConjugateGradients`); for the direct solver A is assembled for a sparse
  Cholesky factorisation. The one-step method solves to relative residual 1e-3 by default, the
  iterated ones far tighter (see :func:`default_cg_tolerance`).
* otherwise (the circle ODE, or any system without that API): Newton-Krylov on the whole state,
  with the residual g(Y) = Y - y0 - tau f(Y) and GMRES on (I - tau df/dy) dY = -g. The
  Jacobian-vector products come from ``system.jacobian_product`` when the system has one
  (``has_jacobian_product``; the circle's Jacobian is the constant rotation generator), else
  from forward differences of ``eval_f`` with the step of Pernice & Walker (1998, NITSOL).

``newton_iterations=1`` is the linearly implicit method: one Newton step from the current state,
taken as the answer (for backward Euler with spring Jacobians, Baraff & Witkin's method). More
iterations run Newton from the consistent start (V = v0, X = x0 + tau v0; or Y = y0) until the
TRUE nonlinear residual (the real f, not the linearised model) is below ``newton_tolerance``,
with a backtracking line search: a step must decrease the residual norm or, for particle
systems, the incremental potential, whose gradient is that residual and which the Newton step
descends because A is positive definite. With the clamped spring Jacobians this is a
quasi-Newton iteration; it converges to the exact implicit solution. Hitting an iteration cap is
Status.NOT_CONVERGED (the residual is in the report's message and ``linear_residual``); a
non-finite result is Status.DIVERGED. A step that fails leaves the state as it was, except that a
non-finite final extrapolation is written (and reported DIVERGED).
"""

import math
import time
from dataclasses import dataclass

import numpy as np
import taichi as ti

from .. import runtime
from ..errors import ConfigError
from ..state import State, finite
from ..systems.base import System
from .base import Integrator, Status, StepReport

LINEAR_SOLVERS = ("cg", "direct")
PRECONDITIONERS = ("ssor", "jacobi")  # of CG on particle systems; see _ConjugateGradients
SSOR_OMEGA = 1.3  # SSOR relaxation: 1.2-1.4 take the fewest iterations on the benchmark cloth
GMRES_RESTART = 20  # Krylov vectors kept before GMRES restarts (memory: this many states)
ARMIJO_SLOPE = 1e-4  # fraction of the predicted decrease a line-search step must achieve
MAX_BACKTRACKS = 20  # step halvings before the line search gives up (smallest step ~1e-6)
MAX_REFINEMENTS = 2  # iterative-refinement steps of a direct solve that missed the tolerance


LINEARISED_CG_TOLERANCE = 1e-3  # default of the one-step Baraff-Witkin method (see below)


def default_cg_tolerance(linearised_step: bool = False) -> float:
    """Default relative residual |rhs - A dV| / |rhs| of a linear solve.

    ``linearised_step``: the solve IS the step, as in Baraff & Witkin's method (implicit Euler
    with ``newton_iterations=1`` on a particle system): 1e-3 (``LINEARISED_CG_TOLERANCE``).
    That step linearises backward Euler once, so it is only first-order accurate; solving its
    linear system much better than the step itself is wasted work. Cloth solvers stop early
    for this reason; Blender's (``cg_filtered`` in ``implicit_blender.cc``) at 1e-2 with at
    most 100 iterations. Measured on the 64 x 64 benchmark cloth (k = 1e4 N/m, h = 1/60 s,
    ``benchmarks/bench_implicit.py --accuracy``, f32 and f64 alike): one step's velocity change
    differs from the exact linear solve's by ~1e-2 of itself (1e-2: ~8e-2); after 1 s the
    positions differ from those of exact solves by ~1 mm rms, 7 mm at most (1e-2: ~8 mm rms),
    where the method's own first-order error (h against h/2) is ~10 cm rms, 25 cm at most.
    Even 1e-8 leaves 0.04 mm rms there (the folding cloth amplifies every perturbation).
    1e-3 takes a quarter of the CG iterations of 1e-8.

    Otherwise (``newton_iterations > 1``, the exact backward Euler solution, or
    :class:`ImplicitMidpoint`, whose second order and conservation are the point; or a system
    solved by GMRES): the Newton convergence test and the line search need accurate steps,
    so 1e-8 in f64; 1e-5 in f32, about 100 f32 rounding units (a residual summing a dozen
    spring forces is not computed much better).
    """
    if linearised_step:
        return LINEARISED_CG_TOLERANCE
    return 1e-8 if runtime.precision() == "f64" else 1e-5


def default_newton_tolerance() -> float:
    """Default relative nonlinear residual of an iterated stage: 1e-6 in f64, far below a
    step's truncation error at practical step sizes (velocities good to ~1e-6 of their scale),
    yet usually reached within 20 iterations where compressed springs make Newton converge only
    linearly (factor ~0.4 per iteration on a folding cloth, slower near buckling); 1e-5 in f32.
    Ask for less when measuring accuracy."""
    return 1e-6 if runtime.precision() == "f64" else 1e-5


@dataclass
class LinearSolverStats:
    """Work done by an implicit integrator's linear solver since it was created.

    Attributes:
        solver: what ran: ``"pcg"`` (preconditioned conjugate gradients on the cached matrix),
            ``"cholesky"`` (sparse direct LL^T, Taichi's SparseSolver) or ``"gmres"``
            (matrix-free Newton-Krylov, for systems without the Jacobian API).
        preconditioner: CG's, ``"ssor"`` or ``"jacobi"``; empty for the others.
        solves: linear systems solved.
        iterations: Krylov iterations in total; for the direct solver, triangular solves (one
            per factorisation, plus any iterative refinement).
        analyze_count: symbolic analyses of the sparsity pattern (direct solver only).
        factorize_count: numeric factorisations (direct solver only).
        analyze_seconds, factorize_seconds: wall time spent in them (s).
        solve_seconds: wall time in linear solves in total, assembly, analysis and factorisation
            included (s).
    """

    solver: str
    preconditioner: str = ""
    solves: int = 0
    iterations: int = 0
    analyze_count: int = 0
    factorize_count: int = 0
    analyze_seconds: float = 0.0
    factorize_seconds: float = 0.0
    solve_seconds: float = 0.0


@dataclass(frozen=True)
class _LinearOutcome:
    iterations: int
    residual: float  # relative: |rhs - A dY| / |rhs|
    converged: bool
    f_evals: int = 0
    message: str = ""


@dataclass
class _StepWork:
    """What one step has done so far, for its report."""

    h: float
    f_evals: int = 0
    linear_iterations: int = 0
    linear_residual: float = 0.0

    def report(self, status: Status, message: str = "", *, accepted: bool = True) -> StepReport:
        return StepReport(accepted=accepted, h=self.h if accepted else 0.0, next_h=self.h,
                          f_evals=self.f_evals, status=status, linear_iterations=self.linear_iterations,
                          linear_residual=self.linear_residual, message=message)

    def failed(self, status: Status, message: str) -> StepReport:
        """A step that left the state as it was."""
        return self.report(status, message, accepted=False)


class _ImplicitStageMethod(Integrator):
    """Shared Newton driver of :class:`ImplicitEuler` and :class:`ImplicitMidpoint`.

    Subclasses set ``stage_fraction`` (theta) and ``default_newton_iterations``.

    Options (keyword-only):
        linear_solver: ``"cg"`` (matrix-free Krylov: preconditioned CG on the symmetric positive
            definite particle system, GMRES for a system without spring Jacobians) or
            ``"direct"`` (sparse Cholesky; needs spring Jacobians and a CPU backend). The
            direct solver analyses the sparsity pattern once and only refactorises while
            ``system.jacobian_pattern_version`` stays the same; see :meth:`invalidate_pattern`.
        newton_iterations: Newton iterations per step, >= 1 (1: the linearly implicit method,
            unchecked; more: iterate to ``newton_tolerance``, NOT_CONVERGED if not reached).
        newton_tolerance: bound on the relative nonlinear residual |g| / |s|, where s adds up
            the magnitudes of the terms of g (momentum, each force piece; for a first-order
            system |Y| + |y0| + tau |f|), i.e. the residual relative to what it is computed
            from. Default :func:`default_newton_tolerance`.
        cg_tolerance: bound on the relative residual |rhs - A dY| / |rhs| of each linear solve
            (CG or GMRES; the direct solver refines its solution until it holds). Default
            :func:`default_cg_tolerance`: 1e-3 for the one-step Baraff-Witkin method
            (:class:`ImplicitEuler` with ``newton_iterations=1`` on a particle system), else
            1e-8 in f64 and 1e-5 in f32.
        cg_max_iterations: Krylov iterations allowed per linear solve (default 1000).
        preconditioner: of CG on a particle system, ``"ssor"`` (block symmetric SOR, applied
            with Eisenstat's trick; the default on CPU backends: a third of the iterations of
            block Jacobi, about half the time) or ``"jacobi"`` (block Jacobi; the default, and
            the only one, on GPU backends, where the iterations run in parallel loops). See
            :class:`_ConjugateGradients`. Not for the direct solver or GMRES.
        warm_start: start the first CG solve of a step from the velocity change V - v0
            extrapolated linearly from the last two steps (the last one's alone after a cold
            step) instead of zero (default True). At 60 steps/s the motion is smooth, so the
            guess is close: about a third fewer iterations on the benchmark cloth. Used only
            when the step continues where the last accepted one ended (same t, no :meth:`reset`
            since); every solve still meets ``cg_tolerance``.
    """

    stage_fraction: float
    default_newton_iterations: int
    implicit = True

    def __init__(self, system: System, *, linear_solver: str = "cg", newton_iterations: int | None = None,
                 newton_tolerance: float | None = None, cg_tolerance: float | None = None,
                 cg_max_iterations: int = 1000, preconditioner: str | None = None,
                 warm_start: bool = True):
        super().__init__(system)
        if linear_solver not in LINEAR_SOLVERS:
            raise ConfigError(f"linear_solver must be one of {', '.join(LINEAR_SOLVERS)}, "
                              f"got {linear_solver!r}")
        self.linear_solver = linear_solver
        self.newton_iterations = _positive_int("newton_iterations", self.default_newton_iterations
                                               if newton_iterations is None else newton_iterations)
        self.cg_max_iterations = _positive_int("cg_max_iterations", cg_max_iterations)
        self.newton_tolerance = _tolerance("newton_tolerance", newton_tolerance, default_newton_tolerance)
        linearised_step = (system.supports_jacobian and self.stage_fraction == 1.0
                           and self.newton_iterations == 1)
        self.cg_tolerance = _tolerance("cg_tolerance", cg_tolerance,
                                       lambda: default_cg_tolerance(linearised_step))
        if not isinstance(warm_start, (bool, np.bool_)):
            raise ConfigError(f"warm_start must be True or False, got {warm_start!r}")
        self.warm_start = bool(warm_start)
        self._resume_time: float | None = None  # where the last accepted step ended
        if preconditioner is not None and (linear_solver != "cg" or not system.supports_jacobian):
            raise ConfigError("preconditioner applies to CG on a particle system with spring Jacobians only")
        if system.supports_jacobian:
            self._stage = _VelocityNewton(system, self.stage_fraction, linear_solver, preconditioner)
        elif linear_solver == "direct":
            raise ConfigError(f"linear_solver 'direct' needs a system with spring Jacobians; "
                              f"{type(system).__name__} has none (use 'cg')")
        else:
            restart = min(GMRES_RESTART, self.cg_max_iterations)
            self._stage = _NewtonKrylov(system, self.stage_fraction, restart)
        self.stats: LinearSolverStats = self._stage.stats

    def invalidate_pattern(self) -> None:
        """Make the direct solver re-analyse the sparsity pattern at its next solve (call it
        after changing which particles couple without bumping a term's ``topology_version``)."""
        self._stage.invalidate_pattern()

    def reset(self) -> None:
        """Forget the previous step (the next one starts its linear solve cold)."""
        self._resume_time = None

    def step(self, state: State, t: float, h: float) -> StepReport:
        tau = self.stage_fraction * h
        t_stage = t + tau
        stage = self._stage
        work = _StepWork(h)
        linearised = self.newton_iterations == 1
        # Continuing from where the last accepted step ended (within rounding of t): the first
        # solve may start from the velocity change extrapolated from the last steps.
        continued = self._resume_time is not None and abs(t - self._resume_time) <= 1e-9 * max(abs(t), h)
        warm = self.warm_start and continued
        self._resume_time = None
        work.f_evals, residual_norm = stage.begin(state, t_stage, tau, linearised)
        merit = math.nan if linearised else stage.merit(state, tau)
        relative_residual = math.nan
        for newton in range(1, self.newton_iterations + 1):
            failure = self._solve_linear(tau, t_stage, work, warm and newton == 1)
            if failure is not None:
                return failure
            if linearised:
                if stage.advance(state, tau, 1.0) > 0:
                    return work.failed(Status.DIVERGED, "non-finite state")
                return self._commit(state, t, work, continued)
            accepted, new_norm, scale, new_merit = self._line_search(state, t_stage, tau, residual_norm,
                                                                     merit, work)
            if not math.isfinite(new_norm):
                return work.failed(Status.DIVERGED,
                                   f"non-finite nonlinear residual at Newton iteration {newton}")
            relative_residual = new_norm / scale if scale > 0 else new_norm
            if relative_residual <= self.newton_tolerance:
                return self._commit(state, t, work, continued)
            if not accepted:
                return work.failed(Status.NOT_CONVERGED,
                                   f"Newton iteration {newton}: the line search found no sufficient "
                                   f"decrease (relative residual {relative_residual:.3g} > "
                                   f"newton_tolerance={self.newton_tolerance:.3g})")
            residual_norm, merit = new_norm, new_merit
        return work.failed(Status.NOT_CONVERGED,
                           f"Newton reached newton_iterations={self.newton_iterations} with relative "
                           f"residual {relative_residual:.3g} > newton_tolerance={self.newton_tolerance:.3g}")

    def _solve_linear(self, tau: float, t_stage: float, work: _StepWork, warm: bool) -> StepReport | None:
        """One linear solve for the Newton step, counted; a failure report, or None."""
        stats = self.stats
        start = time.perf_counter()
        outcome = self._stage.solve(tau, t_stage, self.cg_tolerance, self.cg_max_iterations, warm)
        stats.solve_seconds += time.perf_counter() - start
        stats.solves += 1
        stats.iterations += outcome.iterations
        work.f_evals += outcome.f_evals
        work.linear_iterations += outcome.iterations
        work.linear_residual = outcome.residual
        if not math.isfinite(outcome.residual):
            return work.failed(Status.DIVERGED, f"{stats.solver} produced a non-finite residual")
        if not outcome.converged:
            return work.failed(Status.NOT_CONVERGED, outcome.message)
        return None

    def _line_search(self, state: State, t_stage: float, tau: float, residual_norm: float, merit: float,
                     work: _StepWork) -> tuple[bool, float, float, float]:
        """Take the Newton step, halving it until it is accepted (or MAX_BACKTRACKS).

        Far from the solution a full Newton step can overshoot (stiff springs swinging about a
        pin stretch quadratically along the linearised path). A step is accepted when it
        decreases the residual norm or, where the stage has one, the merit function whose
        gradient is the residual (the incremental potential, which the Newton direction descends
        because A is positive definite) by the Armijo fraction of the decrease the linear model
        predicts. Returns (accepted, |g|, |s|, merit) at the point reached.
        """
        stage = self._stage
        slope = stage.merit_slope()
        fraction = 1.0
        stage.advance(state, tau, fraction)
        for backtrack in range(MAX_BACKTRACKS + 1):
            new_norm, scale = stage.residual(state, t_stage, tau)
            new_merit = stage.merit(state, tau)
            work.f_evals += 1
            accepted = (new_norm <= (1.0 - ARMIJO_SLOPE * fraction) * residual_norm
                        or new_merit <= merit + ARMIJO_SLOPE * fraction * slope)
            if accepted or backtrack == MAX_BACKTRACKS:
                break
            stage.advance(state, tau, -0.5 * fraction)
            fraction *= 0.5
        return accepted, new_norm, scale, new_merit

    def _commit(self, state: State, t: float, work: _StepWork, continued: bool) -> StepReport:
        if self._stage.commit(state, work.h, continued) > 0:
            return work.report(Status.DIVERGED, "non-finite state", accepted=True)
        self._resume_time = t + work.h
        return work.report(Status.OK)


class ImplicitEuler(_ImplicitStageMethod):
    """Backward Euler: y1 = y0 + h f(y1, t + h). First order, L-stable: it damps every
    oscillation (the circle's radius shrinks by (1 + h^2)^(-1/2) per step), so it stays stable
    at any step size and stiffness.

    By default (``newton_iterations=1``) one Newton step, linearised about the current state:
    for a particle system, Baraff & Witkin (1998), "Large steps in cloth simulation",
    (M - h df/dv - h^2 df/dx) dv = h (f0 + h df/dx v0). More iterations give the exact backward
    Euler solution. Options: see :class:`_ImplicitStageMethod`.
    """

    name = "implicit_euler"
    order = 1
    description = "backward Euler (Baraff-Witkin linearised step; exact with newton_iterations > 1)"
    stage_fraction = 1.0
    default_newton_iterations = 1


class ImplicitMidpoint(_ImplicitStageMethod):
    """Implicit midpoint rule: y1 = y0 + h f((y0 + y1) / 2, t + h / 2). Second order, A-stable
    and symmetric; it conserves quadratic invariants exactly (the energy of linear springs, the
    circle's radius) up to the solver tolerances, neither damping nor growing oscillations.

    Solved by Newton iterations (default up to 20, to ``newton_tolerance``) on the midpoint
    stage, a backward Euler stage of size h/2. Where many springs are compressed (a folding
    cloth) the clamped Jacobian makes Newton converge only linearly, slowly near buckling: at
    large steps the cap may be reached (NOT_CONVERGED; e.g. the default cloth at h = 1/60 s after
    about 1 s, while h = 1/120 s runs). Then lower the step, allow more iterations, or use
    :class:`ImplicitEuler`. Options: see :class:`_ImplicitStageMethod`.
    """

    name = "implicit_midpoint"
    order = 2
    description = "implicit midpoint rule (Newton iterations; conserves quadratic invariants)"
    stage_fraction = 0.5
    default_newton_iterations = 20


def _positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(f"{name} must be an integer >= 1, got {value!r}")
    return int(value)


def _tolerance(name: str, value, default) -> float:
    if value is None:
        return default()
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < 1:
        raise ConfigError(f"{name} must be a number in (0, 1), got {value!r}")
    return float(value)


@ti.data_oriented
class _VelocityNewton:
    """The implicit stage of a particle system in velocity form (see the module docstring).

    Scratch: the Newton iterate ``point`` (X, V), the force at it (N), the right-hand side
    (momentum, N s) and the Newton update dV (m/s), each (n,) vec3, plus the linear solver's.
    """

    def __init__(self, system: System, theta: float, linear_solver: str, preconditioner: str | None = None):
        self.system = system
        self.theta = theta
        n, real = system.particle_count, runtime.real()
        self.point = system.make_state()
        self.force = ti.Vector.field(3, real, shape=n)
        self.rhs = ti.Vector.field(3, real, shape=n)
        self.delta = ti.Vector.field(3, real, shape=n)
        # V - v0 of the last committed step, and the first guess of the next step's solve (m/s).
        self.last_change = ti.Vector.field(3, real, shape=n)
        self.guess = ti.Vector.field(3, real, shape=n)
        if linear_solver == "direct":
            self.linear = _SparseCholesky(system, self.point, self.rhs, self.delta)
        else:
            self.linear = _ConjugateGradients(system, self.point, self.rhs, self.delta, self.guess, preconditioner)
        self.stats = LinearSolverStats(solver=self.linear.name,
                                       preconditioner=getattr(self.linear, "preconditioner", ""))

    def invalidate_pattern(self) -> None:
        self.linear.invalidate_pattern()

    def begin(self, y0: State, t: float, tau: float, linearised: bool) -> tuple[int, float]:
        """Start Newton; returns (f evaluations, |g| at the start point or nan).

        Linearised (one step, Baraff & Witkin): at (x0, v0), with the right-hand side of f
        linearised there. Otherwise at the consistent point V = v0, X = x0 + tau v0, with the
        true residual.
        """
        self._begin(y0, 0.0 if linearised else tau)
        if linearised:
            self.system.forces(self.point, self.force, t)
            self._linearised_rhs(tau, t)
            return 1, math.nan
        residual_norm, _ = self.residual(y0, t, tau)
        return 1, residual_norm

    def solve(self, tau: float, t: float, tolerance: float, max_iterations: int,
              warm: bool = False) -> _LinearOutcome:
        """Solve A dV = rhs; ``warm``: start an iterative solver from the previous step's
        velocity change instead of zero."""
        return self.linear.solve(tau, tau * tau, t, tolerance, max_iterations, self.stats, warm)

    def advance(self, y0: State, tau: float, fraction: float) -> int:
        """V += fraction dV, X = x0 + tau V; returns the number of non-finite particles."""
        return self._advance(y0, tau, fraction)

    def residual(self, y0: State, t: float, tau: float) -> tuple[float, float]:
        """Set rhs = -g at the iterate; returns (|g|, |s|), s the magnitudes g sums (N s)."""
        g2, s2 = self._nonlinear_residual(y0, tau, t)
        return math.sqrt(g2), math.sqrt(s2)

    def merit(self, y0: State, tau: float) -> float:
        """The incremental potential at the iterate (J): 1/2 |V - v0|_M^2 + U(X) + tau R(X, V),
        U the potential energy and R the Rayleigh dissipation function. Its gradient in V is g
        (up to the dashpots' dependence on X, which the Jacobian leaves out too), so the stage
        solution minimises it (Martin et al. 2011; Gast et al. 2015)."""
        return (self._half_momentum_change(y0) + self.system.potential_energy(self.point)
                + tau * self.system.dissipation(self.point))

    def merit_slope(self) -> float:
        """Derivative of :meth:`merit` along the Newton step dV: g . dV = -rhs . dV (J)."""
        return self._slope()

    def commit(self, y: State, h: float, continued: bool = False) -> int:
        """y1 from the stage; sets the next step's first guess (``continued``: the step just
        taken followed the previous one, whose velocity change is still in ``last_change``)."""
        return self._commit(y, h, int(continued))

    @ti.kernel
    def _begin(self, y0: ti.template(), tau: float):
        for i in self.point.x:
            # A pinned particle's velocity is not part of the dynamics (its derivative is zero);
            # zeroing it keeps every vector of the solve zero on pinned particles.
            v = ti.Vector.zero(y0.x.dtype, 3)
            x = y0.x[i]
            if self.system.free[i]:
                v = y0.v[i]
                x += tau * v
            self.point.x[i] = x
            self.point.v[i] = v

    @ti.kernel
    def _linearised_rhs(self, tau: float, t: float):
        # f(x0 + tau V, V) ~ f0 + tau df/dx V + df/dv (V - v0): the momentum balance
        # M (V - v0) = tau f becomes A dV = tau f0 + tau^2 df/dx v0 with dV = V - v0.
        for i in self.rhs:
            self.rhs[i] = tau * self.force[i] + self.system.force_jacobian_product(
                i, self.point, self.point.v, 0.0, tau * tau, t)

    @ti.kernel
    def _advance(self, y0: ti.template(), tau: float, fraction: float) -> ti.i32:
        bad = 0
        for i in self.point.x:
            if self.system.free[i]:
                v = self.point.v[i] + fraction * self.delta[i]
                x = y0.x[i] + tau * v
                self.point.v[i] = v
                self.point.x[i] = x
                if not (finite(x) and finite(v)):
                    bad += 1
        return bad

    @ti.kernel
    def _nonlinear_residual(self, y0: ti.template(), tau: float, t: float) -> (float, float):
        # g = M (V - v0) - tau f(X, V) with the true f; returns (|g|^2, |s|^2) where s_i is the
        # sum of the magnitudes of the terms of g_i (what its rounding error is relative to).
        g2 = 0.0
        s2 = 0.0
        for i in self.point.x:
            f, force_scale = self.system.force_and_scale(i, self.point, t)
            g = ti.Vector.zero(y0.x.dtype, 3)
            if self.system.free[i]:
                m = self.system.mass[i]
                g = m * (self.point.v[i] - y0.v[i]) - tau * f
                s = m * (self.point.v[i].norm() + y0.v[i].norm()) + tau * force_scale
                g2 += g.norm_sqr()
                s2 += s * s
            self.rhs[i] = -g
        return g2, s2

    @ti.kernel
    def _half_momentum_change(self, y0: ti.template()) -> float:
        total = 0.0
        for i in self.point.v:
            if self.system.free[i]:
                total += 0.5 * self.system.mass[i] * (self.point.v[i] - y0.v[i]).norm_sqr()
        return total

    @ti.kernel
    def _slope(self) -> float:
        total = 0.0
        for i in self.rhs:
            total -= self.rhs[i].dot(self.delta[i])
        return total

    @ti.kernel
    def _commit(self, y: ti.template(), h: float, continued: ti.i32) -> ti.i32:
        bad = 0
        for i in y.x:
            change = ti.Vector.zero(y.x.dtype, 3)
            guess = ti.Vector.zero(y.x.dtype, 3)
            if self.system.free[i]:
                v_stage = self.point.v[i]
                change = v_stage - y.v[i]
                # The next step's V - v0, extrapolated linearly from this step's and the last
                # one's (smooth motion: about a sixth fewer CG iterations than repeating this
                # step's on the benchmark cloth, a third fewer than starting from zero).
                guess = change
                if continued:
                    guess = 2.0 * change - self.last_change[i]
                y.x[i] = y.x[i] + h * v_stage
                if ti.static(self.theta != 1.0):
                    y.v[i] = y.v[i] + (v_stage - y.v[i]) / self.theta
                else:
                    y.v[i] = v_stage
            # Pinned particles are checked too: a NaN there would otherwise pass unnoticed (a
            # spring of non-finite length exerts no force).
            self.last_change[i] = change
            self.guess[i] = guess
            if not (finite(y.x[i]) and finite(y.v[i])):
                bad += 1
        return bad


@ti.data_oriented
class _ConjugateGradients:
    """Matrix-free preconditioned conjugate gradients on A dV = rhs at the iterate ``point``.

    The matrix. A = M - a df/dv - b df/dx is cached once per solve (one solve per Newton
    iteration): ``system.cache_system_matrix_row`` stores each spring's block
    J_s = a D_s + b K_s (under both of its ends, as the five numbers of alpha I + beta u u^T)
    and returns the diagonal blocks A_ii, kept with their inverses. A product is then a pure
    per-particle gather, (A p)_i = A_ii p_i + sum over i's springs of J_s p_j
    (A_ij = -(a df_i/dv_j + b df_i/dx_j) = +J_s), with no norms or outer products and no atomics.

    The preconditioner (``preconditioner``):

    * ``"jacobi"``: block Jacobi, z_i = A_ii^-1 r_i (zero on pinned particles, so every vector
      of the solve stays zero there).
    * ``"ssor"``: block symmetric successive over-relaxation, M = (D/w + L) (D/w)^-1 (D/w + U)
      for A = L + D + U (D the diagonal blocks, L = U^T the coupling blocks below and above
      it), w = ``SSOR_OMEGA``, applied with Eisenstat's trick (Eisenstat 1981, "Efficient
      implementation of a class of preconditioned conjugate gradient methods"; Saad,
      "Iterative methods for sparse linear systems", 2nd ed., sec. 9.2.2): CG runs on the
      symmetric B = (D/w + L)^-1 A (D/w + U)^-1 preconditioned by D/w, where B p =
      t + (D/w + L)^-1 (p + (1 - 2/w) D t) with t = (D/w + U)^-1 p costs one backward and one
      forward sweep, together one pass over the coupling blocks, like a product with A; and
      dV += alpha t. On the benchmark cloth it takes a third of block Jacobi's iterations at
      about 1.7 times the cost each (the sweeps are sequential: each row waits for the one
      before). The residual tested is still |rhs - A dV| = |(D/w + L) r_B| for the
      transformed residual r_B: that costs half a product, so it is computed only where the
      ratio of the two at the last check predicts the threshold is near (and at the end).

    Where it runs. On a CPU backend the whole solve is ONE kernel: the cache fill and the start
    run in parallel, the iterations serially inside the kernel. A Python loop over iterations
    would launch kernels and read dot products back every iteration, and on a CPU each launch
    and each dispatch to the thread pool costs 15-100 us (more when other processes load the
    cores), as much as a whole product on a 64 x 64 cloth; serial iterations also sum the dot
    products in a fixed order, so a solve is bit-reproducible, and make Gauss-Seidel sweeps
    possible. On a GPU each iteration is one launch of three parallel loops instead
    (``in_kernel_loop=False``), with block Jacobi.

    Start: dV0 = ``guess`` when ``warm`` (extrapolated from the last steps' velocity changes, see
    :class:`_VelocityNewton`), else 0. The guess is used even when it leaves |r| > |rhs|, or
    is farther from the solution than 0 in the A-norm: its error then sits in the stiff modes,
    which CG removes in a few iterations, while it is good in the smooth ones, which take CG
    longest (on the benchmark cloth, with block Jacobi, falling back to 0 on either test gave
    back from 40% to nearly all of the iterations the guess saves). Convergence: the
    recursively updated residual satisfies |rhs - A dV| <= tolerance |rhs|.
    """

    name = "pcg"

    def __init__(self, system: System, point: State, rhs, solution, guess, preconditioner: str | None = None):
        self.system, self.point, self.rhs, self.solution, self.guess = system, point, rhs, solution, guess
        n, real = system.particle_count, runtime.real()
        self.r = ti.Vector.field(3, real, shape=n)  # residual rhs - A dV (for SSOR: of B)
        self.z = ti.Vector.field(3, real, shape=n)  # preconditioned residual
        self.p = ti.Vector.field(3, real, shape=n)  # search direction
        self.q = ti.Vector.field(3, real, shape=n)  # A p (for SSOR: the forward sweep's part of B p)
        self.diagonal = ti.Matrix.field(3, 3, real, shape=n)  # A_ii
        self.inverse_diagonal = ti.Matrix.field(3, 3, real, shape=n)  # A_ii^-1 (zero if pinned)
        self.in_kernel_loop = runtime.backend() in ("x64", "arm64")
        sweeps = self.in_kernel_loop and system.caches_all_couplings
        if preconditioner is None:
            preconditioner = "ssor" if sweeps else "jacobi"
        if preconditioner not in PRECONDITIONERS:
            raise ConfigError(f"preconditioner must be one of {', '.join(PRECONDITIONERS)}, "
                              f"got {preconditioner!r}")
        if preconditioner == "ssor" and not sweeps:
            raise ConfigError("preconditioner 'ssor' needs a CPU backend (its sweeps run serially) and "
                              "force terms that cache their Jacobian blocks; use 'jacobi'")
        self.preconditioner = preconditioner
        self.back = ti.Vector.field(3, real, shape=n) if preconditioner == "ssor" else None  # SSOR: t
        system.bind_jacobian_cache()

    def invalidate_pattern(self) -> None:
        """Nothing to do: CG has no symbolic analysis."""

    def solve(self, a: float, b: float, t: float, tolerance: float, max_iterations: int,
              stats: LinearSolverStats, warm: bool = False) -> _LinearOutcome:
        if not self.in_kernel_loop:
            iterations, breakdown, rr, bb = self._solve_from_python(a, b, t, tolerance, max_iterations, warm)
        elif self.preconditioner == "ssor":
            iterations, breakdown, rr, bb = self._solve_ssor(a, b, t, tolerance, max_iterations, int(warm),
                                                             SSOR_OMEGA)
        else:
            iterations, breakdown, rr, bb = self._solve_jacobi(a, b, t, tolerance, max_iterations, int(warm))
        if bb == 0.0:
            return _LinearOutcome(iterations=0, residual=0.0, converged=True)
        if breakdown:
            # A is positive definite by construction; this means NaN/inf reached the solve.
            return _LinearOutcome(iterations, math.nan, False, message=f"CG breakdown (p.Ap = {rr:.3g})")
        residual = math.sqrt(rr / bb) if math.isfinite(rr) else math.nan
        converged = residual <= tolerance
        return _LinearOutcome(iterations, residual, converged, message="" if converged else (
            f"CG reached cg_max_iterations={max_iterations} with relative residual {residual:.3g} "
            f"> cg_tolerance={tolerance:.3g}"))

    def _solve_from_python(self, a: float, b: float, t: float, tolerance: float, max_iterations: int,
                           warm: bool) -> tuple[int, int, float, float]:
        """Block Jacobi PCG, one kernel launch per iteration (for GPU backends)."""
        bb, rr, rz = self._start_kernel(a, b, t, int(warm))
        if bb == 0.0:
            self._zero_solution()
            return 0, 0, 0.0, 0.0
        threshold = tolerance * tolerance * bb
        iterations = 0
        while rr > threshold and iterations < max_iterations:  # false for NaN
            iterations += 1
            rr, rz, curvature = self._iteration_kernel(a, b, t, rz, threshold)
            if not curvature > 0.0:
                return iterations, 1, curvature, bb
        return iterations, 0, rr, bb

    @ti.kernel
    def _solve_jacobi(self, a: float, b: float, t: float, tolerance: float, max_iterations: ti.i32,
                      warm: ti.i32) -> (ti.i32, ti.i32, float, float):
        # Returns (iterations, breakdown, |r|^2 or p.Ap at a breakdown, |rhs|^2).
        start = self._start(a, b, t, warm)  # a top-level loop: parallel
        bb, rr, rz = start[0], start[1], start[2]
        iterations = 0
        breakdown = 0
        if bb == 0.0:
            rr = 0.0
            self._zero()
        threshold = tolerance * tolerance * bb
        while rr > threshold and iterations < max_iterations:  # loops in here run serially
            iterations += 1
            curvature = self._product(a, b, t)
            if not curvature > 0.0:
                breakdown = 1
                rr = curvature
                break
            update = self._update(rz / curvature)
            rr = update[0]
            if rr > threshold:
                self._direction(update[1] / rz)
            rz = update[1]
        return iterations, breakdown, rr, bb

    @ti.kernel
    def _solve_ssor(self, a: float, b: float, t: float, tolerance: float, max_iterations: ti.i32,
                    warm: ti.i32, omega: float) -> (ti.i32, ti.i32, float, float):
        # Returns (iterations, breakdown, |rhs - A dV|^2 or p.Bp at a breakdown, |rhs|^2).
        n = self.r.shape[0]
        start = self._start(a, b, t, warm)  # parallel: cache, dV0, r = rhs - A dV0
        bb, rr = start[0], start[1]
        iterations = 0
        breakdown = 0
        if bb == 0.0:
            rr = 0.0
            self._zero()
        threshold = tolerance * tolerance * bb
        rz = 0.0
        if rr > threshold:  # serial from here
            for i in range(n):  # r <- (D/w + L)^-1 r, ascending; z = (D/w) r; p = z
                r = omega * (self.inverse_diagonal[i] @ (self.r[i] - self.system.cached_triangle_product(i, self.r, -1)))
                z = (self.diagonal[i] @ r) / omega
                self.r[i] = r
                self.z[i] = z
                self.p[i] = z
                rz += r.dot(z)
        ratio = 1.0  # |rhs - A dV|^2 / r.z at the last check
        if rz > 0.0:
            ratio = rr / rz
        beta = 0.0
        while rr > threshold and iterations < max_iterations:
            iterations += 1
            for k in range(n):  # p = z + beta p; t = (D/w + U)^-1 p, descending
                i = n - 1 - k
                p = self.z[i] + beta * self.p[i]
                self.p[i] = p
                self.back[i] = omega * (self.inverse_diagonal[i] @ (p - self.system.cached_triangle_product(i, self.back, 1)))
            curvature = 0.0
            for i in range(n):  # q = (D/w + L)^-1 (p + (1 - 2/w) D t), ascending; B p = t + q
                g = self.p[i] + (1.0 - 2.0 / omega) * (self.diagonal[i] @ self.back[i])
                q = omega * (self.inverse_diagonal[i] @ (g - self.system.cached_triangle_product(i, self.q, -1)))
                self.q[i] = q
                curvature += self.p[i].dot(self.back[i] + q)
            if not curvature > 0.0:
                breakdown = 1
                rr = curvature
                break
            alpha = rz / curvature
            rz_new = 0.0
            for i in range(n):
                self.solution[i] += alpha * self.back[i]
                r = self.r[i] - alpha * (self.back[i] + self.q[i])
                z = (self.diagonal[i] @ r) / omega
                self.r[i] = r
                self.z[i] = z
                rz_new += r.dot(z)
            rr = ratio * rz_new
            if rr <= 4.0 * threshold or iterations == max_iterations:
                rr = 0.0
                for i in range(n):  # rhs - A dV = (D/w + L) r
                    rr += (self.z[i] + self.system.cached_triangle_product(i, self.r, -1)).norm_sqr()
                if rz_new > 0.0:
                    ratio = rr / rz_new
            beta = rz_new / rz
            rz = rz_new
        return iterations, breakdown, rr, bb

    @ti.kernel
    def _start_kernel(self, a: float, b: float, t: float, warm: ti.i32) -> (float, float, float):
        start = self._start(a, b, t, warm)
        return start[0], start[1], start[2]

    @ti.kernel
    def _iteration_kernel(self, a: float, b: float, t: float, rz: float,
                          threshold: float) -> (float, float, float):
        # One iteration in one launch: three parallel loops, the scalars computed in between.
        curvature = self._product(a, b, t)
        update = self._update(rz / curvature)
        if update[0] > threshold:
            self._direction(update[1] / rz)
        return update[0], update[1], curvature

    @ti.kernel
    def _zero_solution(self):
        self._zero()

    @ti.func
    def _start(self, a, b, t, warm):
        """Fill the cache at ``point``, set dV0, r = rhs - A dV0, z = A_ii^-1 r, p = z; returns
        (|rhs|^2, |r|^2, r.z)."""
        bb = ti.cast(0.0, self.r.dtype)
        rr = ti.cast(0.0, self.r.dtype)
        rz = ti.cast(0.0, self.r.dtype)
        for i in range(self.r.shape[0]):
            diagonal = self.system.cache_system_matrix_row(i, self.point, a, b, t)
            inverse = ti.Matrix.zero(self.r.dtype, 3, 3)
            x = ti.Vector.zero(self.r.dtype, 3)
            if self.system.free[i]:
                inverse = diagonal.inverse()
                if warm:
                    x = self.guess[i]
            self.diagonal[i] = diagonal
            self.inverse_diagonal[i] = inverse
            self.solution[i] = x
            r = self.rhs[i]
            if warm:
                # Row i's blocks were stored just above, by this iteration; ``guess`` is zero
                # where not free, like every vector of the solve.
                r -= self.system.cached_system_matrix_row(i, self.point, self.guess, a, b, t, diagonal)
            z = inverse @ r
            self.r[i] = r
            self.z[i] = z
            self.p[i] = z
            bb += self.rhs[i].norm_sqr()
            rr += r.norm_sqr()
            rz += r.dot(z)
        return ti.Vector([bb, rr, rz])

    @ti.func
    def _product(self, a, b, t):
        """q = A p from the cache (filled with these a, b, t); returns p.q."""
        curvature = ti.cast(0.0, self.r.dtype)
        for i in range(self.r.shape[0]):
            q = self.system.cached_system_matrix_row(i, self.point, self.p, a, b, t, self.diagonal[i])
            self.q[i] = q
            curvature += self.p[i].dot(q)
        return curvature

    @ti.func
    def _update(self, alpha):
        """dV += alpha p, r -= alpha q, z = A_ii^-1 r; returns (|r|^2, r.z)."""
        rr = ti.cast(0.0, self.r.dtype)
        rz = ti.cast(0.0, self.r.dtype)
        for i in range(self.r.shape[0]):
            self.solution[i] += alpha * self.p[i]
            r = self.r[i] - alpha * self.q[i]
            z = self.inverse_diagonal[i] @ r
            self.r[i] = r
            self.z[i] = z
            rr += r.norm_sqr()
            rz += r.dot(z)
        return ti.Vector([rr, rz])

    @ti.func
    def _direction(self, beta):
        for i in range(self.r.shape[0]):
            self.p[i] = self.z[i] + beta * self.p[i]

    @ti.func
    def _zero(self):
        for i in range(self.r.shape[0]):
            self.solution[i] = ti.Vector.zero(self.r.dtype, 3)


@ti.data_oriented
class _SparseCholesky:
    """Sparse direct solve of A dV = rhs: A assembled into a Taichi SparseMatrixBuilder, then
    Taichi's SparseSolver (Eigen's simplicial LL^T with AMD ordering on the CPU) in the run's
    precision (both default to f32 otherwise).

    The symbolic analysis (ordering, elimination tree) depends only on the sparsity pattern,
    which changes only when ``system.jacobian_pattern_version`` does: it runs once per pattern,
    the numeric factorisation once per solve. The residual is recomputed with the matrix-free
    product (which also checks the assembly); while it exceeds the tolerance, up to
    ``MAX_REFINEMENTS`` steps of iterative refinement reuse the factorisation (in f32 a
    stiff cloth's solve can miss 1e-5 by a little; refinement recovers it).
    """

    name = "cholesky"

    def __init__(self, system: System, point: State, rhs, solution):
        if runtime.backend() not in ("x64", "arm64"):
            raise ConfigError(f"linear_solver 'direct' runs on the CPU backend only (this run uses "
                              f"{runtime.backend()}); use 'cg'")
        self.system, self.point, self.rhs, self.solution = system, point, rhs, solution
        size = 3 * system.particle_count
        self.builder = ti.linalg.SparseMatrixBuilder(
            size, size, max_num_triplets=system.system_matrix_triplet_capacity, dtype=runtime.real())
        self.solver = ti.linalg.SparseSolver(dtype=runtime.real(), solver_type="LLT")
        self.analysed_version: int | None = None
        self.residual = ti.Vector.field(3, runtime.real(), shape=system.particle_count)  # then the correction

    def invalidate_pattern(self) -> None:
        self.analysed_version = None

    def solve(self, a: float, b: float, t: float, tolerance: float, max_iterations: int,
              stats: LinearSolverStats, warm: bool = False) -> _LinearOutcome:
        self.system.assemble_system_matrix(self.point, a, b, t, self.builder)
        matrix = self.builder.build()
        version = self.system.jacobian_pattern_version
        if version != self.analysed_version:
            start = time.perf_counter()
            self.solver.analyze_pattern(matrix)
            stats.analyze_seconds += time.perf_counter() - start
            stats.analyze_count += 1
            self.analysed_version = version
        start = time.perf_counter()
        self.solver.factorize(matrix)
        stats.factorize_seconds += time.perf_counter() - start
        stats.factorize_count += 1
        if not self.solver.info():
            return _LinearOutcome(1, math.inf, False, message="sparse Cholesky factorisation failed "
                                  "(the matrix is not numerically positive definite)")
        self.solution.from_numpy(self._solve(self.rhs))
        solves = 1
        while True:
            residual2, rhs2 = self._residual_norms(a, b, t)
            residual = math.sqrt(residual2 / rhs2) if rhs2 > 0 else math.sqrt(residual2)
            if residual <= tolerance or solves > MAX_REFINEMENTS or not math.isfinite(residual):
                break
            self.residual.from_numpy(self._solve(self.residual))
            self._add_correction()
            solves += 1
        # Beyond the tolerance even after refinement, the residual is reported, never accepted.
        converged = residual <= tolerance
        return _LinearOutcome(solves, residual, converged, message="" if converged else (
            f"sparse Cholesky solve left relative residual {residual:.3g} > cg_tolerance={tolerance:.3g} "
            f"after {solves - 1} refinement steps (ill-conditioned matrix)"))

    def _solve(self, right_hand_side) -> np.ndarray:
        """A^-1 applied to a (n,) vec3 field with the current factorisation, as (n, 3) numpy."""
        solution = self.solver.solve(right_hand_side.to_numpy().reshape(-1))
        return np.ascontiguousarray(solution, dtype=runtime.np_real()).reshape(-1, 3)

    @ti.kernel
    def _residual_norms(self, a: float, b: float, t: float) -> (float, float):
        residual2 = 0.0
        rhs2 = 0.0
        for i in self.rhs:
            r = self.rhs[i] - self.system.system_matrix_row(i, self.point, self.solution, a, b, t)
            self.residual[i] = r
            residual2 += r.norm_sqr()
            rhs2 += self.rhs[i].norm_sqr()
        return residual2, rhs2

    @ti.kernel
    def _add_correction(self):
        for i in self.solution:
            self.solution[i] += self.residual[i]


@ti.data_oriented
class _NewtonKrylov:
    """The implicit stage of any system, by Newton-Krylov (GMRES) on the whole state.

    Vectors of the state's shape (x, and v for a second-order system) are rows of one 2-D field
    per component, so every vector kernel compiles once: rows 0..restart hold the Krylov basis,
    then the Newton step dY and the right-hand side -g.
    """

    def __init__(self, system: System, theta: float, restart: int):
        self.system = system
        self.theta = theta
        self.restart = restart
        self.second_order = system.second_order
        self.analytic = system.has_jacobian_product
        n, real = system.particle_count, runtime.real()
        self.step_row = restart + 1
        self.rhs_row = restart + 2
        rows = restart + 3
        self.vx = ti.Vector.field(3, real, shape=(rows, n))
        self.vv = ti.Vector.field(3, real, shape=(rows, n)) if self.second_order else None
        self.coefficients = ti.field(real, shape=restart)
        self.point = system.make_state()   # the Newton iterate Y
        self.f = system.make_state()       # f(Y)
        self.probe = system.make_state()   # Y + eps w (differences) or w (analytic Jacobian)
        self.f_probe = system.make_state()  # f(Y + eps w), or J w
        self.sqrt_eps = math.sqrt(float(np.finfo(runtime.np_real()).eps))
        self.point_norm = 0.0  # |Y| at the current Newton iterate, for the difference step
        self.stats = LinearSolverStats(solver="gmres")

    def invalidate_pattern(self) -> None:
        """Nothing to do: no matrix is assembled."""

    def begin(self, y0: State, t: float, tau: float, linearised: bool) -> tuple[int, float]:
        """Start Newton at Y = y0 (consistent: its residual is the true one); returns
        (f evaluations, |g|)."""
        self._copy_state(y0)
        residual_norm, _ = self.residual(y0, t, tau)
        return 1, residual_norm

    def residual(self, y0: State, t: float, tau: float) -> tuple[float, float]:
        """Set the right-hand side -g, g = Y - y0 - tau f(Y); returns (|g|, |s|) with
        s_i = |Y_i| + |y0_i| + tau |f_i| (the magnitudes g is computed from)."""
        self.system.eval_f(self.point, t, self.f)
        g2, s2 = self._residual(y0, tau)
        return math.sqrt(g2), math.sqrt(s2)

    def advance(self, y0: State, tau: float, fraction: float) -> int:
        """Y += fraction dY; returns the number of non-finite particles."""
        return self._advance(fraction)

    def merit(self, y0: State, tau: float) -> float:
        """No merit function is known for a general system: the line search uses the residual."""
        return math.nan

    def merit_slope(self) -> float:
        return math.nan

    def commit(self, y: State, h: float, continued: bool = False) -> int:
        return self._commit(y)

    def solve(self, tau: float, t: float, tolerance: float, max_iterations: int,
              warm: bool = False) -> _LinearOutcome:
        """Restarted GMRES(restart) on (I - tau J) dY = -g, from dY = 0 (Saad & Schultz 1986)."""
        self._zero(self.step_row)
        rhs_norm = math.sqrt(self._dot(self.rhs_row, self.rhs_row))
        if rhs_norm == 0.0:
            return _LinearOutcome(0, 0.0, True)
        self.point_norm = math.sqrt(self._point_norm2())
        iterations = f_evals = 0
        residual = rhs_norm
        while True:
            if iterations == 0:
                self._copy(self.rhs_row, 0)
            else:  # restart from the true linear residual rhs - A dY
                f_evals += self._apply(self.step_row, 0, t, tau)
                self._axpby(-1.0, 0, 1.0, self.rhs_row, 0)
            residual = math.sqrt(self._dot(0, 0))
            if residual <= tolerance * rhs_norm or not math.isfinite(residual):
                break
            self._scale(0, 1.0 / residual)
            hessenberg = np.zeros((self.restart + 1, self.restart))
            cos, sin = np.zeros(self.restart), np.zeros(self.restart)
            projected = np.zeros(self.restart + 1)
            projected[0] = residual
            size = 0
            while size < self.restart and iterations < max_iterations:
                k = size
                f_evals += self._apply(k, k + 1, t, tau)
                iterations += 1
                for j in range(k + 1):  # modified Gram-Schmidt
                    hessenberg[j, k] = self._dot(j, k + 1)
                    self._axpby(-hessenberg[j, k], j, 1.0, k + 1, k + 1)
                norm = math.sqrt(self._dot(k + 1, k + 1))
                hessenberg[k + 1, k] = norm
                for j in range(k):  # earlier Givens rotations
                    upper, lower = hessenberg[j, k], hessenberg[j + 1, k]
                    hessenberg[j, k] = cos[j] * upper + sin[j] * lower
                    hessenberg[j + 1, k] = -sin[j] * upper + cos[j] * lower
                radius = math.hypot(hessenberg[k, k], hessenberg[k + 1, k])
                if radius:
                    cos[k], sin[k] = hessenberg[k, k] / radius, hessenberg[k + 1, k] / radius
                else:
                    cos[k], sin[k] = 1.0, 0.0
                hessenberg[k, k] = radius
                hessenberg[k + 1, k] = 0.0
                projected[k + 1] = -sin[k] * projected[k]
                projected[k] = cos[k] * projected[k]
                size = k + 1
                residual = abs(projected[k + 1])
                if residual <= tolerance * rhs_norm or norm == 0.0 or not math.isfinite(residual):
                    break
                self._scale(k + 1, 1.0 / norm)
            if size:
                # The rotated Hessenberg matrix is upper triangular; lstsq copes with a singular one.
                weights = np.linalg.lstsq(np.triu(hessenberg[:size, :size]), projected[:size], rcond=None)[0]
                padded = np.pad(weights, (0, self.restart - size))
                self.coefficients.from_numpy(padded.astype(runtime.np_real()))
                self._add_combination(size)
            if (residual <= tolerance * rhs_norm or iterations >= max_iterations
                    or not math.isfinite(residual)):
                break
        relative = float(residual / rhs_norm)
        converged = relative <= tolerance
        message = "" if converged else (f"GMRES reached cg_max_iterations={max_iterations} with relative "
                                        f"residual {relative:.3g} > cg_tolerance={tolerance:.3g}")
        return _LinearOutcome(iterations, relative, converged, f_evals=f_evals, message=message)

    def _apply(self, source: int, target: int, t: float, tau: float) -> int:
        """Row ``target`` = (I - tau J) row ``source``; returns the f evaluations it took."""
        if self.analytic:
            self._load_direction(source)
            self.system.jacobian_product(self.point, t, self.probe, self.f_probe)
            self._store_product(source, target, tau)
            return 0
        source_norm = math.sqrt(self._dot(source, source))
        if source_norm == 0.0:
            self._zero(target)
            return 0
        # Pernice & Walker (1998): balances truncation error against rounding in f.
        eps = self.sqrt_eps * math.sqrt(1.0 + self.point_norm) / source_norm
        self._load_perturbed(source, eps)
        self.system.eval_f(self.probe, t, self.f_probe)
        self._store_product(source, target, tau / eps)
        return 1

    @ti.kernel
    def _copy_state(self, y0: ti.template()):
        for i in self.point.x:
            self.point.x[i] = y0.x[i]
            if ti.static(self.second_order):
                self.point.v[i] = y0.v[i]

    @ti.kernel
    def _residual(self, y0: ti.template(), tau: float) -> (float, float):
        g2 = 0.0
        s2 = 0.0
        for i in self.point.x:
            g = self.point.x[i] - y0.x[i] - tau * self.f.x[i]
            self.vx[self.rhs_row, i] = -g
            s = self.point.x[i].norm() + y0.x[i].norm() + tau * self.f.x[i].norm()
            g2 += g.norm_sqr()
            s2 += s * s
            if ti.static(self.second_order):
                gv = self.point.v[i] - y0.v[i] - tau * self.f.v[i]
                self.vv[self.rhs_row, i] = -gv
                sv = self.point.v[i].norm() + y0.v[i].norm() + tau * self.f.v[i].norm()
                g2 += gv.norm_sqr()
                s2 += sv * sv
        return g2, s2

    @ti.kernel
    def _point_norm2(self) -> float:
        total = 0.0
        for i in self.point.x:
            total += self.point.x[i].norm_sqr()
            if ti.static(self.second_order):
                total += self.point.v[i].norm_sqr()
        return total

    @ti.kernel
    def _dot(self, a: ti.i32, b: ti.i32) -> float:
        total = 0.0
        for i in range(self.vx.shape[1]):
            total += self.vx[a, i].dot(self.vx[b, i])
            if ti.static(self.second_order):
                total += self.vv[a, i].dot(self.vv[b, i])
        return total

    @ti.kernel
    def _axpby(self, alpha: float, a: ti.i32, beta: float, b: ti.i32, target: ti.i32):
        for i in range(self.vx.shape[1]):
            self.vx[target, i] = alpha * self.vx[a, i] + beta * self.vx[b, i]
            if ti.static(self.second_order):
                self.vv[target, i] = alpha * self.vv[a, i] + beta * self.vv[b, i]

    def _copy(self, source: int, target: int) -> None:
        self._axpby(1.0, source, 0.0, source, target)

    def _scale(self, row: int, factor: float) -> None:
        self._axpby(factor, row, 0.0, row, row)

    def _zero(self, row: int) -> None:
        self._axpby(0.0, row, 0.0, row, row)

    @ti.kernel
    def _add_combination(self, size: ti.i32):
        for i in range(self.vx.shape[1]):
            dx = ti.Vector.zero(self.vx.dtype, 3)
            for j in range(size):
                dx += self.coefficients[j] * self.vx[j, i]
            self.vx[self.step_row, i] += dx
            if ti.static(self.second_order):
                dv = ti.Vector.zero(self.vx.dtype, 3)
                for j in range(size):
                    dv += self.coefficients[j] * self.vv[j, i]
                self.vv[self.step_row, i] += dv

    @ti.kernel
    def _load_perturbed(self, row: ti.i32, eps: float):
        for i in self.probe.x:
            self.probe.x[i] = self.point.x[i] + eps * self.vx[row, i]
            if ti.static(self.second_order):
                self.probe.v[i] = self.point.v[i] + eps * self.vv[row, i]

    @ti.kernel
    def _load_direction(self, row: ti.i32):
        for i in self.probe.x:
            self.probe.x[i] = self.vx[row, i]
            if ti.static(self.second_order):
                self.probe.v[i] = self.vv[row, i]

    @ti.kernel
    def _store_product(self, source: ti.i32, target: ti.i32, factor: float):
        # target = source - tau J source, with J source = f_probe (analytic) or
        # (f_probe - f) / eps (differences; factor = tau / eps).
        for i in self.probe.x:
            jx = self.f_probe.x[i]
            if ti.static(not self.analytic):
                jx -= self.f.x[i]
            self.vx[target, i] = self.vx[source, i] - factor * jx
            if ti.static(self.second_order):
                jv = self.f_probe.v[i]
                if ti.static(not self.analytic):
                    jv -= self.f.v[i]
                self.vv[target, i] = self.vv[source, i] - factor * jv

    @ti.kernel
    def _advance(self, fraction: float) -> ti.i32:
        bad = 0
        for i in self.point.x:
            x = self.point.x[i] + fraction * self.vx[self.step_row, i]
            self.point.x[i] = x
            ok = finite(x)
            if ti.static(self.second_order):
                v = self.point.v[i] + fraction * self.vv[self.step_row, i]
                self.point.v[i] = v
                ok = ok and finite(v)
            if not ok:
                bad += 1
        return bad

    @ti.kernel
    def _commit(self, y: ti.template()) -> ti.i32:
        bad = 0
        for i in y.x:
            x = self.point.x[i]
            if ti.static(self.theta != 1.0):
                x = y.x[i] + (x - y.x[i]) / self.theta
            y.x[i] = x
            ok = finite(x)
            if ti.static(self.second_order):
                v = self.point.v[i]
                if ti.static(self.theta != 1.0):
                    v = y.v[i] + (v - y.v[i]) / self.theta
                y.v[i] = v
                ok = ok and finite(v)
            if not ok:
                bad += 1
        return bad
