"""Drive an integrator over a scene: fixed steps or up to an end time, with an energy trace."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from .errors import ConfigError
from .guard import Guard, GuardLimits
from .integrators import Integrator, Status, create_integrator
from .scene.scene import Scene


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
        failed_step, failed_t: where the run stopped when status is not OK (the step that
            failed, or at which the blow-up guard caught it, and its time in s); 0 and NaN
            for an OK run. ``steps`` and ``t`` are those of the state left in the scene: for a
            DIVERGED run the last one that passed the guard (see :mod:`taichi_sim.guard`).
        guard_checks: how many times the guard checked the state.
        constraint_violation: for a scene with constraints, the largest |C| (m) over all
            constraints at each energy sample (aligned with ``energy_t``); None otherwise.
        x_history, t_history: with ``save_every``, the positions (S, N, 3) (m) (for a
            first-order system its state, (S, N, dim)) at t = 0, every ``save_every`` accepted
            steps and at the end, and their times (S,) (s); None otherwise.
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
    constraint_violation: np.ndarray | None = None


def planned_steps(dt: float, t_end: float) -> int:
    """Number of fixed steps of ``dt`` to reach ``t_end`` (the last one shortened to land on it)."""
    return max(1, math.ceil(t_end / dt - 1e-9))


SAMPLES = 2000  # energy samples of a long run


def default_energy_every(step_count: int) -> int:
    """The fewest steps between default energy samples: at most about 2000 samples a run."""
    return 1 if step_count <= SAMPLES else math.ceil(step_count / SAMPLES)


def check_run_args(dt: float | None, steps: int | None, t_end: float | None, *,
                   adaptive: bool = False) -> None:
    """Raise ConfigError for a step size, step count or end time that cannot be run."""
    if dt is None:
        if not adaptive:
            raise ConfigError("dt is required for a fixed-step integrator")
    elif isinstance(dt, bool) or not isinstance(dt, (int, float)) or not (math.isfinite(dt) and dt > 0):
        raise ConfigError(f"dt must be a finite number > 0, got {dt}")
    if (steps is None) == (t_end is None):
        raise ConfigError("give exactly one of steps or t_end")
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
        raise ConfigError(f"steps must be an integer >= 1, got {steps}")
    if t_end is not None and not (math.isfinite(t_end) and t_end > 0):
        raise ConfigError(f"t_end must be a finite number > 0, got {t_end}")


def run(scene: Scene, integrator: Integrator | str, *, dt: float | None, steps: int | None = None,
        t_end: float | None = None, energy_every: int | None = None,
        progress: bool | None = False, guard: GuardLimits | None = None,
        curves: dict | None = None, save_every: int | None = None) -> RunResult:
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

    With ``t_end`` the last step is shortened to land exactly on it. The run stops at the
    first step whose status is not OK, or when the blow-up guard finds the state past a bound
    (status DIVERGED; the guard checks every ``guard.check_work`` f-evaluations and at the
    end). A DIVERGED run leaves in the scene the last state that passed the guard, and its
    energy trace ends there; the result's message says at which step and time it failed, what
    grew, and the predicted stable step of an explicit method.
    """
    if isinstance(integrator, str):
        integrator = create_integrator(integrator, scene.system)
    adaptive = integrator.adaptive
    check_run_args(dt, steps, t_end, adaptive=adaptive)
    if save_every is not None and (isinstance(save_every, bool) or not isinstance(save_every, int)
                                   or save_every < 0):
        raise ConfigError(f"save_every must be an integer >= 0, got {save_every!r}")
    history = _History(scene) if save_every else None
    driver = None
    if curves:
        from .curves import CurveDriver
        driver = CurveDriver(scene, curves)
        driver.apply(0.0)
    watch = Guard(scene, guard)
    f_evals = 0
    if adaptive:
        if dt is None:
            h = integrator.initial_step(scene.state, 0.0, t_end)
            f_evals += integrator.initial_step_f_evals
        else:
            h = dt
        expected = steps  # unknown for an adaptive run to t_end
    else:
        h = dt
        expected = steps if steps is not None else planned_steps(dt, t_end)
    every = (default_energy_every(expected or 1000) if energy_every is None else int(energy_every))
    last_sample = 0
    has_energy = every > 0 and watch.energy0 is not None
    # An adaptive run to t_end has no step count to spread samples over: every t_end / 2000 s.
    sample_interval = t_end / SAMPLES if energy_every is None and expected is None else None
    next_sample = sample_interval

    energy, energy_t = [], []
    violation = [] if scene.constraints is not None else None
    if has_energy:
        energy.append(watch.energy0)
        energy_t.append(0.0)
        if violation is not None:
            violation.append(scene.constraint_violation())
    if history is not None:
        history.keep(0.0)
    status, message = Status.OK, ""
    rejected = done = linear_iterations = 0
    failed_step, failed_t = 0, math.nan
    linear_residual = 0.0
    t = 0.0
    start = time.perf_counter()
    if t_end is not None and expected is None:
        bar = tqdm(total=t_end, unit="s", disable=None if progress is None else not progress,
                   leave=False, mininterval=0.5, bar_format="{l_bar}{bar}| {n:.3g}/{total:.3g} s")
    else:
        bar = tqdm(total=expected, unit="step", disable=None if progress is None else not progress,
                   leave=False, mininterval=0.5)
    if hasattr(integrator, "progress"):  # an iterated implicit method: Newton's work within long steps
        integrator.progress = bar.set_postfix_str if not bar.disable else None
    # read once: an attribute of a Taichi data-oriented object costs about a microsecond
    step, implicit = integrator.step, integrator.implicit
    with bar:
        while (steps is not None and done < steps) or (steps is None and t < t_end):
            last = False
            if t_end is not None and t + h >= t_end * (1 - 1e-12):
                h, last = t_end - t, True
            if driver is not None and driver.apply(t):
                integrator.reset()
                watch.rebase(t, done)
            report = step(scene.state, t, h)
            f_evals += report.f_evals
            linear_iterations += report.linear_iterations
            if implicit:
                linear_residual = report.linear_residual
            if report.status is not Status.OK:
                status = report.status
                failed_step, failed_t = done + 1, (t + h if report.accepted else t)
                detail = f" ({report.message})" if report.message else ""
                if status is Status.DIVERGED:
                    # The state may hold the non-finite values: put back the last good one.
                    watch.restore()
                    done, t = watch.good_step, watch.good_t
                elif watch.work:
                    # The failed attempt left the state at t: check what the steps since the
                    # last check made of it (it may have blown up before the method gave up).
                    breach = watch.check(t, done)
                    if breach is not None:
                        status, detail = Status.DIVERGED, f" ({breach.detail})"
                        watch.restore()
                        done, t = watch.good_step, watch.good_t
                message = failure_message(scene, integrator, status, failed_step, failed_t, h, detail,
                                          watch, done, t)
                break
            if not report.accepted:
                rejected += 1
                h = report.next_h
                continue
            done += 1
            if last:
                t = t_end
            elif adaptive:
                t += report.h
            else:
                t = done * dt  # no round-off drift over many fixed steps
            if scene.after_step(t, report.h):
                integrator.reset()  # an event changed the system (e.g. tore springs)
            due = watch.spend(report.f_evals + report.linear_iterations)
            end = last or done == steps
            if energy_every is not None:
                sample = has_energy and (done % every == 0 or end)
            elif sample_interval is None:
                sample = has_energy and ((due and done - last_sample >= every) or end)
            else:
                sample = has_energy and ((due and t >= next_sample * (1 - 1e-12)) or last)
                if sample:
                    next_sample = (math.floor(t / sample_interval + 1e-9) + 1) * sample_interval
            # An energy sample costs about what a check does, so every sample is a check.
            if due or sample or end:
                breach = watch.check(t, done)
                if breach is not None:
                    status = Status.DIVERGED
                    failed_step, failed_t = done, t
                    watch.restore()
                    done, t = watch.good_step, watch.good_t
                    message = failure_message(scene, integrator, status, failed_step, failed_t, report.h,
                                              f" ({breach.detail})", watch, done, t)
                    break
                if sample:
                    energy.append(watch.health.energy)
                    energy_t.append(t)
                    if violation is not None:
                        violation.append(scene.constraint_violation())
                    last_sample = done
            if history is not None and (done % save_every == 0 or end):
                history.keep(t)
            bar.update(report.h if (t_end is not None and expected is None) else 1)
            if adaptive:
                h = report.next_h
    wall = time.perf_counter() - start
    energy_t = np.asarray(energy_t, float)
    kept = energy_t <= t  # a diverged run's trace ends at the state it returns
    x_history, t_history = history.arrays(t) if history is not None else (None, None)
    return RunResult(status=status, steps=done, t=t, f_evals=f_evals, rejected_steps=rejected,
                     linear_iterations=linear_iterations, linear_residual=linear_residual,
                     energy=np.asarray(energy, float)[kept], energy_t=energy_t[kept],
                     message=message, wall_time=wall, failed_step=failed_step, failed_t=failed_t,
                     guard_checks=watch.checks, x_history=x_history, t_history=t_history,
                     constraint_violation=None if violation is None else np.asarray(violation, float)[kept])


