"""Integrators behind one contract, looked up by name."""
from __future__ import annotations

from ..errors import ConfigError
from .base import Integrator, Status, StepReport
from .explicit_rk import RK4, Euler, ExplicitRK, Midpoint, Trapezoid
from .symplectic import SymplecticEuler
from .tableau import ButcherTableau

INTEGRATORS: dict[str, type[Integrator]] = {
    cls.name: cls for cls in (Euler, Trapezoid, Midpoint, RK4, SymplecticEuler)
}


def integrator_class(name: str) -> type[Integrator]:
    try:
        return INTEGRATORS[name]
    except KeyError:
        raise ConfigError(f"unknown integrator {name!r} (choose from {', '.join(INTEGRATORS)})") from None


def create_integrator(name: str, system, **options) -> Integrator:
    """Bind the integrator called ``name`` to ``system`` (allocates its scratch once)."""
    return integrator_class(name)(system, **options)


__all__ = ["INTEGRATORS", "Integrator", "Status", "StepReport", "ButcherTableau", "ExplicitRK",
           "Euler", "Midpoint", "Trapezoid", "RK4", "SymplecticEuler", "create_integrator",
           "integrator_class"]
