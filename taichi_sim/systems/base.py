"""The ODE contract every system honours (docs/design.md, Contracts)."""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from ..state import State


@dataclass(frozen=True)
class Health:
    """What the blow-up guard (:mod:`taichi_sim.guard`) reads off a state, in one pass.

    Attributes:
        nonfinite: particles whose position or velocity has a NaN or infinite component.
        farthest: largest distance (m) of a particle from the centre the caller gave.
        energy: total energy (J), or None for a system without one.
        kinetic: kinetic energy (J); 0 for a first-order system.
        spring_energy: potential energy of the springs (J); 0 without springs.
        gravity_energy: potential energy of gravity (J, m g h summed over the free particles);
            0 without gravity. The rest of ``energy - kinetic - spring_energy - gravity_energy``
            is any other conservative term's (the grab's pull).
        max_strain: largest strain |d|/r - 1 of a live spring with k > 0; 0 without springs.
    """

    nonfinite: int
    farthest: float
    energy: float | None
    kinetic: float = 0.0
    spring_energy: float = 0.0
    gravity_energy: float = 0.0
    max_strain: float = 0.0


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

    def health(self, y: State, center) -> Health:
        """:class:`Health` of state ``y``, distances measured from ``center`` ((3,), m).

        This generic version reads the state back into numpy; systems with kernels of their own
        override it with a reduction on the device."""
        x, v = y.to_numpy()
        x = np.asarray(x, np.float64)
        parts = x if v is None else np.concatenate([x, np.asarray(v, np.float64)], axis=1)
        finite = np.isfinite(parts).all(axis=1)
        with np.errstate(over="ignore", invalid="ignore"):
            distance = np.linalg.norm(x[finite] - np.asarray(center, np.float64), axis=1)
        return Health(nonfinite=int((~finite).sum()),
                      farthest=float(distance.max()) if len(distance) else 0.0,
                      energy=self.energy(y))
