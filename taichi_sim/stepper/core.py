"""The :class:`Stepper`: a scene, an integrator, the blow-up guard and the curves, stepped in
the house order, and the one loop that advances time (:meth:`Stepper.run_until`)."""
from __future__ import annotations

from .. import interrupt, runtime
from ..convergence import ConvergenceMonitor, format_metres
from ..errors import ConfigError
from ..guard import Guard, GuardLimits
from ..integrators import Integrator, Status, StepReport, integrator_class
from ..scene.handoff import NOTHING_TAKEN
from .binding import bind_integrator, check_dt
from .failure import Failure, failure_advice


def work_options(integrator) -> tuple:
    """The (option, cap) pairs a tolerance raises, in order (the integrator's ``work_options``,
    else its one ``work_option`` and ``work_cap``)."""
    options = getattr(integrator, "work_options", None)
    if options is not None:
        return tuple(options)
    option = getattr(integrator, "work_option", "")
    return ((option, integrator.work_cap),) if option else ()

#: Work that brings a step's estimated error down by less than this factor has stalled (the
#: Stepper stops raising it, :meth:`Stepper._converged`).
STALLED = 0.7
OK = Status.OK  # a module global: read at every step


def _never_due(work: float) -> bool:
    """A bare Stepper's guard schedule: no check is ever due."""
    return False


