"""The implicit methods: backward Euler (exact, by minimisation), its one-step linearisation
(Baraff & Witkin) and the implicit midpoint rule, all on the Newton driver of :mod:`.newton`."""
from __future__ import annotations

from ...systems.base import System
from ..equation import EXACT, FIXED_WORK, Equation
from .common import CgMaxIterations, CgTolerance, LinearSolver, Preconditioner, WarmStart
from .newton import ImplicitStageMethod

_NEWTON_ADVICE = "raise --newton-iterations or lower --newton-tolerance or --dt"


class ImplicitEuler(ImplicitStageMethod):
    """Backward Euler, solved exactly: y1 = y0 + h f(y1, t + h). First order and L-stable.

    On a particle system the step is the minimiser of the incremental potential

        Phi(V) = 1/2 |V - v0|_M^2 + U(x0 + h V) + h R(x0 + h V, V),

    (U the potential energy, R the Rayleigh dissipation; x1 = x0 + h V, v1 = V; Martin et al.
    2011, Gast et al. 2015), found by Newton's method with every spring's Hessian block
    projected to positive semi-definite (a compressed spring's negative transverse stiffness
    dropped), a backtracking line search on Phi, a warm start from the last steps, and the stop
    test |g| <= ``newton_tolerance`` |s| on the true residual (see :class:`ImplicitStageMethod`).
    Where every force is variational (no dashpots, no wind) Phi is exact and decreases at every
    iteration. Backward Euler dissipates energy: on every conservative scene we have run,
    including the stiffest (k up to 1e8 N/m, h up to 1 s; ``tests/test_implicit.py``), the
    energy never rises from one step to the next. It damps motion in exchange (artificial
    damping grows with h omega). At frame-sized steps on stiff cloth Newton needs many
    iterations where the cloth folds or swings far within one step (each solve is then
    inexact, see :func:`~.common.forcing_tolerance`); reaching ``newton_iterations`` is
    NOT_CONVERGED, never a silent answer. On systems without spring Jacobians (the circle ODE)
    Newton-Krylov with GMRES solves the same equations.
    """

    name = "implicit_euler"
    plot_colour = "#e377c2"  # in the benchmarks' plots
    order = 1
    description = "backward Euler, exact: Newton on the incremental potential with a line search"
    stage_fraction = 1.0
    default_newton_iterations = 50
    inexact_newton = True
    equation = Equation("backward_euler", EXACT, advice=_NEWTON_ADVICE)
    # Newton's stop test in metres: a step farther than the run's tolerance is solved again to a
    # tenfold tighter relative test, down to 1e-12
    work_option, work_cap = "newton_tolerance", 1e-12
    advice_note = ("no step limit: exact backward Euler, energy never rises on conservative scenes; "
                   "damps motion more as h omega grows")


class ImplicitEulerLinearised(ImplicitStageMethod):
    """One linearised backward Euler step: Baraff & Witkin (1998), "Large steps in cloth
    simulation", (M - h df/dv - h^2 df/dx) dv = h (f0 + h df/dx v0), solved once to
    ``cg_tolerance`` (default 1e-3) and taken as the step.

    Cheap (one linear solve per step) and unconditionally stable on LINEAR springs, but not on
    real, nonlinear ones: where h^2 k / m is large and springs rotate within a step, the
    linearised step overshoots and can gain energy, e.g. a 24 x 24 cloth at k = 1e8 N/m and
    h = 1/30 s goes from 56 J to 1e9 J in five steps. The blow-up guard stops such runs
    (status DIVERGED); :class:`ImplicitEuler` solves the same step exactly. On systems without
    spring Jacobians: one Newton-Krylov step.
    """

    name = "implicit_euler_linearised"
    plot_colour = "#f7b6d2"  # in the benchmarks' plots
    order = 1
    description = "one linearised backward Euler step (Baraff-Witkin); can gain energy on stiff springs"
    stage_fraction = 1.0
    linearised = True
    equation = Equation("backward_euler", FIXED_WORK,
                        advice="it takes one linearised Newton step: use implicit_euler or lower --dt")
    advice_note = ("no limit on linear springs only: one Newton step can gain energy on "
                   "stretched springs at large h^2 k / m (reported diverged)")

    def __init__(self, system: System, *, linear_solver: LinearSolver = "cg", cg_tolerance: CgTolerance = None,
                 cg_max_iterations: CgMaxIterations = 1000, preconditioner: Preconditioner = None,
                 warm_start: WarmStart = True):
        super().__init__(system, linear_solver=linear_solver, cg_tolerance=cg_tolerance,
                         cg_max_iterations=cg_max_iterations, preconditioner=preconditioner,
                         warm_start=warm_start)


class ImplicitMidpoint(ImplicitStageMethod):
    """Implicit midpoint rule: y1 = y0 + h f((y0 + y1) / 2, t + h / 2). Second order, A-stable
    and symmetric; it conserves quadratic invariants exactly (the energy of linear springs, the
    circle's radius) up to the solver tolerances, neither damping nor growing oscillations.

    Solved by Newton iterations (up to ``newton_iterations``, default 50) on the midpoint stage,
    a backward Euler stage of size h/2, then extrapolated: y1 = 2 Y - y0. On NONLINEAR springs
    it conserves no energy exactly and is not unconditionally stable: where h omega is large
    and springs rotate within a step the extrapolation can overshoot, and the energy can grow
    (a single spring of k = 1e8 N/m at h = 1/60 s); the blow-up guard stops such runs, and where
    Newton cannot converge the step is NOT_CONVERGED. Then lower the step or use
    :class:`ImplicitEuler`.
    """

    name = "implicit_midpoint"
    plot_colour = "#17becf"  # in the benchmarks' plots
    order = 2
    description = "implicit midpoint rule (Newton iterations; conserves quadratic invariants)"
    stage_fraction = 0.5
    default_newton_iterations = 50
    equation = Equation("implicit_midpoint", EXACT, advice=_NEWTON_ADVICE)
    work_option, work_cap = "newton_tolerance", 1e-12  # as ImplicitEuler
    advice_note = ("no limit on linear springs (conserves their energy); on nonlinear springs "
                   "energy can rise and Newton can fail at large h omega (reported)")
