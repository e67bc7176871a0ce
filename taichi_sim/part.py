"""The scene-part protocol: what every optional piece of a scene (a collider, the ground, an
emitter, scripted pins, the self-contact stage) tells the code that runs, saves, guards, draws
and summarises a scene, so each of those loops over ``Scene.parts`` and none lists the kinds.

A part is also its own post-step event (``part(state, t, h)``, applied between accepted steps,
never inside f: docs/design.md). The base class answers "nothing" to every question, so a part
overrides only what it has. Adding a collider is its file (the part and the spec the builder
takes: :class:`PartSpec`) and one builder method; see "Scene parts" in docs/design.md.

This module sits with the foundations (numpy only) so that every layer that builds a part (the
scene's colliders, the self-contact stage below them) can implement it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np


@dataclass(frozen=True)
class SolidMesh:
    """A rigid triangle mesh to draw for a part, in the part's own frame.

    Attributes:
        vertices: (m, 3) float64 (m), about the part's origin; normals: (m, 3) unit outward;
        triangles: (t, 3) int vertex ids, counter-clockwise seen from outside.
        place: returns the (3,) translation (m) of the part's origin now (called every frame,
            so a moving collider is drawn where it is).
        reach: (3,) half extents (m) about that origin the camera frames at the start.
        hidden_from_above: a resting object a cloth drapes over, which a camera from above
            would not see (the scene is then seen from low).
        pose: for a deforming solid (an animated collider mesh), returns its (vertices,
            normals) now, shaped as ``vertices`` and ``normals``; None for a rigid one.
    """

    vertices: np.ndarray
    normals: np.ndarray
    triangles: np.ndarray
    place: Callable[[], np.ndarray]
    reach: np.ndarray
    hidden_from_above: bool = False
    pose: Callable[[], tuple[np.ndarray, np.ndarray]] | None = None


@dataclass(frozen=True)
class MovingSource:
    """A scripted part that pushes the cloth (a moving collider, kinematic pins): the guard
    allows what it gives the cloth moving at twice its ``speed`` (m/s, its fastest surface
    speed) plus the stretch of every spring by its travel, capped at ``farthest`` (m)."""

    label: str
    speed: float
    farthest: float = math.inf


@dataclass(frozen=True)
class LaunchSource:
    """A part that launches particles (an emitter): at most ``count`` of ``mass`` (kg) each at
    ``speed`` (m/s) from ``height`` (m) at a time, each living ``lifetime`` (s)."""

    label: str
    count: int
    mass: float
    speed: float
    height: float
    lifetime: float


class ScenePart:
    """Base of every scene part (module docstring). Override what the part has.

    Class attributes:
        name: the part's key in ``Scene.features`` and in ``Scene.part(name)``.
        order: where its post-step event runs among the scene's parts (lower first): scripted
            pins 0, objects 10-19, the ground 20, self-contact 30, tearing 40, emission 50.
        is_obstacle: the part keeps cloth out of objects that the self-contact stage must not
            push the cloth back into; it then has the ``ti.func`` ``nearest_surface(x, t, reach)``
            (see :class:`~taichi_sim.scene.colliders.obstacle.Obstacle`).
    """

    name = "part"
    order = 50
    is_obstacle = False

    def __call__(self, state, t: float, h: float) -> bool:
        """The post-step event after an accepted step ending at ``t`` (s), ``h`` (s) long.
        Returns whether it changed the system itself (not just the state)."""
        return False

    def reset(self) -> None:
        """Back to t = 0 (a moving collider to where its path starts), keeping changes a run
        made to the model (torn springs stay torn)."""

    def restore(self) -> None:
        """Back to the part as built, changes undone (called before :meth:`reset`)."""

    def features(self) -> dict[str, Any]:
        """What the part adds to ``Scene.features``, e.g. ``{"spheres": 2}``."""
        return {}

    def arrays(self) -> dict[str, np.ndarray]:
        """The part's keys in the run's npz, as they are now (numpy copies)."""
        return {}

    def visuals(self) -> list:
        """What to draw: :class:`SolidMesh` items, or the scene layer's ground plane and
        particle source descriptions (:mod:`taichi_sim.scene.visual`)."""
        return []

    def energy_sources(self) -> list:
        """What the guard must allow this part to inject: :class:`MovingSource` and
        :class:`LaunchSource` items (none for a part that only takes energy away)."""
        return []

    def summary(self) -> str:
        """One line on the run so far for the run's summary ('' for nothing to say)."""
        return ""

    def warning(self) -> str:
        """What may be wrong with the run so far ('' when nothing)."""
        return ""


@dataclass
class PartContext:
    """What a part needs from the scene being built (see :class:`PartSpec`).

    Attributes:
        system: the :class:`~taichi_sim.systems.particles.ParticleSystem` (its ``free`` field,
            its inverse masses).
        faces: the cloth's :class:`~taichi_sim.mesh.TriangleMesh` that object colliders test
            as well as its vertices, or None (no triangles, or object faces turned off).
        seed: the scene's random seed.
        options: builder-wide switches a kind reads (e.g. ``continuous_spheres``).
    """

    system: Any
    faces: Any
    seed: int = 0
    options: dict[str, Any] = field(default_factory=dict)


class PartSpec:
    """What a builder method records for one object of a kind: a frozen dataclass with
    ``part_class``, whose ``from_specs(specs, context)`` builds one part holding every object of
    that kind the scene asked for (one kernel loop over them), at ``finalize``."""

    part_class: type
