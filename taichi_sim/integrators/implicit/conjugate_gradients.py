"""Preconditioned conjugate gradients on the velocity-form Newton system of a particle system,
with block Jacobi and block SSOR preconditioners (see :class:`ConjugateGradients`)."""
import math

import taichi as ti

from ... import runtime
from ...errors import ConfigError
from ...state import State
from ...systems.base import System
from .common import PRECONDITIONERS, LinearOutcome, LinearSolverStats

SSOR_OMEGA = 1.3  # SSOR relaxation: 1.2-1.4 take the fewest iterations on the benchmark cloth


def checked_preconditioner(system: System, preconditioner: str | None) -> str:
    """The preconditioner CG will use on ``system``: ``preconditioner``, or by default block SSOR
    where its serial sweeps can run (a CPU backend, every coupling term caching its blocks),
    else block Jacobi. ConfigError for an unknown one or SSOR where it cannot run."""
    sweeps = runtime.backend() in ("x64", "arm64") and system.caches_all_couplings
    if preconditioner is None:
        return "ssor" if sweeps else "jacobi"
    if preconditioner not in PRECONDITIONERS:
        raise ConfigError(f"preconditioner must be one of {', '.join(PRECONDITIONERS)}, "
                          f"got {preconditioner!r}")
    if preconditioner == "ssor" and not sweeps:
        raise ConfigError("preconditioner 'ssor' needs a CPU backend (its sweeps run serially) and "
                          "force terms that cache their Jacobian blocks; use 'jacobi'")
    return preconditioner


@ti.data_oriented
class ConjugateGradients:
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
    :class:`~.velocity_stage.VelocityStage`), else 0. The guess is used even when it leaves |r| > |rhs|, or
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
        self.preconditioner = preconditioner = checked_preconditioner(system, preconditioner)
        self.back = ti.Vector.field(3, real, shape=n) if preconditioner == "ssor" else None  # SSOR: t
        system.bind_jacobian_cache()

    def invalidate_pattern(self) -> None:
        """Nothing to do: CG has no symbolic analysis."""

    def solve(self, a: float, b: float, t: float, tolerance: float, max_iterations: int,
              stats: LinearSolverStats, warm: bool = False) -> LinearOutcome:
        if not self.in_kernel_loop:
            iterations, breakdown, rr, bb = self._solve_from_python(a, b, t, tolerance, max_iterations, warm)
        elif self.preconditioner == "ssor":
            iterations, breakdown, rr, bb = self._solve_ssor(a, b, t, tolerance, max_iterations, int(warm),
                                                             SSOR_OMEGA)
        else:
            iterations, breakdown, rr, bb = self._solve_jacobi(a, b, t, tolerance, max_iterations, int(warm))
        if bb == 0.0:
            return LinearOutcome(iterations=0, residual=0.0, converged=True)
        if breakdown:
            # A is positive definite by construction; this means NaN/inf reached the solve.
            return LinearOutcome(iterations, math.nan, False, message=f"CG breakdown (p.Ap = {rr:.3g})")
        residual = math.sqrt(rr / bb) if math.isfinite(rr) else math.nan
        converged = residual <= tolerance
        return LinearOutcome(iterations, residual, converged, message="" if converged else (
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
        self.system.prepare_jacobian(self.point, a, b, t)  # (a top-level pass, for terms that have one)
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


