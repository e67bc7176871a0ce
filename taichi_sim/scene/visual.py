"""What to draw for a Scene: a small, explicit description the renderer reads.

:func:`describe` looks at a built :class:`~taichi_sim.scene.scene.Scene` (its name, params,
arrays, features and a few optional attributes) and returns a :class:`SceneVisual`. The renderer
draws only what the visual names; it never steps the scene and never guesses from elsewhere.

Optional scene attributes it looks for (each may be absent; absence draws nothing extra):

``scene.spheres``
    A sequence of sphere colliders, each an object with ``center`` (a 0-D ``ti.Vector.field(3)``,
    m; read every frame so a moving sphere is drawn where it is) and ``radius`` (float, m).
``scene.plane``
    A ground plane as a pair ``(point, normal)`` of (3,) array-likes (m; the normal need not be
    unit length).
``scene.system.term("springs").alive``
    A (S,) integer field over the scene's springs (same order as ``scene.arrays["springs"]``),
    nonzero where the spring is intact. When present the renderer rebuilds its triangle and line
    index buffers every frame: a cloth triangle disappears once one of its edges has torn.
``scene.emitter``
    A particle emitter with ``alive`` (a (capacity,) integer field, nonzero for a live particle),
    ``age`` (a (capacity,) float field, s), ``lifetime`` (float, s) and optionally ``first``
    (int, the particle id of emitter slot 0; default: the last ``capacity`` particles). Only live
    emitter particles are drawn, coloured by age / lifetime.
``scene.view_bounds``
    ``(lo, hi)``, two (3,) array-likes (m): the box the camera should frame at the start,
    overriding the box derived from the initial positions.

Cloth: a scene whose params hold integers ``nx`` and ``ny`` with ``nx * ny <= particle_count``
draws particles ``0 .. nx*ny - 1`` as a grid surface, particle (i, j) having id ``i * ny + j``
(see :func:`taichi_sim.scene.cloth.grid_index`); further particles are drawn as points.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .cloth import STRUCTURAL
from .scene import Scene


@dataclass(frozen=True)
class Sphere:
    """A sphere to draw: ``center`` is a 0-D vec3 field (m), ``radius`` a float (m)."""

    center: Any
    radius: float


@dataclass(frozen=True)
class Plane:
    """An infinite plane through ``point`` (m) with unit ``normal``; both (3,) float64."""

    point: np.ndarray
    normal: np.ndarray


@dataclass(frozen=True)
class Emitter:
    """Emitter slots ``first .. first + capacity - 1``: ``alive`` (capacity,) int field,
    ``age`` (capacity,) float field (s), ``lifetime`` (s)."""

    alive: Any
    age: Any
    lifetime: float
    first: int
    capacity: int


@dataclass(frozen=True)
class SceneVisual:
    """Everything the renderer draws for one scene.

    Attributes:
        name: the scene's preset name (used in labels).
        positions: ``scene.state.x``, the (n,) vec3 field read every frame (m).
        particle_count: n.
        first_order: whether the system is a first-order ODE (positions only).
        pinned: (n,) bool, pinned particles (drawn in a distinct colour).
        grid: (nx, ny) when particles ``0 .. nx*ny - 1`` form a cloth grid, else None.
        springs: (S, 2) int64 particle ids of every spring (S may be 0).
        spring_kind: (S,) int64, 0 structural, 1 shear, 2 flex.
        rest_length: (S,) float64 rest lengths (m).
        spring_alive: (S,) int field, nonzero where intact, or None when springs never tear.
        line_springs: (L,) int64 ids of the springs drawn as lines and used for the strain
            colour map: the structural springs of a cloth, every spring otherwise.
        spheres, plane, emitter: the optional extras (see the module docstring).
        trail: draw a fading trail behind each particle (the circle ODE).
        guides: static polylines drawn faintly, each (k, 3) float64 (m), e.g. the exact orbit.
        particle_radius: radius of a drawn particle (m).
        bounds: (lo, hi), each (3,) float64: the box to frame at the start (m).
        view: (yaw, pitch) of the initial camera direction (degrees; yaw 0 looks along -z).
    """

    name: str
    positions: Any
    particle_count: int
    first_order: bool
    pinned: np.ndarray
    grid: tuple[int, int] | None
    springs: np.ndarray
    spring_kind: np.ndarray
    rest_length: np.ndarray
    spring_alive: Any | None
    line_springs: np.ndarray
    spheres: tuple[Sphere, ...]
    plane: Plane | None
    emitter: Emitter | None
    trail: bool
    guides: tuple[np.ndarray, ...]
    particle_radius: float
    bounds: tuple[np.ndarray, np.ndarray]
    view: tuple[float, float]

    @property
    def center(self) -> np.ndarray:
        """Centre of :attr:`bounds` (m)."""
        return 0.5 * (self.bounds[0] + self.bounds[1])

    @property
    def extent(self) -> np.ndarray:
        """Size of :attr:`bounds` along x, y, z (m)."""
        return self.bounds[1] - self.bounds[0]


def describe(scene: Scene) -> SceneVisual:
    """The :class:`SceneVisual` of ``scene`` (reads it; allocates no Taichi fields)."""
    n = scene.particle_count
    x0 = np.asarray(scene.x0, dtype=np.float64).reshape(n, 3)
    pinned = np.asarray(scene.arrays.get("pinned", np.zeros(n, bool)), bool).reshape(n)
    springs = np.asarray(scene.arrays.get("springs", np.zeros((0, 2))), np.int64).reshape(-1, 2)
    S = len(springs)
    kind = np.asarray(scene.arrays.get("spring_kind", np.zeros(S)), np.int64).reshape(S)
    rest = np.asarray(scene.arrays.get("rest_length", np.zeros(S)), np.float64).reshape(S)
    grid = _grid(scene.params, n)
    line_springs = np.flatnonzero(kind == STRUCTURAL) if grid is not None else np.arange(S)
    first_order = not scene.system.second_order

    term = scene.system.term("springs") if hasattr(scene.system, "term") else None
    spring_alive = getattr(term, "alive", None) if term is not None else None
    spheres = tuple(Sphere(center=s.center, radius=float(s.radius))
                    for s in (getattr(scene, "spheres", None) or ()))
    plane = _plane(getattr(scene, "plane", None))
    emitter = _emitter(getattr(scene, "emitter", None), n)

    guides: tuple[np.ndarray, ...] = ()
    if scene.name == "simple":  # the exact solution: a circle of the initial radius about z
        angle = np.linspace(0.0, 2.0 * math.pi, 129)
        radius = float(np.linalg.norm(x0[0, :2]))
        guides = (np.stack([radius * np.cos(angle), radius * np.sin(angle),
                            np.full_like(angle, x0[0, 2])], axis=1),)

    gravity = np.asarray(scene.arrays.get("gravity", np.zeros(3)), float).reshape(3)
    lo, hi = _bounds(x0, pinned, hanging=bool(np.any(gravity != 0)), guides=guides, spheres=spheres)
    override = getattr(scene, "view_bounds", None)
    if override is not None:
        lo, hi = (np.asarray(b, np.float64).reshape(3) for b in override)
    extent = float(np.linalg.norm(hi - lo)) or 1.0

    if grid is not None:
        nx, ny = grid
        spacing = float(np.median(rest[line_springs])) if len(line_springs) else extent / max(nx, ny)
        radius = 0.3 * spacing
        view = (35.0, 25.0)
    else:
        radius = 0.03 * extent
        if S:
            radius = min(radius, 0.25 * float(np.median(rest)))
        planar = bool(np.ptp(x0[:, 2]) == 0.0)
        view = (0.0, 0.0) if first_order else ((0.0, 8.0) if planar else (30.0, 20.0))
    return SceneVisual(
        name=scene.name, positions=scene.state.x, particle_count=n, first_order=first_order,
        pinned=pinned, grid=grid, springs=springs, spring_kind=kind, rest_length=rest,
        spring_alive=spring_alive, line_springs=line_springs.astype(np.int64), spheres=spheres,
        plane=plane, emitter=emitter, trail=first_order, guides=guides,
        particle_radius=float(radius), bounds=(lo, hi), view=view)


def _grid(params: dict, n: int) -> tuple[int, int] | None:
    nx, ny = params.get("nx"), params.get("ny")
    if isinstance(nx, int) and isinstance(ny, int) and nx >= 2 and ny >= 2 and nx * ny <= n:
        return nx, ny
    return None


def _plane(value) -> Plane | None:
    if value is None:
        return None
    point, normal = (np.asarray(v, np.float64).reshape(3) for v in value)
    length = float(np.linalg.norm(normal))
    if not length > 0:
        raise ValueError("scene.plane normal must be nonzero")
    return Plane(point=point, normal=normal / length)


def _emitter(value, n: int) -> Emitter | None:
    if value is None:
        return None
    capacity = int(value.alive.shape[0])
    first = int(getattr(value, "first", n - capacity))
    if first < 0 or first + capacity > n:
        raise ValueError(f"emitter slots {first}..{first + capacity - 1} are not particles of the scene")
    return Emitter(alive=value.alive, age=value.age, lifetime=float(value.lifetime), first=first,
                   capacity=capacity)


def _bounds(x0: np.ndarray, pinned: np.ndarray, *, hanging: bool, guides, spheres) -> tuple[np.ndarray, np.ndarray]:
    """The box to frame (m): the initial positions, guides and spheres; for a pinned scene under
    gravity also where it can swing (mirrored about the pins' centroid in x and z) and hang (down
    from that centroid by 1.2x the farthest particle's distance)."""
    points = [x0]
    if hanging and pinned.any():
        pin = x0[pinned].mean(axis=0)
        reach = 1.2 * float(np.max(np.linalg.norm(x0 - pin, axis=1)))
        mirrored = x0.copy()
        mirrored[:, [0, 2]] = 2.0 * pin[[0, 2]] - x0[:, [0, 2]]
        points += [mirrored, (pin - [0.0, reach, 0.0])[None, :]]
    points += list(guides)
    for s in spheres:
        c = np.asarray(s.center.to_numpy(), np.float64).reshape(3)
        points.append(np.stack([c - s.radius, c + s.radius]))
    allp = np.concatenate(points)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    pad = 0.05 * max(float(np.max(hi - lo)), 1e-3)
    return lo - pad, hi + pad
