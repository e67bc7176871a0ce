"""Adaptive explicit Runge-Kutta pairs: an embedded error estimate chooses the step size.

The step-size control follows Hairer, Norsett & Wanner, Solving ODEs I (2nd ed.), II.4, and
scipy's ``integrate._ivp.rk``: an RMS error norm scaled by ``atol + rtol * |y|``, a clamped
controller that never grows right after a rejection, a smallest step, and the d0/d1/d2 starting
step.
"""

import math
from typing import Annotated

import numpy as np
import taichi as ti

from .. import runtime
from ..state import State, finite
from ..systems.base import System
from .base import Integrator, Status, StepReport
from .explicit_rk import state_parts, weighted_stages
from .options import Option
from .tableau import DORMAND_PRINCE, FEHLBERG, ButcherTableau

STIFFNESS_FRACTION = 0.98  # h |lambda| above this fraction of the real stability boundary is stiff
STIFF_STEPS = 15  # accepted steps bounded by stability before a run is called stiff (Hairer: 15)
STIFF_BREAK = 6  # non-stiff steps in a row that reset the count (Hairer: 6)


@ti.data_oriented
class EmbeddedRK(Integrator):
    """Adaptive explicit RK over an embedded pair. Subclasses set ``tableau`` (with ``b_hat``).

    Each call to :meth:`step` makes ONE attempt from ``t`` with step ``h``: it evaluates the
    stages, then one kernel writes the candidate y_new into scratch (the caller's state is
    untouched until the step is accepted) and returns the error norm

        err = sqrt(mean over all components of (e_i / (atol + rtol * max(|y_i|, |y_new_i|)))^2)

    with e_i = |y_new_i - y_hat_i| + u |y_new_i|. The second term (u: unit round-off of the
    precision) is the rounding error of storing y_new, which no step size removes; without it a
    tolerance below round-off (rtol = 1e-30) would be "met" by steps of ~1e-14 s, whose
    truncation error estimate is below even that tolerance, and a run would crawl on instead of
    reporting STEP_TOO_SMALL. At sane tolerances it is negligible (u / rtol = 1e-10 for f64
    and rtol = 1e-6).

    err <= 1 accepts: the state becomes y_new and the report proposes
    ``next_h = h * min(10, safety * err^(-1/(q+1)))`` (q: the lower order of the pair), capped
    at ``h`` when an attempt from the same t was just rejected. err > 1 rejects: the state is
    unchanged, the report has ``accepted=False``, ``h=0`` (nothing was taken) and
    ``next_h = h * max(0.2, safety * err^(-1/(q+1)))``; the caller retries with it. A candidate
    with NaN or infinite values is rejected with the largest shrink (0.2), so it is never
    accepted. When a rejection proposes a step below :meth:`smallest_step`, the report's status
    is DIVERGED if the candidate was non-finite, else STEP_TOO_SMALL (the tolerance cannot be
    met in this precision).

    Reuse of the first stage: f(y, t) is kept between calls and reused when the next call
    starts from the same t and the same state values (checked bitwise by a kernel): after a
    rejection (every pair), and after an accepted step for FSAL pairs, whose last stage is f at
    y_new. A state changed between calls (post-step events, ``scene.reset()``) is detected and
    f is evaluated afresh. A change to the system itself between steps (a grab target moved, a
    spring torn, a stiffness changed) is not visible here: without :meth:`reset` it takes effect
    from the second stage of the next step, as if it happened a fraction of a step later.

    Options (keyword-only):
        rtol: relative tolerance (default 1e-6), >= 0.
        atol: absolute tolerance (default 1e-9), > 0, in the state's units (m and m/s: one
            value for positions and velocities, like scipy's scalar atol).
        safety: factor (0, 1] on the optimal step, default 0.9.
        min_step: smallest step (s) the controller may propose before giving up; default and
            floor 10 ulp of t, ``10 * eps * max(|t|, 1)``.
        max_step: largest step (s) it may propose (default: unbounded). Post-step events
            (collisions, tearing, emission) act only between steps, so scenes with them need one.
    ``rtol``, ``atol`` and ``safety`` are read at every step (the tolerances as kernel
    arguments), so they may be changed between steps without recompiling.
    """

    tableau: ButcherTableau
    adaptive = True
    stability_constant = None  # the controller picks the step
    initial_step_f_evals = 2
    takes_constraints = True
    max_growth = 10.0
    min_shrink = 0.2

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        cls.order = cls.tableau.order
        # the stages, two stage inputs, the candidate and the first stage's point
        cls.scratch_states = cls.tableau.stage_count + 4
        cls.f_evals_per_step = float(cls.tableau.stage_count - (1 if cls.tableau.fsal else 0))
        cls.stiffness_threshold = STIFFNESS_FRACTION * cls.tableau.real_stability_boundary()

    def __init__(self, system: System, *,
                 rtol: Annotated[float, Option("relative tolerance of a step's estimated error", flag=True,
                                               at_least=0)] = 1e-6,
                 # atol > 0: 0 would divide 0 by 0 for a component that is exactly zero (z in a plane)
                 atol: Annotated[float, Option("absolute tolerance of a step's estimated error", flag=True,
                                               above=0)] = 1e-9,
                 safety: Annotated[float, Option("the step controller's safety factor", above=0,
                                                 at_most=1)] = 0.9,
                 min_step: Annotated[float | None, Option("smallest step before the run ends step_too_small",
                                                          unit="s", above=0)] = None,
                 max_step: Annotated[float, Option(
                     "largest step", unit="s", flag=True, above=0, finite=False,
                     default_text="unbounded, or 10x the scene's default dt when the scene has collisions, "
                                  "tearing or emission")] = math.inf):
        super().__init__(system)
        self.rtol, self.atol, self.safety = float(rtol), float(atol), float(safety)
        self.min_step = min_step
        self.max_step = float(max_step)

        tab = self.tableau
        self.error_exponent = -1.0 / (min(tab.order, tab.embedded_order) + 1)
        # y_new - y_hat = h sum_j (b_j - b_hat_j) k_j: formed from the stages, not by subtraction.
        self.error_weights = tuple(b - b_hat for b, b_hat in zip(tab.b, tab.b_hat))
        self.part_count = 2 if system.second_order else 1
        self.component_count = 3 * system.particle_count * self.part_count
        self.eps = float(np.finfo(runtime.np_real()).eps)
        self.unit_roundoff = self.eps / 2

        self.stages = [system.make_state() for _ in range(tab.stage_count)]
        # Stage i's input goes to stage_inputs[i % 2], so the last two stages' inputs are both
        # kept (the stiffness estimate compares them); an FSAL pair's last is the candidate.
        self.stage_inputs = [system.make_state(), system.make_state()]
        self.stage_input = self.stage_inputs[0]  # the initial-step probe's scratch
        self.candidate = system.make_state()
        self.first_stage_point = system.make_state()  # the y at which stages[0] = f(y, t)
        self.first_stage_time: float | None = None  # that t; None: stages[0] is stale
        self.rejected_at: float | None = None  # t of the last attempt, when it was rejected
        self.stiff_steps = 0  # accepted steps in a row (bar short breaks) limited by stability
        self.non_stiff_steps = 0
        self.last_h_lambda = 0.0

    def reset(self) -> None:
        """Forget the kept first stage, the last rejection and the stiffness count (call after
        changing the system)."""
        self.first_stage_time = None
        self.rejected_at = None
        self.stiff_steps = self.non_stiff_steps = 0

    def smallest_step(self, t: float) -> float:
        """The smallest step (s) a rejection may propose at time ``t`` before the step fails."""
        floor = 10.0 * self.eps * max(abs(t), 1.0)
        return floor if self.min_step is None else max(self.min_step, floor)

    def step(self, state: State, t: float, h: float) -> StepReport:
        """One attempt to advance ``state`` from ``t`` by ``h`` seconds (see the class doc)."""
        if not (math.isfinite(h) and h > 0):
            raise ValueError(f"step size must be a finite number > 0, got {h}")
        tab = self.tableau
        f_evals = 0
        if not self._first_stage_is_current(state, t):
            self._evaluate_first_stage(state, t)
            f_evals += 1
        inputs = [state]
        for i in range(1, tab.stage_count):
            # An FSAL pair's last stage input is y_new itself: build it where the candidate lives.
            is_fsal_stage = tab.fsal and i == tab.stage_count - 1
            stage_input = self.candidate if is_fsal_stage else self.stage_inputs[i % 2]
            self._stage_input(state, i, h, stage_input)
            self.system.eval_f(stage_input, t + tab.c[i] * h, self.stages[i])
            inputs.append(stage_input)
            f_evals += 1
        squares, nonfinite, change2, spread2 = self._candidate_and_error(
            state, h, self.rtol, self.atol, self.unit_roundoff, inputs[-1], inputs[-2])
        err = math.sqrt(squares / self.component_count)
        if nonfinite == 0 and err <= 1.0:
            if spread2 > 0.0 and self._stiff(h * math.sqrt(change2 / spread2)):
                return self._stiff_report(t, h, f_evals)
            return self._accept(state, t, h, err, f_evals)
        return self._reject(t, h, err, nonfinite > 0 or not math.isfinite(err), f_evals)

    def _stiff(self, h_lambda: float) -> bool:
        """Hairer's test (Hairer & Wanner, Solving ODEs II, IV.2; ``dopri5.f``): h |lambda| from
        the last two stages, h |k_s - k_(s-1)| / |Y_s - Y_(s-1)| (Y the stage inputs), is an
        estimate of h times the largest eigenvalue the step sees; above ``stiffness_threshold``
        (98% of the method's stability boundary on the negative real axis) the step is bounded
        by stability, not by the tolerance. STIFF_STEPS such accepted steps, with no
        STIFF_BREAK non-stiff steps in a row between them, make the problem stiff."""
        self.last_h_lambda = h_lambda
        if h_lambda > self.stiffness_threshold:
            self.non_stiff_steps = 0
            self.stiff_steps += 1
        else:
            self.non_stiff_steps += 1
            if self.non_stiff_steps >= STIFF_BREAK:
                self.stiff_steps = 0
        return self.stiff_steps >= STIFF_STEPS

    def _stiff_report(self, t: float, h: float, f_evals: int) -> StepReport:
        self.stiff_steps = 0
        message = (f"the problem is stiff: the last {STIFF_STEPS} steps were bounded by stability, not by "
                   f"rtol={self.rtol:g} (h |lambda| ~ {self.last_h_lambda:.3g} at h = {h:.3g} s, stability "
                   f"boundary {self.stiffness_threshold / STIFFNESS_FRACTION:.3g}); an explicit method needs "
                   f"steps of ~{h:.2g} s here whatever the tolerance")
        return StepReport(accepted=False, h=0.0, next_h=h, f_evals=f_evals, status=Status.STIFF, message=message)

    def initial_step(self, state: State, t: float, t_end: float | None) -> float:
        """A first step (s) from ``state`` at ``t``, never past ``t_end``.

        Hairer, Norsett & Wanner I, II.4 (as scipy's ``select_initial_step``): with norms
        scaled by atol + rtol |y0|, d0 = |y0|, d1 = |f0|, h0 = 0.01 d0/d1; one explicit Euler
        probe of h0 gives d2 = |f(y0 + h0 f0) - f0| / h0, and h1 = (0.01 / max(d1, d2))^(1/(q+1))
        makes the local error about 1% of the tolerance. Returns min(100 h0, h1, t_end - t).
        Costs ``initial_step_f_evals`` = 2 evaluations of f (not part of any StepReport; the run
        loop adds them); the first is kept as the first stage of the next step.
        """
        remaining = math.inf if t_end is None else t_end - t
        if not remaining > 0:
            raise ValueError(f"t_end = {t_end} s is not after t = {t} s")
        self._evaluate_first_stage(state, t)
        y_squares, f_squares = self._initial_norms(state, self.rtol, self.atol)
        d0 = math.sqrt(y_squares / self.component_count)
        d1 = math.sqrt(f_squares / self.component_count)
        if not math.isfinite(d0 + d1):
            return min(1e-6, remaining)  # a non-finite state: the step reports it as DIVERGED
        h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
        h0 = min(h0, remaining)
        self._euler_probe(state, h0)
        self.system.eval_f(self.stage_input, t + h0, self.stages[1])
        d2 = math.sqrt(self._slope_change_norm(state, self.rtol, self.atol) / self.component_count) / h0
        if max(d1, d2) <= 1e-15:
            h1 = max(1e-6, h0 * 1e-3)
        else:
            h1 = (0.01 / max(d1, d2)) ** -self.error_exponent
        return min(100 * h0, h1, remaining, self.max_step)

    def _first_stage_is_current(self, state: State, t: float) -> bool:
        return (self.first_stage_time is not None and self.first_stage_time == t
                and self._differing_particles(state) == 0)

    def _evaluate_first_stage(self, state: State, t: float) -> None:
        self.system.eval_f(state, t, self.stages[0])
        self.first_stage_point.copy_from(state)
        self.first_stage_time = t

    def _accept(self, state: State, t: float, h: float, err: float, f_evals: int) -> StepReport:
        factor = self.max_growth
        if err > 0:
            factor = min(self.max_growth, self.safety * err ** self.error_exponent)
        if self.rejected_at == t:
            factor = min(1.0, factor)  # this step just failed at a larger h: do not grow back yet
        self.rejected_at = None
        self._commit(state)
        # FSAL: _commit made stages[0] = f(y_new, t + h); otherwise y changed under stages[0].
        self.first_stage_time = t + h if self.tableau.fsal else None
        return StepReport(accepted=True, h=h, next_h=min(h * factor, self.max_step), f_evals=f_evals)

    def _reject(self, t: float, h: float, err: float, nonfinite: bool, f_evals: int) -> StepReport:
        if nonfinite:
            factor = self.min_shrink
        else:
            factor = max(self.min_shrink, self.safety * err ** self.error_exponent)
        self.rejected_at = t
        next_h = h * factor
        smallest = self.smallest_step(t)
        if next_h >= smallest:
            return StepReport(accepted=False, h=0.0, next_h=next_h, f_evals=f_evals)
        if nonfinite:
            status = Status.DIVERGED
            message = f"the candidate state is not finite even at h = {h:.3g} s"
        else:
            status = Status.STEP_TOO_SMALL
            message = (f"error norm {err:.3g} at h = {h:.3g} s; a smaller step would be below "
                       f"{smallest:.3g} s: rtol={self.rtol:g}, atol={self.atol:g} cannot be met "
                       f"in {runtime.precision()}")
        return StepReport(accepted=False, h=0.0, next_h=next_h, f_evals=f_evals, status=status,
                          message=message)

    @ti.func
    def _combination(self, weights: ti.template(), part: ti.template(), p):
        return weighted_stages(self.stages, weights, part, p)

    @ti.kernel
    def _stage_input(self, y: ti.template(), i: ti.template(), h: float, out: ti.template()):
        for p in y.x:
            for part in ti.static(range(self.part_count)):
                ti.static(state_parts(out)[part])[p] = (ti.static(state_parts(y)[part])[p]
                                                   + h * self._combination(self.tableau.a[i], part, p))

    @ti.kernel
    def _candidate_and_error(self, y: ti.template(), h: float, rtol: float, atol: float,
                             roundoff: float, last_input: ti.template(),
                             previous_input: ti.template()) -> (float, ti.i32, float, float):
        """Write y_new into ``candidate`` (an FSAL pair already did); return (sum of squared
        scaled errors, number of particles with a non-finite y_new, |k_s - k_(s-1)|^2,
        |Y_s - Y_(s-1)|^2) for the stiffness estimate (Y: the inputs of the last two stages)."""
        squares = 0.0
        nonfinite = 0
        change2 = 0.0
        spread2 = 0.0
        for p in y.x:
            for part in ti.static(range(self.part_count)):
                dk = (ti.static(state_parts(self.stages[-1])[part])[p]
                      - ti.static(state_parts(self.stages[-2])[part])[p])
                dy = ti.static(state_parts(last_input)[part])[p] - ti.static(state_parts(previous_input)[part])[p]
                change2 += dk.dot(dk)
                spread2 += dy.dot(dy)
        for p in y.x:
            ok = True
            for part in ti.static(range(self.part_count)):
                y_old = ti.static(state_parts(y)[part])[p]
                if ti.static(not self.tableau.fsal):
                    ti.static(state_parts(self.candidate)[part])[p] = (
                        y_old + h * self._combination(self.tableau.b, part, p))
                y_new = ti.static(state_parts(self.candidate)[part])[p]
                error = ti.abs(h * self._combination(self.error_weights, part, p)) + roundoff * ti.abs(y_new)
                scaled = error / (atol + rtol * ti.max(ti.abs(y_old), ti.abs(y_new)))
                squares += scaled.dot(scaled)
                ok = ok and finite(y_new)
            if not ok:
                nonfinite += 1
        return squares, nonfinite, change2, spread2

    @ti.kernel
    def _commit(self, y: ti.template()):
        """y = y_new; an FSAL pair also keeps its last stage as the next first stage."""
        for p in y.x:
            for part in ti.static(range(self.part_count)):
                y_new = ti.static(state_parts(self.candidate)[part])[p]
                ti.static(state_parts(y)[part])[p] = y_new
                if ti.static(self.tableau.fsal):
                    ti.static(state_parts(self.first_stage_point)[part])[p] = y_new
                    ti.static(state_parts(self.stages[0])[part])[p] = ti.static(state_parts(self.stages[-1])[part])[p]

    @ti.kernel
    def _differing_particles(self, y: ti.template()) -> ti.i32:
        """Particles whose state differs from the one the kept first stage was evaluated at."""
        count = 0
        for p in y.x:
            same = True
            for part in ti.static(range(self.part_count)):
                kept = ti.static(state_parts(self.first_stage_point)[part])[p]
                if (ti.static(state_parts(y)[part])[p] != kept).any():
                    same = False
            if not same:
                count += 1
        return count

    @ti.kernel
    def _initial_norms(self, y: ti.template(), rtol: float, atol: float) -> (float, float):
        """(sum of (y / scale)^2, sum of (f0 / scale)^2), scale = atol + rtol |y|."""
        y_squares = 0.0
        f_squares = 0.0
        for p in y.x:
            for part in ti.static(range(self.part_count)):
                y_p = ti.static(state_parts(y)[part])[p]
                scale = atol + rtol * ti.abs(y_p)
                y_scaled = y_p / scale
                f_scaled = ti.static(state_parts(self.stages[0])[part])[p] / scale
                y_squares += y_scaled.dot(y_scaled)
                f_squares += f_scaled.dot(f_scaled)
        return y_squares, f_squares

    @ti.kernel
    def _euler_probe(self, y: ti.template(), h: float):
        """stage_input = y + h f0."""
        for p in y.x:
            for part in ti.static(range(self.part_count)):
                ti.static(state_parts(self.stage_input)[part])[p] = (
                    ti.static(state_parts(y)[part])[p] + h * ti.static(state_parts(self.stages[0])[part])[p])

    @ti.kernel
    def _slope_change_norm(self, y: ti.template(), rtol: float, atol: float) -> float:
        """Sum of ((f1 - f0) / scale)^2 with f1 in stages[1], scale = atol + rtol |y|."""
        squares = 0.0
        for p in y.x:
            for part in ti.static(range(self.part_count)):
                change = (ti.static(state_parts(self.stages[1])[part])[p]
                          - ti.static(state_parts(self.stages[0])[part])[p])
                scaled = change / (atol + rtol * ti.abs(ti.static(state_parts(y)[part])[p]))
                squares += scaled.dot(scaled)
        return squares


class DormandPrince45(EmbeddedRK):
    """Dormand-Prince 5(4): 7 stages, FSAL (6 evaluations of f per step after the first)."""

    name = "rk45"
    plot_colour = "#9467bd"  # in the benchmarks' plots
    tableau = DORMAND_PRINCE
    description = "adaptive Dormand-Prince 5(4), FSAL"


class Fehlberg45(EmbeddedRK):
    """Runge-Kutta-Fehlberg 4(5): 6 stages, propagates the fourth-order solution."""

    name = "rkf45"
    plot_colour = "#8c564b"  # in the benchmarks' plots
    tableau = FEHLBERG
    description = "adaptive Runge-Kutta-Fehlberg 4(5)"
