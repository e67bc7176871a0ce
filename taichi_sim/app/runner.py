"""A Runner steps one scene with one integrator, frame by frame, and freezes when it fails.

The launcher and the recorder own runners; the renderer only reads what a runner shows
(:attr:`Runner.display`): the scene's field while the run is healthy, the last finite state
after it diverged.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..convergence import ConvergenceMonitor
from ..guard import Guard
from .energy import EnergySample, EnergyTrace
from ..integrators import Status, create_integrator, integrator_class
from ..render.drawer import DRAWABLE_LIMIT
from ..scene.scene import Scene
from ..theory import stable_step_advice

ADVICE = "lower the step or pick a more stable integrator"

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
        failure: what stopped the run ("diverged at t = 0.24 s (energy rose to ...)"), else "";
            failed_at: the time (s) it names.
        advice: what to do about it: the predicted stable step of an explicit method (or, for a
            stiff problem, to use an implicit one), then ADVICE; "" while running.
        message: ``failure``, the method and step, and ``advice``, in one line; "" while running.
        energy: total energy (J) at the last frame, or None when the system has none.
        energy_trace: an :class:`~taichi_sim.app.energy.EnergyTrace` of the energy at every
            guard check that passed since the last restart (empty for a system without energy).
        drift: the largest |C| (m) of the scene's constraints at the last check, or None
            without constraints.
        residual: the relative residual of the last step measured (:mod:`taichi_sim.convergence`:
            at the guard's checks and the last step of each frame), or None for a method that
            solves nothing per step (or a scene it cannot measure); converged: whether it is
            within the bound (a method that promises the exact step freezes when it is not).
        sim_ms: wall time (ms) of the last :meth:`advance`.
        last_good: (n, 3) float64 positions of the last state that passed the blow-up guard
            (:mod:`taichi_sim.guard`, checked at the end of every frame).
    """

    def __init__(self, scene: Scene, integrator: str, dt: float):
        self.scene = scene
        self.dt = float(dt)
        self._integrators: dict = {}  # bound once per method: scratch fields, compiled kernels
        self.driver = None  # a CurveDriver when curves drive the scene's parameters
        self.energy_trace = EnergyTrace()
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
        self.integrator.reset()  # a method switched back to may hold a stale f
        self.monitor = ConvergenceMonitor(self.scene, self.integrator)
        self.residual = None
        self._h_next = self.dt

    def set_dt(self, dt: float) -> None:
        """Change the step size (s) from the next step on."""
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a finite number > 0, got {dt}")
        self.dt = float(dt)
        self._h_next = self.dt

    def set_curves(self, curves: dict | None) -> None:
        """Drive parameters along ``curves`` (name -> Spline; None or empty: stop), from the
        current time on, one value per step (ConfigError for a parameter this scene cannot
        change while it runs)."""
        from ..curves import CurveDriver

        if self.driver is not None:
            self.driver.detach()
            self.driver = None
        if curves:
            self.driver = CurveDriver(self.scene, curves)
            if self.driver.apply(self.t):
                self.system_changed()

    def system_changed(self) -> None:
        """Call after changing the running system from outside (a stiffness, the wind, the grab
        target): methods that cache f between steps forget it, and the blow-up guard takes the
        current state as its new reference (energy put in from outside is not a blow-up)."""
        self.integrator.reset()
        if not self.frozen:
            self.guard.rebase(self.t, self.steps)

    def restart(self) -> None:
        """Back to t = 0 from the scene's current state (call after ``scene.reset()``)."""
        self.t = 0.0
        self.steps = 0
        self.f_evals = 0
        self.status = Status.OK
        self.failure = self.message = self.advice = ""
        self.failed_at = 0.0
        self.sim_ms = 0.0
        self._pending = 0.0
        self._h_next = self.dt
        if self.driver is not None:
            self.driver.restart()
            self.driver.apply(0.0)
        self.integrator.reset()  # the state jumped: a cached f is stale
        self.guard = Guard(self.scene)
        self._grab_moves = self._grabber_moves()
        self.last_good = self.guard.last_good_positions()
        self.energy = self.guard.energy0
        self.energy_trace.clear()
        self._sample_energy()
        self.drift = self.scene.constraint_violation()
        self.residual = None

    @property
    def converged(self) -> bool:
        return self.residual is None or not self.monitor.exceeds(self.residual)

    def reset(self) -> None:
        """Back to the scene as built (torn springs mended, emitted particles gone), in place:
        nothing is allocated or compiled again."""
        self.scene.restore()
        for integrator in self._integrators.values():
            integrator.reset()  # a solver may hold a factorisation of the torn topology
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
        call, so ``dt`` is never changed); an adaptive one lands exactly on the end. The blow-up
        guard checks the state whenever enough work was done and at the end: a failed step or a
        failed check freezes the run on the last good state with a one-line message.
        """
        if self.frozen or duration <= 0:
            return
        if self._grabber_moves() != self._grab_moves:
            self._grab_moves = self._grabber_moves()
            self.system_changed()  # the user moved the pull: its work is not a blow-up
        start = time.perf_counter()
        self._pending += duration
        calls = 0
        adaptive = self.integrator.adaptive
        guard, monitor = self.guard, self.monitor
        driver, forces_changed = self.driver, False
        while not self.frozen and calls < MAX_CALLS_PER_ADVANCE:
            if adaptive:
                if self._pending <= 1e-12 * max(1.0, self.t):
                    break
                h = min(self._h_next, self._pending)
            else:
                if self._pending < self.dt * (1.0 - 1e-9):
                    break
                h = self.dt
            if driver is not None and driver.apply(self.t):
                self.integrator.reset()
                forces_changed = True
            if monitor.active:
                monitor.before_step(self.scene.state)
            report = self.integrator.step(self.scene.state, self.t, h)
            calls += 1
            self.f_evals += report.f_evals
            if report.status is not Status.OK:
                if report.status is Status.DIVERGED:
                    guard.restore()
                self._freeze(report.status, self.t + h, report.message, h)
                break
            if adaptive:
                self._h_next = report.next_h
            if not report.accepted:
                continue
            self.t += report.h
            self._pending -= report.h
            self.steps += 1
            due = guard.spend(report.f_evals + report.linear_iterations)
            frame_ends = self._pending < (1e-12 * max(1.0, self.t) if adaptive else self.dt * (1.0 - 1e-9))
            if monitor.active and (due or frame_ends) and not self._converged_step(report.h):
                break
            if self.scene.after_step(self.t, report.h):
                self.integrator.reset()
            if due and not self._check(report.h):
                break
        if calls >= MAX_CALLS_PER_ADVANCE:
            self._pending = 0.0
        if not self.frozen and guard.work:
            self._check(self.dt)
        if forces_changed and not self.frozen:
            guard.rebase(self.t, self.steps)  # the curves put that energy in, not a blow-up
        self.sim_ms = 1e3 * (time.perf_counter() - start)

    def step_once(self) -> None:
        """One step: ``dt`` for a fixed-step method, the proposed step for an adaptive one
        (which, after a rejection, may take it in several accepted pieces)."""
        self._pending = 0.0
        self.advance(self._h_next if self.integrator.adaptive else self.dt)

    def _converged_step(self, h: float) -> bool:
        """Measure the step that just ended (before the post-step events move the state);
        freezes a method that promises the exact step when it did not converge. False then."""
        self.residual = self.monitor.measure(self.scene.state, self.t, h)
        if self.monitor.exceeds(self.residual) and self.monitor.promises_exact:
            self._freeze(Status.NOT_CONVERGED, self.t, self.monitor.breach_message(self.residual, self.t), h)
            return False
        return True

    def _grabber_moves(self) -> int:
        grabber = self.scene.grabber
        return -1 if grabber is None else grabber.moves

    def _check(self, h: float) -> bool:
        """Guard check of the current state; freezes the run on a breach. True when it passed."""
        breach = self.guard.check(self.t, self.steps)
        if breach is None:
            x = self.guard.last_good_positions()
            with np.errstate(invalid="ignore", over="ignore"):
                drawable = bool(np.all(np.abs(x) <= DRAWABLE_LIMIT))
            if drawable:
                self.last_good = x
                self.energy = self.guard.health.energy
                self._sample_energy()
                self.drift = self.scene.constraint_violation()
                return True
            breach_detail = "positions too large to draw"
        else:
            breach_detail = breach.detail
        self.guard.restore()
        self._freeze(Status.DIVERGED, self.t, breach_detail, h)
        return False

    def _sample_energy(self) -> None:
        """Keep the energy of the check that just passed (no device work: the guard has it)."""
        health = self.guard.health
        if health is not None and health.energy is not None:
            self.energy_trace.add(EnergySample.from_health(self.t, health))

    def _freeze(self, status: Status, t: float, detail: str, h: float) -> None:
        self.status = status
        self.failed_at = t
        detail = f" ({detail})" if detail else ""
        self.failure = f"{status.value.replace('_', ' ')} at t = {t:.4g} s{detail}"
        advice = ""
        if status is Status.DIVERGED:
            advice = stable_step_advice(self.scene, self.integrator.name)
        elif status is Status.STIFF:
            advice = "the problem is stiff: use an implicit method (implicit_euler)"
        self.advice = f"{advice}: {ADVICE}" if advice else ADVICE
        self.message = f"{self.failure} with {self.integrator.name}, h = {h:.3g} s; {self.advice}"
