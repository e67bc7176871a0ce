"""Vertex block descent: backward Euler by Gauss-Seidel over the vertices, one 3x3 Newton step
each."""

import math
from typing import Annotated

import numpy as np
import taichi as ti

from .... import field_io, runtime
from ....scene.handoff import ContactInputs, ContactTakeover
from ....state import finite
from ....systems.base import System
from ...base import Integrator, Status, StepReport
from ...equation import FIXED_WORK, Equation
from ...options import Option
from ..chebyshev import ChebyshevHistory, chebyshev_weight
from ..colouring import colour_vertices
from .active import SKIP_MOVE_FLOOR, active_set
from .contact_model import solve_forces
from .energy import EnergyCap
from .kernels import bind_kernels, serial_sweeps
from .membranes import MembraneTerms
from .pieces import FAILURES, PACE_SHARE, PieceSchedule
from .setup import ContactSetup, contact_setup
from .springs import SpringTerms


@ti.data_oriented
class VBD(Integrator):
    """Vertex block descent (Chen, Liu, Yang & Yuksel 2024, "Vertex Block Descent").

    A step of h seconds (``substeps`` pieces of dt = h / substeps) minimises backward Euler's
    incremental potential over the new positions x,

        G(x) = |x - x0 - dt v0|_M^2 / (2 dt^2) + U(x) + dt R(x, (x - x0) / dt),

    one vertex at a time: vertex i takes one Newton step on its own block of G's gradient,

        r_i = m_i (x_i - x0_i - dt v0_i) / dt^2 - f_i(x, v),   v = (x - x0) / dt,
        H_i = m_i / dt^2 I - df_i/dx_i - df_i/dv_i / dt,       x_i -= H_i^-1 r_i,

    with every force term of the scene (gravity, drag, springs with their dashpots, the grab, a
    membrane and its bending: :mod:`.membranes`) at the iterate, as
    :class:`~taichi_sim.integrators.ImplicitEuler` takes them, each spring's and element's 3x3
    block kept positive semi-definite. The vertices are coloured once so that no two of a colour
    share a term (:func:`colour_vertices`); a sweep solves one colour after the other, each one
    parallel loop (Gauss-Seidel). ``iterations`` sweeps per substep.

    Where a sweep starts: with ``warm_start`` the paper's adaptive initialisation, x0 + dt v0 +
    dt^2 a, a the last substep's acceleration projected on gravity and clamped between 0 and g;
    else x0 + dt v0; or x0 (V = 0) where that has the lower G: a guess that stretches stiff
    springs by more energy than the motion carries is not one a few sweeps undo.
    ``chebyshev_rho`` > 0 over-relaxes each sweep with Chebyshev weights (Wang 2015; the paper's
    acceleration) for that estimated spectral radius.

    What it converges to: with enough sweeps, the exact backward Euler step of dt (r = 0 for
    every vertex, dashpots included). With few a stiff cloth lags behind it (docs/vbd.md); the
    work is as set unless a run's tolerance raises it (:attr:`work_options`).

    Args:
        system: a particle system (second order).
        iterations: Gauss-Seidel sweeps per substep (>= 1, default 20).
        substeps: substeps per step (>= 1, default 1).
        warm_start: start from the adaptive initialisation (default) or from x0 + dt v0.
        chebyshev_rho: 0 (off, default) or Chebyshev's spectral radius estimate in (0, 1).
        augmented: springs in the augmented form of :meth:`~.springs.SpringTerms.augmented_tension` (after Giles,
            Diaz & Yuksel 2025, "Augmented Vertex Block Descent"); off by default.
        penalty: the augmented form's penalty rho at the start of each substep (N/m, > 0).
        penalty_growth: its ramp: rho grows by this times |C| after each sweep (N/m^2, >= 0).
        The contact in the solve (:mod:`.setup`; the manual: docs/vbd-contact.md):
        contact: the scene's objects in the solve as contact energies (default True).
        self_contact: the cloth against itself in the solve: None (default) where the scene has
            a self-collision stage, which the solve then takes over (:attr:`takeover`); True on
            any scene (a stage still runs after each step); False never.
        contact_radius: contact radius (m, > 0); None: the scene's ``thickness``.
        contact_stiffness: the penalty's stiffness in units of the vertex's m / dt^2 (> 0).
        bound_fraction: a vertex's move cap, a fraction of its distance to its nearest contact,
            in (0, 0.5).
        friction_epsilon: the slip speed (m/s) below which friction is smoothed (IPC's eps_v).
        contact_refresh: sweeps between self-contact detections; 0 (default): once a piece.
        contact_pieces: with self-contact, the most pieces (default 16) a substep is cut into
            so that the start guesses of all but ``pace_share`` (default 0.005) of the free
            vertices stay within their bounds, the others cut to them (:mod:`.pieces`).
        object_faces: the cloth's triangles against the objects and a collider mesh's sharp
            features too (:mod:`.faces`, :mod:`.mesh_faces`; default True).
        energy_cap: without contact in the solve, on a closed scene, shorten a substep that
            would end with more energy (J) than it started with (:mod:`.energy`; default True).
        skip_move: with self-contact and serial sweeps, a vertex whose last step and its
            neighbours' since moved at most this far (m) is passed by (:mod:`.active`; 1e-5).
    """

    name = "vbd"
    plot_colour = "#393b79"  # in the benchmarks' plots
    # its solve holds the membrane's triangles and the bending stencils too (membranes.py)
    takes_elastic_models = True
    order = 1
    requires_second_order = True
    description = "vertex block descent: backward Euler by per-vertex Newton steps, Gauss-Seidel over a colouring"
    equation = Equation("backward_euler", FIXED_WORK,
                        advice="raise --iterations or --substeps, or lower --dt")
    # Under a --tolerance substeps, not sweeps: a substep of dt / 2 has a quarter of k dt^2 / m,
    # where sweeps stall on stiff cloth (docs/integrators.md); with self-contact, work_options.
    work_option, work_cap = "substeps", 64
    work_note = ("with self-contact in its solve, first --option pace_share divided by ten to none, then "
                 "skip_move to 1e-7")
    tracks_solved_start = True
    # No step-size limit: each sweep lowers the incremental potential at any step. An unconverged
    # step may still gain energy, which the energy cap takes back on closed scenes (energy.py).
    stability_constant = math.inf
    advice_note = ("no step-size limit; on stiff springs (k >= 1e6) its per-vertex sweeps leave the cloth "
                   "lagging behind the exact step, and an unconverged step is damped by the energy cap "
                   "(docs/vbd.md): it is not yet accurate there")

    @classmethod
    def scratch_bytes(cls, particles: int, springs: int, real_bytes: int, linear_solver: str = "cg") -> int:
        """Per particle: x0, v0, the displacement, two earlier ones (Chebyshev), the acceleration
        along gravity, the colour order, the active set's marks; per spring: a penalty and a
        multiplier (augmented), two neighbour entries of the active set."""
        return particles * (16 * real_bytes + 12) + springs * (2 * real_bytes + 8)

    def __init__(
            self, system: System, *,
            iterations: Annotated[int, Option("sweeps per substep", flag=True, at_least=1)] = 20,
            substeps: Annotated[int, Option("substeps per step", flag=True, at_least=1)] = 1,
            warm_start: Annotated[bool, Option("start from the adaptive initialisation (else x0 + dt v0)")] = True,
            chebyshev_rho: Annotated[float, Option("Chebyshev acceleration: the spectral radius estimate (0: off)",
                                                   flag=True, at_least=0, below=1)] = 0.0,
            augmented: Annotated[bool, Option("springs as augmented Lagrangian constraints")] = False,
            penalty: Annotated[float, Option("augmented springs' starting penalty", unit="N/m", above=0)] = 1e3,
            penalty_growth: Annotated[float, Option("augmented springs' penalty growth per metre of |C| a sweep", unit="N/m^2",
                                                    at_least=0)] = 1e5,
            contact: Annotated[bool, Option("the scene's objects in the solve")] = True,
            self_contact: Annotated[bool | None, Option("the cloth against itself in the solve",
                                                        default_text="the scene's self_collision")] = None,
            contact_radius: Annotated[float | None, Option("contact distance", unit="m", above=0,
                                                           default_text="the scene's thickness, 0.005 m without one")] = None,
            contact_stiffness: Annotated[float, Option("contact stiffness in units of the vertex's m / dt^2",
                                                       above=0)] = 100.0,
            bound_fraction: Annotated[float, Option("a vertex's move cap, as a fraction of its distance to the nearest contact",
                                                    above=0, below=0.5)] = 0.4,
            friction_epsilon: Annotated[float, Option("slip speed below which friction is smoothed", unit="m/s",
                                                      above=0)] = 0.01,
            contact_refresh: Annotated[int, Option("sweeps between contact detections (0: once per piece)",
                                                   at_least=0)] = 0,
            contact_pieces: Annotated[int, Option("most pieces a substep with self-contact is cut into",
                                                  at_least=1)] = 16,
            pace_share: Annotated[float, Option("share of the vertices a piece may cut to their contact bounds",
                                                at_least=0, below=1)] = PACE_SHARE,
            object_faces: Annotated[bool, Option("the cloth's triangles against the objects too")] = True,
            energy_cap: Annotated[bool, Option("cap a closed scene's energy per substep")] = True,
            skip_move: Annotated[float, Option("with self-contact, the serial sweeps pass by a vertex whose "
                                               "move and its neighbours' stayed below this (0: none)",
                                               unit="m", at_least=0)] = 1e-5):
        super().__init__(system)
        # the options' types and bounds are checked from their declarations above (Integrator.__new__)
        self.iterations, self.substeps = int(iterations), int(substeps)
        self.warm_start = bool(warm_start)
        self.chebyshev_rho = float(chebyshev_rho)
        self.augmented = bool(augmented)
        self.penalty, self.penalty_growth = float(penalty), float(penalty_growth)
        self.contact_pieces = int(contact_pieces)
        self.self_contact = None if self_contact is None else bool(self_contact)
        self.energy_cap = bool(energy_cap)
        self.contact_options = dict(objects=bool(contact), object_faces=bool(object_faces), radius=contact_radius,
                                    stiffness=float(contact_stiffness), bound_fraction=float(bound_fraction),
                                    friction_epsilon=float(friction_epsilon), refresh=int(contact_refresh))
        # The parts the solve is made of, each given what it reads (see their modules):
        # the scene's contact (bind_contact), the energy cap, the pieces of a substep with
        # contact and, below, the springs' terms and a membrane's.
        self.setup = ContactSetup()  # what the bound scene put in the solve: nothing yet
        self._inputs = None  # the scene's ContactInputs bound (bind_contact)
        self.cap = EnergyCap(system)
        self.cap_active = False  # set by bind_contact on a closed scene (read by the kernels)
        self.scene_closed = False
        self.schedule = PieceSchedule(self.contact_pieces, float(pace_share))
        real, n = runtime.real(), system.particle_count
        self.springs = system.term("springs")
        self.has_springs = self.springs is not None
        self.gravity = system.term("gravity")
        self.has_gravity = self.gravity is not None
        membrane, bending = system.term("membrane"), system.term("bending")
        self.has_membrane = membrane is not None or bending is not None
        self.membrane_terms = MembraneTerms(membrane, bending) if self.has_membrane else None
        self._merit_skip = MembraneTerms.names if self.has_membrane else ()  # _merit sums them per element
        own = {"springs", *self._merit_skip}
        self.others = [term for term in system.terms if term.name not in own]
        self.point = system.make_state()  # the iterate (x, v = (x - x0) / dt)
        self.start_x = ti.Vector.field(3, real, shape=n)  # x0 (m)
        self.start_v = ti.Vector.field(3, real, shape=n)  # v0 (m/s)
        # x - x0 (m), kept apart from x so that v = delta / dt carries no cancellation in f32.
        self.delta = ti.Vector.field(3, real, shape=n)
        self.chebyshev = self.chebyshev_rho > 0.0
        self.history = ChebyshevHistory(n, real) if self.chebyshev else None
        self.has_multipliers = self.augmented and self.has_springs
        self.spring_terms = SpringTerms(self.springs, augmented=self.augmented, penalty=self.penalty,
                                        penalty_growth=self.penalty_growth) if self.has_springs else None
        ends = self.springs.ends_np if self.has_springs else np.zeros((0, 2), np.int32)
        if self.has_membrane:  # a triangle's or stencil's vertices in different colours too
            ends = np.concatenate([np.asarray(ends, np.int64).reshape(-1, 2), self.membrane_terms.pairs()])
        order, self.starts = colour_vertices(n, ends)
        self.order = ti.field(ti.i32, shape=max(1, n))
        self.colour_start = ti.field(ti.i32, shape=len(self.starts))  # the serial kernels loop over colours
        field_io.write((self.order, order), (self.colour_start, self.starts))  # one kernel, not two
        self._skip_move = float(skip_move)  # the serial sweeps' active set, where it may be used
        self.active = active_set(n, ends, self._skip_move, self.chebyshev or self.has_multipliers, self.others)
        self._work = n + (self.springs.spring_count if self.has_springs else 0) \
            + (self.membrane_terms.work if self.has_membrane else 0)  # a sweep's, in springs' worth
        self._serial: bool | None = None  # set: a caller's choice (tests, benchmarks) over the rule
        self.rest_starts = ti.field(ti.i32, shape=())  # substeps whose sweeps started at V = 0
        self.last_rest = ti.field(ti.i32, shape=())  # whether the last begun start was V = 0
        # the last substep's acceleration along gravity (m/s^2), for a piece begun again
        self.gravity_along = ti.field(real, shape=max(1, n))
        self._kernels: dict = {}
        self._resume_time: float | None = None  # when the last step ended (warm start continues it)
        self._last_dt = 0.0
        self.sweeps = 0  # sweeps run since construction (all substeps)

    # -- what the bound scene put in the solve (ContactSetup): the run, the monitor, the kernels --

    contact = property(lambda self: self.setup.contact,
                       doc="The contact terms in the solve (SolveContact), None where the scene gives it none.")
    has_contact = property(lambda self: self.setup.contact is not None)
    has_self_contact = property(lambda self: self.setup.has_self_contact)
    pins = property(lambda self: self.setup.pins, doc="The scripted pins the solve moves (pins.py), or None.")
    drives_pins = property(lambda self: self.setup.pins is not None)
    takeover = property(lambda self: self.setup.takeover, doc="What the solve took over (ContactTakeover).")
    work_weight = property(lambda self: self.setup.work_weight)
    capped = property(lambda self: self.cap.capped, doc="Substeps the energy cap shortened (0-d i32 field).")
    pieces = property(lambda self: self.schedule.pieces, doc="Pieces of substeps run with contact (pieces.py).")
    pace_share = property(lambda self: self.schedule.pace_share,
                          lambda self, share: setattr(self.schedule, "pace_share", float(share)))

    @property
    def uses_active_set(self) -> bool:
        """Whether the serial sweeps pass settled vertices by: with self-contact in the solve,
        on a closed scene (:mod:`.active` says why)."""
        return self.active is not None and self.has_self_contact and self.scene_closed

    def _set_skip_move(self, value: float) -> None:
        self._skip_move = float(value)
        if self.active is not None:
            field_io.write((self.active.threshold, self._skip_move))

    skip_move = property(lambda self: self._skip_move, _set_skip_move,
                         doc="The active set's threshold (m; :mod:`.active`), read at every sweep.")

    @property
    def work_options(self) -> tuple:
        """With self-contact, a tolerance first lowers the share of vertices a piece cuts to
        their bounds (to none), then the active set's threshold, then doubles the substeps."""
        substeps = ((self.work_option, self.work_cap),)
        if not self.has_self_contact:
            return substeps
        skip = (("skip_move", SKIP_MOVE_FLOOR),) if self.uses_active_set and self._skip_move > SKIP_MOVE_FLOOR else ()
        return (("pace_share", 0.5 / max(self.contact.free_count, 1)),) + skip + substeps

    def bind_contact(self, inputs: ContactInputs) -> ContactTakeover:
        """Put the scene's objects (with ``self_contact``, its cloth) from ``inputs`` in the solve
        (:func:`~.setup.contact_setup`), or the energy cap where the scene is closed and there is
        no contact; returns what the solve takes over. ConfigError for a contact radius the mesh
        cannot take or a start that intersects: the method is then left unbound, never half-bound."""
        if inputs.same_as(self._inputs):
            return self.setup.takeover  # already bound to them (a launcher switching methods back)
        self._inputs = None
        setup = contact_setup(inputs, self.contact_options, self.self_contact, self.delta)  # may raise
        self.setup = setup
        # Not with contact in the solve: its penalty energy is not in E, and a vertex pushed
        # out of a contact would read as a gain (the folds measured never rose, docs/vbd.md).
        self.cap_active = self.energy_cap and setup.contact is None and inputs.closed
        self.scene_closed = inputs.closed  # where the active set may pass vertices by (uses_active_set)
        self._kernels = {}  # the kernels compile the contact terms and the cap in
        self._inputs = inputs
        return setup.takeover

    def run_warning(self, accuracy_judged: bool = False) -> str:
        """The energy cap's and the contact lists' lines (:meth:`.energy.EnergyCap.warning`,
        :meth:`.contact.SolveContact.warning`), joined."""
        lines = (self.cap.warning(accuracy_judged), self.contact.warning() if self.contact is not None else "")
        return "; ".join(line for line in lines if line)

    def solve_forces(self, state, t: float, h: float):
        """The in-solve contact's forces at ``state`` (the result of a piece of ``h`` s ending at
        ``t`` s), for the convergence monitor (:mod:`.contact_model`); None without contact."""
        if not self.has_contact:
            return None
        return solve_forces(self.contact, self.system, state, self.delta.to_numpy().astype(float), h, t)

    @property
    def serial(self) -> bool:
        """Whether a substep's sweeps run as one serial task (else each colour a parallel loop,
        :meth:`_sweep`), by :func:`.kernels.serial_sweeps`; assigning it overrides the rule."""
        if self._serial is not None:
            return self._serial
        return serial_sweeps(self._work, self.system.particle_count, self.has_self_contact)

    @serial.setter
    def serial(self, value: bool) -> None:
        self._serial = bool(value)

    @property
    def colour_count(self) -> int:
        """Colours of the vertex graph (parallel phases of one sweep)."""
        return len(self.starts) - 1

    def reset(self) -> None:
        self._resume_time = None
        if self.contact is not None:
            self.contact.forget()  # found at positions a reset or a switch has left
        if self.spring_terms is not None:
            self.spring_terms.reset()

    def step(self, state, t: float, h: float) -> StepReport:
        dt = h / self.substeps
        continued = self._resume_time is not None and abs(t - self._resume_time) <= 1e-9 * max(abs(t), h)
        use_acceleration = int(self.warm_start and continued)
        kernels = self._bound(state)
        bad = 0
        pieces_before = self.schedule.pieces
        for k in range(self.substeps):
            last = k == self.substeps - 1
            if self.solved_start is not None and last and self.contact is None:
                self._record_start(state, dt)
            t_end = t + (k + 1) * dt  # backward Euler evaluates the forces at the substep's end
            previous_dt = self._last_dt  # the last substep's (or piece's) length: its v0 is start_v
            if self.contact is not None:
                # in pieces where the bounds or the scripted pins need them (pieces.py)
                bad = self.schedule.substep(
                    kernels, self._sweeps, state, self.point.x, self.contact, self.pins, dt=dt, t_end=t_end,
                    use_acceleration=use_acceleration, previous_dt=previous_dt, iterations=self.iterations,
                    warm_start=self.warm_start,
                    record=self._record_start if self.solved_start is not None and last else None)
                self._last_dt = self.schedule.last_length
                if bad < 0:
                    self._resume_time = None
                    return StepReport(accepted=False, h=0.0, next_h=h, f_evals=k * self.iterations,
                                      status=Status.DIVERGED, message=FAILURES[bad])
            elif self.serial:
                bad = kernels["substep"](dt, t_end, use_acceleration, previous_dt, self.iterations)
            else:
                kernels["begin"](dt, use_acceleration, previous_dt, t_end, 0)
                self._sweeps(kernels, dt, t_end, 0, self.iterations)
                bad = kernels["end"](dt)
            use_acceleration = int(self.warm_start)
            if self.contact is None:
                self._last_dt = dt
            if bad:
                self._resume_time = None
                return StepReport(accepted=False, h=0.0, next_h=h, f_evals=(k + 1) * self.iterations,
                                  status=Status.DIVERGED, message=f"vbd: {bad} particles non-finite")
        work = (self.schedule.pieces - pieces_before if self.contact is not None else self.substeps) * self.iterations
        self.sweeps += work
        self._resume_time = t + h
        return StepReport(accepted=True, h=h, next_h=h, f_evals=work, linear_iterations=work)

    def _record_start(self, state, h: float) -> None:
        """Keep the start of the step's last piece (a substep, or a piece of one) and its
        length, which the convergence monitor measures."""
        self.solved_start.copy_from(state)
        self.solved_h = h

    # -- kernels (kernels.py: closures made once per state) -------------------------------------

    def _bound(self, y) -> dict:
        kernels = self._kernels.get(id(y))
        if kernels is None:
            kernels = self._kernels[id(y)] = bind_kernels(self, y)
        return kernels

    def _sweeps(self, kernels: dict, dt: float, t: float, first: int, count: int) -> None:
        """Sweeps ``first`` .. ``first + count - 1`` of a begun substep or piece of dt seconds
        ending at t: one serial kernel, or parallel sweeps (the Chebyshev weights taken from
        sweep 0 on, as the serial kernel does)."""
        if self.serial:
            kernels["sweeps"](dt, t, first, count)
            return
        omega = 1.0
        for sweep in range(first + count):
            omega = chebyshev_weight(self.chebyshev_rho ** 2, sweep, omega) if self.chebyshev else 1.0
            if sweep >= first:
                self._sweep(kernels, dt, t, omega, sweep)

    def _sweep(self, kernels: dict, dt: float, t: float, omega: float, index: int) -> None:
        """One parallel sweep (sweep ``index``, Chebyshev weight ``omega``): the objects' contacts
        with the triangles, then each colour's vertices at once, colour after colour."""
        if self.contact is None or not self.contact.obstacles:
            kernels["sweep_unrolled"](dt, t, omega, index)
            return
        if self.contact.queries_faces:
            kernels["query"](t)
        for c in range(self.colour_count):
            kernels["colour"](dt, t, c)
        if self.has_multipliers or self.chebyshev:
            kernels["after_colours"](dt, t, omega, index)

    @ti.func
    def _begin(self, y, dt, use_acceleration, previous_dt, t, again):
        """Keep (x0, v0) and put the iterate at the start guess (see the class docstring).
        ``again`` != 0: the same start begun again with another dt (a shortened piece,
        pieces.py): start_v already holds y.v, so the acceleration is the one kept the first
        time, and the first time's start choice is not counted twice."""
        direction = ti.Vector.zero(y.x.dtype, 3)
        g = ti.cast(0.0, y.x.dtype)
        if ti.static(self.has_gravity):
            g = self.gravity.g[None].norm()
            if g > 0.0:
                direction = self.gravity.g[None] / g
        for i in range(self.system.particle_count):
            delta = ti.Vector.zero(y.x.dtype, 3)
            if self.system.free[i]:
                if use_acceleration and previous_dt > 0.0:
                    # The last substep's acceleration along gravity, clamped to [0, g] (Chen et
                    # al. 2024, adaptive initialisation); start_v still holds that substep's v0.
                    along = self.gravity_along[i]
                    if not again:
                        along = (y.v[i] - self.start_v[i]).dot(direction) / previous_dt
                        self.gravity_along[i] = along
                    delta = dt * y.v[i] + dt * dt * ti.min(ti.max(along, 0.0), g) * direction
                else:
                    delta = dt * y.v[i]
            if ti.static(self.drives_pins):
                if self.pins.driven[i]:  # a scripted pin: where the script puts it (pins.py)
                    delta = self.pins.target[i] - y.x[i]
            self.start_x[i] = y.x[i]
            self.start_v[i] = y.v[i]
            self.delta[i] = delta
        if ti.static(self.has_contact):
            # the triangles near the objects along the guess (faces.py), for its bounds
            self.contact.measure_face_reach(self.delta)
            self.contact.query_faces(self.start_x, t)
            self.contact.query_mesh_faces(self.start_x)
            # The guess kept within the bounds, measured from the mean guess (a falling cloth
            # moves as a whole); from none where an object stops a vertex short of that.
            self.contact.fit_shift(self.delta, self.system.free)
            stopped = 0
            for i in range(self.system.particle_count):
                if self.system.free[i]:
                    kept = self.contact.limit(i, ti.Vector.zero(y.x.dtype, 3), self.delta[i], self.start_x[i], t,
                                              self.start_x)
                    stopped += int(self.contact.outside_ball(i, kept, self.start_x[i]))
            if ti.static(self.has_self_contact):
                if stopped > 0:
                    self.contact.shift[None] = ti.Vector.zero(y.x.dtype, 3)
            if ti.static(self.has_self_contact):
                for b in self.contact.overshoot:  # how far the bounds cut the guess (pieces.py)
                    self.contact.overshoot[b] = 0
            for i in range(self.system.particle_count):
                if self.system.free[i]:
                    if ti.static(self.has_self_contact):
                        self.contact.count_overshoot(i, self.delta[i], self.start_x[i])
                    self.delta[i] = self.contact.limit(i, ti.Vector.zero(y.x.dtype, 3), self.delta[i],
                                                       self.start_x[i], t, self.start_x)
        for i in range(self.system.particle_count):
            self.point.x[i] = self.start_x[i] + self.delta[i]
            self.point.v[i] = self.delta[i] / dt
        # The guess against staying put (V = 0): on a stiff cloth the guess may stretch the
        # springs by more energy than the whole motion carries, which a few sweeps do not undo
        # (the energy rose step after step); the sweeps start from the lower merit.
        guess_merit = self._merit(dt)
        for i in range(self.system.particle_count):
            if not self._scripted(i):  # the scripted pins move either way
                self.point.x[i] = self.start_x[i]
                self.point.v[i] = ti.Vector.zero(y.x.dtype, 3)
        at_rest = self._merit(dt) < guess_merit
        if again:
            self.rest_starts[None] -= self.last_rest[None]
        self.last_rest[None] = int(at_rest)
        if at_rest:
            self.rest_starts[None] += 1
            if ti.static(self.has_self_contact):
                self.contact.shift[None] = ti.Vector.zero(y.x.dtype, 3)  # staying put needs none
        for i in range(self.system.particle_count):
            delta = self.delta[i]
            if at_rest and not self._scripted(i):
                delta = ti.Vector.zero(y.x.dtype, 3)
            self.delta[i] = delta
            if self.system.free[i] or self._scripted(i):
                self.point.x[i] = self.start_x[i] + delta
                self.point.v[i] = delta / dt
            if ti.static(self.chebyshev):
                self.history.start(i, delta)
        if ti.static(self.has_multipliers):
            self.spring_terms.begin_penalties()

    @ti.func
    def _after_colours(self, dt, t, omega, index):
        """A sweep's end: the springs' multipliers, Chebyshev's over-relaxation."""
        if ti.static(self.has_multipliers):
            self.spring_terms.update_multipliers(self.point.x)
        if ti.static(self.chebyshev):
            for i in range(self.system.particle_count):
                self._accelerate(i, dt, omega, index, t)

    @ti.func
    def _query_faces(self, t):
        """The objects' contacts with the triangles at the iterate, for the next sweep (faces.py)."""
        if ti.static(self.has_contact):
            self.contact.query_faces(self.point.x, t)

    @ti.func
    def _scripted(self, i):
        """Whether particle i is a scripted pin this solve moves (pins.py)."""
        out = False
        if ti.static(self.drives_pins):
            out = self.pins.driven[i] != 0
        return out

    @ti.func
    def _merit(self, dt):
        """Backward Euler's incremental potential at the iterate, up to a constant (J):
        1/2 |v - v0|_M^2 + U(x) + dt R(x, v); top-level loops (the membrane and bending by
        element, once each, not at each of their corners)."""
        total = ti.cast(0.0, self.delta.dtype)
        for i in range(self.system.particle_count):
            u, r = self.system.potential_and_dissipation_at(i, self.point, ti.static(self._merit_skip))
            total += u + dt * r
            if self.system.free[i]:
                total += 0.5 * self.system.mass[i] * (self.point.v[i] - self.start_v[i]).norm_sqr()
        if ti.static(self.has_membrane):
            total += self.membrane_terms.merit(self.point, dt)
        return total

    @ti.func
    def _solve_vertex(self, i, dt, t):
        """One Newton step of vertex i on its block of G (the class docstring), neighbours fixed;
        returns how far it moved the vertex (m)."""
        moved = ti.cast(0.0, self.delta.dtype)
        if self.system.free[i]:
            m = self.system.mass[i]
            inertia = m / (dt * dt)
            delta = self.delta[i]
            r = inertia * (delta - dt * self.start_v[i])
            H = inertia * ti.Matrix.identity(self.delta.dtype, 3)
            if ti.static(self.has_springs):
                f, block = self.spring_terms.at(i, self.point.x, self.point.v, dt)
                r -= f
                H += block
            if ti.static(self.has_membrane):
                f, block = self.membrane_terms.at(i, self.point, dt)
                r -= f
                H += block
            if ti.static(self.has_contact):
                f, block = self.contact.terms(i, self.point.x, m, dt, t)
                r -= f
                H += block
            for term in ti.static(self.others):
                r -= term.force(i, self.point, m, t)
                H -= term.jacobian_diagonal_block(i, self.point, 1.0 / dt, 1.0, t)
            # H is symmetric positive definite (mass plus PSD blocks): its determinant is > 0
            # unless something is not finite, and then the vertex stays put.
            if H.determinant() > 0.0:
                old = delta
                delta -= H.inverse() @ r
                if ti.static(self.has_contact):
                    delta = self.contact.limit(i, old, delta, self.start_x[i], t, self.point.x)
                self.delta[i] = delta
                self.point.x[i] = self.start_x[i] + delta
                self.point.v[i] = delta / dt
                moved = (delta - old).norm()
        return moved

    @ti.func
    def _accelerate(self, i, dt, omega, sweep, t):
        """Chebyshev over-relaxation of vertex i after sweep ``sweep`` (0-based):
        delta = omega (delta - delta two sweeps back) + delta two sweeps back."""
        if self.system.free[i]:
            delta = self.delta[i]
            if sweep >= 1:
                old = delta
                delta = self.history.relaxed(i, delta, omega)
                if ti.static(self.has_contact):
                    delta = self.contact.limit(i, old, delta, self.start_x[i], t, self.point.x)
                self.delta[i] = delta
                self.point.x[i] = self.start_x[i] + delta
                self.point.v[i] = delta / dt
            self.history.shift(i, delta)

    @ti.func
    def _finish(self, y, dt):
        """The energy cap where it is on (:mod:`.energy`), then the iterate into ``y``;
        returns the particles left non-finite."""
        if ti.static(self.cap_active):
            self.cap.apply(y, self.point, self.start_x, self.delta, dt, self.serial)
        return self._end(y, dt)

    @ti.func
    def _end(self, y, dt):
        bad = 0
        for i in range(self.system.particle_count):
            if self.system.free[i]:
                y.x[i] = self.start_x[i] + self.delta[i]
                y.v[i] = self.delta[i] / dt
            if ti.static(self.drives_pins):
                if self.pins.driven[i]:  # where the script puts it, at the script's velocity
                    y.x[i] = self.pins.target[i]
                    y.v[i] = self.pins.velocity[i]
            if not (finite(y.x[i]) and finite(y.v[i])):
                bad += 1
        return bad

