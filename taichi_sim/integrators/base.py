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


@dataclass(frozen=True)
class StepReport:
    """What one call to :meth:`Integrator.step` did.

    Attributes:
        accepted: whether the state advanced (a fixed-step method always accepts unless it failed).
        h: the step taken (s); 0 when not accepted.
        next_h: the step the method proposes next (s); fixed-step methods echo ``h``.
        f_evals: evaluations of the system's f during the call.
        status: :class:`Status`; anything but OK means the state must not be trusted.
    """

    accepted: bool
    h: float
    next_h: float
    f_evals: int
    status: Status = Status.OK


class Integrator(ABC):
    """A time-stepping method bound to one system.

    Scratch (stage buffers) is allocated once in ``__init__``; ``step`` allocates nothing.
    Class attributes: ``name`` (the registry name), ``order`` (global order of accuracy),
    ``requires_second_order`` (only for systems with velocities), ``adaptive``.
    """

    name: str = ""
    order: int = 0
    requires_second_order: bool = False
    adaptive: bool = False
    description: str = ""

    def __init__(self, system: System):
        if self.requires_second_order and not system.second_order:
            raise ConfigError(f"integrator {self.name!r} needs a second-order (particle) system")
        self.system = system

    @abstractmethod
    def step(self, state: State, t: float, h: float) -> StepReport:
        """Advance ``state`` in place from time ``t`` by ``h`` seconds."""
