"""A Runner steps one scene with one integrator, frame by frame, and freezes when it fails.

The launcher and the recorder own runners; the renderer only reads what a runner shows
(:attr:`Runner.display`): the scene's field while the run is healthy, the last finite state
after it diverged.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..integrators import Status, create_integrator, integrator_class
from ..render.drawer import DRAWABLE_LIMIT
from ..scene import build_scene
from ..scene.scene import Scene

ADVICE = "lower the step or pick a more stable integrator"

#: A run whose energy rises above its start by more than this many times the scene's energy
#: scale (see :func:`energy_scale`) has diverged, even while its numbers are still finite.
ENERGY_GROWTH_LIMIT = 100.0

#: Most integrator calls in one :meth:`Runner.advance` (an adaptive method crawling at tiny
#: steps must not freeze the window); the rest of that frame's simulated time is dropped.
MAX_CALLS_PER_ADVANCE = 100_000


class Runner:
    """One scene, one integrator, a step size, and the run's status.

    Args:
        scene: the scene to step (the runner owns its state from now on).
        integrator: registry name of the method.
        dt: the step (s): every step of a fixed-step method, the first of an adaptive one.

    Attributes:
        t: simulated time (s); steps: accepted steps; f_evals: evaluations of f.
        status: ``Status.OK`` while running; anything else froze the run.
        failure: what stopped the run ("diverged at t = 0.24 s (energy overflowed)"), else "";
            failed_at: the time (s) it names.
        message: ``failure`` with the advice (": lower the step or pick a more stable
            integrator"), else "".
        energy: total energy (J) at the last frame, or None when the system has none.
        sim_ms: wall time (ms) of the last :meth:`advance`.
        last_good: (n, 3) float64 positions of the last frame whose state was finite.
    """

    def __init__(self, scene: Scene, integrator: str, dt: float):
        self.scene = scene
        self.dt = float(dt)
        self._integrators: dict = {}  # bound once per method: scratch fields, compiled kernels
        self.set_integrator(integrator)
        self.restart()

    # -- configuration ------------------------------------------------------------------------

    @property
    def name(self) -> str:
        """The label shown for this run: its integrator's name."""
        return self.integrator.name

    def set_integrator(self, name: str) -> None:
        """Switch method (keeps the state and time; a frozen run stays frozen until reset).
        Each method is bound to the system once and reused when switched back to."""
        integrator_class(name)  # unknown names raise ConfigError before anything changes
        if name not in self._integrators:
            self._integrators[name] = create_integrator(name, self.scene.system)
        self.integrator = self._integrators[name]
        self.system_changed()  # a method switched back to may hold a stale f
        self._h_next = self.dt

    def set_dt(self, dt: float) -> None:
        """Change the step size (s) from the next step on."""
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a finite number > 0, got {dt}")
        self.dt = float(dt)
        self._h_next = self.dt

    def system_changed(self) -> None:
        """Call after changing a parameter of the running system (a stiffness, the wind):
        methods that cache f between steps forget it."""
        self.integrator.reset()

    def restart(self) -> None:
        """Back to t = 0 from the scene's current state (call after ``scene.reset()``)."""
        self.t = 0.0
        self.steps = 0
        self.f_evals = 0
        self.status = Status.OK
        self.failure = self.message = ""
        self.failed_at = 0.0
        self.sim_ms = 0.0
        self._pending = 0.0
        self._h_next = self.dt
        self.system_changed()  # the state jumped: a cached f is stale
        self.last_good = np.asarray(self.scene.state.x.to_numpy(), np.float64)
        self.energy = self.energy0 = self.scene.energy()
        self.energy_scale = energy_scale(self.scene, self.energy0)

    def reset(self) -> None:
        """Back to the initial state. A scene whose model changes while it runs (torn springs,
        emitted particles) is rebuilt with the same parameters (``scene`` is then a new object)."""
        f = self.scene.features
        if f.get("tearing") or f.get("emitter"):
            self.scene = build_scene(self.scene.name, self.scene.params, seed=self.scene.seed)
            name, self._integrators = self.integrator.name, {}
            self.set_integrator(name)
        else:
            self.scene.reset()
        self.restart()

    # -- running ------------------------------------------------------------------------------

    @property
    def frozen(self) -> bool:
        return self.status is not Status.OK

    @property
    def display(self):
        """What to draw: the scene's position field, or the last finite positions once frozen."""
        return self.last_good if self.frozen else self.scene.state.x

    def advance(self, duration: float) -> None:
        """Advance the simulated time by ``duration`` (s).

        A fixed-step method takes whole steps of ``dt`` (the remainder carries over to the next
        call, so ``dt`` is never changed); an adaptive one lands exactly on the end. Then the
        positions are checked: a non-finite or huge state, a non-finite energy or a failed
        step freezes the run on the last finite state with a one-line message.
        """
        if self.frozen or duration <= 0:
            return
        start = time.perf_counter()
        self._pending += duration
        calls = 0
        adaptive = self.integrator.adaptive
        while not self.frozen and calls < MAX_CALLS_PER_ADVANCE:
            if adaptive:
                if self._pending <= 1e-12 * max(1.0, self.t):
                    break
                h = min(self._h_next, self._pending)
            else:
                if self._pending < self.dt * (1.0 - 1e-9):
                    break
                h = self.dt
            report = self.integrator.step(self.scene.state, self.t, h)
            calls += 1
            self.f_evals += report.f_evals
            if report.status is not Status.OK:
                self._freeze(report.status, self.t + h, report.message)
                break
            if adaptive:
                self._h_next = report.next_h
            if not report.accepted:
                continue
            self.t += report.h
            self._pending -= report.h
            self.steps += 1
            if self.scene.after_step(self.t, report.h):
                self.system_changed()
        if calls >= MAX_CALLS_PER_ADVANCE:
            self._pending = 0.0
        if not self.frozen:
            self._check()
        self.sim_ms = 1e3 * (time.perf_counter() - start)

    def step_once(self) -> None:
        """One step: ``dt`` for a fixed-step method, the proposed step for an adaptive one
        (which, after a rejection, may take it in several accepted pieces)."""
        self._pending = 0.0
        self.advance(self._h_next if self.integrator.adaptive else self.dt)

    def _check(self) -> None:
        x = np.asarray(self.scene.state.x.to_numpy(), np.float64)
        with np.errstate(invalid="ignore", over="ignore"):
            ok = bool(np.all(np.abs(x) <= DRAWABLE_LIMIT))
        if not ok:
            self._freeze(Status.DIVERGED, self.t, "positions blew up")
            return
        energy = self.scene.energy()
        if energy is not None and not math.isfinite(energy):
            self._freeze(Status.DIVERGED, self.t, "energy overflowed")
        elif self.energy_scale is not None and energy - self.energy0 > ENERGY_GROWTH_LIMIT * self.energy_scale:
            self._freeze(Status.DIVERGED, self.t, "energy blew up")
        else:
            self.last_good = x
            self.energy = energy

    def _freeze(self, status: Status, t: float, detail: str) -> None:
        self.status = status
        self.failed_at = t
        detail = f" ({detail})" if detail else ""
        self.failure = f"{status.value.replace('_', ' ')} at t = {t:.4g} s{detail}"
        self.message = f"{self.failure}: {ADVICE}"


def energy_scale(scene: Scene, energy0: float | None) -> float | None:
    """A typical energy (J) of ``scene``: the larger of |E(0)| and total mass x |g| x size; None
    when the energy has no scale to grow from (no energy, or an emitter feeding in particles)."""
    if energy0 is None or scene.features.get("emitter"):
        return None
    x0 = np.asarray(scene.x0, np.float64)
    size = float(np.linalg.norm(np.ptp(x0, axis=0))) if len(x0) > 1 else float(np.linalg.norm(x0))
    arrays = scene.arrays
    weight = float(np.sum(arrays.get("mass", 0.0))) * float(np.linalg.norm(arrays.get("gravity", 0.0)))
    return max(abs(energy0), weight * size, 1e-12)
