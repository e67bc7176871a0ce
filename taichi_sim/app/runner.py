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

#: Most integrator calls in one :meth:`Runner.advance` (an adaptive method crawling at tiny
#: steps must not freeze the window); the rest of that frame's simulated time is dropped.
MAX_CALLS_PER_ADVANCE = 100_000


class Runner:
    """One scene, one integrator, a step size, and the run's status.

    Args:
        scene: the scene to step (the runner owns its state from now on).
        integrator: registry name of the method.
        dt: the step (s): every step of a fixed-step method, the first of an adaptive one.
        label: shown next to the scene (default: the integrator's name).

    Attributes:
        t: simulated time (s); steps: accepted steps; f_evals: evaluations of f.
        status: ``Status.OK`` while running; anything else froze the run.
        message: one line saying why the run froze ("diverged at t = ...: lower the step or
            pick a more stable integrator"), else "".
        energy: total energy (J) at the last frame, or None when the system has none.
        sim_ms: wall time (ms) of the last :meth:`advance`.
        last_good: (n, 3) float64 positions of the last frame whose state was finite.
    """

    def __init__(self, scene: Scene, integrator: str, dt: float, *, label: str | None = None):
        self.scene = scene
        self.label = label
        self.dt = float(dt)
        self.set_integrator(integrator)
        self.restart()

    # -- configuration ------------------------------------------------------------------------

    @property
    def name(self) -> str:
        """The label shown for this run."""
        return self.label or self.integrator.name

    def set_integrator(self, name: str) -> None:
        """Switch method (keeps the state and time; a frozen run stays frozen until reset)."""
        integrator_class(name)  # unknown names raise ConfigError before anything changes
        self.integrator = create_integrator(name, self.scene.system)
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
        if hasattr(self.integrator, "reset"):
            self.integrator.reset()

    def restart(self) -> None:
        """Back to t = 0 from the scene's current state (call after ``scene.reset()``)."""
        self.t = 0.0
        self.steps = 0
        self.f_evals = 0
        self.status = Status.OK
        self.message = ""
        self.sim_ms = 0.0
        self._pending = 0.0
        self._h_next = self.dt
        self.system_changed()  # the state jumped: a cached f is stale
        self.last_good = np.asarray(self.scene.state.x.to_numpy(), np.float64)
        self.energy = self.scene.energy()

    def reset(self) -> None:
        """Back to the initial state. A scene whose model changes while it runs (torn springs,
        emitted particles) is rebuilt with the same parameters (``scene`` is then a new object)."""
        f = self.scene.features
        if f.get("tearing") or f.get("emitter"):
            self.scene = build_scene(self.scene.name, self.scene.params, seed=self.scene.seed)
            self.set_integrator(self.integrator.name)
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
            self.scene.after_step(self.t, report.h)
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
        energy = self.scene.energy() if ok else None
        if ok and (energy is None or math.isfinite(energy)):
            self.last_good = x
            self.energy = energy
        else:
            self._freeze(Status.DIVERGED, self.t, "" if ok else "positions blew up")

    def _freeze(self, status: Status, t: float, detail: str) -> None:
        self.status = status
        what = status.value.replace("_", " ")
        detail = f" ({detail})" if detail else ""
        self.message = (f"{what} at t = {t:.4g} s{detail}: lower the step or pick a more "
                        f"stable integrator")
