"""The handoff between a scene and the integrator that steps it: what the scene offers a solve
(:class:`ContactInputs`, :meth:`Scene.contact_inputs <taichi_sim.scene.scene.Scene.contact_inputs>`)
and what the integrator answers it took over (:class:`ContactTakeover`, applied by
:meth:`Scene.hand_over <taichi_sim.scene.scene.Scene.hand_over>`).

The Stepper makes one call each way when it binds an integrator,
``scene.hand_over(integrator.bind_contact(scene.contact_inputs()))``: an integrator learns
the scene's contact only from the inputs (never by reading its parts by name), and the scene
alone acts on the answer (which post-step events it leaves out, whether the objects' face pass
waits). A method that meets nothing in its solve answers :data:`NOTHING_TAKEN`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..part import MovingSource

# The contact radius (m) a solve takes on a scene without a ``thickness`` parameter (one built
# without a cloth preset's parameters).
DEFAULT_THICKNESS = 0.005


@dataclass(frozen=True, eq=False)
class ContactInputs:
    """What a scene offers an integrator that takes contact into its solve.

    Attributes:
        system: the scene's particle system (the one the integrator is bound to).
        state: the scene's state (read at the handoff: where the cloth starts).
        cloth: the cloth's :class:`~taichi_sim.mesh.TriangleMesh`, or None.
        rest_x: (n, 3) float64 positions (m) the cloth rests in, or None (then its positions
            at the handoff are its rest: :meth:`rest`).
        plane: the ground (:class:`~taichi_sim.scene.colliders.plane.PlaneCollider`), or None.
        shapes: the analytic object colliders (spheres, capsules, boxes, registered kinds:
            the parts with the shape functions of
            :class:`~taichi_sim.scene.colliders.obstacle.Obstacle`), in the scene's order.
        collider_mesh: the triangle-mesh collider
            (:class:`~taichi_sim.scene.colliders.mesh_collider.MeshCollider`), or None.
        self_collision: the post-step self-collision stage
            (:class:`~taichi_sim.collide.SelfCollision`), or None.
        pins: the scripted pins (:class:`~taichi_sim.scene.kinematic.KinematicPins`), or None.
        thickness: the distance (m) the cloth keeps from itself and from the objects (the
            scene's ``thickness``, :data:`DEFAULT_THICKNESS` without one).
        self_friction: the cloth's friction coefficient against itself (>= 0).
        closed: whether nothing in the scene can add energy within a step: no wind, no
            turbulence, no part that launches particles or moves (a moving collider, scripted
            pins), as the guard counts them (a solve may then cap its energy).
    """

    system: Any
    state: Any
    cloth: Any = None
    rest_x: np.ndarray | None = None
    plane: Any = None
    shapes: tuple = ()
    collider_mesh: Any = None
    self_collision: Any = None
    pins: Any = None
    thickness: float = DEFAULT_THICKNESS
    self_friction: float = 0.0
    closed: bool = False

    @property
    def has_objects(self) -> bool:
        """Whether the scene has an object to meet: the ground, a shape or a collider mesh."""
        return self.plane is not None or bool(self.shapes) or self.collider_mesh is not None

    def positions(self) -> np.ndarray:
        """(n, 3) float64: the state's positions (m) now."""
        return self.state.to_numpy()[0]

    def rest(self) -> np.ndarray:
        """(n, 3): the positions (m) the cloth rests in (``rest_x``, else its positions now)."""
        return self.rest_x if self.rest_x is not None else self.positions()

    def same_as(self, other: ContactInputs | None) -> bool:
        """Whether ``other`` offers the same objects, stages and settings (a method bound to it
        need not bind again: a launcher switching methods back)."""
        if other is None:
            return False
        same = ("system", "state", "cloth", "rest_x", "plane", "collider_mesh", "self_collision", "pins")
        return (all(getattr(self, name) is getattr(other, name) for name in same)
                and len(self.shapes) == len(other.shapes)
                and all(a is b for a, b in zip(self.shapes, other.shapes))
                and (self.thickness, self.self_friction, self.closed)
                == (other.thickness, other.self_friction, other.closed))


@dataclass(frozen=True)
class ContactTakeover:
    """What an integrator took over from the scene once bound to its :class:`ContactInputs`.

    Attributes:
        parts: names of the scene parts (``ScenePart.name``: ``self_collision``,
            ``kinematic``, ``collider_mesh``) whose post-step work the solve does itself: their
            events are left out after each step.
        pauses_object_faces: whether the object colliders' face pass waits (their vertex pass
            still runs): the solve keeps the cloth off itself with bounds on each vertex's
            move, which a face push after the step would break (a box's edge under a fold
            tangled it: docs/vbd-contact.md).
    """

    parts: frozenset = frozenset()
    pauses_object_faces: bool = False

    def __post_init__(self):
        parts = self.parts
        if isinstance(parts, str) or not all(isinstance(name, str) for name in parts):
            raise ValueError(f"ContactTakeover parts must be part names, got {parts!r}")
        object.__setattr__(self, "parts", frozenset(parts))


NOTHING_TAKEN = ContactTakeover()


def closed_scene(system, parts) -> bool:
    """Whether nothing among ``system``'s terms and ``parts`` can add energy within a step
    (:attr:`ContactInputs.closed`)."""
    term = getattr(system, "term", None)  # (a first-order ODE has no force terms)
    if term is not None and any(term(name) is not None for name in ("wind", "turbulence")):
        return False
    sources = [source for part in parts for source in part.energy_sources()]
    return all(isinstance(source, MovingSource) and not source.speed > 0 for source in sources)
