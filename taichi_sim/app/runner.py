"""A Runner steps one scene with one integrator, frame by frame, and freezes when it fails.

The launcher and the recorder own runners; the renderer only reads what a runner shows
(:attr:`Runner.display`): the scene's field while the run is healthy, the last finite state
after it diverged. The steps themselves are a :class:`~taichi_sim.stepper.Stepper`'s.
"""
from __future__ import annotations

import time

import numpy as np

from ..integrators import integrator_class
from ..render.drawer import DRAWABLE_LIMIT
from ..scene.scene import Scene
from ..stepper import Stepper, bind_integrator
from .energy import EnergySample, EnergyTrace

#: Most integrator calls in one :meth:`Runner.advance` (an adaptive method crawling at tiny
#: steps must not freeze the window); the rest of that frame's simulated time is dropped.
MAX_CALLS_PER_ADVANCE = 100_000


class Runner:
    """One scene, one integrator, a step size, and the run's status.

    Args:
        scene: the scene to step (the runner owns its state from now on).
        integrator: registry name of the method.
        dt: the step (s): every step of a fixed-step method, the first of an adaptive one.
        options: integrator name -> its keyword options, used whenever that method is bound
            (over the scene's own, :func:`~taichi_sim.stepper.bind_integrator`).

    Attributes:
        stepper: the :class:`~taichi_sim.stepper.Stepper` that steps the scene; ``t``
            (simulated time, s), ``steps``, ``f_evals``, ``status``, ``guard``, ``integrator``,
            ``driver`` and ``dt`` are its.
        failure: what stopped the run ("diverged at t = 0.24 s (energy rose to ...)"), else "";
            failed_at: the time (s) it names.
        advice: what to do about it: the predicted stable step of an explicit method (or, for a
            stiff problem, to use an implicit one); "" while running.
        message: the stepper's one-line failure message (step, time, method, step size, detail,
            the state returned, advice); "" while running.
        energy: total energy (J) at the last frame, or None when the system has none.
        energy_trace: an :class:`~taichi_sim.app.energy.EnergyTrace` of the energy at every
            guard check that passed since the last restart (empty for a system without energy).
        drift: the largest |C| (m) of the scene's constraints at the last check, or None
            without constraints.
        residual: the relative solver residual of the last step sampled
            (:mod:`taichi_sim.convergence`), or None (a method that solves nothing per step, a
            scene it cannot measure, no sample yet); error_estimate: that step's estimated
            distance (m) from its equation's solution, or None; converged: whether that is
            within the tolerance (a method that promises the solved step freezes when it is not).
        sim_ms: wall time (ms) of the last :meth:`advance` that compiled nothing (0 before).
        compile_s: wall time (s) of the first advance with the current integrator, which
            compiles its kernels (and the scene's), or None before it; compiled_at: when that
            advance ended (``time.perf_counter()``), so the HUD can show it for a while.
        last_good: (n, 3) float64 positions of the last state that passed the blow-up guard
            (:mod:`taichi_sim.guard`, checked at the end of every frame) and could be drawn.
    """

    def __init__(self, scene: Scene, integrator: str, dt: float, options: dict | None = None):
        self.scene = scene
        integrator_class(integrator)  # unknown names raise ConfigError before anything is bound
        self._options = options or {}  # integrator name -> its keyword options
        self._integrators = {integrator: bind_integrator(scene, integrator, **self._options.get(integrator, {}))}
        self.energy_trace = EnergyTrace()
        self.stepper = Stepper(scene, self._integrators[integrator], dt, observers=(self,))
        self._compiled: set[str] = set()  # integrators that have stepped this scene (kernels built)
        self.compile_s: float | None = None
        self.compiled_at = 0.0
        self.restart()

    # -- what the launcher and the HUD read ---------------------------------------------------

    @property
    def name(self) -> str:
        """The label shown for this run: its integrator's name."""
        return self.stepper.integrator.name

    integrator = property(lambda self: self.stepper.integrator)
    guard = property(lambda self: self.stepper.guard)
    driver = property(lambda self: self.stepper.driver)
    dt = property(lambda self: self.stepper.dt)
    t = property(lambda self: self.stepper.t)
    steps = property(lambda self: self.stepper.steps)
    f_evals = property(lambda self: self.stepper.f_evals)
    status = property(lambda self: self.stepper.status)

    @property
    def residual(self) -> float | None:
        values = self.stepper.monitor.values
        return values[-1] if values else None

    @property
    def error_estimate(self) -> float | None:
        distances = self.stepper.monitor.distances
        return distances[-1] if distances else None

    @property
    def converged(self) -> bool:
        distance = self.error_estimate
        return distance is None or not self.stepper.monitor.exceeds(distance)

    @property
    def failure(self) -> str:
        failure = self.stepper.failure
        return "" if failure is None else failure.summary

    @property
    def failed_at(self) -> float:
        failure = self.stepper.failure
        return 0.0 if failure is None else failure.t

    @property
    def advice(self) -> str:
        failure = self.stepper.failure
        return "" if failure is None else failure.advice

    @property
    def message(self) -> str:
        failure = self.stepper.failure
        return "" if failure is None else failure.message

    # -- configuration ------------------------------------------------------------------------

    def set_integrator(self, name: str) -> None:
        """Switch method (keeps the state and time; a frozen run stays frozen until reset).
        Each method is bound to the system once and reused when switched back to."""
        integrator_class(name)  # unknown names raise ConfigError before anything changes
        if name not in self._integrators:
            self._integrators[name] = bind_integrator(self.scene, name, **self._options.get(name, {}))
        self.stepper.set_integrator(self._integrators[name])

    def set_dt(self, dt: float) -> None:
        """Change the step size (s) from the next step on (ConfigError for a bad one)."""
        self.stepper.set_dt(dt)

    def set_curves(self, curves: dict | None) -> None:
        """Drive parameters along ``curves`` (name -> Spline; None or empty: stop), from the
        current time on, one value per step (ConfigError for a parameter this scene cannot
        change while it runs)."""
        self.stepper.set_curves(curves)

    def system_changed(self) -> None:
        """Call after changing the running system from outside (a stiffness, the wind, the grab
        target): methods that cache f between steps forget it, and the blow-up guard takes the
        current state as its new reference (energy put in from outside is not a blow-up)."""
        self.stepper.system_changed()

    def restart(self) -> None:
        """Back to t = 0 from the scene's current state (call after ``scene.reset()``)."""
        self.stepper.restart()
        self.sim_ms = 0.0
        self._pending = 0.0
        self._grab_moves = self._grabber_moves()
        self.last_good = self.guard.last_good_positions()
        self.energy = self.guard.energy0
        self.energy_trace.clear()
        self._sample_energy()
        self.drift = self.scene.constraint_violation()

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
        return self.stepper.failure is not None

    @property
    def compiled(self) -> bool:
        """Whether the current method has stepped this scene (its kernels are built): the next
        :meth:`advance` compiles when not."""
        return self.name in self._compiled

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
        stepper = self.stepper
        self._pending += duration
        end = stepper.t + self._pending
        calls = stepper.advance_to(end, whole_steps=True, max_calls=MAX_CALLS_PER_ADVANCE)
        self._pending = 0.0 if calls >= MAX_CALLS_PER_ADVANCE else max(end - stepper.t, 0.0)
        now = time.perf_counter()
        if self.name in self._compiled:
            self.sim_ms = 1e3 * (now - start)
        else:  # the first frame compiles kernels: its time is not a cost per frame
            self._compiled.add(self.name)
            self.compile_s, self.compiled_at = now - start, now

    def step_once(self) -> None:
        """One step: ``dt`` for a fixed-step method, the proposed step for an adaptive one
        (which, after a rejection, may take it in several accepted pieces)."""
        self._pending = 0.0
        self.advance(self.stepper.h if self.stepper.adaptive else self.dt)

    def _grabber_moves(self) -> int:
        grabber = self.scene.grabber
        return -1 if grabber is None else grabber.moves

    def after_check(self, stepper: Stepper) -> str | None:
        """The stepper's hook after a check passed: keep what the HUD shows, or refuse a state
        too large to draw."""
        x = np.asarray(self.scene.state.x.to_numpy(), np.float64)
        with np.errstate(invalid="ignore", over="ignore"):
            if not np.all(np.abs(x) <= DRAWABLE_LIMIT):
                return "positions too large to draw"
        self.last_good = x
        self.energy = self.guard.health.energy
        self._sample_energy()
        self.drift = self.scene.constraint_violation()
        return None

    def _sample_energy(self) -> None:
        """Keep the energy of the check that just passed (no device work: the guard has it)."""
        health = self.guard.health
        if health is not None and health.energy is not None:
            self.energy_trace.add(EnergySample.from_health(self.t, health))
