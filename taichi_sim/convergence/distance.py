"""How far a step's positions are from the solution of the equation its method declares, in
metres.

A force residual cannot tell a frozen stiff cloth from a good one: a stiff spring turns a
micrometre into newtons. The distance can. For the equations of :mod:`.residual` (backward
Euler, or implicit midpoint on its midpoint stage) the step's result x1 is a root of

    r(x) = M (x - x0 - tau v0) / tau^2 - F(x, (x - x0) / tau)

(the gradient of the incremental potential), and one Newton step from x1,

    delta = J^-1 r(x1),   J = M / tau^2 - K(x1) - D / tau,

is the estimate of x1 - x*: exact for a linear force, and to second order in |x1 - x*| near
the root. K is the springs' (and the grab's) stiffness, each spring's 3x3 block kept positive
semi-definite (a compressed spring's transverse stiffness clamped at 0, as the implicit methods
do), so J is positive definite and the step is the minimiser's; D the damping (dashpots, drag
unless the method takes it at the step's start, the grab's). J is assembled with
``scipy.sparse`` over the free particles and factorised once per estimate (SuperLU): an exact
solve rather than a few CG iterations, because on stiff cloth (k = 1e8 against m / tau^2 ~ 1)
a Krylov solve needs thousands of iterations to see the slow, cloth-wide motion that is
exactly what a frozen step misses.

The figure is the largest distance of one particle, ``max_i |delta_i|`` (m), for the step's
positions (for implicit midpoint: twice the midpoint stage's, x1 = 2 X - x0).

Where it has to decide against a tolerance and reads within a factor of ``DECIDE`` of it, the
estimate is not trusted to decide, and the step is solved instead (:func:`solve_step` from x1,
at most ``REFINE_ITERATIONS`` Jacobians, fewer where the caller cannot pay for them): the
figure is then the distance itself, or, where Newton has not converged by then, the larger of
the estimate and the last iterate's distance plus the geometric tail of Newton's corrections
at their last contraction (on a 16 x 16 cloth at k = 1e8 N/m Newton's line search takes the
turn a part at a time: 0.32, 0.42, 0.60, 0.81 mm after 1, 2, 4, 8 steps against 1.06 mm,
converged after 16). The tail tends to read high (up to 1.7 times on the cloth at k = 1e8),
which near the tolerance costs a method more work rather than a warning. The
estimate's one Newton step (and its chord step) reads low where x1 - x* is mostly a turn of
near-inextensible springs (a cloth or chain that lags its swing): the linear step moves the
particles along the turn's tangent, which lengthens each spring by a second-order amount that
a stiff spring resists, so Newton takes only part of the turn per step (a 10-particle pendulum
at k = 1e8 N/m: 0.46, 0.83, 0.95 mm after one, two, three Newton steps, against 1.02 mm; a
16 x 16 cloth at k = 1e6 N/m: 0.47, 0.94, 1.03 against 1.08 mm). Away from the tolerance the
factor it may read low by decides nothing.

:func:`solve_step` iterates the same Newton step to the root: the converged step the estimate
is validated against (tests, ``benchmarks/bench_error_estimate.py``).
"""
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..integrators.equation import Equation
from .residual import ForceModel

#: A distance within this factor of the tolerance (either side) is decided by solving the step:
#: the estimate's worst reading on the warning matrix (benchmarks/bench_warning_matrix.py) was
#: 3.3 times low (vbd's first step of a 16 x 16 cloth at k = 1e8 N/m: 0.32 of 1.06 mm).
DECIDE = 4.0
#: The Jacobians (Newton steps) that solving a step to decide may take; then the estimate stands.
REFINE_ITERATIONS = 16
#: The step is solved to this fraction of the tolerance (m / m).
REFINE_FRACTION = 0.01


