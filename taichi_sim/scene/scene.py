"""A Scene: a system, the state it owns, its post-step events, and how to describe them."""
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..state import State
from ..systems.base import System


@dataclass
class Scene:
    """What a preset builds: a system, its state, post-step events and metadata.

    Attributes:
        name: the preset name.
        system: the ODE (eval_f).
        state: the current state (owned here; integrators step it in place).
        x0, v0: initial positions and velocities, (n, 3) float64 numpy arrays (v0 is None for a
            first-order system).
        params: the resolved parameter values.
        features: what the scene models, e.g. {"gravity": True, "springs": 1200, "wind": False};
            a feature that is absent (False / 0) allocated no field and compiled no kernel.
        static_arrays: model data fixed at build time (mass, pinned, gravity, drag, ...); see
            :attr:`arrays` for everything.
        default_dt, default_integrator: what ``simulate`` uses when not told.
        seed: the random seed the scene was built with.
        post_step: events applied after every accepted step, in order (colliders, tearing,
            emitter).
        springs, mesh, spheres, capsules, boxes, plane, emitter, grabber, constraints, kinematic:
            the optional parts, or None (``kinematic``: the scripted pins, also in ``post_step``).
        rest_x: (n, 3) float64 positions the springs rest in (before a seeded jitter), or None.
    """

    name: str
    system: System
    state: State
    x0: np.ndarray
    v0: np.ndarray | None
    params: dict[str, Any]
    features: dict[str, Any]
    static_arrays: dict[str, np.ndarray]
    default_dt: float
    default_integrator: str
    seed: int = 0
    post_step: list = field(default_factory=list)
    springs: Any = None
    mesh: Any = None
    spheres: Any = None
    capsules: Any = None
    boxes: Any = None
    plane: Any = None
    emitter: Any = None
    grabber: Any = None
    constraints: Any = None
    kinematic: Any = None
    rest_x: np.ndarray | None = None

    @property
    def particle_count(self) -> int:
        return self.system.particle_count

    def spare_state(self) -> State:
        """A second state of this scene's shape, allocated on first use and the same object
        ever after (the blow-up guard keeps its last good state there: copying between two
        states compiles a kernel per pair of State objects, so the pair must not change)."""
        spare = self.__dict__.get("_spare_state")
        if spare is None:
            spare = self.__dict__["_spare_state"] = self.system.make_state()
        return spare

    def reset(self) -> None:
        """Back to the initial state (the model's optional parts keep their changes: torn
        springs stay torn; rebuild the scene for a fresh one)."""
        self.state.from_numpy(self.x0, self.v0)
        for colliders in (self.spheres, self.capsules, self.boxes):
            if colliders is not None:
                colliders.move_to(0.0)

    def restore(self) -> None:
        """Back to the scene as built: the initial state, torn springs mended, no particle
        emitted and the emitter's random stream restarted (unlike :meth:`reset`), without
        allocating anything."""
        for event in self.post_step:
            if hasattr(event, "restore"):
                event.restore()
        self.reset()

    def energy(self) -> float | None:
        """Total energy (J) of the current state, or None when the system defines none."""
        return self.system.energy(self.state)

    def after_step(self, t: float, h: float) -> bool:
        """Apply post-step events (collisions, tearing, emission) after an accepted step that
        ended at time ``t`` (s) and was ``h`` (s) long. Returns whether an event changed the
        system itself (not just the state), so integrators that carry data between steps must
        be reset."""
        changed = False
        for event in self.post_step:
            changed |= bool(event(self.state, t, h))
        return changed

    @property
    def arrays(self) -> dict[str, np.ndarray]:
        """The npz's model keys as they are now (numpy copies): the static arrays plus what
        may change during a run (springs, live springs, sphere centres, emitter ages)."""
        out = dict(self.static_arrays)
        if self.springs is not None:
            out.update(self.springs.arrays())
        if self.spheres is not None:
            out["sphere_center"] = self.spheres.centers()
        if self.capsules is not None:
            out["capsule_center"] = self.capsules.centers()
        if self.boxes is not None:
            out["box_center"] = self.boxes.centers()
        if self.emitter is not None:
            out.update(self.emitter.arrays())
        if self.constraints is not None:
            out.update(self.constraints.arrays())
        return out

    def constraint_violation(self) -> float | None:
        """The largest |C| (m) over the constraints at the current state, or None without
        constraints."""
        return None if self.constraints is None else self.constraints.violation(self.state)
