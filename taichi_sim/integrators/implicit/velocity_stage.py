"""The implicit stage of a particle system in velocity form (Baraff & Witkin 1998), with the
incremental potential its Newton iterations minimise.

With X = x0 + tau V the unknown is V, and the stage solves

    g(V) = M (V - v0) - tau f(X, V) = 0,

the gradient (when every force term is variational) of the incremental potential

    Phi(V) = 1/2 |V - v0|_M^2 + U(X) + tau R(X, V)

(U the potential energy, R the Rayleigh dissipation; Martin et al. 2011, Gast et al. 2015). Each
Newton iteration solves A dV = -g with A = M - tau df/dv - tau^2 df/dx and analytic force
Jacobians, kept symmetric positive definite (a compressed spring's transverse stiffness is
clamped at 0, the dashpots' dependence on positions left out: see
:class:`taichi_sim.forces.Springs`), so CG and Cholesky apply and dV descends Phi. Pinned
particles are filtered out of the solve (identity rows) and keep their position bit for bit.

Every evaluation a Newton iteration needs (move the iterate, the residual g and the scales it is
judged against, Phi and the energy of the iterate) is ONE kernel (:meth:`VelocityStage.trial`):
on a CPU each launch of a data-oriented kernel costs tens to hundreds of microseconds of Python,
as much as the arithmetic on a 64 x 64 cloth.
"""

import math

import taichi as ti

from ... import runtime
from ...state import State, finite
from ...systems.base import System
from .cholesky import SparseCholesky
from .common import Evaluation, LinearOutcome, LinearSolverStats
from .conjugate_gradients import ConjugateGradients

ROUNDING_FLOOR = 2.0  # a residual within this many rounding errors of zero is as solved as it gets
ENERGY_ROUNDING = 1000.0  # rounding units of the summed energies an iterate's energy may exceed E0 by


