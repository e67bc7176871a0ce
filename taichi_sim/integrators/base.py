"""The integrator contract: step a caller-owned state and report what happened."""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from enum import Enum

from ..errors import ConfigError
from ..scene.handoff import NOTHING_TAKEN, ContactInputs, ContactTakeover
from ..state import State
from ..systems.base import System
from .options import check_values, option_specs


class Status(str, Enum):
    """Outcome of a step or a run (the npz ``status`` string is the value)."""

    OK = "ok"
    DIVERGED = "diverged"
    NOT_CONVERGED = "not_converged"
    STEP_TOO_SMALL = "step_too_small"
    STIFF = "stiff"  # an explicit adaptive method found its step bound by stability, not accuracy


@dataclass(frozen=True)
class StepReport:
    """What one call to :meth:`Integrator.step` did.

    Attributes:
        accepted: whether the state advanced (a fixed-step method always accepts unless it failed).
        h: the step taken (s); 0 when not accepted.
        next_h: the step the method proposes next (s); fixed-step methods echo ``h``.
        f_evals: evaluations of the system's f during the call.
        status: :class:`Status`; anything but OK means the state must not be trusted.
        linear_iterations: iterations of the linear solver (implicit methods), else 0.
        linear_residual: the final relative residual of the last linear solve (implicit methods).
        message: detail for a status other than OK (e.g. the residual that missed tolerance).
    """

    accepted: bool
    h: float
    next_h: float
    f_evals: int
    status: Status = Status.OK
    linear_iterations: int = 0
    linear_residual: float = 0.0
    message: str = ""


class _Missing:
    """The value of a fact a method has not declared (see :func:`missing_facts`)."""

    def __repr__(self) -> str:
        return "<missing>"


MISSING = _Missing()
REAL_PARTS_PER_PARTICLE = 6  # a state copy: x and v, 3 reals each


