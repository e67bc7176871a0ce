"""A Scene: a system, the state it owns, and how to describe both."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..state import State
from ..systems.base import System


@dataclass
class Scene:
    """What a preset builds: a system, its state, and metadata.

    Attributes:
        name: the preset name.
        system: the ODE (eval_f).
        state: the current state (owned here; integrators step it in place).
        x0, v0: initial positions and velocities, (n, 3) float64 numpy arrays (v0 is None for a
            first-order system).
        params: the resolved parameter values.
        features: what the scene models, e.g. {"gravity": True, "springs": 1200}; a feature that
            is absent allocated nothing.
        arrays: time-invariant model data for the npz (mass, pinned, springs, ...).
        default_dt, default_integrator: what ``simulate`` uses when not told.
        seed: the random seed the scene was built with.
    """

    name: str
    system: System
    state: State
    x0: np.ndarray
    v0: np.ndarray | None
    params: dict[str, Any]
    features: dict[str, Any]
    arrays: dict[str, np.ndarray]
    default_dt: float
    default_integrator: str
    seed: int = 0
    post_step: list = field(default_factory=list)

    @property
    def particle_count(self) -> int:
        return self.system.particle_count

    def reset(self) -> None:
        """Back to the initial state."""
        self.state.from_numpy(self.x0, self.v0)

    def energy(self) -> float | None:
        """Total energy (J) of the current state, or None when the system defines none."""
        return self.system.energy(self.state)

    def after_step(self, t: float, h: float) -> None:
        """Apply post-step events (collisions, tearing, emission) after an accepted step."""
        for event in self.post_step:
            event(self.state, t, h)