class _History:
    """Frames of a run's positions, copied from the device as they are kept."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self.frames: list[np.ndarray] = []
        self.times: list[float] = []

    def keep(self, t: float) -> None:
        if self.times and self.times[-1] == t:
            return  # the end of a run that ends on a saving step
        self.frames.append(np.asarray(self.scene.state.x.to_numpy(), np.float64))
        self.times.append(t)

    def arrays(self, t_final: float) -> tuple[np.ndarray, np.ndarray]:
        """The frames up to ``t_final`` (a diverged run ends at the state it returns), with
        that state last."""
        times = np.asarray(self.times, float)
        kept = times <= t_final
        frames = [f for f, k in zip(self.frames, kept) if k]
        times = times[kept]
        if not len(times) or times[-1] != t_final:
            frames.append(np.asarray(self.scene.state.x.to_numpy(), np.float64))
            times = np.append(times, t_final)
        return np.stack(frames), times


def failure_message(scene: Scene, integrator: Integrator, status: Status, step: int, t: float, h: float,
                    detail: str, watch: Guard, good_step: int, good_t: float) -> str:
    """One line: what stopped a run, where, and what to do about it."""
    from .theory import stable_step_advice

    text = f"{status.value} at step {step} (t = {t:.6g} s) with {integrator.name}, h = {h:.3g} s{detail}"
    if status is Status.DIVERGED:
        text += (f"; the state returned is that of step {good_step} (t = {good_t:.6g} s), the last "
                 f"that passed the blow-up check")
        advice = stable_step_advice(scene, integrator.name)
        if advice:
            text += f"; {advice}"
        return text + ": lower the step or pick a more stable integrator"
    if status is Status.STEP_TOO_SMALL:
        return text + ": loosen rtol/atol or use f64"
    if status is Status.STIFF:
        return text + ": use an implicit method (implicit_euler)"
    return text + ": lower the step or pick a more stable integrator"
