"""SceneBuilder: collect what a particle scene asks for, allocate fields once in finalize()."""
from __future__ import annotations

from typing import Any

import numpy as np

from ..forces import Drag, Gravity, Springs
from ..systems.particles import ParticleSystem
from .scene import Scene


class SceneBuilder:
    """Collects particles, springs and force terms as numpy data; ``finalize`` allocates.

    Only what was asked for becomes a field or a kernel: a scene without springs has no spring
    fields, one without drag no drag term.
    """

    def __init__(self):
        self._x: list[np.ndarray] = []
        self._v: list[np.ndarray] = []
        self._mass: list[np.ndarray] = []
        self._pinned: list[np.ndarray] = []
        self._springs: list[tuple] = []
        self._gravity: np.ndarray | None = None
        self._drag: float | None = None
        self._count = 0

    @property
    def particle_count(self) -> int:
        return self._count

    def positions(self) -> np.ndarray:
        return np.concatenate(self._x) if self._x else np.zeros((0, 3))

    def add_particles(self, x, mass, *, v=None, pinned=None) -> np.ndarray:
        """Add particles at positions ``x`` (m, shape (k, 3)) with ``mass`` (kg, scalar or (k,)).

        ``v`` (m/s, (k, 3)) defaults to rest; ``pinned`` ((k,) bool) to none. A pinned particle
        starts at rest whatever ``v`` says. Returns the new particles' ids (k,).
        """
        x = np.asarray(x, dtype=float).reshape(-1, 3)
        k = len(x)
        mass = np.broadcast_to(np.asarray(mass, dtype=float), (k,)).copy()
        if not np.all(mass > 0):
            raise ValueError("particle_mass must be > 0")
        pinned = np.zeros(k, bool) if pinned is None else np.asarray(pinned, bool).reshape(k)
        v = np.zeros((k, 3)) if v is None else np.asarray(v, dtype=float).reshape(k, 3).copy()
        v[pinned] = 0.0
        self._x.append(x)
        self._v.append(v)
        self._mass.append(mass)
        self._pinned.append(pinned)
        ids = np.arange(self._count, self._count + k)
        self._count += k
        return ids

    def add_springs(self, ends, *, stiffness, damping=0.0, kind=0, rest_length=None) -> None:
        """Add springs joining ``ends`` ((S, 2) particle ids).

        ``stiffness`` (N/m), ``damping`` (dashpot, N s/m), ``kind`` (0 structural, 1 shear,
        2 flex) and ``rest_length`` (m; default: the current distance) are scalars or (S,).
        """
        ends = np.asarray(ends, dtype=np.int64).reshape(-1, 2)
        S = len(ends)
        if S == 0:
            return
        if ends.min() < 0 or ends.max() >= self._count:
            raise ValueError("spring ends must be ids of particles already added")
        if np.any(ends[:, 0] == ends[:, 1]):
            raise ValueError("a spring must join two different particles")
        stiffness = np.broadcast_to(np.asarray(stiffness, float), (S,)).copy()
        if np.any(stiffness < 0):
            raise ValueError("stiffness must be >= 0")
        damping = np.broadcast_to(np.asarray(damping, float), (S,)).copy()
        if np.any(damping < 0):
            raise ValueError("spring damping must be >= 0")
        if rest_length is None:
            x = self.positions()
            rest_length = np.linalg.norm(x[ends[:, 0]] - x[ends[:, 1]], axis=1)
        rest_length = np.broadcast_to(np.asarray(rest_length, float), (S,)).copy()
        kind = np.broadcast_to(np.asarray(kind, np.int8), (S,)).copy()
        self._springs.append((ends, rest_length, stiffness, damping, kind))

    def set_gravity(self, g) -> None:
        """Gravity: a magnitude (m/s^2, pointing -y) or a 3-vector."""
        g = np.asarray(g, dtype=float)
        self._gravity = np.array([0.0, -float(g), 0.0]) if g.ndim == 0 else g.reshape(3).copy()

    def set_drag(self, k_drag: float) -> None:
        """Viscous drag coefficient (N s/m, >= 0)."""
        if k_drag < 0:
            raise ValueError("drag must be >= 0")
        self._drag = float(k_drag)

    def finalize(self, *, name: str, params: dict[str, Any], default_dt: float,
                 default_integrator: str, seed: int = 0) -> Scene:
        """Allocate every field and return the Scene."""
        if self._count == 0:
            raise ValueError("a scene needs at least one particle")
        x0, v0 = self.positions(), np.concatenate(self._v)
        mass, pinned = np.concatenate(self._mass), np.concatenate(self._pinned)

        features: dict[str, Any] = {"particles": self._count, "pinned": int(pinned.sum())}
        arrays: dict[str, np.ndarray] = {
            "mass": mass, "pinned": pinned,
            "gravity": np.zeros(3) if self._gravity is None else self._gravity,
            "drag": np.float64(self._drag or 0.0),
        }
        system = ParticleSystem(mass, pinned)
        if self._gravity is not None and np.any(self._gravity != 0):
            system.add_term(Gravity(self._gravity, system.mass))
        if self._drag:
            system.add_term(Drag(self._drag))
        if self._springs:
            ends, rest, k, c, kind = (np.concatenate(parts) for parts in zip(*self._springs))
            springs = Springs(self._count, ends, rest, k, c, kind)
            system.add_term(springs)
            arrays.update(springs.arrays())
            features["springs"] = springs.spring_count
            features["dashpots"] = springs.damped
        features["gravity"] = system.term("gravity") is not None
        features["drag"] = system.term("drag") is not None

        state = system.make_state()
        scene = Scene(name=name, system=system, state=state, x0=x0, v0=v0, params=params,
                      features=features, arrays=arrays, default_dt=default_dt,
                      default_integrator=default_integrator, seed=seed)
        scene.reset()
        return scene
