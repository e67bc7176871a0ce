"""The Newton driver shared by the implicit methods: one implicit stage, solved by Newton's
method with a backtracking line search, then extrapolated.

With tau = theta h, the stage is the state Y with

    Y = y0 + tau f(Y, t + tau),        then  y1 = y0 + (Y - y0) / theta

(theta = 1: backward Euler, y1 = Y; theta = 1/2: the implicit midpoint rule, y1 = 2 Y - y0).
Where the stage is solved is the *stage* object's business (:class:`~.velocity_stage.VelocityStage`
for particle systems with spring Jacobians, :class:`~.newton_krylov.NewtonKrylovStage` for any
other system); this module only drives it:

* **linearised** methods (``implicit_euler_linearised``, Baraff & Witkin 1998) take one Newton
  step from the current state as the answer: no line search, no convergence test. Cheap, and
  unconditionally stable on linear springs, but on nonlinear springs at large h k / m the one
  step can overshoot and gain energy (the blow-up guard of :mod:`taichi_sim.guard` watches it).
* **iterated** methods run Newton from a start point (the consistent start V = v0, or a warm
  start extrapolated from the last steps, whichever has the lower merit) until the relative
  nonlinear residual is below ``newton_tolerance``. Each iteration solves the linear system only
  as well as the current residual warrants (inexact Newton, :func:`~.common.forcing_tolerance`;
  a solve stopped at its iteration cap still gives a descent direction), then a backtracking
  line search (Armijo) decides how far to go: on a particle system it must decrease the
  *incremental potential* (the merit, whose minimiser is the stage solution: Martin et al. 2011,
  Gast et al. 2015) by a fraction of the decrease the linear model predicts. Where every force
  is the gradient of a potential or of a velocity-only dissipation (no spring dashpots, no
  wind), the merit is exact and only its decrease counts, so the iterates descend it
  monotonically; otherwise (dashpots, whose direction depends on positions, and wind, which
  has no potential) a decrease of the residual norm is accepted too.

Hitting ``newton_iterations`` is Status.NOT_CONVERGED (with the residual in the message and
``linear_residual``); a line search that finds no decrease is NOT_CONVERGED too; a non-finite
result is Status.DIVERGED. A step that fails leaves the state as it was, except that a
non-finite final extrapolation is written (and reported DIVERGED).
"""
from __future__ import annotations

import math
import time

from ... import runtime
from ...errors import ConfigError
from ...state import State
from ...systems.base import System
from ..base import Integrator, Status, StepReport, elastic_models
from .common import (
    CgMaxIterations,
    CgTolerance,
    LinearSolver,
    LinearSolverStats,
    MaxSubdivisions,
    NewtonIterations,
    NewtonTolerance,
    Preconditioner,
    StepWork,
    WarmStart,
    default_cg_tolerance,
    default_newton_tolerance,
    forcing_tolerance,
    tolerance,
)
from .conjugate_gradients import checked_preconditioner
from .newton_krylov import GMRES_RESTART, NewtonKrylovStage
from .velocity_stage import VelocityStage

ARMIJO_SLOPE = 1e-4  # fraction of the predicted decrease a line-search step must achieve
MAX_BACKTRACKS = 30  # step halvings before the line search gives up (smallest step ~1e-9)
DEFAULT_SUBDIVISIONS = 10  # a step Newton cannot solve is split into halves, at most this deep
PROGRESS_INTERVAL = 0.5  # s between two progress texts of a running step (see ``progress``)


def shared_stage(system: System, linear_solver: str, preconditioner: str | None, restart: int):
    """The stage object (scratch fields, compiled kernels) the implicit methods on ``system``
    share: one per linear solver and preconditioner (GMRES: per restart length), made on first
    use. Compiling a stage's kernels takes seconds; sharing them lets every implicit method on a
    system (and a launcher switching between them) pay once. The methods keep their own
    statistics and step history; the stage's warm-start guess is only used by a method that
    continues its own last step."""
    stages = system.__dict__.setdefault("_implicit_stages", {})
    if system.supports_jacobian:
        if linear_solver == "cg":
            preconditioner = checked_preconditioner(system, preconditioner)
        key = ("velocity", linear_solver, preconditioner)
        if key not in stages:
            stages[key] = VelocityStage(system, linear_solver, preconditioner)
    else:
        key = ("newton-krylov", restart)
        if key not in stages:
            stages[key] = NewtonKrylovStage(system, restart)
    return stages[key]