class Stepper:
    """Steps ``scene.state`` with one integrator, watched by a :class:`~taichi_sim.guard.Guard`.

    Args:
        scene: the scene to step (the stepper owns its state from now on).
        integrator: an integrator bound to ``scene.system``, or a registry name (bound with the
            scene's options for it, :func:`bind_integrator`).
        dt: the step (s) of a fixed-step method; for an adaptive one the first step (None: the
            method picks it at the first step).
        limits: the guard's limits (default :class:`~taichi_sim.guard.GuardLimits`).
        curves: parameter name -> :class:`~taichi_sim.curves.Spline` driving the scene from t = 0.
        observers: objects with any of ``before_step(stepper, h)`` (just before the integrator
            call), ``after_step(stepper, report)`` (after an accepted step and its guard check)
            and ``after_check(stepper) -> str | None`` (after the guard passed the state, before
            it becomes the last good one; a string refuses it: the run ends DIVERGED with that
            detail, on the state before).
        max_residual: bound on the sampled relative residual (recorded; see
            :mod:`taichi_sim.convergence`).
        tolerance: how far (m) a step's positions may be from the solution of the equation the
            method solves (default :data:`~taichi_sim.convergence.DEFAULT_TOLERANCE`). A sampled
            step past it is solved again with more work (the method's
            :attr:`~taichi_sim.integrators.Integrator.work_option`, unless the caller set that
            option: iterations or substeps doubled, a Newton tolerance divided by ten) until it
            is within the tolerance, the option reaches its cap, or a change brings the estimate
            down by less than ``STALLED`` (the option then goes back to its value before); then a
            method that promises the solved step ends the run NOT_CONVERGED and a fixed-work one
            warns once and goes on.
        raise_work: False keeps the method's work as it was set (benchmarks that measure a
            method at its settings); past the tolerance it then only warns or fails.
        bare: step the method as it is, for the benchmarks that measure its bare step (its
            stable step, its kernels' times): no guard (nothing is checked, so ``check`` and
            :meth:`check` are refused, and a failed run leaves the state where the failed step
            left it), no convergence sampling, no raising of work, no refusal for precision.
            Everything else is as in every run: the method bound to the scene's contact, the
            curves, the post-step events, the observers, :meth:`run_until`.

    Attributes:
        t: simulated time (s); steps: accepted steps; rejected: steps an adaptive method retried.
        h: the next step (s): ``dt``, or the adaptive method's proposal.
        f_evals, linear_iterations: work in total; linear_residual: that of the last solve.
        guard: the :class:`~taichi_sim.guard.Guard` (None when ``bare``).
        checked: whether the guard checked (and passed) the state after the last accepted step.
        failure: a :class:`Failure` once the run stopped, else None; ``status`` its status (OK
            while running).
    """

    def __init__(self, scene, integrator: Integrator | str, dt: float | None, *,
                 limits: GuardLimits | None = None, curves: dict | None = None, observers=(),
                 max_residual: float | None = None, tolerance: float | None = None, raise_work: bool = True,
                 bare: bool = False):
        if isinstance(integrator, str):  # a bad dt is refused before anything is bound
            check_dt(dt, adaptive=integrator_class(integrator).adaptive)
            integrator = bind_integrator(scene, integrator)
        self.scene = scene
        self.dt = check_dt(dt, adaptive=integrator.adaptive)
        self.bare = bool(bare)
        self.guard = None if self.bare else Guard(scene, limits)
        self.max_residual = max_residual
        self.tolerance = tolerance
        self.raise_work = raise_work and not self.bare
        self._stopping = False  # an observer asked run_until to end (stop)
        self._step_start = None  # the whole step's start, kept while the work may be raised
        self._attempt = None  # a step's result before it was solved again with more work
        # bound once: each attribute lookup is paid at every step
        self._events = scene.after_step
        self._spend = _never_due if self.bare else self.guard.spend
        self.driver = None
        self._before, self._after, self._on_check = (), (), ()  # tuples: a hook may remove itself
        self._monitors: dict[int, tuple] = {}  # id(integrator) -> (integrator, its monitor)
        for observer in observers:
            self.add_observer(observer)
        self.set_integrator(integrator)
        self.restart()
        if curves:
            self.set_curves(curves)

    # -- configuration ------------------------------------------------------------------------

    _HOOKS = (("before_step", "_before"), ("after_step", "_after"), ("after_check", "_on_check"))

    def add_observer(self, observer) -> None:
        """Call ``observer``'s hooks (see the class docstring) from now on."""
        for hook, calls in self._HOOKS:
            if hasattr(observer, hook):
                setattr(self, calls, (*getattr(self, calls), getattr(observer, hook)))

    def remove_observer(self, observer) -> None:
        """Stop calling ``observer``'s hooks (also from inside one of them: the hooks of the
        step under way are still called)."""
        for hook, calls in self._HOOKS:
            if hasattr(observer, hook):
                setattr(self, calls, tuple(h for h in getattr(self, calls) if h != getattr(observer, hook)))

    def set_integrator(self, integrator: Integrator) -> None:
        """Step with ``integrator`` (bound to the scene's system) from the current state on."""
        if self.dt is None and not integrator.adaptive:
            raise ConfigError("dt is required for a fixed-step integrator")
        # The handoff (scene/handoff.py): the scene offers its contact, the method answers what
        # its solve took over, and the scene leaves that out of its post-step events (an object
        # stepping like an integrator without deriving from one takes nothing).
        bind = getattr(integrator, "bind_contact", None)
        self.scene.hand_over(NOTHING_TAKEN if bind is None else bind(self.scene.contact_inputs()))
        self.integrator = integrator
        # read once: an attribute of a Taichi data-oriented object costs about a microsecond
        self._integrate = integrator.step
        self.adaptive, self.implicit = integrator.adaptive, integrator.implicit
        integrator.reset()  # a method switched back to may hold a stale f
        # How far each step is from the equation the method solves (convergence.py); a method
        # that promises the solved step on a scene its precision cannot resolve is refused.
        # One monitor per method, kept: each holds a State, and a new one per switch back and
        # forth (the launcher) would allocate a field and compile its copy kernel every time.
        entry = self._monitors.get(id(integrator))
        if entry is None or entry[0] is not integrator:
            entry = self._monitors[id(integrator)] = (integrator, ConvergenceMonitor(
                self.scene, integrator, self.max_residual, self.tolerance,
                unmeasured="a bare Stepper measures nothing" if self.bare else ""))
        self.monitor = entry[1]
        self.monitor.clear()
        self.refusal = self.monitor.check_precision(self.scene.state, runtime.precision(),
                                                    runtime.machine_epsilon())
        self.warnings: list[str] = []
        self.h = self.dt
        # The option whose work --tolerance may raise: the method's, unless the caller set it
        # (``--iterations N`` means exactly N).
        given = getattr(integrator, "given_options", ())
        self._work_options = tuple((name, cap) for name, cap in work_options(integrator) if name not in given) \
            if self.raise_work and self.monitor.active else ()
        self.work_option = self._work_options[0][0] if self._work_options else ""
        if self.work_option and self._step_start is None:
            self._step_start = self.scene.system.make_state()

    def set_dt(self, dt: float) -> None:
        """Step ``dt`` (s) from the next step on (an adaptive method's next proposal)."""
        self.dt = check_dt(dt, adaptive=self.adaptive)
        self.h = self.dt
        self._base_t, self._base_steps = self.t, self.steps

    def set_curves(self, curves: dict | None) -> None:
        """Drive parameters along ``curves`` (name -> Spline; None or empty: stop) from the
        current time on (ConfigError for a parameter the scene cannot change while it runs)."""
        from ..curves import CurveDriver

        if self.driver is not None:
            self.driver.detach()
            self.driver = None
        if curves:
            self.driver = CurveDriver(self.scene, curves)
            if self.driver.apply(self.t):
                self.system_changed()

    def system_changed(self) -> None:
        """Call after changing the running system from outside (a parameter, the wind, the grab
        target): the integrator forgets what it carries between steps, and the guard takes the
        current state as its new reference (energy put in from outside is not a blow-up)."""
        self.integrator.reset()
        if self.failure is None and self.guard is not None:
            self.guard.rebase(self.t, self.steps)

    def restart(self) -> None:
        """Back to t = 0 from the scene's current state (after ``scene.reset()`` or
        ``scene.restore()``): counters cleared, the guard re-based, the curves from their start."""
        self.t = 0.0
        self.steps = self.rejected = self.f_evals = self.linear_iterations = 0
        self.linear_residual = 0.0
        self.failure, self.status, self.checked = None, Status.OK, False
        self.h = self.dt
        self._base_t, self._base_steps = 0.0, 0  # fixed steps: t = base_t + (steps - base_steps) dt
        if self.driver is not None:
            self.driver.restart()
            self.driver.apply(0.0)
        self.integrator.reset()  # the state jumped: a cached f is stale
        if self.guard is not None:
            self.guard.rebase(0.0, 0)
        self.monitor.clear()
        self.warnings = []

    # -- stepping -----------------------------------------------------------------------------

    def step(self, h: float | None = None, check: bool = False, land: float | None = None) -> StepReport:
        """One integrator call from :attr:`t` of ``h`` s (default :attr:`h`) and everything after
        it (module docstring). ``check``: check the state after it even when the guard is not
        due. ``land``: the time an accepted step of the full ``h`` ends at (the caller shortened
        ``h`` to reach it), used instead of t + h. Returns the integrator's report; a step
        that fails sets :attr:`failure`."""
        if h is None:
            h = self.h if self.h is not None else self._first_step(None)
        t = self.t
        if self.driver is not None and self.driver.apply(t):  # 1. parameters at the start
            self.system_changed()
        if self.refusal:
            self.fail(Status.NOT_CONVERGED, self.steps + 1, t, h, self.refusal, restore=False)
            return StepReport(accepted=False, h=0.0, next_h=h, f_evals=0, status=Status.NOT_CONVERGED,
                              message=self.refusal)
        for hook in self._before:  # 2.
            hook(self, h)
        monitor = self.monitor
        if monitor.active:
            monitor.before_step(self.scene.state)
            if self.work_option:
                self._step_start.copy_from(self.scene.state)
        report = self._integrate(self.scene.state, t, h)  # 3.
        self.f_evals += report.f_evals
        self.linear_iterations += report.linear_iterations
        if self.implicit:
            self.linear_residual = report.linear_residual
        if report.status is not OK:  # 4.
            self._step_failed(report, h)
            return report
        if self.adaptive:
            self.h = report.next_h
        if not report.accepted:
            self.rejected += 1
            return report
        self.steps += 1  # 5. an accepted step
        if land is not None and report.h == h:
            self.t = land
            self._base_t, self._base_steps = land, self.steps
        elif self.adaptive or h != self.dt:
            self.t = t + report.h
            self._base_t, self._base_steps = self.t, self.steps
        else:
            self.t = self._base_t + (self.steps - self._base_steps) * h  # no drift over many steps
        work = report.f_evals + report.linear_iterations
        due = self._spend(work) or check
        # The step's distance from its equation is the method's: measured before the post-step
        # events move the state.
        if monitor.active:
            monitor.spend(work)
            # Before the guard judges a state by its energy, a method whose work the tolerance
            # may raise has the step sampled when that energy is past the guard's bound: an
            # unsolved stiff spring holds k C^2 / 2 (0.1 mm at k = 1e8 N/m: 0.5 J), so the
            # estimate, not the energy, tells whether the step is off; if it is, the step is
            # solved again with more work, and the guard judges that.
            sample = check or monitor.due() or (due and self.work_option and self._energy_past_bound())
            if sample and not self._converged(t, report.h):
                return report
        if self._events(self.t, report.h):
            self.integrator.reset()  # an event changed the system (e.g. tore springs)
        if due:
            self.check(report.h)
        else:
            self.checked = False
        if self._after and self.failure is None:  # 6.
            for hook in self._after:
                hook(self, report)
        return report

    def step_toward(self, t_end: float, check: bool = False) -> StepReport:
        """:meth:`step`, shortened to land exactly on ``t_end`` (s) when it would reach it."""
        h = self.h if self.h is not None else self._first_step(t_end)
        if self.t + h >= t_end * (1 - 1e-12):
            return self.step(t_end - self.t, check, t_end)
        return self.step(h, check)

    def run_until(self, *, steps: int | None = None, t_end: float | None = None, check_every: int = 0,
                  check_last: bool = False, whole_steps: bool = False, max_calls: int | None = None) -> int:
        """The stepping loop, the only one: step until :attr:`steps` reaches ``steps``, or
        :attr:`t` reaches ``t_end`` (s), or ``max_calls`` integrator calls were made (the
        only bound when neither is given), or the run fails, or an observer calls
        :meth:`stop`; returns the calls made. What a caller does at each step is an observer's
        ``after_step`` (:func:`taichi_sim.run` keeps its energy trace, frames and progress bar
        that way); what it does at the end, after this returns.

        Up to ``t_end`` the last step is shortened to land on it; with ``whole_steps`` a
        fixed-step method takes only whole steps of ``dt`` (the rest is left for a later call).
        ``check_every``: the guard also checks the state after every ``check_every``-th
        accepted step (0: only when due). ``check_last``: the step that reaches ``steps`` or
        ``t_end`` is checked inside it (the method's own result is measured before the
        post-step events move it). A Ctrl-C that Taichi swallowed while compiling is raised
        between steps (:func:`taichi_sim.interrupt.check`)."""
        if steps is not None and t_end is not None:
            raise ConfigError("give at most one of steps and t_end")
        if steps is None and t_end is None and max_calls is None:
            raise ConfigError("give steps, t_end or max_calls")
        whole = whole_steps and not self.adaptive and t_end is not None
        step, step_toward, interrupted = self.step, self.step_toward, interrupt.check
        calls = 0
        self._stopping = False
        while self.failure is None and not self._stopping and (max_calls is None or calls < max_calls):
            if steps is not None:
                if self.steps >= steps:
                    break
            elif whole:
                if t_end - self.t < self.dt * (1.0 - 1e-9):
                    break
            elif t_end is not None and not self.t < t_end:
                break
            interrupted()
            check = check_every > 0 and (self.steps + 1) % check_every == 0
            if t_end is None or whole:
                step(self.dt if whole else None,
                     check or (check_last and steps is not None and self.steps + 1 >= steps))
            else:
                step_toward(t_end, check or (check_last and self.t + (self.h or 0.0) >= t_end * (1 - 1e-12)))
            calls += 1
        return calls

    def stop(self) -> None:
        """End :meth:`run_until` after the step under way (an observer's way out: a time
        budget spent)."""
        self._stopping = True

    def advance_to(self, t_end: float, *, whole_steps: bool = False, max_calls: int | None = None) -> int:
        """:meth:`run_until` ``t_end`` (s); then the state is checked when work was done since
        the last check. Returns the calls made."""
        calls = self.run_until(t_end=t_end, whole_steps=whole_steps, max_calls=max_calls)
        if self.failure is None and self.guard is not None and self.guard.work:
            self.check()
        return calls

    def advance(self, duration: float, **options) -> int:
        """:meth:`advance_to` ``t + duration``."""
        return self.advance_to(self.t + duration, **options)

    def check(self, h: float | None = None) -> bool:
        """Check the current state now (the guard, then observers' ``after_check``); a state
        that fails ends the run DIVERGED on the last good one. ``h``: the step named in the
        failure (default :attr:`h`). True when it passed. ConfigError on a bare Stepper (it has
        no guard)."""
        if self.guard is None:
            raise ConfigError("a bare Stepper has no guard: it checks nothing")
        hooks = self._on_check
        breach = self.guard.check(self.t, self.steps, keep=not hooks)
        detail = None if breach is None else breach.detail
        if detail is None and hooks:
            for hook in hooks:
                detail = hook(self)
                if detail:
                    break
            if not detail:
                self.guard.keep(self.t, self.steps)
        self.checked = not detail
        if detail:
            self.fail(Status.DIVERGED, self.steps, self.t, self.h if h is None else h, detail, restore=True)
        return self.checked

    def _converged(self, t0: float, h: float) -> bool:
        """Sample the step of ``h`` s from ``t0`` that just ended. Past the tolerance, solve it
        again with more work while the method's work option may grow (the class docstring);
        then a method that promises the solved step ends the run NOT_CONVERGED (False), a
        fixed-work one warns once (:attr:`warnings`) and goes on."""
        monitor = self.monitor
        value, distance = monitor.measure(self.scene.state, self.t, h)
        stopped = ""
        while monitor.exceeds(distance) and not stopped:
            before = getattr(self.integrator, self.work_option) if self.work_option else None
            if not self._raise_work():
                if self.work_option:
                    stopped = f"stopped at the cap of {self.work_option} = {before}"
                    if self._next_work_option():
                        stopped = ""
                        continue
                break
            if self._attempt is None:
                self._attempt = self.scene.system.make_state()
            self._attempt.copy_from(self.scene.state)  # kept in case more work lands farther
            self.scene.state.copy_from(self._step_start)
            self.integrator.reset()
            report = self._integrate(self.scene.state, t0, h)
            self.f_evals += report.f_evals
            self.linear_iterations += report.linear_iterations
            if report.status is not OK or not report.accepted:
                self._step_failed(report, h)
                return False
            earlier, earlier_value = distance, value
            monitor.forget_last()
            value, distance = monitor.measure(self.scene.state, self.t, h)
            # (a count only: a Newton test tightened tenfold may take no further iteration)
            if isinstance(before, int) and monitor.exceeds(distance) and not distance <= STALLED * earlier:
                # more work hardly helps (sweeps on a stiff cloth): go back to the work before
                # rather than pay for more on every step to come
                now = getattr(self.integrator, self.work_option)
                setattr(self.integrator, self.work_option, before)
                stopped = (f"{self.work_option} {before} -> {now} moved the estimate only from "
                           f"{format_metres(earlier)} to {format_metres(distance)}, so it stays at {before}")
                if distance > earlier:  # farther: the step solved with the work before stands
                    self.scene.state.copy_from(self._attempt)
                    monitor.forget_last()
                    monitor.record(self.t, earlier_value, earlier)
                    distance, value = earlier, earlier_value
                if self._next_work_option():  # the method's next kind of work may help
                    stopped = ""
        if not monitor.exceeds(distance):
            return True
        if monitor.promises_exact:
            self.fail(Status.NOT_CONVERGED, self.steps, self.t, h, monitor.breach_message(distance, self.t),
                      restore=False)
            return False
        if not monitor.warned:
            monitor.warned = True
            self.warnings.append(monitor.warning_message(distance, self.t, stopped))
        return True

    def _energy_past_bound(self) -> bool:
        """Whether the state's energy is past the guard's bound (what its check would call a
        blow-up)."""
        guard = self.guard
        if guard.scale is None:
            return False
        energy = self.scene.system.health(self.scene.state, guard.center).energy
        return energy is not None and not energy <= guard.energy_bound(self.t)[0]

    def _next_work_option(self) -> bool:
        """Move on to the method's next work option (:func:`work_options`) for this and later
        steps; False when there is none."""
        names = [name for name, _ in self._work_options]
        following = names.index(self.work_option) + 1 if self.work_option in names else len(names)
        if following >= len(names):
            return False
        self.work_option = names[following]
        return True

    def _raise_work(self) -> bool:
        """Double the method's work count, or divide its relative tolerance by ten, up to its
        cap; False when it is there."""
        option = self.work_option
        if not option:
            return False
        value = getattr(self.integrator, option)
        cap = dict(self._work_options)[option]
        if isinstance(value, int):
            if value >= cap:
                return False
            setattr(self.integrator, option, min(cap, 2 * value))
        else:
            if value <= cap:
                return False
            setattr(self.integrator, option, max(cap, value / 10))
        return True

    def fail(self, status: Status, step: int, t: float, h: float, detail: str, *, restore: bool) -> None:
        """End the run with ``status`` at ``step`` (time ``t`` s, step size ``h`` s); with
        ``restore`` put the last state that passed the guard back into the scene."""
        good_step = good_t = None
        if restore and self.guard is not None:
            self.guard.restore()
            good_step, good_t = self.guard.good_step, self.guard.good_t
            self.t, self.steps = good_t, good_step
            self._base_t, self._base_steps = good_t, good_step
        self.status = status
        self.failure = Failure(status, step, t, self.integrator.name, h, detail or "", good_step, good_t,
                               failure_advice(self.scene, self.integrator.name, status))

    def _step_failed(self, report: StepReport, h: float) -> None:
        status, detail = report.status, report.message
        failed_step, failed_t = self.steps + 1, (self.t + h if report.accepted else self.t)
        if status is not Status.DIVERGED and self.guard is not None and self.guard.work:
            # The failed attempt left the state at t: check what the steps since the last check
            # made of it (it may have blown up before the method gave up).
            breach = self.guard.check(self.t, self.steps)
            if breach is not None:
                status, detail = Status.DIVERGED, breach.detail
        # A diverged state may hold non-finite values: put back the last good one.
        self.fail(status, failed_step, failed_t, h, detail, restore=status is Status.DIVERGED)

    def _first_step(self, t_end: float | None) -> float:
        """An adaptive method's first step (s) when none was given (costs its f evaluations)."""
        self.h = self.integrator.initial_step(self.scene.state, self.t, t_end)
        self.f_evals += self.integrator.initial_step_f_evals
        return self.h
