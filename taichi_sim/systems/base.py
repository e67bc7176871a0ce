"""The ODE contract every system honours (DESIGN.md section 3)."""
from __future__ import annotations

from abc import ABC, abstractmethod

from ..state import State


class System(ABC):
    """An ODE dy/dt = f(y, t) over the state of ``particle_count`` particles.

    Subclasses set ``particle_count`` and ``second_order`` (whether the state carries
    velocities, i.e. the system is Newton's second law written as a first-order ODE in (x, v)).
    """

    particle_count: int
    second_order: bool

    supports_jacobian = False
    """Whether the system provides the mass-spring Jacobian API of
    :class:`~taichi_sim.systems.ParticleSystem` (``system_matrix_row`` and kin), with which
    implicit methods solve for velocities with CG or a sparse Cholesky factorisation."""

    has_jacobian_product = False
    """Whether :meth:`jacobian_product` is implemented (else implicit methods difference f)."""

    def make_state(self) -> State:
        """A zeroed state of this system's shape (the caller owns it)."""
        return State(self.particle_count, self.second_order)

    @abstractmethod
    def eval_f(self, y: State, t: float, out: State) -> None:
        """Write f(y, t) into ``out``.

        ``y`` is any state (an RK stage, a Newton iterate), never assumed to be the scene's
        current one. ``y`` is read only; every entry of ``out`` is written: ``out.x`` gets
        dx/dt, and for second-order systems ``out.v`` gets dv/dt.
        """

    def jacobian_product(self, y: State, t: float, w: State, out: State) -> None:
        """Write (df/dy)(y, t) w into ``out``: the Jacobian of f at ``y`` applied to the
        direction ``w`` (all states of this system's shape; ``y`` and ``w`` are read only)."""
        raise NotImplementedError(f"{type(self).__name__} has no analytic Jacobian")

    def energy(self, y: State) -> float | None:
        """The system's energy (J) at ``y``, or None when it has none."""
        return None
