"""Drive an integrator over a scene: fixed steps or up to an end time, with an energy trace."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from .errors import ConfigError
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


def planned_steps(dt: float, t_end: float) -> int:
    """Number of fixed steps of ``dt`` to reach ``t_end`` (the last one shortened to land on it)."""
    return max(1, math.ceil(t_end / dt - 1e-9))


def default_energy_every(step_count: int) -> int:
    """Every step for runs up to 2000 steps, else about 2000 samples."""
    return 1 if step_count <= 2000 else math.ceil(step_count / 2000)


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
        progress: bool | None = False) -> RunResult:
    """Advance ``scene.state`` from t = 0 by ``steps`` accepted steps, or up to ``t_end`` s.

    Args:
        integrator: an integrator bound to ``scene.system``, or a registry name.
        dt: the step (s) of a fixed-step method; for an adaptive one the first step (None: the
            method chooses it).
        energy_every: sample the energy every this many accepted steps (0: never; None: every
            step for short runs, about 2000 samples for long ones). The first and last states
            are always sampled.
        progress: show a progress bar on stderr (None: only when stderr is a terminal).

    With ``t_end`` the last step is shortened to land exactly on it. The run stops at the
    first step whose status is not OK; the result's message says at which step and time.
    """
    if isinstance(integrator, str):
        integrator = create_integrator(integrator, scene.system)
    adaptive = integrator.adaptive
    check_run_args(dt, steps, t_end, adaptive=adaptive)
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
    has_energy = every > 0 and scene.energy() is not None

    energy, energy_t = [], []
    if has_energy:
        energy.append(scene.energy())
        energy_t.append(0.0)
    status, message = Status.OK, ""
    rejected = done = linear_iterations = 0
    linear_residual = 0.0
    t = 0.0
    start = time.perf_counter()
    if t_end is not None and expected is None:
        bar = tqdm(total=t_end, unit="s", disable=None if progress is None else not progress,
                   leave=False, mininterval=0.5, bar_format="{l_bar}{bar}| {n:.3g}/{total:.3g} s")
    else:
        bar = tqdm(total=expected, unit="step", disable=None if progress is None else not progress,
                   leave=False, mininterval=0.5)
    with bar:
        while (steps is not None and done < steps) or (steps is None and t < t_end):
            last = False
            if t_end is not None and t + h >= t_end * (1 - 1e-12):
                h, last = t_end - t, True
            report = integrator.step(scene.state, t, h)
            f_evals += report.f_evals
            linear_iterations += report.linear_iterations
            if integrator.implicit:
                linear_residual = report.linear_residual
            if report.status is not Status.OK:
                status = report.status
                detail = f" ({report.message})" if report.message else ""
                advice = ("loosen rtol/atol or use f64" if status is Status.STEP_TOO_SMALL
                          else "lower the step or pick a more stable integrator")
                reached = t + h if report.accepted else t  # a rejected attempt left the state at t
                message = (f"{status.value} at step {done + 1} (t = {reached:.6g} s) with "
                           f"{integrator.name}, h = {h:.3g} s{detail}: {advice}")
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
            if has_energy and (done % every == 0 or last or done == steps):
                e = scene.energy()
                if not math.isfinite(e):  # the state is finite but its squares overflow
                    status = Status.DIVERGED
                    message = (f"diverged at step {done} (t = {t:.6g} s) with {integrator.name}, "
                               f"h = {report.h:.3g} s (energy overflowed): lower the step or pick "
                               f"a more stable integrator")
                    break
                energy.append(e)
                energy_t.append(t)
            bar.update(report.h if (t_end is not None and expected is None) else 1)
            if adaptive:
                h = report.next_h
    wall = time.perf_counter() - start
    return RunResult(status=status, steps=done, t=t, f_evals=f_evals, rejected_steps=rejected,
                     linear_iterations=linear_iterations, linear_residual=linear_residual,
                     energy=np.asarray(energy, float), energy_t=np.asarray(energy_t, float),
                     message=message, wall_time=wall)