class Integrator(ABC):
    """A time-stepping method bound to one system.

    Scratch (stage buffers) is allocated once in ``__init__``; ``step`` allocates nothing.
    Options (tolerances, solver choices) are keyword-only constructor arguments, each with its
    help, unit, flag and bounds on its annotation (:class:`~.options.Option`); the command line,
    ``list`` and :func:`~taichi_sim.integrators.check_options` read them from the signature
    (:func:`~.options.option_specs`).

    A method declares its facts as class attributes, and every tool reads them from the class
    (theory, memory, ``advise``, ``list``); :func:`missing_facts` names what is not declared,
    and a plug-in lacking one is refused. Required: ``name`` (the registry name),
    ``order`` (global order of accuracy, >= 1), ``description`` (one line),
    ``stability_constant`` and the scratch (``scratch_states`` or :meth:`scratch_bytes`);
    ``advice_note`` when the constant is inf, :meth:`amplification_squared` when it is 0.
    Capabilities (default False): ``requires_second_order`` (only for systems with velocities),
    ``adaptive`` (the step size is proposed by the method: ``step`` may reject, and
    ``initial_step`` picks the first one), ``implicit`` (reports linear-solver work),
    ``takes_constraints``.
    """

    name: str = ""
    order: int = 0
    requires_second_order: bool = False
    adaptive: bool = False
    implicit: bool = False
    description: str = ""

    stability_constant = MISSING
    """C such that the method is stable on an undamped linear oscillator of angular frequency
    omega while h omega <= C (:mod:`taichi_sim.theory`): a positive number; 0 when it grows at
    every step on the imaginary axis (then :meth:`amplification_squared` says how fast);
    ``math.inf`` when no step makes it blow up (then ``advice_note`` says what "no limit"
    means for it); None for an adaptive method, whose controller picks the step."""
    advice_note: str = ""
    """What ``taichi-sim advise`` prints beside the method's step limit (required for an
    unlimited method: which scenes, what it costs instead, e.g. damping)."""
    scratch_states = MISSING
    """Scratch in copies of the state (6 reals per particle), for :meth:`scratch_bytes`; a
    method whose scratch is not whole states overrides :meth:`scratch_bytes` instead."""
    f_evals_per_step: float | None = None
    """Evaluations of f per step as declared (None: it varies, e.g. with Newton iterations)."""

    takes_constraints: bool = False
    """Whether the method steps a system with constraint forces (``system.constraints``): the
    methods that only call eval_f (explicit Runge-Kutta, symplectic Euler, the embedded
    pairs) do; the implicit and positional ones, which assemble the forces term by term, do
    not and refuse such a system."""

    takes_elastic_models: bool = True
    """Whether the method steps a system with continuum force terms (a membrane, bending:
    :attr:`~taichi_sim.forces.ForceTerm.elastic_model`): the methods that call eval_f or the
    force-Jacobian API do, and VBD, whose vertex solve holds the membrane's triangles and the
    bending stencils; XPBD and projective dynamics, whose solves hold only springs, would take
    those forces explicitly at their large steps and refuse."""

    equation = None
    """The equation a step solves (:class:`~taichi_sim.integrators.equation.Equation`) for the
    methods that solve a system per step; None for the explicit ones. Runs measure its residual
    (:class:`taichi_sim.convergence.ConvergenceMonitor`)."""
    unmodelled_forces = ""
    """Forces the method adds inside its own solve that the measured residual's model does not
    hold (e.g. ``vbd``'s in-solve contact), "" for none: such a run's residual is not measured
    rather than reported as a convergence figure it is not."""
    work_option: str = ""
    """The option (an attribute read at every step) that brings a method's step closer to its
    equation's solution: a count that grows (``iterations``, ``substeps``: doubled) or a
    relative tolerance that shrinks (``newton_tolerance``: divided by ten). A run whose sampled
    step is farther than its tolerance changes it, up to ``work_cap``, and solves the step
    again (:class:`taichi_sim.Stepper`). "" for none."""
    work_cap: float = 0
    """The furthest ``work_option`` may go under a tolerance (the largest count, the smallest
    tolerance)."""

    @property
    def work_options(self) -> tuple:
        """(option, cap) pairs a tolerance raises in turn: the next once one is at its cap or
        stops helping (the Stepper); by default ``work_option`` alone."""
        return ((self.work_option, self.work_cap),) if self.work_option else ()
    work_weight: float = 1.0
    """What a unit of the method's reported work costs, relative to a sweep over springs (the
    convergence monitor's cost model: how often a run can pay for a sample)."""
    plot_colour: str = ""
    """The method's colour in the benchmarks' plots ("#1f77b4"); "" takes one from a palette by
    its name (:func:`~taichi_sim.integrators.colour_of`)."""
    given_options: frozenset = frozenset()
    """The options the caller set (:func:`~taichi_sim.integrators.create_integrator`)."""
    tracks_solved_start = False
    """Whether the method, when ``solved_start`` is set to a State, copies into it the start of
    the last piece of a step it solved (a substep, a halving) and sets ``solved_h`` (s)."""
    solved_start = None
    solved_h = float("nan")

    def __new__(cls, system=None, *args, **options):
        # Every constructor's options are checked against their declarations (type, bounds)
        # before its __init__ runs, however it is called: one check for the API, the command
        # line and scene files (a plug-in's __init__ needs no checks of its own).
        check_values(cls, options, cls.name)
        return super().__new__(cls)

    def __init__(self, system: System):
        if self.requires_second_order and not system.second_order:
            raise ConfigError(f"integrator {self.name!r} needs a second-order (particle) system")
        constraints = getattr(system, "constraints", None)
        if constraints is not None and not self.takes_constraints:
            raise ConfigError(
                f"integrator {self.name!r} cannot step scene {constraints.scene!r}: its constraint "
                f"forces are computed inside eval_f, which the implicit and positional methods do "
                f"not use; pick an explicit method (rk4, rk45, symplectic_euler)")
        models = elastic_models(system)
        if models and not self.takes_elastic_models:
            raise ConfigError(
                f"integrator {self.name!r} cannot step a cloth of material {'+'.join(models)}: its solve holds "
                f"springs only, and it would take the membrane and bending forces explicitly at its large "
                f"steps; pick implicit_euler, implicit_midpoint, vbd or an explicit method (symplectic_euler, rk4)")
        self.system = system

    initial_step_f_evals: int = 0

    @classmethod
    def scratch_bytes(cls, particles: int, springs: int, real_bytes: int, linear_solver: str = "cg") -> int:
        """Estimated peak bytes of the method's scratch on a system of ``particles`` and
        ``springs`` at reals of ``real_bytes`` bytes (:mod:`taichi_sim.memory`)."""
        return int(cls.scratch_states) * REAL_PARTS_PER_PARTICLE * real_bytes * particles

    @classmethod
    def amplification_squared(cls, theta: float) -> float | None:
        """|R(i theta)|^2: the growth of an undamped oscillation's energy per step at
        theta = h omega (the stability function on the imaginary axis); None when unknown."""
        return None

    @classmethod
    def damped_limit(cls, omega: float, gamma: float) -> float | None:
        """The largest stable step (s) on the damped oscillator x'' = -omega^2 x - gamma x'
        (omega in rad/s, gamma in 1/s; with gamma = 0 it is C / omega); None when the method
        does not say (then C / omega, the undamped limit, is all that is predicted). An
        explicit method's limit shrinks with the damping: its stable region is bounded along
        the negative real axis too."""
        return None

    @classmethod
    def options(cls) -> dict:
        """The method's options: keyword-only arguments of ``__init__`` and their defaults
        (:func:`~.options.option_specs` has their types, help and bounds)."""
        return {name: spec.default for name, spec in option_specs(cls).items()}

    def initial_step(self, state: State, t: float, t_end: float | None) -> float:
        """First step size (s) for an adaptive method when the user gives none; it costs
        ``initial_step_f_evals`` evaluations of f."""
        raise NotImplementedError(f"{self.name} needs an explicit step size")

    def reset(self) -> None:
        """Forget anything carried between steps (call after the system itself changed: a
        spring torn, a parameter moved). Stateless methods do nothing."""

    def bind_contact(self, inputs: ContactInputs) -> ContactTakeover:
        """Take what the method's solve holds of a scene's contact from ``inputs`` (the
        scene's ground, shapes, collider mesh, self-collision stage, scripted pins, thickness:
        :meth:`Scene.contact_inputs <taichi_sim.scene.scene.Scene.contact_inputs>`) and answer
        what it took over (which parts' post-step work its solve does, whether the objects'
        face pass must wait), which the scene applies (:meth:`Scene.hand_over
        <taichi_sim.scene.scene.Scene.hand_over>`). The Stepper calls it when it binds the
        method to a scene; it may raise ConfigError (a contact the solve cannot take) and must
        then leave the method as it was. The default takes nothing: the scene's parts do all
        their work after each step."""
        return NOTHING_TAKEN

    def run_warning(self, accuracy_judged: bool = False) -> str:
        """What may be wrong with the steps taken since the method was bound that no step's
        status says ('' when nothing; e.g. ``vbd``'s contact pairs dropped for lack of room):
        a run ends with it among its warnings. ``accuracy_judged``: the run's error estimate
        judged its steps, so a warning about how close they came to their solution alone is
        left to it."""
        return ""

    @abstractmethod
    def step(self, state: State, t: float, h: float) -> StepReport:
        """Advance ``state`` in place from time ``t`` by ``h`` seconds."""


