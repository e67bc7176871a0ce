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
        steps: accepted steps taken; t: simulated time reached (s).
        f_evals: evaluations of f in total; rejected_steps: steps an adaptive method retried.
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
    energy: np.ndarray
    energy_t: np.ndarray
    message: str
    wall_time: float


def planned_steps(dt: float, steps: int | None, t_end: float | None) -> int:
    """Number of fixed steps to reach ``t_end`` (the last one shortened to land on it)."""
    if steps is not None:
        return steps
    return max(1, math.ceil(t_end / dt - 1e-9))


def default_energy_every(step_count: int) -> int:
    """Every step for runs up to 2000 steps, else about 2000 samples."""
    return 1 if step_count <= 2000 else math.ceil(step_count / 2000)


def check_run_args(dt: float, steps: int | None, t_end: float | None) -> None:
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise ConfigError(f"dt must be a finite number > 0, got {dt}")
    if (steps is None) == (t_end is None):
        raise ConfigError("give exactly one of steps or t_end")
    if steps is not None and (not isinstance(steps, int) or steps < 1):
        raise ConfigError(f"steps must be an integer >= 1, got {steps}")
    if t_end is not None and not (math.isfinite(t_end) and t_end > 0):
        raise ConfigError(f"t_end must be a finite number > 0, got {t_end}")


def run(scene: Scene, integrator: Integrator | str, *, dt: float, steps: int | None = None,
        t_end: float | None = None, energy_every: int | None = None,
        progress: bool | None = False) -> RunResult:
    """Advance ``scene.state`` from t = 0 by ``steps`` steps of ``dt`` s, or up to ``t_end`` s.

    Args:
        integrator: an integrator bound to ``scene.system``, or a registry name.
        energy_every: sample the energy every this many steps (0: never; None: every step for
            short runs, about 2000 samples for long ones). The first and last states are
            always sampled.
        progress: show a progress bar on stderr (None: only when stderr is a terminal).

    The run stops at the first step whose status is not OK; the result says which step and time.
    """
    check_run_args(dt, steps, t_end)
    if isinstance(integrator, str):
        integrator = create_integrator(integrator, scene.system)
    n_steps = planned_steps(dt, steps, t_end)
    every = default_energy_every(n_steps) if energy_every is None else int(energy_every)
    has_energy = every > 0 and scene.energy() is not None

    energy, energy_t = [], []

    def sample(t_now: float) -> None:
        energy.append(scene.energy())
        energy_t.append(t_now)

    if has_energy:
        sample(0.0)
    status, message = Status.OK, ""
    f_evals = rejected = done = 0
    t = 0.0
    start = time.perf_counter()
    bar = tqdm(total=n_steps, unit="step", disable=(None if progress is None else not progress),
               leave=False, mininterval=0.5)
    with bar:
        while done < n_steps:
            h = dt if t_end is None else min(dt, t_end - t)
            report = integrator.step(scene.state, t, h)
            f_evals += report.f_evals
            if report.status is not Status.OK:
                status = report.status
                message = (f"{status.value} at step {done + 1} (t = {t + h:.6g} s) with "
                           f"{integrator.name}, dt = {dt:g}: lower the step or pick a more stable integrator")
                break
            if not report.accepted:
                rejected += 1
                continue
            done += 1
            t = done * dt if t_end is None or done < n_steps else t_end
            scene.after_step(t, h)
            if has_energy and (done % every == 0 or done == n_steps):
                sample(t)
            bar.update(1)
    wall = time.perf_counter() - start
    return RunResult(status=status, steps=done, t=t, f_evals=f_evals, rejected_steps=rejected,
                     energy=np.asarray(energy, float), energy_t=np.asarray(energy_t, float),
                     message=message, wall_time=wall)
