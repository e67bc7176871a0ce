"""An integrator of your own, as a plug-in: velocity Verlet on the ``eval_f`` contract.

Run it from the command line without installing anything::

    taichi-sim simulate spring --integrator examples/plugin_velocity_verlet.py:VelocityVerlet \\
        --steps 1000 --out run.npz
    taichi-sim advise cloth --integrators examples/plugin_velocity_verlet.py:VelocityVerlet,rk4 --target-error 1e-3
    taichi-sim bench work-precision --quick --scenes spring \\
        --integrators examples/plugin_velocity_verlet.py:VelocityVerlet --out bench-out

or, with this folder on the Python path, as ``plugin_velocity_verlet:VelocityVerlet``; a package
can install it under the entry-point group ``taichi_sim.integrators`` (docs/plugins.md).

The method: with a(x, v) the acceleration the system's ``eval_f`` gives,

    x1 = x0 + h v0 + h^2 / 2 a(x0, v0)
    v1 = v0 + h / 2 (a(x0, v0) + a(x1, v0 + h a(x0, v0)))

Where the forces do not depend on the velocity this is exactly velocity Verlet (Swope et al.
1982): second order, symplectic, stable on an undamped oscillator of angular frequency omega
while h omega <= 2, energy bounded below that. Where they do (dashpots, drag, wind) the
velocity at which the second acceleration is taken is predicted with an Euler step, which
keeps the method second order (a plain velocity Verlet that reuses the half-step velocity
would drop to first order). Two evaluations of f per step.

Checklist for a method of your own (what this file does, and what the tools read):

1. Subclass :class:`taichi_sim.integrators.Integrator` and decorate it ``@ti.data_oriented``
   when it has kernels (Taichi reads their source, so the class must live in a real file).
2. Declare its facts as class attributes (a plug-in missing one is refused with one line;
   ``taichi_sim.integrators.missing_facts(cls)`` lists what is missing):
   ``name`` (not a built-in's), ``order`` (global order of accuracy; the work-precision bench
   measures it against this), ``description`` (one line, shown by ``taichi-sim list``),
   ``stability_constant`` (C with h_max = C / omega_max on an undamped oscillator; 0 if it
   grows at every step, then define ``amplification_squared``; ``math.inf`` if no step blows
   it up, then write ``advice_note``; None only when ``adaptive``), its scratch
   (``scratch_states``: copies of the state it allocates, or a ``scratch_bytes`` classmethod),
   and optionally ``f_evals_per_step``.
3. Declare its capabilities: ``requires_second_order`` (it reads velocities),
   ``takes_constraints`` (True only if it evaluates forces through ``eval_f`` alone),
   ``adaptive`` (then also ``initial_step``), ``implicit``.
4. Options are keyword-only arguments of ``__init__`` with defaults, each declared once there:
   ``damping: Annotated[float, Option("extra damping", unit="1/s", flag=True, at_least=0)] = 0.0``
   (``taichi_sim.integrators.Option``) gives it help, a ``simulate --damping`` flag and its
   checks; it also reaches ``__init__`` from ``--option NAME=VALUE`` (docs/plugins.md). This
   method has none.
5. Allocate all scratch in ``__init__`` (``system.make_state()``); ``step`` allocates nothing.
6. ``step(state, t, h)`` advances the caller's ``state`` in place and returns a
   :class:`~taichi_sim.integrators.StepReport` (accepted, h, next_h, f_evals, status). A step
   that produced non-finite values says ``Status.DIVERGED``; never return a silent NaN.
7. ``eval_f(y, t, out)`` writes the derivative of the state ``y`` it is given into ``out``
   (``out.x`` = velocity, ``out.v`` = acceleration; pinned particles get zero); never step
   the scene's state through anything else.
8. ``reset()`` forgets whatever is carried between steps (this method carries nothing).
9. ``bind_contact(inputs)``, only for a method whose solve meets the scene's contact itself:
   read it from ``inputs`` (``taichi_sim.scene.handoff.ContactInputs``) and return a
   ``ContactTakeover`` naming the parts whose post-step work the solve does (the scene leaves
   their events out). This method takes nothing (the default): the scene's colliders and
   self-collision stage run after each of its steps.
"""
import taichi as ti

from taichi_sim.integrators import Integrator, Status, StepReport
from taichi_sim.state import State, finite


@ti.data_oriented
class VelocityVerlet(Integrator):
    """Velocity Verlet with an Euler-predicted velocity for velocity-dependent forces (module
    docstring). Second order; stable while h omega_max <= 2."""

    name = "velocity_verlet"
    order = 2
    description = "velocity Verlet (plug-in example): second order, symplectic without damping"
    requires_second_order = True
    takes_constraints = True  # it only evaluates f, so constraint forces come through eval_f
    stability_constant = 2.0
    scratch_states = 3  # the two derivatives and the predicted state
    f_evals_per_step = 2.0

    def __init__(self, system):
        super().__init__(system)
        self.start = system.make_state()  # f at the start: (v0, a0)
        self.end = system.make_state()  # f at the predicted end: (v_pred, a1)
        self.predicted = system.make_state()

    def step(self, state: State, t: float, h: float) -> StepReport:
        self.system.eval_f(state, t, self.start)
        self._predict(state, h)
        self.system.eval_f(self.predicted, t + h, self.end)
        bad = self._finish(state, h)
        return StepReport(accepted=True, h=h, next_h=h, f_evals=2,
                          status=Status.OK if bad == 0 else Status.DIVERGED)

    @ti.kernel
    def _predict(self, y: ti.template(), h: float):
        for p in y.x:
            a0 = self.start.v[p]
            self.predicted.x[p] = y.x[p] + h * y.v[p] + 0.5 * h * h * a0
            self.predicted.v[p] = y.v[p] + h * a0

    @ti.kernel
    def _finish(self, y: ti.template(), h: float) -> ti.i32:
        bad = 0
        for p in y.x:
            x = self.predicted.x[p]
            v = y.v[p] + 0.5 * h * (self.start.v[p] + self.end.v[p])
            y.x[p] = x
            y.v[p] = v
            if not (finite(x) and finite(v)):
                bad += 1
        return bad
