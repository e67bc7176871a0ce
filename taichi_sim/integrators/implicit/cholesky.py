"""Sparse direct solve (Cholesky) of the velocity-form Newton system of a particle system."""
import math
import time

import taichi as ti

from ... import runtime
from ...errors import ConfigError
from ...state import State
from ...systems.base import System
from .common import LinearOutcome, LinearSolverStats

MAX_REFINEMENTS = 2  # iterative-refinement steps of a direct solve that missed the tolerance


@ti.data_oriented
class SparseCholesky:
    """Sparse direct solve of A dV = rhs: the lower triangle of A assembled by a kernel into a
    Taichi SparseMatrixBuilder, then Taichi's SparseSolver (Eigen's simplicial LL^T with AMD
    ordering on the CPU, which reads only that triangle) in the run's precision (both default
    to f32 otherwise).

    The symbolic analysis (ordering, elimination tree) depends only on the sparsity pattern,
    which changes only when ``system.jacobian_pattern_version`` does: it runs once per pattern,
    the numeric factorisation once per solve. The residual is recomputed with the matrix-free
    product (which also checks the assembly); while it exceeds the tolerance, up to
    ``MAX_REFINEMENTS`` steps of iterative refinement reuse the factorisation (in f32 a
    stiff cloth's solve can miss 1e-5 by a little; refinement recovers it).

    Where the time goes is counted in the :class:`LinearSolverStats` passed to :meth:`solve`:
    assembly (kernel and ``build()``), analysis, factorisation, and the triangular solves with
    their copies between the (n,) vec3 fields and the solver's flat (3n,) ndarrays. The
    numeric factorisation dominates: on the 64 x 64 benchmark cloth it is over 90 % of a solve
    (``benchmarks/bench_implicit.py`` prints the split).
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
        # The solver's right-hand side, flat (3n,): an ndarray goes to Eigen without a numpy copy.
        self.flat = ti.ndarray(runtime.real(), shape=size)

    def invalidate_pattern(self) -> None:
        self.analysed_version = None

    def solve(self, a: float, b: float, t: float, tolerance: float, max_iterations: int,
              stats: LinearSolverStats, warm: bool = False) -> LinearOutcome:
        start = time.perf_counter()
        self.system.assemble_system_matrix(self.point, a, b, t, self.builder)
        matrix = self.builder.build()
        stats.assemble_seconds += time.perf_counter() - start
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
            return LinearOutcome(1, math.inf, False, message="sparse Cholesky factorisation failed "
                                  "(the matrix is not numerically positive definite)")
        self._substitute(self.rhs, self.solution, stats)
        solves = 1
        while True:
            residual2, rhs2 = self._residual_norms(a, b, t)
            residual = math.sqrt(residual2 / rhs2) if rhs2 > 0 else math.sqrt(residual2)
            if residual <= tolerance or solves > MAX_REFINEMENTS or not math.isfinite(residual):
                break
            self._substitute(self.residual, self.residual, stats)
            self._add_correction()
            solves += 1
        # Beyond the tolerance even after refinement, the residual is reported, never accepted.
        converged = residual <= tolerance
        return LinearOutcome(solves, residual, converged, message="" if converged else (
            f"sparse Cholesky solve left relative residual {residual:.3g} > cg_tolerance={tolerance:.3g} "
            f"after {solves - 1} refinement steps (ill-conditioned matrix)"))

    def _substitute(self, right_hand_side, out, stats: LinearSolverStats) -> None:
        """``out`` = A^-1 ``right_hand_side`` with the current factorisation (both (n,) vec3
        fields; may be the same), timed into ``stats.substitute_seconds``."""
        start = time.perf_counter()
        self._flatten(right_hand_side, self.flat)
        self._unflatten(self.solver.solve(self.flat), out)
        stats.substitute_seconds += time.perf_counter() - start

    @ti.kernel
    def _flatten(self, source: ti.template(), flat: ti.types.ndarray(ndim=1)):
        for i in source:
            for k in ti.static(range(3)):
                flat[3 * i + k] = source[i][k]

    @ti.kernel
    def _unflatten(self, flat: ti.types.ndarray(ndim=1), out: ti.template()):
        for i in out:
            out[i] = ti.Vector([flat[3 * i], flat[3 * i + 1], flat[3 * i + 2]])

    @ti.kernel
    def _residual_norms(self, a: float, b: float, t: float) -> (float, float):
        residual2 = 0.0
        rhs2 = 0.0
        self.system.prepare_jacobian(self.point, a, b, t)
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
