"""What :func:`taichi_sim.run` keeps beside the steps, each an observer of the
:class:`~taichi_sim.stepper.Stepper` (its ``after_step`` hook, called after every accepted
step that did not end the run): the energy trace, the saved frames, the progress bar and the
clock that leaves the first step's compiling out of the rate."""
from __future__ import annotations

import math
import time

import numpy as np

SAMPLES = 2000  # energy samples of a long run


def default_energy_every(step_count: int) -> int:
    """The fewest steps between default energy samples: at most about 2000 samples a run."""
    return 1 if step_count <= SAMPLES else math.ceil(step_count / SAMPLES)


class EnergyTrace:
    """The energy (J) at the guard's checks, thinned, and for a scene with constraints the
    largest |C| (m) beside each sample.

    Args:
        stepper: the run's stepper (its guard computes the energy at each check).
        every: sample at most every this many accepted steps (>= 1).
        forced: ``every`` was asked for: the steps it names are sampled (the run checks them).
        interval: for an adaptive run to an end time with no step count, sample at most once
            per this many seconds of simulated time instead (None: by steps).
    """

    def __init__(self, stepper, every: int, forced: bool, interval: float | None):
        self.watch, self.scene = stepper.guard, stepper.scene
        self.every, self.forced, self.interval = every, forced, interval
        self.next_sample, self.last_sample = interval, 0
        self.energy: list[float] = []
        self.times: list[float] = []
        self.violation = [] if self.scene.constraints is not None else None

    def sample(self, t: float) -> None:
        """Keep the energy the guard's last check computed, at time ``t`` (s)."""
        self.energy.append(self.watch.health.energy)
        self.times.append(t)
        if self.violation is not None:
            self.violation.append(self.scene.constraint_violation())

    def after_step(self, stepper, report) -> None:
        if not stepper.checked:  # a sample costs what a check does: samples are taken at checks
            return
        done, t = stepper.steps, stepper.t
        if self.forced:
            keep = done % self.every == 0
        elif self.interval is None:
            keep = done - self.last_sample >= self.every
        else:
            keep = t >= self.next_sample * (1 - 1e-12)
            if keep:
                self.next_sample = (math.floor(t / self.interval + 1e-9) + 1) * self.interval
        if keep:
            self.sample(t)
            self.last_sample = done

    def arrays(self, t_final: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Energies (J), their times (s) and the constraint violations (m, or None) up to
        ``t_final`` (a diverged run's trace ends at the state it returns)."""
        times = np.asarray(self.times, float)
        kept = times <= t_final
        violation = None if self.violation is None else np.asarray(self.violation, float)[kept]
        return np.asarray(self.energy, float)[kept], times[kept], violation


class FrameHistory:
    """Frames of a run's positions every ``every`` accepted steps, copied from the device as
    they are kept, with where the scene's objects (spheres, capsules, boxes, a collider mesh:
    the parts with ``centers_at``) were then."""

    def __init__(self, scene, every: int):
        self.scene, self.every = scene, every
        self.frames: list[np.ndarray] = []
        self.times: list[float] = []
        self.centers: list[dict[str, np.ndarray]] = []

    def after_step(self, stepper, report) -> None:
        if stepper.steps % self.every == 0:
            self.keep(stepper.t)

    def keep(self, t: float) -> None:
        if self.times and self.times[-1] == t:
            return  # the end of a run that ends on a saving step
        self.frames.append(np.asarray(self.scene.state.x.to_numpy(), np.float64))
        self.times.append(t)
        self.centers.append(self.scene.object_centers(t))

    def arrays(self, t_final: float) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """The frames up to ``t_final`` (a diverged run ends at the state it returns), with
        that state last; their times; ``{key}_history`` (S, K, 3) of each object centre key."""
        times = np.asarray(self.times, float)
        kept = times <= t_final
        frames = [f for f, k in zip(self.frames, kept) if k]
        centers = [c for c, k in zip(self.centers, kept) if k]
        times = times[kept]
        if not len(times) or times[-1] != t_final:
            frames.append(np.asarray(self.scene.state.x.to_numpy(), np.float64))
            centers.append(self.scene.object_centers(t_final))
            times = np.append(times, t_final)
        objects = {f"{key}_history": np.stack([c[key] for c in centers]) for key in (centers[0] if centers else {})}
        return np.stack(frames), times, objects


class ProgressBar:
    """A tqdm bar on stderr over the steps, or over simulated time (s) for a run to an end time
    with no step count; ``shown``: None only when stderr is a terminal. A hidden bar
    (``hidden``) needs no observing."""

    def __init__(self, steps: int | None, t_end: float | None, shown: bool | None):
        from tqdm import tqdm

        self.by_time = steps is None
        disable = None if shown is None else not shown
        if self.by_time:
            self.bar = tqdm(total=t_end, unit="s", disable=disable, leave=False, mininterval=0.5,
                            bar_format="{l_bar}{bar}| {n:.3g}/{total:.3g} s")
        else:
            self.bar = tqdm(total=steps, unit="step", disable=disable, leave=False, mininterval=0.5)
        self.update = self.bar.update  # bound once: read at every step
        self.hidden = bool(self.bar.disable)

    def after_step(self, stepper, report) -> None:
        self.update(report.h if self.by_time else 1)

    def close(self) -> None:
        self.bar.close()


class WarmClock:
    """When the first accepted step ended, and the error estimate's seconds until then: the
    rate after it leaves the first step's compiling out. It watches that one step only."""

    def __init__(self, monitor):
        self.monitor = monitor
        self.warm: float | None = None
        self.estimated = 0.0

    def after_step(self, stepper, report) -> None:
        self.warm, self.estimated = time.perf_counter(), self.monitor.seconds
        stepper.remove_observer(self)