class DistanceModel:
    """The Jacobian of an equation's residual over a scene's free particles (see the module
    docstring), on top of the residual's :class:`~.residual.ForceModel`."""

    def __init__(self, model: ForceModel, equation: Equation, newton_steps: int = 2):
        self.model, self.equation, self.newton_steps = model, equation, newton_steps
        self.free = np.flatnonzero(model.free)
        index = np.full(len(model.free), -1, np.int64)
        index[self.free] = np.arange(len(self.free))
        self.index = index  # particle -> its place among the free ones (-1: pinned)

    def stage(self, x0, v0, x1, v1, h):
        """(x, v, tau, scale): where the residual is taken and how a stage distance maps to x1."""
        if self.equation.rule == "implicit_midpoint":
            return 0.5 * (x0 + x1), 0.5 * (v0 + v1), 0.5 * h, 2.0
        return x1, v1, h, 1.0

    def residual(self, x, v, x0, v0, tau, extra=None, x1=None) -> np.ndarray:
        """r at (x, v) ((n, 3), N) for the stage of tau s from (x0, v0); ``extra``: the method's
        own :class:`~taichi_sim.integrators.equation.SolveForces`, linearised at x1."""
        model, eq = self.model, self.equation
        internal = model.internal(x, v, x0, tau, eq.isotropic_dashpots, model.spring_arrays())
        external = model.external(v0 if eq.explicit_external else v)
        r = model.mass[:, None] * (x - x0 - tau * v0) / tau**2 - internal - external
        if extra is not None:
            r -= extra.at(x, x if x1 is None else x1)
        return r

    def jacobian(self, x, tau, extra=None) -> sp.csc_matrix:
        """dr/dx over the free particles at positions x ((3 nf, 3 nf), N/m), v = (x - x0) / tau;
        with ``extra`` (SolveForces) its stiffness added."""
        model, eq = self.model, self.equation
        nf = len(self.free)
        diagonal = np.repeat(model.mass[self.free] / tau**2, 3)
        if not eq.explicit_external:
            diagonal = diagonal + model.drag / tau
        grab = model.grab
        if grab is not None and int(grab.particle[None]) >= 0 and self.index[int(grab.particle[None])] >= 0:
            j = self.index[int(grab.particle[None])]
            diagonal[3 * j:3 * j + 3] += float(grab.stiffness[None]) + float(grab.damping[None]) / tau
        rows, cols, vals = [np.arange(3 * nf)], [np.arange(3 * nf)], [diagonal]
        springs = model.spring_arrays()
        if springs is not None and len(springs[0]):
            ends, rest, k, c = springs
            a, b = self.index[ends[:, 0]], self.index[ends[:, 1]]
            d = x[ends[:, 0]] - x[ends[:, 1]]
            length = np.sqrt(np.einsum("ij,ij->i", d, d))
            u = d / np.where(length > 0, length, 1.0)[:, None]
            outer = u[:, :, None] * u[:, None, :]
            # d^2/dx^2 of k (|d| - r)^2 / 2 with its transverse part clamped at 0 (PSD)
            transverse = np.clip(1.0 - rest / np.where(length > 0, length, np.inf), 0.0, None)
            block = k[:, None, None] * (outer + transverse[:, None, None] * (np.eye(3) - outer))
            damping = (c / tau)[:, None, None] * (np.broadcast_to(np.eye(3), outer.shape)
                                                  if eq.isotropic_dashpots else outer)
            block = block + damping
            for p, q, sign in ((a, a, 1.0), (b, b, 1.0), (a, b, -1.0), (b, a, -1.0)):
                keep = (p >= 0) & (q >= 0)
                r3 = (3 * p[keep])[:, None, None] + np.arange(3)[None, :, None]
                c3 = (3 * q[keep])[:, None, None] + np.arange(3)[None, None, :]
                rows.append(np.broadcast_to(r3, (keep.sum(), 3, 3)).ravel())
                cols.append(np.broadcast_to(c3, (keep.sum(), 3, 3)).ravel())
                vals.append(sign * block[keep].ravel())
        matrix = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                               shape=(3 * nf, 3 * nf))
        if extra is not None:
            dofs = (3 * self.free[:, None] + np.arange(3)[None]).ravel()
            matrix = matrix + extra.stiffness.tocsr()[dofs][:, dofs].tocsc()
        return matrix

    def correction(self, x0, v0, x1, v1, h, steps: int | None = None, extra=None, at=None) -> np.ndarray:
        """x1 - x* estimated by up to ``steps`` (default two) Newton corrections from x1 with one
        factorisation of J (the second at the first's result: a chord step, which takes in much
        of the nonlinearity a single step misses on stiff cloth; taken only where it contracts)
        ((n, 3), m; 0 on pinned particles). Arrays of any float type; computed in float64; inf
        where the residual is not finite. ``extra``: the method's own forces (SolveForces) at
        x1, for a backward Euler step (at ``at``'s stage positions when given)."""
        x0, v0, x1, v1 = (np.asarray(a, np.float64) for a in (x0, v0, x1, v1))
        v0, v1 = v0.copy(), v1.copy()
        pinned = ~self.model.free
        v0[pinned] = v1[pinned] = 0.0  # as the residual: a pin is at rest within a step
        x, v, tau, scale = self.stage(x0, v0, x1, v1, h)
        out = np.zeros_like(x1)
        if not len(self.free):
            return out
        at = x if at is None else at
        r = self.residual(x, v, x0, v0, tau, extra, at)[self.free]
        if not np.all(np.isfinite(r)):
            out[:] = math.inf
            return out
        # SuperLU's default ordering (COLAMD): minimum degree on J + J^T is 1.7 times faster on
        # a grid cloth but filled in 11 times more with self-contact pairs (the garment's J:
        # 196 s against 2.3 s)
        solve = spla.splu(self.jacobian(x, tau, extra)).solve
        delta = solve(r.ravel()).reshape(-1, 3)
        steps = self.newton_steps if steps is None else steps
        for _ in range(steps - 1):
            moved = x.copy()
            moved[self.free] -= delta
            r = self.residual(moved, v + (moved - x) / tau, x0, v0, tau, extra, at)[self.free]
            if not np.all(np.isfinite(r)):
                break
            more = solve(r.ravel()).reshape(-1, 3)
            # Only a contracting correction is taken: at k = 1e8 the first correction rotates
            # stiff springs so far that J from x1 no longer describes them, and the chord
            # iteration runs away (1 m and more where the truth is 3 mm); one step reads 0.9 of it.
            if not _largest(more) <= 0.5 * _largest(delta):
                break
            delta = delta + more
        out[self.free] = scale * delta
        return out

    def distance(self, x0, v0, x1, v1, h, extra=None, tolerance: float | None = None,
                 refine: int = REFINE_ITERATIONS) -> float:
        """The estimate's figure: ``max_i |x1_i - x*_i|`` (m); 0 with nothing free. With a
        ``tolerance`` (m), a figure within a factor of ``DECIDE`` of it is replaced by the
        solved step's distance where :meth:`solve_step` gets there within ``refine`` Newton
        steps, else by the larger of it and the last iterate's distance plus the corrections'
        tail (module docstring). :attr:`jacobians` is then the Jacobians the figure took."""
        estimate = _largest(self.correction(x0, v0, x1, v1, h, extra=extra))
        self.jacobians = 1
        if tolerance is None or refine < 1 or not tolerance / DECIDE < estimate < DECIDE * tolerance:
            return estimate
        x_star, _ = self.solve_step(x0, v0, h, guess=x1, tolerance=REFINE_FRACTION * tolerance,
                                    max_iterations=refine, extra=extra, strict=False)
        self.jacobians += self.iterations
        solved = _largest((np.asarray(x1, np.float64) - x_star)[self.free])
        if self.converged:
            return solved
        # Not converged, the last iterate is still nearer x* than one step: these Newton
        # iterations approach x* from x1's side (the turn is taken a part at a time), and what
        # is left is about the geometric tail of their corrections at the last contraction
        tail = 0.0
        last = self.corrections[-2:]
        if len(last) == 2 and 0.0 < last[1] < last[0]:
            ratio = last[1] / last[0]
            tail = last[1] * ratio / (1.0 - ratio)
        return max(estimate, solved + tail)

    def solve_step(self, x0, v0, h, guess=None, *, tolerance: float = 1e-10,
                   max_iterations: int = 500, extra=None, strict: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """The equation's converged step from (x0, v0) over h s: (x1, v1), by Newton from
        ``guess`` (default x0 + h v0) until a correction is below ``tolerance`` (m) (halving a
        correction that raises |r|). ``extra``: the method's own forces (SolveForces) as
        linearised at ``guess``'s stage. RuntimeError when it does not converge (without
        ``strict``: the last iterate); :attr:`iterations` is the Newton steps taken,
        :attr:`converged` whether the last correction was below ``tolerance``,
        :attr:`corrections` the largest particle's move of each (m)."""
        x0, v0 = (np.asarray(a, np.float64).copy() for a in (x0, v0))
        pinned = ~self.model.free
        v0[pinned] = 0.0
        x1 = x0 + h * v0 if guess is None else np.asarray(guess, np.float64).copy()
        x1[pinned] = x0[pinned]

        def velocity(x1):
            v1 = (x1 - x0) / h if self.equation.rule == "backward_euler" else 2 * (x1 - x0) / h - v0
            v1[pinned] = 0.0
            return v1

        anchor = self.stage(x0, v0, x1, velocity(x1), h)[0] if extra is not None else None

        def norm_r(x1):
            x, v, tau, _ = self.stage(x0, v0, x1, velocity(x1), h)
            return float(np.linalg.norm(self.residual(x, v, x0, v0, tau, extra, anchor)[self.free]))

        current = norm_r(x1)
        self.iterations, self.converged, self.corrections = 0, False, []
        for _ in range(max_iterations):
            self.iterations += 1
            delta = self.correction(x0, v0, x1, velocity(x1), h, steps=1, extra=extra, at=anchor)
            step = 1.0
            while step > 1e-6:
                trial = x1 - step * delta
                value = norm_r(trial)
                if value <= current or step < 1e-3:
                    break
                step *= 0.5
            x1, current = trial, value
            self.corrections.append(step * _largest(delta[self.free]))
            if step * float(np.max(np.abs(delta), initial=0.0)) < tolerance:
                self.converged = True
                return x1, velocity(x1)
        if not strict:
            return x1, velocity(x1)
        raise RuntimeError(f"the reference step did not converge in {max_iterations} Newton iterations")


def _largest(delta: np.ndarray) -> float:
    """The largest length of the rows of ``delta`` ((n, 3)); 0 for none."""
    if not len(delta):
        return 0.0
    return float(np.sqrt(np.max(np.einsum("ij,ij->i", delta, delta))))

