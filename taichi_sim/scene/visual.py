"""What to draw for a Scene: a small, explicit description the renderer reads.

:func:`describe` looks at a built :class:`~taichi_sim.scene.scene.Scene` and returns a
:class:`SceneVisual`. The renderer draws only what the visual names; it never steps the scene.

What it reads from the scene (every optional part may be None or absent; then nothing extra is
drawn):

- ``scene.x0``, ``scene.name``, ``scene.params``, ``scene.system.second_order``,
  ``scene.arrays["pinned"]`` and ``scene.arrays["gravity"]`` (positions are read every frame by
  the renderer from ``scene.state.x``).
- ``scene.springs``: the springs term, with ``ends_np`` (S, 2), ``kind_np`` (S,) (0 structural,
  1 shear, 2 flex), ``rest`` (an (S,) field, m) and, when ``tearable``, ``alive`` (an (S,) int
  field, nonzero while intact). Springs are drawn as lines: a cloth's structural ones only.
- ``scene.constraints``: rods (drawn as the springs would be, in a scene without springs) and
  the circular wires beads ride on (drawn as guides).
- ``scene.mesh``: the surface triangles, with ``triangles_np`` (T, 3) particle ids wound
  counter-clockwise seen from the front, ``tearable``, and the kernel
  ``fill_index_buffer(out)`` that writes the 3T indices into a 1-D i32 field, a torn triangle
  as a degenerate one. Drawn as a shaded two-coloured surface.
- ``scene.parts``: each part's ``visuals()`` (:class:`~taichi_sim.part.ScenePart`): rigid
  meshes (:class:`~taichi_sim.part.SolidMesh`: the colliders, drawn where their ``place()`` puts
  them every frame), a ground :class:`Plane`, an :class:`Emitter`'s particles. Only live emitter
  particles are drawn, with the look ``scene.params["effect"]`` names (water without one).
- ``scene.grabber``: the mouse-grab API (``pick(origin, direction)``, ``grab(particle)``,
  ``drag_to(target)``, ``release()``), passed through for the launcher.
- ``scene.params["pin"] == "pole"`` on a cloth: its pinned edge hangs on a pole, drawn as a
  rod through the pinned particles (down to the ground, or to y = 0 without one, when the edge
  is vertical).
- ``scene.view_bounds`` (optional): ``(lo, hi)``, two (3,) array-likes (m), the box the camera
  frames at the start, overriding the one derived from the initial positions, pins, spheres,
  spray and ground.

A scene whose params hold integers ``nx`` and ``ny`` with ``nx * ny <= particle_count`` is a
cloth grid: particle (i, j) has id ``i * ny + j`` (see :func:`taichi_sim.scene.cloth.grid_index`),
which the fabric pattern uses.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np

from ..part import SolidMesh
from ..systems.constraints import PLANE, POINT, ROD
from .cloth import STRUCTURAL
from .scene import Scene


@dataclass(frozen=True)
class Plane:
    """An infinite plane through ``point`` (m) with unit ``normal``; both (3,) float64."""

    point: np.ndarray
    normal: np.ndarray


@dataclass(frozen=True)
class Emitter:
    """Emitter slots ``first .. first + capacity - 1``: ``alive`` (capacity,) int field,
    ``age`` (capacity,) float field (s), ``lifetime`` (s) as built, and ``effect``, the look of
    its particles over their life (``water``, ``fire`` or ``smoke``; see
    :mod:`taichi_sim.render.effects`). ``lifetime_now()``, when given, returns the lifetime (s)
    as it is now (a slider or a curve may change it while the scene runs)."""

    alive: Any
    age: Any
    lifetime: float
    first: int
    capacity: int
    effect: str = "water"
    lifetime_now: Callable[[], float] | None = None
    spec: Any = None  # the emitter's EmitterSpec (nozzle, direction, speed, spread), to frame the spray


@dataclass(frozen=True)
class Pole:
    """A rod from ``bottom`` to ``top`` ((3,) float64, m) of ``radius`` (m): the pole a flag's
    pinned edge hangs on."""

    bottom: np.ndarray
    top: np.ndarray
    radius: float


@dataclass(frozen=True)
class SceneVisual:
    """Everything the renderer draws for one scene.

    Attributes:
        name: the scene's preset name (used in labels).
        particle_count: n (the positions themselves are read every frame from the scene's
            ``state.x`` field, or from an array the caller passes the renderer).
        first_order: whether the system is a first-order ODE (positions only).
        pinned: (n,) bool, pinned particles (drawn in a distinct colour).
        grid: (nx, ny) when particles ``0 .. nx*ny - 1`` form a cloth grid, else None.
        triangles: (T, 3) int64 surface triangles (T may be 0).
        mesh: the scene's mesh object (its ``fill_index_buffer`` kernel drops torn triangles),
            or None when there is no surface.
        tearing: whether springs (and so triangles) can tear: index buffers change per frame.
        springs: (S, 2) int64 particle ids of every spring (S may be 0).
        rest_length: (S,) float64 rest lengths (m).
        spring_alive: (S,) int field, nonzero where intact, or None when springs never tear.
        line_springs: (L,) int64 ids of the springs drawn as lines and used for the strain
            colour map: a cloth's structural springs, every spring otherwise.
        plane, emitter: the optional extras (see the module docstring).
        solids: the parts' rigid meshes (colliders), possibly none.
        pole: the rod a cloth pinned with ``pin=pole`` hangs on, or None.
        grabber: the scene's mouse-grab API, or None.
        trail: draw a fading trail behind each particle (the circle ODE).
        guides: static polylines drawn faintly, each (k, 3) float64 (m), e.g. the exact orbit.
        particle_radius: radius of a drawn particle (m).
        bounds: (lo, hi), each (3,) float64: the box to frame at the start (m).
        view: (yaw, pitch) of the initial camera direction (degrees; yaw 0 looks along -z).
    """

    name: str
    particle_count: int
    first_order: bool
    pinned: np.ndarray
    grid: tuple[int, int] | None
    triangles: np.ndarray
    mesh: Any | None
    tearing: bool
    springs: np.ndarray
    rest_length: np.ndarray
    spring_alive: Any | None
    line_springs: np.ndarray
    plane: Plane | None
    emitter: Emitter | None
    pole: Pole | None
    grabber: Any | None
    trail: bool
    guides: tuple[np.ndarray, ...]
    particle_radius: float
    bounds: tuple[np.ndarray, np.ndarray]
    view: tuple[float, float]
    solids: tuple[SolidMesh, ...] = ()

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
    arrays = scene.arrays
    pinned = np.asarray(arrays.get("pinned", np.zeros(n, bool)), bool).reshape(n)
    first_order = not scene.system.second_order

    term = getattr(scene, "springs", None)
    if term is not None:
        springs = np.asarray(term.ends_np, np.int64).reshape(-1, 2)
        kind = np.asarray(term.kind_np, np.int64).reshape(-1)
        rest = np.asarray(term.rest.to_numpy(), np.float64).reshape(-1)
        alive = term.alive if term.tearable else None
    else:
        springs, kind, rest, alive = np.zeros((0, 2), np.int64), np.zeros(0, np.int64), np.zeros(0), None
    constraints = getattr(scene, "constraints", None)
    if term is None and constraints is not None:  # rods are drawn as the springs would be
        rods = constraints.kind_np == ROD
        springs = constraints.particles_np[rods].astype(np.int64).reshape(-1, 2)
        kind, rest = np.zeros(len(springs), np.int64), constraints.length_np[rods].astype(np.float64)
    mesh = getattr(scene, "mesh", None)
    triangles = np.asarray(mesh.triangles_np, np.int64).reshape(-1, 3) if mesh is not None \
        else np.zeros((0, 3), np.int64)
    line_springs = np.flatnonzero(kind == STRUCTURAL) if len(triangles) else np.arange(len(springs))

    items = [item for part in getattr(scene, "parts", ()) for item in part.visuals()]
    solids = tuple(item for item in items if isinstance(item, SolidMesh))
    plane = next((item for item in items if isinstance(item, Plane)), None)
    emitter = next((item for item in items if isinstance(item, Emitter)), None)
    if emitter is not None:
        emitter = replace(emitter, effect=str(scene.params.get("effect", "water")))

    guides: tuple[np.ndarray, ...] = ()
    if scene.name == "simple":  # the exact solution: the initial circle about the z axis
        angle = np.linspace(0.0, 2.0 * math.pi, 129)
        radius = float(np.linalg.norm(x0[0, :2]))
        guides = (np.stack([radius * np.cos(angle), radius * np.sin(angle),
                            np.full_like(angle, x0[0, 2])], axis=1),)
    if constraints is not None:
        guides += _wires(constraints)

    gravity = np.asarray(arrays.get("gravity", np.zeros(3)), np.float64).reshape(3)
    pole = _pole(x0[pinned], plane) if scene.params.get("pin") == "pole" and len(triangles) else None
    live = np.ones(n, bool)
    extra = list(guides) + ([np.stack([pole.bottom, pole.top])] if pole is not None else [])
    for solid in solids:  # each solid's bounding box, to frame it
        center = np.asarray(solid.place(), np.float64).reshape(1, 3)
        extra += [center - solid.reach, center + solid.reach]
    if emitter is not None:  # dead slots all sit at the nozzle: frame the spray's paths instead
        live[emitter.first:emitter.first + emitter.capacity] = False
        live[emitter.first] = True
        drag = float(arrays.get("drag", 0.0))
        tau = float(np.asarray(arrays["mass"])[emitter.first]) / drag if drag > 0 else math.inf
        extra.append(_spray(emitter.spec, gravity, plane, tau))
    lo, hi = _bounds(x0[live], pinned[live], hanging=bool(np.any(gravity != 0)),
                     swinging=not len(triangles), extra=extra, plane=plane)
    override = getattr(scene, "view_bounds", None)
    if override is not None:
        lo, hi = (np.asarray(b, np.float64).reshape(3) for b in override)
    size = float(np.linalg.norm(hi - lo)) or 1.0

    grid = _grid(scene.params, n)
    if len(triangles):
        spacing = float(np.median(rest[line_springs])) if len(line_springs) else 0.02 * size
        radius = 0.3 * spacing
        # A vertical cloth (a flag) is seen from the front, a horizontal one from above, or from
        # low when it falls onto a resting sphere: from above, the draped cloth hides the sphere.
        if scene.params.get("orientation") == "vertical":
            view = (20.0, 8.0)
        elif any(s.hidden_from_above for s in solids) and scene.params.get("sphere_motion", "static") == "static":
            view = (30.0, 10.0)
        else:
            view = (30.0, 30.0)
    else:
        radius = (0.005 if emitter is not None else 0.025) * size  # a spray is many small drops
        if len(rest):
            radius = min(radius, 0.15 * float(np.median(rest)))
        planar = bool(np.ptp(x0[:, 2]) == 0.0)
        view = (0.0, 0.0) if first_order else ((0.0, 8.0) if planar and emitter is None else (30.0, 20.0))
    return SceneVisual(
        name=scene.name, particle_count=n, first_order=first_order,
        pinned=pinned, grid=grid, triangles=triangles, mesh=mesh if len(triangles) else None,
        tearing=alive is not None, springs=springs, rest_length=rest, spring_alive=alive,
        line_springs=line_springs.astype(np.int64), plane=plane, emitter=emitter, pole=pole,
        grabber=getattr(scene, "grabber", None), trail=first_order, guides=guides,
        particle_radius=float(radius), bounds=(lo, hi), view=view, solids=solids)


def _pole(pins: np.ndarray, plane: Plane | None) -> Pole | None:
    """The rod through the pinned particles ``pins`` ((k, 3), m): 5 % longer than the pinned
    edge at its top, and, when the edge is vertical, down to the ground plane (y = 0 without
    one), as a flagpole stands; None for fewer than two distinct pins."""
    if len(pins) < 2:
        return None
    centre = pins.mean(axis=0)
    axis = pins[np.argmax(np.linalg.norm(pins - centre, axis=1))] - centre
    length = 2.0 * float(np.linalg.norm(axis))
    if length == 0.0:
        return None
    axis /= np.linalg.norm(axis)
    if axis[1] < 0:
        axis = -axis
    along = (pins - centre) @ axis
    top = centre + (along.max() + 0.05 * length) * axis
    bottom = centre + (along.min() - 0.05 * length) * axis
    if abs(axis[1]) > 0.9:  # upright: it stands on the ground
        ground = plane.point[1] if plane is not None and abs(plane.normal[1]) > 0.9 else 0.0
        bottom = np.array([top[0], min(bottom[1], ground), top[2]])
        top = np.array([top[0], top[1], top[2]])
    return Pole(bottom=bottom, top=top, radius=0.012 * length)


def _grid(params: dict, n: int) -> tuple[int, int] | None:
    nx, ny = params.get("nx"), params.get("ny")
    if isinstance(nx, int) and isinstance(ny, int) and nx >= 2 and ny >= 2 and nx * ny <= n:
        return nx, ny
    return None


def _spray(spec, gravity: np.ndarray, plane: Plane | None, tau: float = math.inf) -> np.ndarray:
    """Points (m) on the paths of the spray's axis and cone edges over a lifetime, up to where
    they meet the ground plane: under gravity and linear drag with time constant ``tau`` =
    mass / drag (s; inf: ballistic), exactly (turbulence left out)."""
    axis = np.asarray(spec.direction, np.float64)
    axis /= np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    w = np.cross(axis, u)
    c, s = math.cos(math.radians(spec.spread)), math.sin(math.radians(spec.spread))
    dirs = np.stack([axis, c * axis + s * u, c * axis - s * u, c * axis + s * w, c * axis - s * w])
    t = np.linspace(0.0, spec.lifetime, 40)[:, None, None]
    v0 = spec.speed * dirs[None]
    if math.isinf(tau):
        paths = np.asarray(spec.position, np.float64) + v0 * t + 0.5 * gravity * t**2
    else:  # x = x0 + g tau t + (v0 - g tau) tau (1 - exp(-t / tau))
        paths = np.asarray(spec.position, np.float64) + gravity * tau * t \
            + (v0 - gravity * tau) * tau * -np.expm1(-t / tau)
    paths = paths.reshape(-1, 3)
    if plane is not None:
        paths = paths[(paths - plane.point) @ plane.normal >= 0.0]
    return paths


def _wires(constraints) -> tuple[np.ndarray, ...]:
    """The circles beads are held on (a POINT row and a PLANE row through the same centre on
    one particle), as closed polylines (129, 3) (m)."""
    out = []
    kind, ends = constraints.kind_np, constraints.particles_np
    for r in np.flatnonzero(kind == POINT):
        center = constraints.point_np[r]
        planes = [q for q in np.flatnonzero(kind == PLANE)
                  if ends[q, 0] == ends[r, 0] and np.allclose(constraints.point_np[q], center)]
        if not planes:
            continue
        n = constraints.normal_np[planes[0]]
        e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        angle = np.linspace(0.0, 2.0 * math.pi, 129)[:, None]
        out.append(center + constraints.length_np[r] * (np.cos(angle) * e1 + np.sin(angle) * e2))
    return tuple(out)


def _bounds(x0: np.ndarray, pinned: np.ndarray, *, hanging: bool, swinging: bool, extra,
            plane: Plane | None) -> tuple[np.ndarray, np.ndarray]:
    """The box to frame (m): the initial positions and extra points; for a pinned scene
    under gravity also where it hangs (down from the pins' centroid by 1.2x the farthest
    particle's distance) and, when ``swinging`` (a chain, not a cloth, which crumples), where it
    swings through to (mirrored about the pins in x and z); never below a ground plane."""
    points = [x0]
    if hanging and pinned.any():
        pin = x0[pinned].mean(axis=0)
        reach = 1.1 * float(np.max(np.linalg.norm(x0 - pin, axis=1)))
        points.append((pin - [0.0, reach, 0.0])[None, :])
        if swinging:
            mirrored = x0.copy()
            mirrored[:, [0, 2]] = 2.0 * pin[[0, 2]] - x0[:, [0, 2]]
            points.append(mirrored)
    points += list(extra)
    allp = np.concatenate(points)
    if plane is not None and abs(plane.normal[1]) > 0.9:  # nothing goes below the ground
        ground = plane.point[1]
        allp[:, 1] = np.maximum(allp[:, 1], ground) if plane.normal[1] > 0 else np.minimum(allp[:, 1], ground)
        allp = np.concatenate([allp, plane.point[None, :]])
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    pad = 0.05 * max(float(np.max(hi - lo)), 1e-3)
    return lo - pad, hi + pad
