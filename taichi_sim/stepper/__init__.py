"""The one stepping core: a scene, an integrator, the blow-up guard and the curves, stepped in
the house order, and the one loop that advances time.

Every path that steps a scene goes through :class:`Stepper`: :func:`taichi_sim.run` (and
through it ``simulate``, ``advise``, the benchmarks), the launcher's and the recorder's
:class:`~taichi_sim.app.runner.Runner`, the throughput workers, the stability bench (a bare
Stepper) and the tests that step a scene by hand. One call of :meth:`Stepper.step` is one integrator call and everything after it:

1. the curves set the parameters for the step's start (a force change resets the integrator
   and re-bases the guard: energy put in from outside is not a blow-up);
2. observers' ``before_step`` (nothing else runs between them and the integrator);
3. ``integrator.step``;
4. a failed step ends the run here (:meth:`Stepper._step_failed`);
5. an accepted step: the time, the scene's post-step events (``scene.after_step``, less the
   parts the integrator took over in its own solve; the integrator forgets what it carries
   when they changed the system), the guard's work count
   and, when due or asked for, its check (a failed check ends the run on the last good state);
6. observers' ``after_step``.

:meth:`Stepper.run_until` repeats it until a step count, an end time or a number of calls:
the only loop that advances time. A caller's work at each step (a run's energy trace, saved
frames and progress bar: :mod:`taichi_sim.run_observers`; the launcher's HUD; a benchmark's
clock) is an observer's, not a loop of its own.

Binding a method to the scene is one handoff each way (:mod:`taichi_sim.scene.handoff`):
``scene.hand_over(integrator.bind_contact(scene.contact_inputs()))``: the scene offers its
contact (ground, shapes, collider mesh, self-collision stage, scripted pins, thickness), the
method answers what its solve took over, and the scene applies that to its own parts.

A bare Stepper (``bare=True``) steps the method as it is, for the benchmarks that measure
its bare step (its stable step, its kernels' times): no guard, no convergence sampling, no
raising of work; the same loop, events and observers.

A run that fails is frozen: :attr:`Stepper.failure` says what, where and what to do, in one
place (:class:`Failure`), and the scene holds the last state that passed the guard whenever
the state may be garbage.

The parts: :mod:`.core` (the Stepper and its loop), :mod:`.binding` (an integrator bound to a
scene, the step it may take), :mod:`.failure` (why a run stopped, the advice).
"""
from .binding import bind_integrator, check_dt
from .core import STALLED, Stepper
from .failure import ADVICE, Failure, failure_advice

__all__ = ["Stepper", "Failure", "bind_integrator", "check_dt", "failure_advice", "ADVICE", "STALLED"]
