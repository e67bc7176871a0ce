"""Integrators behind one contract, looked up by name."""
from __future__ import annotations

import inspect

from ..errors import ConfigError
from .adaptive import DormandPrince45, EmbeddedRK, Fehlberg45
from .base import Integrator, Status, StepReport
from .explicit_rk import RK4, Euler, ExplicitRK, Midpoint, Trapezoid
from .implicit import ImplicitEuler, ImplicitEulerLinearised, ImplicitMidpoint, LinearSolverStats
from .positional import XPBD, ProjectiveDynamics
from .positional.vbd import VBD
from .symplectic import SymplecticEuler
from .tableau import ButcherTableau

INTEGRATORS: dict[str, type[Integrator]] = {
    cls.name: cls for cls in (Euler, Trapezoid, Midpoint, RK4, SymplecticEuler, DormandPrince45, Fehlberg45,
                              ImplicitEuler, ImplicitEulerLinearised, ImplicitMidpoint, ProjectiveDynamics, XPBD, VBD)
}


def integrator_class(name: str) -> type[Integrator]:
    try:
        return INTEGRATORS[name]
    except KeyError:
        raise ConfigError(f"unknown integrator {name!r} (choose from {', '.join(INTEGRATORS)})") from None


def check_options(name: str, options: dict) -> type[Integrator]:
    """The class of integrator ``name``, after checking it takes every keyword in ``options``
    (ConfigError otherwise); nothing is allocated."""
    cls = integrator_class(name)
    accepted = {p.name for p in inspect.signature(cls.__init__).parameters.values()
                if p.kind is inspect.Parameter.KEYWORD_ONLY}
    unknown = sorted(set(options) - accepted)
    if unknown:
        raise ConfigError(f"integrator {name!r} takes no option {unknown[0]!r}"
                          + (f" (it takes: {', '.join(sorted(accepted))})" if accepted else ""))
    return cls


def create_integrator(name: str, system, **options) -> Integrator:
    """Bind the integrator called ``name`` to ``system`` (allocates its scratch once).

    ``options`` are the method's keyword-only settings (e.g. ``rtol`` for rk45); an option the
    method does not take raises ConfigError.
    """
    return check_options(name, options)(system, **options)
