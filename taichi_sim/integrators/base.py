"""The integrator contract: step a caller-owned state and report what happened."""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from enum import Enum

from ..errors import ConfigError
from ..state import State
from ..systems.base import System


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


class Integrator(ABC):
    """A time-stepping method bound to one system.

    Scratch (stage buffers) is allocated once in ``__init__``; ``step`` allocates nothing.
    Class attributes: ``name`` (the registry name), ``order`` (global order of accuracy),
    ``requires_second_order`` (only for systems with velocities), ``adaptive`` (the step size
    is proposed by the method: ``step`` may reject, and ``initial_step`` picks the first one),
    ``implicit`` (reports linear-solver work).
    Options (tolerances, solver choices) are keyword-only constructor arguments.
    """

    name: str = ""
    order: int = 0
    requires_second_order: bool = False
    adaptive: bool = False
    implicit: bool = False
    description: str = ""
    takes_constraints: bool = False
    """Whether the method steps a system with constraint forces (``system.constraints``): the
    methods that only call eval_f (explicit Runge-Kutta, symplectic Euler, the embedded
    pairs) do; the implicit and positional ones, which assemble the forces term by term, do
    not and refuse such a system."""

    equation = None
    """The equation a step solves (:class:`~taichi_sim.integrators.equation.Equation`) for the
    methods that solve a system per step; None for the explicit ones. Runs measure its residual
    (:class:`taichi_sim.convergence.ConvergenceMonitor`)."""
    tracks_solved_start = False
    """Whether the method, when ``solved_start`` is set to a State, copies into it the start of
    the last piece of a step it solved (a substep, a halving) and sets ``solved_h`` (s)."""
    solved_start = None
    solved_h = float("nan")

    def __init__(self, system: System):
        if self.requires_second_order and not system.second_order:
            raise ConfigError(f"integrator {self.name!r} needs a second-order (particle) system")
        constraints = getattr(system, "constraints", None)
        if constraints is not None and not self.takes_constraints:
            raise ConfigError(
                f"integrator {self.name!r} cannot step scene {constraints.scene!r}: its constraint "
                f"forces are computed inside eval_f, which the implicit and positional methods do "
                f"not use; pick an explicit method (rk4, rk45, symplectic_euler)")
        self.system = system

    initial_step_f_evals: int = 0

    def initial_step(self, state: State, t: float, t_end: float | None) -> float:
        """First step size (s) for an adaptive method when the user gives none; it costs
        ``initial_step_f_evals`` evaluations of f."""
        raise NotImplementedError(f"{self.name} needs an explicit step size")

    def reset(self) -> None:
        """Forget anything carried between steps (call after the system itself changed: a
        spring torn, a parameter moved). Stateless methods do nothing."""

    @abstractmethod
    def step(self, state: State, t: float, h: float) -> StepReport:
        """Advance ``state`` in place from time ``t`` by ``h`` seconds."""
