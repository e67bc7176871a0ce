"""Implicit integrators: backward Euler (exact, by minimising the incremental potential), its
one-step linearisation (Baraff & Witkin) and the implicit midpoint rule.

The parts, each readable on its own:

* :mod:`.methods`: the three methods (what they solve, what they promise);
* :mod:`.newton`: the Newton driver and its backtracking line search;
* :mod:`.velocity_stage`: the implicit stage of a particle system in velocity form, with the
  incremental potential (merit) its iterations minimise;
* :mod:`.conjugate_gradients`: preconditioned CG (block Jacobi, block SSOR) on that stage;
* :mod:`.cholesky`: the sparse direct solve (analyse once per pattern, factorise per solve);
* :mod:`.newton_krylov`: Newton-Krylov (GMRES) for systems without spring Jacobians;
* :mod:`.common`: solver statistics, tolerances (fixed, and Eisenstat-Walker forcing terms).
"""
from .common import LINEAR_SOLVERS, PRECONDITIONERS, LinearSolverStats, default_cg_tolerance, default_newton_tolerance
from .methods import ImplicitEuler, ImplicitEulerLinearised, ImplicitMidpoint
from .newton import ImplicitStageMethod

__all__ = ["ImplicitEuler", "ImplicitEulerLinearised", "ImplicitMidpoint", "ImplicitStageMethod",
           "LinearSolverStats", "LINEAR_SOLVERS", "PRECONDITIONERS", "default_cg_tolerance",
           "default_newton_tolerance"]
