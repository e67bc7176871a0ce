"""Newton-Krylov (GMRES) for the implicit stage of any system: what the implicit methods use
when a system has no spring Jacobians (the circle ODE).

The residual is g(Y) = Y - y0 - tau f(Y) on the whole state, and each Newton iteration solves
(I - tau df/dy) dY = -g by restarted GMRES. The Jacobian-vector products come from
``system.jacobian_product`` when the system has one (``has_jacobian_product``; the circle's
Jacobian is the constant rotation generator), else from forward differences of ``eval_f`` with
the step of Pernice & Walker (1998, NITSOL).
"""
import dataclasses
import math

import numpy as np
import taichi as ti

from ... import runtime
from ...state import State, finite
from ...systems.base import System
from .common import Evaluation, LinearOutcome

GMRES_RESTART = 20  # Krylov vectors kept before GMRES restarts (memory: this many states)


@ti.data_oriented
class NewtonKrylovStage:
    """The implicit stage of any system, by Newton-Krylov (GMRES) on the whole state.

    Vectors of the state's shape (x, and v for a second-order system) are rows of one 2-D field
    per component, so every vector kernel compiles once: rows 0..restart hold the Krylov basis,
    then the Newton step dY and the right-hand side -g.
    """

    def __init__(self, system: System, restart: int):
        self.system = system
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
        self.solver_name = "gmres"
        self.preconditioner = ""

    def invalidate_pattern(self) -> None:
        """Nothing to do: no matrix is assembled."""

    merit_is_exact = False  # there is no merit: the line search uses the residual norm
    merit_noise = 0.0
    rounding_floor = 0.0  # the residual is measured relative to |Y| + |y0| + tau |f| already

    def energy_ok(self) -> bool:
        """No energy test: a general system's energy need not fall under backward Euler."""
        return True

    def begin(self, y0: State, t: float, tau: float, linearised: bool, warm: bool = False) -> Evaluation:
        """Start Newton at Y = y0 (consistent: its residual is the true one). A linearised step
        starts there too (its one Newton step linearises f at y0); there is no warm start."""
        self._copy_state(y0)
        return self._evaluate(y0, t, tau)

    def trial(self, y0: State, t: float, tau: float, fraction: float) -> Evaluation:
        """Y += fraction dY, and the residual there (no merit: a general system has none)."""
        bad = self._advance(fraction)
        return dataclasses.replace(self._evaluate(y0, t, tau), nonfinite=int(bad))

    def _evaluate(self, y0: State, t: float, tau: float) -> Evaluation:
        """Set the right-hand side -g, g = Y - y0 - tau f(Y); |g| and |s| with
        s_i = |Y_i| + |y0_i| + tau |f_i| (the magnitudes g is computed from)."""
        self.system.eval_f(self.point, t, self.f)
        g2, s2 = self._residual(y0, tau)
        return Evaluation(residual=math.sqrt(g2), scale=math.sqrt(s2))

    def advance(self, y0: State, tau: float, fraction: float) -> int:
        """Y += fraction dY; returns the number of non-finite particles."""
        return self._advance(fraction)

    def commit(self, y: State, h: float, theta: float, continued: bool = False) -> int:
        """y1 = y0 + (Y - y0) / theta; returns the number of non-finite particles."""
        return self._commit(y, theta)

    def solve(self, tau: float, t: float, tolerance: float, max_iterations: int, stats=None,
              warm: bool = False) -> LinearOutcome:
        """Restarted GMRES(restart) on (I - tau J) dY = -g, from dY = 0 (Saad & Schultz 1986)."""
        self._zero(self.step_row)
        rhs_norm = math.sqrt(self._dot(self.rhs_row, self.rhs_row))
        if rhs_norm == 0.0:
            return LinearOutcome(0, 0.0, True)
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
        return LinearOutcome(iterations, relative, converged, f_evals=f_evals, message=message)

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
    def _commit(self, y: ti.template(), theta: float) -> ti.i32:
        bad = 0
        for i in y.x:
            x = self.point.x[i]
            if theta != 1.0:
                x = y.x[i] + (x - y.x[i]) / theta
            y.x[i] = x
            ok = finite(x)
            if ti.static(self.second_order):
                v = self.point.v[i]
                if theta != 1.0:
                    v = y.v[i] + (v - y.v[i]) / theta
                y.v[i] = v
                ok = ok and finite(v)
            if not ok:
                bad += 1
        return bad

