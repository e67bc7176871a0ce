"""An integrator bound to a scene, and the step it may take."""
from __future__ import annotations

import math

from ..errors import ConfigError
from ..integrators import Integrator, create_integrator


def check_dt(dt, *, adaptive: bool = False) -> float | None:
    """``dt`` as a float (s), or None for an adaptive method that picks its first step; raises
    ConfigError naming ``dt`` for anything else."""
    if dt is None:
        if adaptive:
            return None
        raise ConfigError("dt is required for a fixed-step integrator")
    if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not (math.isfinite(dt) and dt > 0):
        raise ConfigError(f"dt must be a finite number > 0, got {dt}")
    return float(dt)


def bind_integrator(scene, name: str, **options) -> Integrator:
    """Integrator ``name`` bound to ``scene``'s system with ``options`` over the scene's own
    for that method (:meth:`~taichi_sim.scene.scene.Scene.options_for`: ``cloth-stiff`` runs
    XPBD with 50 substeps unless told otherwise); ConfigError for an unknown name or option.
    Only ``options`` count as given (the scene's are defaults a tolerance may raise)."""
    integrator = create_integrator(name, scene.system, **{**scene.options_for(name), **options})
    integrator.given_options = frozenset(options)
    return integrator