def elastic_models(system) -> list[str]:
    """The continuum models of ``system``'s force terms (``ForceTerm.elastic_model``), sorted."""
    return sorted({getattr(term, "elastic_model", "") for term in getattr(system, "terms", ())} - {""})


def missing_facts(cls) -> list[str]:
    """The facts (class docstring of :class:`Integrator`) that ``cls`` does not declare, or
    declares with a value no tool can use; empty when it is complete."""
    missing = []
    if not (isinstance(cls.name, str) and cls.name):
        missing.append("name (a non-empty str)")
    if isinstance(cls.order, bool) or not isinstance(cls.order, int) or cls.order < 1:
        missing.append("order (an int >= 1)")
    if not (isinstance(cls.description, str) and cls.description):
        missing.append("description (a one-line str)")
    c = cls.stability_constant
    if c is MISSING or not (c is None or (isinstance(c, (int, float)) and c >= 0 and not math.isnan(c))):
        missing.append("stability_constant (a number >= 0, math.inf, or None when adaptive)")
    elif c is None and not cls.adaptive:
        missing.append("stability_constant (None is only for adaptive methods)")
    elif c == math.inf and not cls.advice_note:
        missing.append("advice_note (what 'no step limit' means for this method)")
    elif c == 0 and cls.amplification_squared(1.0) is None:
        missing.append("amplification_squared (how fast it grows on the imaginary axis)")
    if cls.scratch_states is MISSING and cls.scratch_bytes.__func__ is Integrator.scratch_bytes.__func__:
        missing.append("scratch_states or scratch_bytes (its scratch memory)")
    if getattr(cls, "__abstractmethods__", None):
        missing.append(f"an implementation of {', '.join(sorted(cls.__abstractmethods__))}")
    return missing