class ImplicitStageMethod(Integrator):
    """Newton on one implicit stage (module docstring). Subclasses set ``stage_fraction``
    (theta), ``linearised`` and ``default_newton_iterations``.

    Options (keyword-only):
        linear_solver: ``"cg"`` (matrix-free Krylov: preconditioned CG on the symmetric positive
            definite particle system, GMRES for a system without spring Jacobians) or
            ``"direct"`` (sparse Cholesky; needs spring Jacobians and a CPU backend). The
            direct solver analyses the sparsity pattern once and only refactorises while
            ``system.jacobian_pattern_version`` stays the same; see :meth:`invalidate_pattern`.
        newton_iterations: most Newton iterations per step (iterated methods), >= 1; reaching
            it without meeting ``newton_tolerance`` is NOT_CONVERGED.
        newton_tolerance: bound on the relative nonlinear residual |g| / |s|, where s adds up
            the magnitudes of the terms of g (for a particle system the momenta M V and M v0
            and tau times each force piece; for a first-order system |Y| + |y0| + tau |f|), i.e.
            the residual relative to what it is computed from; a residual down to the rounding
            error of the forces counts as met. Default: 1e-3 for backward Euler on a particle
            system (its iterates must also not raise the energy, see
            :meth:`~.velocity_stage.VelocityStage.energy_ok`; on a falling 32 x 32 cloth at
            h = 1/60 s the positions after 1 s are 10 to 20 times closer to those of a 1e-8
            solve than the method's own error, h against h/2), otherwise
            :func:`~.common.default_newton_tolerance` (1e-6 in f64, 1e-5 in f32).
        cg_tolerance: a fixed bound on the relative residual |rhs - A dY| / |rhs| of every
            linear solve (CG or GMRES; the direct solver refines its solution until it holds).
            Default: 1e-3 for the linearised method, 1e-8 (f64) / 1e-5 (f32) for the others
            (:func:`~.common.default_cg_tolerance`), except backward Euler on a particle
            system, whose solves are asked only what the current Newton residual warrants
            (:func:`~.common.forcing_tolerance`).
        cg_max_iterations: Krylov iterations allowed per linear solve (default 1000). A
            linearised step whose solve reaches it is NOT_CONVERGED; an iterated method uses
            the direction reached.
        preconditioner: of CG on a particle system, ``"ssor"`` (block symmetric SOR, the
            default on CPU backends) or ``"jacobi"`` (block Jacobi; the only one on GPU
            backends). See :class:`~.conjugate_gradients.ConjugateGradients`.
        warm_start: use the last steps' velocity changes, extrapolated, as the start of this
            step when the step continues where the last accepted one ended (same t, no
            :meth:`reset` since): the first CG guess of a linearised step, the first Newton
            iterate of an iterated one when its merit is below the consistent start's
            (default True).
        max_subdivisions: iterated methods only. When Newton does not converge within
            ``newton_iterations``, the step is taken as two steps of h/2 instead, each split
            again where it fails, down to h / 2^max_subdivisions (default 10: 1/1024 of the
            step; 0: never split, the step is NOT_CONVERGED at once). Every piece is a solved
            step of the same method, so the answer is the method's at a finer step where the
            motion needed it (more accurate, less damped); ``stats.substeps`` counts the
            steps solved. Only a piece that fails at the finest level makes the step NOT_CONVERGED.
    """

    stage_fraction: float
    linearised: bool = False
    default_newton_iterations: int = 1
    inexact_newton: bool = False  # forcing terms and inexact_newton_tolerance on particle systems
    inexact_newton_tolerance: float = 1e-3
    implicit = True
    tracks_solved_start = True
    stability_constant = math.inf  # A-stable on linear springs; see each method's advice_note

    @classmethod
    def scratch_bytes(cls, particles: int, springs: int, real_bytes: int, linear_solver: str = "cg") -> int:
        """Newton's point, force, rhs, delta, guess, the Krylov vectors and 3 x 3 diagonal
        blocks (about 40 reals per particle) and the cached spring Jacobian blocks (10 reals +
        2 ids per spring); the direct solver adds a sparse matrix (9 (n + 2 S) entries of a
        real and an index) and its Cholesky factor, taken as 4 times that."""
        total = particles * 40 * real_bytes + springs * (10 * real_bytes + 8)
        if linear_solver == "direct":
            total += 4 * 9 * (particles + 2 * springs) * (real_bytes + 4)
        return total
    coarsen_after = 4
    """Steps solved in pieces of one size before the next step tries pieces twice as long (see
    :meth:`step`): a try that fails costs ``newton_iterations`` Newton iterations."""
    progress = None
    """Called with a one-line text (Newton iteration, residual, linear iterations of the step,
    and the averages per solved step so far) at most every ``PROGRESS_INTERVAL`` seconds while
    an iterated method steps, so that a run loop can show what a long step is doing (the
    command line's progress bar shows it as its postfix); None: nothing is reported."""

    def __init__(self, system: System, *, linear_solver: LinearSolver = "cg",
                 newton_iterations: NewtonIterations = None, newton_tolerance: NewtonTolerance = None,
                 cg_tolerance: CgTolerance = None, cg_max_iterations: CgMaxIterations = 1000,
                 preconditioner: Preconditioner = None, warm_start: WarmStart = True,
                 max_subdivisions: MaxSubdivisions = None):
        super().__init__(system)
        # A membrane's Hessian, its projection and its stress make the solver's kernels large,
        # and Taichi's control-flow-graph pass grows faster than a kernel: it was most of their
        # compile (an 8 x 8 StVK cloth's first step took 14.2 s with it, 6.2 s without; a
        # 32 x 32 Neo-Hookean one 15.9 and 7.8 s, stepping 33.8 and 33.9 ms, alternated in one
        # process; docs/materials.md). Spring systems compile as before.
        self._compile_without_cfg = bool(elastic_models(system))
        # the options' types and bounds were checked against their declarations (Integrator.__new__)
        if max_subdivisions is None:
            max_subdivisions = 0 if self.linearised else DEFAULT_SUBDIVISIONS
        if self.linearised and max_subdivisions:
            raise ConfigError("max_subdivisions applies to the iterated methods only")
        self.max_subdivisions = int(max_subdivisions)
        self._level = 0  # the subdivision level the next step starts at (see step)
        self._steps_at_level = 0  # steps solved in a row at that level
        self._progress_time = time.perf_counter()
        self.last_relative_residual = math.nan
        """|g| / |s| at the end of the last Newton solve of an iterated method (see
        ``newton_tolerance``), converged or not; NaN before the first."""
        self._saved = system.make_state() if self.max_subdivisions else None  # the step's start
        self.linear_solver = linear_solver
        self.newton_iterations = int(self.default_newton_iterations if newton_iterations is None
                                     else newton_iterations)
        self.cg_max_iterations = int(cg_max_iterations)
        # Inexact Newton (forcing terms) and the loose default tolerance are for the particle
        # stage of backward Euler, where the incremental potential and the energy test keep the
        # iterates honest; elsewhere every solve is tight.
        inexact = self.inexact_newton and system.supports_jacobian
        self.newton_tolerance = tolerance("newton_tolerance", newton_tolerance,
                                          lambda: self.inexact_newton_tolerance if inexact
                                          else default_newton_tolerance())
        linearised_step = self.linearised and system.supports_jacobian
        self.fixed_cg_tolerance = cg_tolerance is not None or not inexact
        self.cg_tolerance = tolerance("cg_tolerance", cg_tolerance,
                                      lambda: default_cg_tolerance(linearised_step))
        self.warm_start = bool(warm_start)
        self._resume_time: float | None = None  # where the last accepted step ended
        if preconditioner is not None and (linear_solver != "cg" or not system.supports_jacobian):
            raise ConfigError("preconditioner applies to CG on a particle system with spring Jacobians only")
        if linear_solver == "direct" and not system.supports_jacobian:
            raise ConfigError(f"linear_solver 'direct' needs a system with spring Jacobians; "
                              f"{type(system).__name__} has none (use 'cg')")
        self._stage = shared_stage(system, linear_solver, preconditioner, min(GMRES_RESTART, self.cg_max_iterations))
        self.stats = LinearSolverStats(solver=self._stage.solver_name, preconditioner=self._stage.preconditioner)

    def invalidate_pattern(self) -> None:
        """Make the direct solver re-analyse the sparsity pattern at its next solve (call it
        after changing which particles couple without bumping a term's ``topology_version``)."""
        self._stage.invalidate_pattern()

    def reset(self) -> None:
        """Forget the previous step (the next one starts cold, undivided)."""
        self._resume_time = None
        self._level = 0
        self._steps_at_level = 0

    def step(self, state: State, t: float, h: float) -> StepReport:
        if self._compile_without_cfg:
            with runtime.without_cfg_optimisation():
                return self._step(state, t, h)
        return self._step(state, t, h)

    def _step(self, state: State, t: float, h: float) -> StepReport:
        if self.linearised or not self.max_subdivisions:
            report = self._attempt(state, t, h)
            self.stats.substeps += report.status is Status.OK
            return report
        # Where Newton cannot solve a step (the motion swings or folds too far for it within
        # one step), the step is taken as 2, 4, ... solved steps of the same method. A step
        # starts at the level the last one needed; after ``coarsen_after`` steps in a row that
        # needed no more, the next tries one level coarser. (Trying coarser after every such
        # step made every other step of a stiff cloth fail its first try and pay
        # ``newton_iterations`` for nothing; docs/exact-step.md.)
        self._saved.copy_from(state)  # a failure after some pieces were taken restores it
        work = StepWork(h)
        level = self._level
        self._deepest = level
        pieces = 2 ** level
        for k in range(pieces):
            failure = self._piece(state, t + k * (h / pieces), h / pieces, level, work)
            if failure is not None:
                state.copy_from(self._saved)
                self._resume_time = None
                return failure
        if self._deepest > level:
            self._level, self._steps_at_level = self._deepest, 0
        else:
            self._steps_at_level += 1
            if self._steps_at_level >= self.coarsen_after:
                self._level, self._steps_at_level = max(level - 1, 0), 0
        return work.report(Status.OK)

    def _piece(self, state: State, t: float, h: float, depth: int, work: StepWork) -> StepReport | None:
        """Advance ``state`` from t by h, split into halves where Newton fails (down to depth
        ``max_subdivisions``); adds the work to ``work``. None when done, else the failure."""
        report = self._attempt(state, t, h)
        work.f_evals += report.f_evals
        work.linear_iterations += report.linear_iterations
        work.linear_residual = report.linear_residual
        if report.status is Status.OK:
            self.stats.substeps += 1
            return None
        if report.status is Status.NOT_CONVERGED and depth < self.max_subdivisions:
            self._deepest = max(self._deepest, depth + 1)
            for start in (t, t + 0.5 * h):
                failure = self._piece(state, start, 0.5 * h, depth + 1, work)
                if failure is not None:
                    return failure
            return None
        detail = (f" (in pieces of 1/{2 ** depth} of the step)"
                  if report.status is Status.NOT_CONVERGED and depth else "")
        return work.failed(report.status, report.message + detail)

    def _attempt(self, state: State, t: float, h: float) -> StepReport:
        """One try at the step from t by h, without subdividing."""
        if self.solved_start is not None:  # the last try of a step is the piece it solved
            self.solved_start.copy_from(state)
            self.solved_h = h
        tau = self.stage_fraction * h
        t_stage = t + tau
        work = StepWork(h)
        # Continuing from where the last accepted step ended (within rounding of t): the step
        # may start from the velocity change extrapolated from the last steps.
        continued = self._resume_time is not None and abs(t - self._resume_time) <= 1e-9 * max(abs(t), h)
        warm = self.warm_start and continued
        self._resume_time = None
        if self.linearised:
            return self._linearised_step(state, t, tau, t_stage, work, warm, continued)
        return self._newton_step(state, t, tau, t_stage, work, warm, continued)

    def _linearised_step(self, state, t, tau, t_stage, work, warm, continued) -> StepReport:
        stage = self._stage
        stage.begin(state, t_stage, tau, linearised=True)
        work.f_evals = 1
        failure = self._solve_linear(tau, t_stage, self.cg_tolerance, work, warm, require_converged=True)
        if failure is not None:
            return failure
        if stage.advance(state, tau, 1.0) > 0:
            return work.failed(Status.DIVERGED, "non-finite state")
        return self._commit(state, t, work, continued)

    def _newton_step(self, state, t, tau, t_stage, work, warm, continued) -> StepReport:
        stage = self._stage
        stats = self.stats
        point = stage.begin(state, t_stage, tau, linearised=False, warm=warm)
        work.f_evals = 2 if warm else 1
        if point.nonfinite or not math.isfinite(point.residual):
            return work.failed(Status.DIVERGED, "non-finite state at the start of the step")
        relative = self._relative(point)
        self.last_relative_residual = relative
        for newton in range(1, self.newton_iterations + 1):
            if relative <= self.newton_tolerance and stage.energy_ok():
                break
            stats.newton_iterations += 1
            eta = self.cg_tolerance if self.fixed_cg_tolerance else forcing_tolerance(relative, self.newton_tolerance)
            failure = self._solve_linear(tau, t_stage, eta, work, False, require_converged=False)
            if failure is not None:
                return failure
            accepted, point = self._line_search(state, t_stage, tau, point, work)
            if not math.isfinite(point.residual) or point.nonfinite:
                return work.failed(Status.DIVERGED,
                                   f"non-finite nonlinear residual at Newton iteration {newton}")
            relative = self._relative(point)
            self.last_relative_residual = relative
            if self.progress is not None:
                self._report_progress(t, newton, relative, work)
            if not accepted and not (relative <= self.newton_tolerance and stage.energy_ok()):
                return work.failed(Status.NOT_CONVERGED,
                                   f"Newton iteration {newton}: the line search found no sufficient "
                                   f"decrease (relative residual {relative:.3g}, newton_tolerance="
                                   f"{self.newton_tolerance:.3g})")
        if relative > self.newton_tolerance:
            return work.failed(Status.NOT_CONVERGED,
                               f"Newton reached newton_iterations={self.newton_iterations} with relative "
                               f"residual {relative:.3g} > newton_tolerance={self.newton_tolerance:.3g}")
        if not stage.energy_ok():
            return work.failed(Status.NOT_CONVERGED,
                               f"Newton reached newton_iterations={self.newton_iterations} without an "
                               f"iterate whose energy is at most the step's start energy")
        return self._commit(state, t, work, continued)

    def _report_progress(self, t: float, newton: int, relative: float, work: StepWork) -> None:
        """Hand ``progress`` the state of the running step, at most every PROGRESS_INTERVAL s."""
        now = time.perf_counter()
        if now - self._progress_time < PROGRESS_INTERVAL:
            return
        self._progress_time = now
        stats = self.stats
        solved = max(stats.substeps, 1)
        self.progress(f"t={t:.4g} s Newton {newton} |g|/|s|={relative:.1e} linear it {work.linear_iterations}; "
                      f"per solved step: Newton {stats.newton_iterations / solved:.1f}, "
                      f"linear it {stats.iterations / solved:.0f}")

    def _relative(self, point) -> float:
        """|g| / |s| at ``point``, or 0 when |g| is down to what rounding leaves (the stage's
        floor): then the iterate is as solved as the precision allows."""
        if point.residual <= self._stage.rounding_floor:
            return 0.0
        return point.residual / point.scale if point.scale > 0 else point.residual

    def _solve_linear(self, tau: float, t_stage: float, tolerance: float, work: StepWork, warm: bool, *,
                      require_converged: bool) -> StepReport | None:
        """One linear solve for the Newton step, counted; a failure report, or None."""
        stats = self.stats
        start = time.perf_counter()
        outcome = self._stage.solve(tau, t_stage, tolerance, self.cg_max_iterations, stats, warm)
        stats.solve_seconds += time.perf_counter() - start
        stats.solves += 1
        stats.iterations += outcome.iterations
        work.f_evals += outcome.f_evals
        work.linear_iterations += outcome.iterations
        work.linear_residual = outcome.residual
        if not outcome.usable:
            return work.failed(Status.DIVERGED, f"{stats.solver} produced a non-finite residual"
                               + (f" ({outcome.message})" if outcome.message else ""))
        if require_converged and not outcome.converged:
            return work.failed(Status.NOT_CONVERGED, outcome.message)
        return None

    def _line_search(self, state: State, t_stage: float, tau: float, start, work: StepWork):
        """Take the Newton step from the iterate ``start`` (an Evaluation), halving it until it
        is accepted (or MAX_BACKTRACKS halvings). Returns (accepted, the Evaluation reached).

        Far from the solution a full Newton step can overshoot (stiff springs swinging about a
        pin stretch quadratically along the linearised path). Accepted: a decrease of the merit
        by the Armijo fraction of the decrease the linear model predicts; or, where the merit is
        not exact (module docstring) or its change is within its rounding noise, a decrease of
        the residual norm.
        """
        stage = self._stage
        fraction, move = 1.0, 1.0
        slope = math.nan
        point = start
        accepted = False
        for backtrack in range(MAX_BACKTRACKS + 1):
            point = stage.trial(state, t_stage, tau, move)
            work.f_evals += 1
            self.stats.line_search_evaluations += 1
            if backtrack == 0:
                slope = point.slope
            by_merit = math.isfinite(start.merit) and math.isfinite(slope) and slope < 0
            decreased = point.residual <= (1.0 - ARMIJO_SLOPE * fraction) * start.residual
            level = abs(point.merit - start.merit) <= stage.merit_noise  # says nothing either way
            accepted = ((by_merit and point.merit <= start.merit + ARMIJO_SLOPE * fraction * slope)
                        or ((not (by_merit and stage.merit_is_exact) or level) and decreased))
            if accepted or backtrack == MAX_BACKTRACKS:
                break
            move = -0.5 * fraction
            fraction *= 0.5
        return accepted, point

    def _commit(self, state: State, t: float, work: StepWork, continued: bool) -> StepReport:
        if self._stage.commit(state, work.h, self.stage_fraction, continued) > 0:
            return work.report(Status.DIVERGED, "non-finite state", accepted=True)
        self._resume_time = t + work.h
        return work.report(Status.OK)
