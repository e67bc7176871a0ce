"""What the implicit methods' parts share: solver statistics, outcomes, tolerances, option checks."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np

from ... import runtime
from ...errors import ConfigError
from ..base import Status, StepReport
from ..options import Option

LINEAR_SOLVERS = ("cg", "direct")

# The implicit methods' options (types for their constructors' signatures: :mod:`..options`).
LinearSolver = Annotated[str, Option("linear solver", flag=True, choices=LINEAR_SOLVERS)]
NewtonIterations = Annotated[int | None, Option("most Newton iterations per step, before the step is split",
                                                flag=True, at_least=1, default_text="50")]
NewtonTolerance = Annotated[float | None, Option(
    "relative nonlinear residual at which Newton stops", flag=True, above=0, below=1,
    default_text="1e-3 for backward Euler on particles, else 1e-6 in f64 / 1e-5 in f32")]
CgTolerance = Annotated[float | None, Option(
    "relative residual at which CG stops", flag=True, above=0, below=1,
    default_text="1e-3 for the one linearised step, adaptive (forcing terms) for backward Euler on "
                 "particles, else 1e-8 in f64 / 1e-5 in f32")]
CgMaxIterations = Annotated[int, Option("Krylov iterations allowed per linear solve", at_least=1)]
Preconditioner = Annotated[str | None, Option("CG's preconditioner on particles: ssor or jacobi",
                                              default_text="ssor on CPU, jacobi on GPU")]
WarmStart = Annotated[bool, Option("start each step from the last steps' velocity changes, extrapolated")]
MaxSubdivisions = Annotated[int | None, Option("halvings of a step Newton cannot solve (0: none)",
                                               at_least=0, at_most=30, default_text="10")]
PRECONDITIONERS = ("ssor", "jacobi")  # of CG on particle systems; see ConjugateGradients
LINEARISED_CG_TOLERANCE = 1e-3  # default of the one-step Baraff-Witkin method (see below)
FORCING_CEILING = 0.1  # loosest relative residual an iterated Newton step asks of its linear solve


def default_cg_tolerance(linearised_step: bool = False) -> float:
    """Default relative residual |rhs - A dV| / |rhs| of a linear solve whose accuracy is fixed.

    ``linearised_step``: the solve IS the step, as in Baraff & Witkin's method
    (``implicit_euler_linearised`` on a particle system): 1e-3 (``LINEARISED_CG_TOLERANCE``).
    That step linearises backward Euler once, so it is only first-order accurate; solving its
    linear system much better than the step itself is wasted work. Cloth solvers stop early
    for this reason; Blender's (``cg_filtered`` in ``implicit_blender.cc``) at 1e-2 with at
    most 100 iterations. Measured on the 64 x 64 benchmark cloth (k = 1e4 N/m, h = 1/60 s,
    ``benchmarks/bench_implicit.py --accuracy``, f32 and f64 alike): one step's velocity change
    differs from the exact linear solve's by ~1e-2 of itself (1e-2: ~8e-2); after 1 s the
    positions differ from those of exact solves by ~1 mm rms, 7 mm at most (1e-2: ~8 mm rms),
    where the method's own first-order error (h against h/2) is ~10 cm rms, 25 cm at most.
    1e-3 takes a quarter of the CG iterations of 1e-8.

    Otherwise (a solve inside Newton iterations given a fixed ``cg_tolerance``): 1e-8 in f64,
    1e-5 in f32, about 100 f32 rounding units. By default the iterated methods choose each
    solve's tolerance from the Newton residual instead (:func:`forcing_tolerance`).
    """
    if linearised_step:
        return LINEARISED_CG_TOLERANCE
    return 1e-8 if runtime.precision() == "f64" else 1e-5


def forcing_tolerance(relative_residual: float, newton_tolerance: float) -> float:
    """Relative residual asked of the linear solve of an inexact Newton step (Eisenstat & Walker
    1996, "Choosing the forcing terms in an inexact Newton method"): sqrt of the current
    relative nonlinear residual, at most ``FORCING_CEILING``, at least a tenth of the Newton
    tolerance. Far from the solution a rough direction is as good as an exact one (the line
    search decides how far to go); near it the solve tightens, and Newton converges
    superlinearly (the residual falls like its 3/2 power per iteration)."""
    if not math.isfinite(relative_residual):
        return FORCING_CEILING
    return min(FORCING_CEILING, max(math.sqrt(relative_residual), 0.1 * newton_tolerance))


def default_newton_tolerance() -> float:
    """Default relative nonlinear residual of an iterated stage: 1e-6 in f64 (velocities good
    to ~1e-6 of their scale, far below a step's truncation error at practical step sizes),
    1e-5 in f32 (the residual of a dozen summed spring forces is not computed much better).
    See :attr:`ImplicitStageMethod.newton_tolerance` for what is relative to what."""
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
        assemble_seconds: wall time assembling the matrix (the kernel that fills the builder and
            ``build()``; direct solver only, s).
        analyze_seconds, factorize_seconds: wall time in the analyses and factorisations (s).
        substitute_seconds: wall time in the triangular solves with the factor, the copies of
            their right-hand sides and solutions included (direct solver only, s).
        solve_seconds: wall time in linear solves in total, the above included (s); for the
            direct solver the rest is the residual check of each solve.
        newton_iterations: Newton iterations in total (one per linear solve of an iterated
            method); line_search_evaluations: merit or residual evaluations of line searches.
        substeps: steps of the method actually solved; more than the steps taken where steps
            were split into pieces because Newton could not solve them whole (iterated methods,
            see ``max_subdivisions``).
    """

    solver: str
    preconditioner: str = ""
    solves: int = 0
    iterations: int = 0
    analyze_count: int = 0
    factorize_count: int = 0
    assemble_seconds: float = 0.0
    analyze_seconds: float = 0.0
    factorize_seconds: float = 0.0
    substitute_seconds: float = 0.0
    solve_seconds: float = 0.0
    newton_iterations: int = 0
    line_search_evaluations: int = 0
    substeps: int = 0


@dataclass(frozen=True)
class LinearOutcome:
    """One linear solve: its ``iterations``, final relative ``residual`` |rhs - A dY| / |rhs|,
    whether it met its tolerance (``converged``), the f evaluations it took (matrix-free
    products by differences), and a ``message`` when it did not converge. ``usable``: the
    solution is finite (a solve stopped at its iteration cap still gives a usable Newton
    direction)."""

    iterations: int
    residual: float
    converged: bool
    f_evals: int = 0
    message: str = ""

    @property
    def usable(self) -> bool:
        return math.isfinite(self.residual)


@dataclass(frozen=True)
class Evaluation:
    """The stage at one Newton iterate.

    Attributes:
        residual: |g| (N s); scale: |s|, the magnitudes g sums (N s).
        merit: Phi (J), NaN where the stage has none.
        slope: g . dV at the point the move started from (J): the merit's predicted rate of
            change along the Newton step (NaN where it was not computed).
        nonfinite: particles with a non-finite position or velocity at the iterate.
    """

    residual: float
    scale: float
    merit: float = math.nan
    slope: float = math.nan
    nonfinite: int = 0


@dataclass
class StepWork:
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


def positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(f"{name} must be an integer >= 1, got {value!r}")
    return int(value)


def tolerance(name: str, value, default) -> float:
    """A relative tolerance in (0, 1), or ``default()`` when ``value`` is None."""
    if value is None:
        return default()
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < 1:
        raise ConfigError(f"{name} must be a number in (0, 1), got {value!r}")
    return float(value)
