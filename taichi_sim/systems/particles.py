"""Particle systems: Newton's second law for particles under composable force terms."""

import numpy as np
import taichi as ti

from .. import runtime
from ..forces.base import ForceTerm
from ..loops import anchor
from ..state import State, finite
from .base import Health, System
from .implicit_api import ImplicitAPI


def _given(hook) -> bool:
    # "is not" is not allowed inside a kernel, even under ti.static
    return hook is not None


@ti.data_oriented
class ParticleSystem(ImplicitAPI, System):
    """dx/dt = v, dv/dt = F(x, v, t) / m, with F the sum of the force terms.

    Pinned particles have zero derivative (they neither move nor accelerate), whatever their
    forces.

    Args:
        mass: (n,) particle masses in kg, all > 0.
        pinned: (n,) bool.
        active: (n,) bool, default all: an inactive particle (a dead sprinkler slot) is frozen
            like a pinned one until an event activates it (``free`` field).
        terms: force terms (see :class:`taichi_sim.forces.ForceTerm`); more may be added with
            :meth:`add_term` before the first evaluation (one kernel sums them, compiled then).

    Constraints (:class:`~taichi_sim.systems.constraints.Constraints`, set with
    :meth:`set_constraints` before the first evaluation) are a stage after the sum: every
    kernel that evaluates forces then gathers each particle's applied force Q first, solves
    for the multipliers at the same state and adds Jᵀ λ. Without them no field exists and no
    kernel contains the stage.
    """

    second_order = True

    def __init__(self, mass: np.ndarray, pinned: np.ndarray, terms: list[ForceTerm] = (),
                 active: np.ndarray | None = None):
        mass = np.asarray(mass, dtype=float).reshape(-1)
        pinned = np.asarray(pinned, dtype=bool).reshape(-1)
        if len(mass) != len(pinned):
            raise ValueError("mass and pinned must have the same length")
        if not np.all(mass > 0):
            raise ValueError("mass must be > 0 for every particle")
        self.particle_count = n = len(mass)
        self.mass_np = mass
        self.pinned_np = pinned
        self.terms = []
        self.serial_loops = False
        for term in terms:
            self.add_term(term)
        self.constraints = None
        self._launchers: dict[tuple, object] = {}
        self.mass = ti.field(runtime.real(), shape=n)
        self.free = ti.field(ti.i32, shape=n)
        moving = ~pinned if active is None else (~pinned & np.asarray(active, bool).reshape(n))
        self._upload(mass.astype(runtime.np_real()), moving.astype(np.int32))

    @ti.kernel
    def _upload(self, mass: ti.types.ndarray(ndim=1), free: ti.types.ndarray(dtype=ti.i32, ndim=1)):
        for i in range(self.particle_count):
            self.mass[i] = mass[i]
            self.free[i] = free[i]

    def add_term(self, term: ForceTerm) -> None:
        """Add a force term; only before the first eval_f (its kernel is compiled then)."""
        self.terms.append(term)
        # springs whose pass is serial anyway (a grid's) leave only the per-particle gather to
        # the loops chosen here, so they do not count: on the development machine a grid cloth's
        # symplectic Euler step with serial loops against parallel took 1057 against 1541 us at
        # 256 x 256 and 4987 against 6350 at 512 x 512 (benchmarks/bench_serial_loops.py)
        springs = sum(getattr(t, "spring_count", 0) for t in self.terms if not getattr(t, "serial_pass", False))
        # one thread where hand-off costs more than the second thread gives (runtime.SERIAL_WORK)
        self.serial_loops = runtime.serial_loops(self.particle_count + springs)
        for t in self.terms:  # their whole-system passes (precompute) follow the system's choice
            t.serial_loops = self.serial_loops

    def set_constraints(self, constraints) -> None:
        """Add the constraint stage; only before the first eval_f (compiled into its kernels).
        The implicit and positional methods refuse a constrained system (see
        :attr:`~taichi_sim.integrators.Integrator.takes_constraints`)."""
        self.constraints = constraints

    def constraint_violation(self, y: State) -> float:
        """The largest |C| (m) over the constraints at ``y``; 0 without constraints."""
        return 0.0 if self.constraints is None else self.constraints.violation(y)

    def term(self, name: str) -> ForceTerm | None:
        """The force term called ``name`` (``"gravity"``, ``"drag"``, ``"springs"``), if any."""
        return next((t for t in self.terms if t.name == name), None)

    def eval_f(self, y: State, t: float, out: State) -> None:
        self._launcher(("eval_f", y, out), lambda: self._bind_eval_f(y, out))(t)

    def _launcher(self, key: tuple, bind):
        """The kernel bound to the objects in ``key`` (made by ``bind()`` the first time).

        The hot kernels (a force evaluation, a fused step) are closures over the states they
        work on, taking only floats: a method kernel with template arguments costs about
        100 us of Python per call on the development machine, a closure about 50, which is a
        fifth of a symplectic Euler step at 64 x 64. Each binding compiles once; the closure
        keeps its objects alive, so their ids stay theirs."""
        ids = tuple(id(k) if not isinstance(k, str) else k for k in key)
        launch = self._launchers.get(ids)
        if launch is None:
            launch = self._launchers[ids] = bind()
        return launch

    def _bind_eval_f(self, y, out):
        system = self

        @ti.kernel
        def eval_f(t: float):
            system._eval_f_body(y, out, t)

        return eval_f

    @ti.func
    def _precompute(self, y):
        """Every term's whole-system pass (see :attr:`ForceTerm.precomputes`); call at the top
        level of a kernel, before the loop that sums the forces at the same ``y``."""
        for term in ti.static(self.terms):
            if ti.static(term.precomputes):
                term.precompute(y)

    @ti.func
    def _summed_force(self, i, y, mass_i, t):
        """The net force on i (N), in a kernel that ran :meth:`_precompute` at ``y`` first."""
        f = ti.Vector.zero(y.x.dtype, 3)
        for term in ti.static(self.terms):
            if ti.static(term.precomputes):
                f += term.precomputed_force(i, y, mass_i, t)
            else:
                f += term.force(i, y, mass_i, t)
        return f

    @ti.func
    def _prepare(self, y, t):
        """Everything a force evaluation at ``y`` does before the per-particle loop: the
        precomputes and, with constraints, the applied forces Q and the constraint solve. Call
        at the top level of a kernel; then :meth:`_net_force` gives each particle's force."""
        self._precompute(y)
        if ti.static(_given(self.constraints)):
            for i in y.x:
                f = ti.Vector.zero(y.x.dtype, 3)
                if self.free[i]:
                    f = self._summed_force(i, y, self.mass[i], t)
                self.constraints.applied[i] = f
            self.constraints.solve(y, self.mass, self.free)

    @ti.func
    def inverse_mass(self, i):
        """1 / mass (1/kg) of particle i; 0 for a pinned one, which nothing moves."""
        inv = 0.0 * self.mass[i]
        if self.free[i]:
            inv = 1.0 / self.mass[i]
        return inv

    @ti.func
    def _net_force(self, i, y, mass_i, t):
        """The net force on free particle i (N), constraint force included, in a kernel that
        ran :meth:`_prepare` at the same ``y`` (with constraints it reads only particle i)."""
        f = ti.Vector.zero(y.x.dtype, 3)
        if ti.static(_given(self.constraints)):
            f = self.constraints.applied[i] + self.constraints.force[i]
        else:
            f = self._summed_force(i, y, mass_i, t)
        return f

    @ti.func
    def _derivative(self, i, y, out, t, accelerations_only: ti.template() = False):
        """out's entry i: (v_i, F_i / m_i), zero when i is pinned (after :meth:`_prepare`);
        with ``accelerations_only``, F_i / m_i into ``out.v`` and nothing into ``out.x``."""
        if self.free[i]:
            m = self.mass[i]
            if ti.static(not accelerations_only):
                out.x[i] = y.v[i]
            out.v[i] = self._net_force(i, y, m, t) / m
        else:
            if ti.static(not accelerations_only):
                out.x[i] = ti.Vector.zero(y.x.dtype, 3)
            out.v[i] = ti.Vector.zero(y.x.dtype, 3)

    @ti.func
    def _eval_f_body(self, y, out, t, accelerations_only: ti.template() = False):
        self._prepare(y, t)
        if ti.static(self.serial_loops):
            ti.loop_config(serialize=True)
            for _ in range(1):
                self._anchor(y, out)
                for i in range(self.particle_count):
                    self._derivative(i, y, out, t, accelerations_only)
        else:
            for i in range(self.particle_count):
                self._derivative(i, y, out, t, accelerations_only)

    @ti.func
    def _anchor(self, y, out):
        """Anchor (:mod:`taichi_sim.loops`) every field the per-particle force loop reads or
        writes whose term declares it: the states, the masses and every term's
        :attr:`~taichi_sim.forces.ForceTerm.anchored_fields`. A field left out only costs a
        re-read of its base address per particle."""
        for field in ti.static((y.x, y.v, out.x, out.v, self.mass, self.free)):
            anchor(field)
        for term in ti.static(self.terms):
            for field in ti.static(term.anchored_fields()):
                anchor(field)

    def eval_f_stages(self, plan, t: float, h: float) -> None:
        """Every force evaluation of a Runge-Kutta step, with the step's bookkeeping, in one
        kernel launch (compiled once per ``plan``).

        ``plan`` (see :class:`~taichi_sim.integrators.explicit_rk.StagePlan`) gives
        ``inputs`` and ``outputs`` (a state of this system's shape each, per stage), ``c``
        (each stage's time as a fraction of ``h``) and ``@ti.func after(s, h)``, with top-level
        loops of its own, run once stage s's accelerations, the v part of
        f(inputs[s], t + c[s] h), are in ``outputs[s].v`` (its x part, the input's velocity or
        zero, is left for the plan to rebuild); ``after`` writes the next stage's input or,
        last, the new state. Each loop finishes before the next starts, so ``after`` may
        write any state. One launch per step saves what each kernel call costs on a CPU
        (about 35 us here)."""
        self._launcher(("stages", plan), lambda: self._bind_stages(plan))(t, h)

    def _bind_stages(self, plan):
        system = self

        @ti.kernel
        def eval_f_stages(t: float, h: float):
            system._stages_body(plan, t, h)

        return eval_f_stages

    @ti.func
    def _stages_body(self, plan: ti.template(), t, h):
        for s in ti.static(range(len(plan.inputs))):
            stage_time = t + ti.static(plan.c[s]) * h
            self._eval_f_body(plan.inputs[s], plan.outputs[s], stage_time, True)
            plan.after(s, h)

    def sums_locally(self) -> bool:
        """Whether, after the precompute, particle i's force reads no other particle's state,
        so a kernel may move each particle as soon as its force is summed. With constraints
        every force is gathered before that loop (:meth:`_prepare`), so it always does."""
        if self.constraints is not None:
            return True
        return all(term.precomputes or not term.reads_other_particles for term in self.terms)

    def symplectic_euler_step(self, y: State, t: float, h: float, scratch: State) -> None:
        """One symplectic Euler step of ``y`` in place (v += h F/m, then x += h v), in one
        kernel launch and without reading anything back: the same arithmetic as
        :meth:`eval_f` followed by the update (the same result up to how the compiler fuses
        multiply-adds).
        ``scratch``'s ``v`` holds the accelerations when a term reads other particles after
        its precompute (wind), so that no particle moves before every force is summed."""
        self._launcher(("symplectic", y, scratch), lambda: self._bind_symplectic(y, scratch))(t, h)

    def _bind_symplectic(self, y, scratch):
        system = self

        @ti.kernel
        def symplectic_euler(t: float, h: float):
            system._symplectic_body(y, scratch, t, h)

        return symplectic_euler

    @ti.func
    def _symplectic_body(self, y, scratch, t, h):
        self._prepare(y, t)
        if ti.static(self.sums_locally() and self.serial_loops):
            ti.loop_config(serialize=True)
            for _ in range(1):
                self._anchor(y, y)
                for i in range(self.particle_count):
                    self._symplectic_update(i, y, t, h)
        elif ti.static(self.sums_locally()):
            for i in range(self.particle_count):
                self._symplectic_update(i, y, t, h)
        else:
            ti.loop_config(serialize=self.serial_loops)
            for i in range(self.particle_count):
                if self.free[i]:
                    scratch.v[i] = self._net_force(i, y, self.mass[i], t) / self.mass[i]
            ti.loop_config(serialize=self.serial_loops)
            for i in range(self.particle_count):
                v = y.v[i]
                if self.free[i]:
                    v += h * scratch.v[i]
                    y.v[i] = v
                y.x[i] += h * v

    @ti.func
    def _symplectic_update(self, i, y, t, h):
        v = y.v[i]
        if self.free[i]:
            v += h * (self._net_force(i, y, self.mass[i], t) / self.mass[i])
            y.v[i] = v
        y.x[i] += h * v

    def forces(self, y: State, out: ti.Field, t: float = 0.0) -> None:
        """Net force (N) on every particle at ``y`` and time ``t`` (s) into a (n,) vec3 field;
        zero when pinned."""
        self._forces(y, out, t)

    @ti.kernel
    def _forces(self, y: ti.template(), out: ti.template(), t: float):
        self._prepare(y, t)
        for i in y.x:
            f = ti.Vector.zero(y.x.dtype, 3)
            if self.free[i]:
                f = self._net_force(i, y, self.mass[i], t)
            out[i] = f

    def kinetic_energy(self, y: State) -> float:
        return float(self._kinetic(y))

    @ti.kernel
    def _kinetic(self, y: ti.template()) -> float:
        total = 0.0
        for i in y.v:
            total += 0.5 * self.mass[i] * y.v[i].norm_sqr()
        return total

    def energy(self, y: State) -> float:
        """Kinetic plus the potential energy of every conservative term (J)."""
        total = self.kinetic_energy(y)
        for term in self.terms:
            e = term.energy(y)
            if e is not None:
                total += e
        return total

    def health(self, y: State, center) -> Health:
        """:class:`Health` of ``y`` in one kernel: a gather over the particles of the non-finite
        count, the farthest distance from ``center``, the kinetic energy, the potential energy
        each term attributes to each particle (the springs' and gravity's also apart), and the
        springs' largest strain. The kernel is a closure over ``y`` (see :meth:`_launcher`):
        the blow-up guard calls it about once per hundred steps, where a method kernel's
        Python cost was a tenth of a 64 x 64 cloth's check."""
        nonfinite, farthest2, kinetic, potential, spring_energy, gravity_energy, strain = self._launcher(
            ("health", y), lambda: self._bind_health(y))(float(center[0]), float(center[1]), float(center[2]))
        return Health(nonfinite=int(nonfinite), farthest=float(farthest2) ** 0.5,
                      energy=float(kinetic) + float(potential), kinetic=float(kinetic),
                      spring_energy=float(spring_energy), gravity_energy=float(gravity_energy),
                      max_strain=float(strain))

    def _bind_health(self, y):
        system = self

        @ti.kernel
        def health(cx: float, cy: float, cz: float) -> (ti.i32, float, float, float, float, float, float):
            return system._health_body(y, cx, cy, cz)

        return health

    @ti.func
    def _health_body(self, y, cx, cy, cz):
        bad = 0
        farthest2 = 0.0
        kinetic = 0.0
        potential = 0.0
        spring_energy = 0.0
        gravity_energy = 0.0
        worst = 0.0
        c = ti.Vector([cx, cy, cz])
        ti.loop_config(serialize=self.serial_loops)
        for i in range(self.particle_count):
            if finite(y.x[i]) and finite(y.v[i]):
                ti.atomic_max(farthest2, (y.x[i] - c).norm_sqr())
                kinetic += 0.5 * self.mass[i] * y.v[i].norm_sqr()
                free_i = self.free[i]
                for term in ti.static(self.terms):
                    if ti.static(hasattr(term, "energy_and_strain")):
                        pass  # summed over the whole system below
                    elif ti.static(hasattr(term, "energy_and_strain_at")):
                        u, strain = term.energy_and_strain_at(i, y)
                        potential += u
                        spring_energy += u
                        ti.atomic_max(worst, strain)
                    elif ti.static(hasattr(term, "energy_at")):
                        u = term.energy_at(i, y, free_i)
                        potential += u
                        if ti.static(term.name == "gravity"):
                            gravity_energy += u
            else:
                bad += 1
        for term in ti.static(self.terms):
            # a term that sums its energy and strain over the whole system in one pass
            if ti.static(hasattr(term, "energy_and_strain")):
                u, strain = term.energy_and_strain(y)
                potential += u
                spring_energy += u
                worst = ti.max(worst, strain)
        return bad, farthest2, kinetic, potential, spring_energy, gravity_energy, worst

    def potential_energy(self, y: State) -> float:
        """Potential energy (J) of every conservative term at ``y``."""
        return float(sum(e for e in (term.energy(y) for term in self.terms) if e is not None))

    def dissipation(self, y: State) -> float:
        """Rayleigh dissipation function (W) of every dissipative term at ``y`` (see
        :meth:`ForceTerm.dissipation`)."""
        return float(sum(r for r in (term.dissipation(y) for term in self.terms) if r is not None))
