"""Drive an integrator over a scene: fixed steps or up to an end time, with an energy trace."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .errors import ConfigError
from .guard import GuardLimits
from .integrators import Integrator, Status
from .run_observers import SAMPLES, EnergyTrace, FrameHistory, ProgressBar, WarmClock, default_energy_every
from .scene.scene import Scene
from .stepper import Stepper, bind_integrator, check_dt


@dataclass
class RunResult:
    """The outcome of :func:`run`.

    Attributes:
        status: OK, or why the run stopped early (DIVERGED, NOT_CONVERGED, STEP_TOO_SMALL).
        steps: accepted steps; rejected_steps: steps an adaptive method retried.
        t: simulated time reached (s).
        f_evals: evaluations of f in total.
        linear_iterations: linear-solver iterations in total (implicit methods).
        linear_residual: relative residual of the last linear solve (implicit methods).
        energy, energy_t: the energy trace (J) and its sample times (s); empty when the system
            has no energy or sampling was off.
        message: a one-line explanation when status is not OK.
        wall_time: seconds spent stepping (compile time of the first step included).
        warm_time: seconds from the end of the first accepted step to the end of the run: the
            stepping without the first step, which compiles most kernels (NaN for a run of
            fewer than two steps); :attr:`steps_per_second` divides by it, less
            ``estimate_time``'s share after the first step.
        estimate_time: seconds the error estimate's samples took (all of them) and
            estimate_warm_time: those after the first step (see ``error_estimate``).
        failed_step, failed_t: where the run stopped when status is not OK (the step that
            failed, or at which the blow-up guard caught it, and its time in s); 0 and NaN
            for an OK run. ``steps`` and ``t`` are those of the state left in the scene: for a
            DIVERGED run the last one that passed the guard (see :mod:`taichi_sim.guard`).
        guard_checks: how many times the guard checked the state.
        constraint_violation: for a scene with constraints, the largest |C| (m) over all
            constraints at each energy sample (aligned with ``energy_t``); None otherwise.
        solver_residual, residual_t: for a method that solves a system per step, its relative
            residual (:mod:`taichi_sim.convergence`) at the sampled steps (the last, and as many
            before it as cost at most 5 % of the run, chosen by work, so identical runs sample
            identical steps) and their times (s); empty arrays otherwise.
            residual_note: why a run has none ("").
        error_estimate: at the same samples, the estimated distance (m) of the step's positions
            from the solution of its method's equation (the largest over the particles);
            worst_error_estimate its largest (NaN when none); tolerance: the tolerance (m).
        worst_residual: the largest residual sample (NaN when none); max_residual: the bound
            applied (``max_residual``, or more where the precision rounds more: see
            :meth:`~taichi_sim.convergence.ConvergenceMonitor.check_precision`); warnings:
            one-line warnings (a fixed-work method whose estimated error exceeded the tolerance
            at its cap, the integrator's own
            :meth:`~taichi_sim.integrators.Integrator.run_warning`).
        x_history, t_history: with ``save_every``, the positions (S, N, 3) (m) (for a
            first-order system its state, (S, N, dim)) at t = 0, every ``save_every`` accepted
            steps and at the end, and their times (S,) (s); None otherwise.
        object_history: with ``save_every``, where the scene's spheres, capsules, boxes and
            collider mesh were at those times: ``sphere_center_history`` (S, K, 3) (m) and the
            like (``collider_mesh_center_history`` (S, 3), ``collider_mesh_vertices_history``
            (S, V, 3) for a sequence of frames); empty
            otherwise (what `taichi-sim check` tests the saved frames against).
    """

    status: Status
    steps: int
    t: float
    f_evals: int
    rejected_steps: int
    linear_iterations: int
    linear_residual: float
    energy: np.ndarray
    energy_t: np.ndarray
    message: str
    wall_time: float
    failed_step: int = 0
    failed_t: float = math.nan
    guard_checks: int = 0
    x_history: np.ndarray | None = None
    t_history: np.ndarray | None = None
    object_history: dict[str, np.ndarray] = field(default_factory=dict)
    constraint_violation: np.ndarray | None = None
    solver_residual: np.ndarray = field(default_factory=lambda: np.zeros(0))
    error_estimate: np.ndarray = field(default_factory=lambda: np.zeros(0))
    residual_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    residual_note: str = ""
    worst_residual: float = math.nan
    max_residual: float = math.nan
    worst_error_estimate: float = math.nan
    tolerance: float = math.nan
    warnings: tuple = ()
    warm_time: float = math.nan
    estimate_time: float = 0.0
    estimate_warm_time: float = 0.0

    @property
    def steps_per_second(self) -> float:
        """Accepted steps per second of wall time after the first accepted step (compile time
        left out: the first step compiles the step's kernels and the guard's); NaN for a run
        of fewer than two steps, whose rate would be mostly compile time."""
        stepping = self.warm_time - self.estimate_warm_time
        if self.steps < 2 or not stepping > 0:
            return math.nan
        return (self.steps - 1) / stepping


def planned_steps(dt: float, t_end: float) -> int:
    """Number of fixed steps of ``dt`` to reach ``t_end`` (the last one shortened to land on it)."""
    return max(1, math.ceil(t_end / dt - 1e-9))


def check_run_args(dt: float | None, steps: int | None, t_end: float | None, *,
                   adaptive: bool = False) -> None:
    """Raise ConfigError for a step size, step count or end time that cannot be run (``dt`` is
    the stepper's: :func:`~taichi_sim.stepper.check_dt`)."""
    check_dt(dt, adaptive=adaptive)
    if (steps is None) == (t_end is None):
        raise ConfigError("give exactly one of steps or t_end")
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
        raise ConfigError(f"steps must be an integer >= 1, got {steps}")
    if t_end is not None and not (math.isfinite(t_end) and t_end > 0):
        raise ConfigError(f"t_end must be a finite number > 0, got {t_end}")


def run(scene: Scene, integrator: Integrator | str, *, dt: float | None, steps: int | None = None,
        t_end: float | None = None, energy_every: int | None = None,
        progress: bool | None = False, guard: GuardLimits | None = None,
        curves: dict | None = None, save_every: int | None = None,
        max_residual: float | None = None, tolerance: float | None = None,
        raise_work: bool = True) -> RunResult:
    """Advance ``scene.state`` from t = 0 by ``steps`` accepted steps, or up to ``t_end`` s.

    Args:
        integrator: an integrator bound to ``scene.system``, or a registry name.
        dt: the step (s) of a fixed-step method; for an adaptive one the first step (None: the
            method chooses it).
        energy_every: sample the energy every this many accepted steps (0: never). None (the
            default): at the blow-up guard's checks (after 1, 2, 4, ... units of work, then
            every ``guard.check_work``: about 1 % of the run), thinned to at most about 2000
            samples a run (for an adaptive run to ``t_end``, at most one per t_end / 2000 s). A sample
            costs about two force evaluations, so ``energy_every=1`` on a cheap method
            (symplectic Euler) makes the run about three times slower. The first and last
            states are always sampled.
        progress: show a progress bar on stderr (None: only when stderr is a terminal).
        guard: the blow-up guard's limits (default :class:`~taichi_sim.guard.GuardLimits`).
        curves: parameter name -> :class:`~taichi_sim.curves.Spline`: each parameter takes its
            curve's value at the start of every step (the emitter's rate is integrated exactly
            over the step); a change of a force re-bases the guard (it is put in from outside).
        save_every: keep the positions every this many accepted steps, at t = 0 and at the end
            (``x_history``, ``t_history``); None or 0: keep none. Each kept frame is copied
            from the device: N x 3 reals.
        max_residual: bound on the relative residual of a method that solves a system per
            step (default :data:`~taichi_sim.convergence.DEFAULT_MAX_RESIDUAL`), sampled with
            the guard's checks and at the last step: above it a method that promises the
            solved step (implicit_euler, implicit_midpoint) stops the run NOT_CONVERGED; a
            fixed-work one (projective dynamics, XPBD, the linearised step) goes on with a
            warning in ``warnings``. Such a method on a scene whose springs the precision
            cannot resolve is refused (ConfigError) before any step.
        tolerance: how far (m) a step's positions may be from the solution of the equation its
            method solves, estimated at the same samples (``error_estimate``; default
            :data:`~taichi_sim.convergence.DEFAULT_TOLERANCE`): past it a fixed-work method
            (vbd, xpbd, projective dynamics) solves the step again with twice its work option
            (``iterations`` or ``substeps``, unless given) up to its cap, then warns; a method
            that promises the solved step ends the run NOT_CONVERGED
            (:class:`~taichi_sim.stepper.Stepper`).
        raise_work: False keeps the method's work as set (a benchmark of its settings).

    The steps are a :class:`~taichi_sim.stepper.Stepper`'s, taken by its one loop
    (:meth:`~taichi_sim.stepper.Stepper.run_until`); this function adds the energy trace, the
    saved frames and the progress bar as its observers (:mod:`taichi_sim.run_observers`). With ``t_end`` the last step is shortened to
    land exactly on it. The run stops at the first step whose status is not OK, or when the
    blow-up guard finds the state past a bound (status DIVERGED; the guard checks every
    ``guard.check_work`` f-evaluations and at the end). A DIVERGED run leaves in the scene the
    last state that passed the guard, and its energy trace ends there; the result's message
    says at which step and time it failed, what grew, and the predicted stable step of an
    explicit method.
    """
    if isinstance(integrator, str):
        integrator = bind_integrator(scene, integrator)
    adaptive = integrator.adaptive
    check_run_args(dt, steps, t_end, adaptive=adaptive)
    if save_every is not None and (isinstance(save_every, bool) or not isinstance(save_every, int)
                                   or save_every < 0):
        raise ConfigError(f"save_every must be an integer >= 0, got {save_every!r}")
    stepper = Stepper(scene, integrator, dt, limits=guard, curves=curves, max_residual=max_residual,
                      tolerance=tolerance, raise_work=raise_work)
    if stepper.refusal:
        raise ConfigError(stepper.refusal)
    expected = steps if adaptive else (steps if steps is not None else planned_steps(dt, t_end))
    every = (default_energy_every(expected or 1000) if energy_every is None else int(energy_every))
    # An energy sample costs about what a check does, so every sample is a check; with
    # energy_every given, the steps it names are checked whether the guard is due or not.
    forced = every > 0 and stepper.guard.energy0 is not None and energy_every is not None
    # The run's own work at each step, in this order: observers of the stepper's one loop.
    trace = None
    if every > 0 and stepper.guard.energy0 is not None:
        # an adaptive run to t_end has no step count to spread samples over: every t_end / 2000 s
        trace = EnergyTrace(stepper, every, forced,
                            t_end / SAMPLES if energy_every is None and expected is None else None)
        trace.sample(0.0)
        stepper.add_observer(trace)
    history = FrameHistory(scene, save_every) if save_every else None
    if history is not None:
        history.keep(0.0)
        stepper.add_observer(history)
    start = time.perf_counter()
    bar = ProgressBar(expected, t_end, progress)
    if not bar.hidden:
        stepper.add_observer(bar)
    clock = WarmClock(stepper.monitor)
    stepper.add_observer(clock)
    if hasattr(integrator, "progress"):  # an iterated implicit method: Newton's work within long steps
        integrator.progress = bar.bar.set_postfix_str if not bar.hidden else None
    try:
        # the last step is checked too: the method's own result is measured before the
        # post-step events move it, so the end's check must happen inside the step
        stepper.run_until(steps=steps, t_end=None if steps is not None else t_end,
                          check_every=every if forced else 0, check_last=True)
        # The last state is always checked and sampled.
        if stepper.failure is None and not stepper.checked:
            stepper.check()
        if stepper.failure is None and trace is not None and trace.times[-1] != stepper.t:
            trace.sample(stepper.t)
    finally:
        bar.close()
    end = time.perf_counter()
    wall = end - start
    t, failure, monitor = stepper.t, stepper.failure, stepper.monitor
    energy, energy_t, violation = trace.arrays(t) if trace is not None else (np.zeros(0), np.zeros(0), None)
    if violation is None and scene.constraints is not None:
        violation = np.zeros(0)
    x_history, t_history, object_history = history.arrays(t) if history is not None else (None, None, {})
    warm = clock.warm
    return RunResult(status=stepper.status, steps=stepper.steps, t=t, f_evals=stepper.f_evals,
                     rejected_steps=stepper.rejected, linear_iterations=stepper.linear_iterations,
                     linear_residual=stepper.linear_residual,
                     energy=energy, energy_t=energy_t,
                     message="" if failure is None else failure.message, wall_time=wall,
                     failed_step=0 if failure is None else failure.step,
                     failed_t=math.nan if failure is None else failure.t,
                     guard_checks=stepper.guard.checks, x_history=x_history, t_history=t_history,
                     object_history=object_history, constraint_violation=violation,
                     solver_residual=np.asarray(monitor.values, float), residual_t=np.asarray(monitor.times, float),
                     error_estimate=np.asarray(monitor.distances, float),
                     worst_error_estimate=monitor.worst_distance, tolerance=monitor.tolerance,
                     residual_note=monitor.reason, worst_residual=monitor.worst, max_residual=monitor.bound,
                     warnings=tuple(stepper.warnings) + integrator_warnings(stepper.integrator, monitor),
                     warm_time=math.nan if warm is None or stepper.steps < 2 else end - warm,
                     estimate_time=monitor.seconds,
                     estimate_warm_time=0.0 if warm is None else monitor.seconds - clock.estimated)


def integrator_warnings(integrator, monitor) -> tuple[str, ...]:
    """The integrator's :meth:`~taichi_sim.integrators.Integrator.run_warning`, if it says
    anything (an object stepping like an integrator without deriving from one has none); told
    whether the error estimate judged the run's steps."""
    warn = getattr(integrator, "run_warning", None)
    said = warn(accuracy_judged=monitor.active and bool(monitor.distances)) if warn is not None else ""
    return (said,) if said else ()