@ti.data_oriented
class VelocityStage:
    """The implicit stage of a particle system in velocity form (see the module docstring).

    Scratch: the Newton iterate ``point`` (X, V), the force at it (N), the right-hand side
    (momentum, N s) and the Newton update dV (m/s), each (n,) vec3, plus the linear solver's.
    """

    def __init__(self, system: System, linear_solver: str, preconditioner: str | None = None):
        self.system = system
        n, real = system.particle_count, runtime.real()
        self.point = system.make_state()
        self.force = ti.Vector.field(3, real, shape=n)
        self.rhs = ti.Vector.field(3, real, shape=n)
        self.delta = ti.Vector.field(3, real, shape=n)
        # V - v0 of the last committed step, and the first guess of the next step's solve (m/s).
        self.last_change = ti.Vector.field(3, real, shape=n)
        self.guess = ti.Vector.field(3, real, shape=n)
        if linear_solver == "direct":
            self.linear = SparseCholesky(system, self.point, self.rhs, self.delta)
        else:
            self.linear = ConjugateGradients(system, self.point, self.rhs, self.delta, self.guess, preconditioner)
        self.solver_name = self.linear.name
        self.preconditioner = getattr(self.linear, "preconditioner", "")
        self.energy0 = self.energy_slack = self.iterate_energy = self.rounding_floor = 0.0
        self.merit_is_exact = all(term.variational for term in system.terms)
        """Whether Phi's gradient is exactly g: every force term is *variational* (see
        :attr:`taichi_sim.forces.ForceTerm.variational`)."""
        self.energy_bounded = not any(term.source for term in system.terms)
        """Whether the stage's energy may not rise: no force term is an energy source (wind)."""

    def invalidate_pattern(self) -> None:
        self.linear.invalidate_pattern()

    # -- Newton ---------------------------------------------------------------------------------

    def begin(self, y0: State, t: float, tau: float, linearised: bool, warm: bool = False) -> Evaluation:
        """Start Newton; returns the stage at the start point (NaNs for the linearised step).

        Linearised (one step, Baraff & Witkin): at (x0, v0), with the right-hand side of f
        linearised there. Otherwise at the consistent point V = v0, X = x0 + tau v0, or with
        ``warm`` at V = v0 + the velocity change extrapolated from the last steps when its merit
        is lower; the right-hand side is then -g, the true residual.
        """
        if linearised:
            self._place(y0, 0.0, 0)
            self.system.forces(self.point, self.force, t)
            self._linearised_rhs(tau, t)
            return Evaluation(math.nan, math.nan)
        start = self._evaluate(y0, t, tau, self._start(y0, tau, t, 0))
        if warm:
            warm_start = self._evaluate(y0, t, tau, self._start(y0, tau, t, 1))
            if warm_start.merit < start.merit:
                return warm_start
            start = self._evaluate(y0, t, tau, self._start(y0, tau, t, 0))
        return start

    def solve(self, tau: float, t: float, tolerance: float, max_iterations: int, stats: LinearSolverStats,
              warm: bool = False) -> LinearOutcome:
        """Solve A dV = rhs, counting the work in ``stats``; ``warm``: start an iterative solver
        from the previous step's velocity change instead of zero."""
        return self.linear.solve(tau, tau * tau, t, tolerance, max_iterations, stats, warm)

    def trial(self, y0: State, t: float, tau: float, fraction: float) -> Evaluation:
        """V += fraction dV (X = x0 + tau V), and the stage there; its ``slope`` is g . dV at the
        point moved from (meaningful when the right-hand side was still -g there: the first
        trial after a solve)."""
        return self._evaluate(y0, t, tau, self._trial(y0, tau, t, fraction))

    def advance(self, y0: State, tau: float, fraction: float) -> int:
        """V += fraction dV, X = x0 + tau V without evaluating anything (the linearised step);
        returns the number of non-finite particles."""
        return self._advance(y0, tau, fraction)

    @property
    def merit_noise(self) -> float:
        """Rounding noise of the merit (J): the same allowance as :meth:`energy_ok`'s."""
        return self.energy_slack

    def energy_ok(self) -> bool:
        """Whether the energy of the last evaluated iterate, 1/2 |V|_M^2 + U(X), is at most the
        step's start energy plus rounding (ENERGY_ROUNDING units of round-off of the energies
        summed), or the system has a source. Backward Euler dissipates, so an iterate that has
        met the residual test but not this one is not yet the step's answer."""
        if not self.energy_bounded:
            return True
        return self.iterate_energy <= self.energy0 + self.energy_slack

    def commit(self, y: State, h: float, theta: float, continued: bool = False) -> int:
        """y1 = y0 + (Y - y0) / theta from the stage Y; sets the next step's first guess
        (``continued``: the step just taken followed the previous one, whose velocity change is
        still in ``last_change``)."""
        return self._commit(y, h, theta, int(continued))

    def _evaluate(self, y0: State, t: float, tau: float, sums) -> Evaluation:
        (g2, s2, e2, change, kinetic, potential, dissipation, slope, bad,
         kinetic0, potential0, magnitude0) = sums
        self.rounding_floor = ROUNDING_FLOOR * runtime.machine_epsilon() * math.sqrt(max(e2, 0.0))
        self.iterate_energy = kinetic + potential
        if math.isfinite(kinetic0):  # a start: the step's reference energy
            self.energy0 = kinetic0 + potential0
            self.energy_slack = ENERGY_ROUNDING * runtime.machine_epsilon() * (
                kinetic0 + magnitude0 + abs(self.energy0))
        merit = change + potential + tau * dissipation
        return Evaluation(residual=math.sqrt(max(g2, 0.0)), scale=math.sqrt(max(s2, 0.0)), merit=merit,
                          slope=slope, nonfinite=int(bad))

    # -- kernels ------------------------------------------------------------------------------
    # Each returns (|g|^2, |s|^2, |e|^2, 1/2 |V - v0|_M^2, 1/2 |V|_M^2, U(X), R(X, V), slope,
    # non-finite count, 1/2 |v0|_M^2, U(x0), sum of |U_i(x0)|) at the iterate it leaves; the
    # last three only from _start (NaN otherwise), slope only from _trial.

    @ti.func
    def _stage_sums(self, y0, tau, t):
        """Residual, scales and merit parts at ``point``, in one gather over the particles."""
        g2 = ti.cast(0.0, y0.x.dtype)
        s2 = ti.cast(0.0, y0.x.dtype)
        e2 = ti.cast(0.0, y0.x.dtype)
        change = ti.cast(0.0, y0.x.dtype)
        kinetic = ti.cast(0.0, y0.x.dtype)
        potential = ti.cast(0.0, y0.x.dtype)
        dissipation = ti.cast(0.0, y0.x.dtype)
        for i in self.point.x:
            # g = M (V - v0) - tau f(X, V) with the true f; s_i sums the magnitudes of the
            # terms of g_i (what its rounding error is relative to), e_i the scale of that
            # rounding error (see ParticleSystem.force_and_scale).
            f, force_scale, force_rounding, u, r = self.system.evaluate_at(i, self.point, t)
            potential += u
            dissipation += r
            g = ti.Vector.zero(y0.x.dtype, 3)
            if self.system.free[i]:
                m = self.system.mass[i]
                g = m * (self.point.v[i] - y0.v[i]) - tau * f
                momenta = m * (self.point.v[i].norm() + y0.v[i].norm())
                s = m * (self.point.v[i] - y0.v[i]).norm() + tau * force_scale
                e = momenta + tau * force_rounding
                g2 += g.norm_sqr()
                s2 += s * s
                e2 += e * e
                change += 0.5 * m * (self.point.v[i] - y0.v[i]).norm_sqr()
                kinetic += 0.5 * m * self.point.v[i].norm_sqr()
            self.rhs[i] = -g
        return g2, s2, e2, change, kinetic, potential, dissipation

    @ti.kernel
    def _start(self, y0: ti.template(), tau: float, t: float, use_guess: ti.i32) -> (
            float, float, float, float, float, float, float, float, ti.i32, float, float, float):
        kinetic0 = 0.0
        potential0 = 0.0
        magnitude0 = 0.0
        bad = 0
        for i in self.point.x:
            x, v = self._start_point(i, y0, tau, use_guess)
            if self.system.free[i]:
                kinetic0 += 0.5 * self.system.mass[i] * y0.v[i].norm_sqr()
            u, _dissipation = self.system.potential_and_dissipation_at(i, y0)
            potential0 += u
            # Rounding of the energies: relative to each term's size, and for a force F at a
            # position rounded to eps |x|, |F| eps |x| (a spring's |d| - r near rest length
            # loses digits: at small stretch this dominates ½ k (|d| - r)^2 itself).
            # (each unused value its own name: Taichi keeps one type per name, and one `_` for
            # this loop's scalars and vectors fails to compile at opt_level 0)
            _force, pieces, _rounding = self.system.force_and_scale(i, y0, t)
            magnitude0 += ti.abs(u) + pieces * x.norm()
            if not (finite(x) and finite(v)):
                bad += 1
        g2, s2, e2, change, kinetic, potential, dissipation = self._stage_sums(y0, tau, t)
        return (g2, s2, e2, change, kinetic, potential, dissipation, ti.math.nan, bad,
                kinetic0, potential0, magnitude0)

    @ti.kernel
    def _trial(self, y0: ti.template(), tau: float, t: float, fraction: float) -> (
            float, float, float, float, float, float, float, float, ti.i32, float, float, float):
        slope = 0.0
        for i in self.rhs:  # g . dV with the right-hand side -g of the point moved from
            slope -= self.rhs[i].dot(self.delta[i])
        bad = 0
        for i in self.point.x:
            bad += self._move_point(i, y0, tau, fraction)
        g2, s2, e2, change, kinetic, potential, dissipation = self._stage_sums(y0, tau, t)
        return (g2, s2, e2, change, kinetic, potential, dissipation, slope, bad,
                ti.math.nan, ti.math.nan, ti.math.nan)

    @ti.func
    def _move_point(self, i, y0, tau, fraction):
        """Move free particle i of the iterate by ``fraction`` of the Newton step (V += fraction
        dV, X = x0 + tau V); 1 when the result is not finite, else 0."""
        bad = 0
        if self.system.free[i]:
            v = self.point.v[i] + fraction * self.delta[i]
            x = y0.x[i] + tau * v
            self.point.v[i] = v
            self.point.x[i] = x
            if not (finite(x) and finite(v)):
                bad = 1
        return bad

    @ti.kernel
    def _place(self, y0: ti.template(), tau: float, use_guess: ti.i32):
        for i in self.point.x:
            self._start_point(i, y0, tau, use_guess)

    @ti.func
    def _start_point(self, i, y0, tau, use_guess):
        """Put particle i of the iterate at the start (V = v0, plus the warm-start guess when
        ``use_guess``; X = x0 + tau V) and return its (x, v). A pinned particle's velocity is
        not part of the dynamics (its derivative is zero): zeroing it keeps every vector of the
        solve zero on pinned particles."""
        v = ti.Vector.zero(y0.x.dtype, 3)
        x = y0.x[i]
        if self.system.free[i]:
            v = y0.v[i]
            if use_guess:
                v += self.guess[i]
            x += tau * v
        self.point.x[i] = x
        self.point.v[i] = v
        return x, v

    @ti.kernel
    def _linearised_rhs(self, tau: float, t: float):
        # f(x0 + tau V, V) ~ f0 + tau df/dx V + df/dv (V - v0): the momentum balance
        # M (V - v0) = tau f becomes A dV = tau f0 + tau^2 df/dx v0 with dV = V - v0.
        self.system.prepare_jacobian(self.point, 0.0, tau * tau, t)
        for i in self.rhs:
            self.rhs[i] = tau * self.force[i] + self.system.force_jacobian_product(
                i, self.point, self.point.v, 0.0, tau * tau, t)

    @ti.kernel
    def _advance(self, y0: ti.template(), tau: float, fraction: float) -> ti.i32:
        bad = 0
        for i in self.point.x:
            bad += self._move_point(i, y0, tau, fraction)
        return bad

    @ti.kernel
    def _commit(self, y: ti.template(), h: float, theta: float, continued: ti.i32) -> ti.i32:
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
                if theta == 1.0:
                    y.v[i] = v_stage
                else:
                    y.v[i] = y.v[i] + (v_stage - y.v[i]) / theta
            # Pinned particles are checked too: a NaN there would otherwise pass unnoticed (a
            # spring of non-finite length exerts no force).
            self.last_change[i] = change
            self.guess[i] = guess
            if not (finite(y.x[i]) and finite(y.v[i])):
                bad += 1
        return bad
