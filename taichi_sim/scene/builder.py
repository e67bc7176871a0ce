"""SceneBuilder: collect what a particle scene asks for, allocate fields once in finalize()."""
from __future__ import annotations

import warnings
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any

import numpy as np

from ..errors import InputNote
from ..forces import Drag, GrabSpring, Gravity, Springs, Turbulence, Wind
from ..forces.membrane import (
    HingeBending,
    IsometricBending,
    Membrane,
    MembraneMaterial,
    bending_stencils,
    check_bending_model,
)
from ..forces.springs.grid import GridSprings, grid_layout
from ..mesh import TriangleMesh
from ..part import PartContext, PartSpec
from ..systems.constraints import PLANE, POINT, ROD, Constraints, check_gains
from ..systems.particles import ParticleSystem
from .colliders import Box, Capsule, GroundPlane, MeshObstacle, Sphere, SpherePath
from .events import Emitter, EmitterSpec, Tearing
from .grab import Grabber
from .scene import Scene

_GENERAL_PATHS = ContextVar("general_paths", default=False)


@contextmanager
def general_paths():
    """Scenes built inside this block use the general spring-list path even where the grid
    stencil applies (to compare the two, in tests and benchmarks)."""
    token = _GENERAL_PATHS.set(True)
    try:
        yield
    finally:
        _GENERAL_PATHS.reset(token)


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
        self._triangles: list[np.ndarray] = []
        self._wind: dict | None = None
        self._turbulence: dict | None = None
        self._part_specs: list[PartSpec] = []  # the objects of every collider kind, as asked for
        self._plane: GroundPlane | None = None
        self._object_faces = True
        self._tear_strain = None
        self._self_collision = None
        self._kinematic = None
        self._emitter: tuple | None = None
        self._grab: tuple | None = None
        self._grid: tuple[int, int, int] | None = None
        self._constraints: list[tuple] = []  # (kind, a, b, point, normal, length)
        self._feedback = (0.0, 0.0)
        self._rest_x: list[np.ndarray] = []
        self._membrane: tuple[MembraneMaterial, float] | None = None
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
        self._rest_x.append(x)  # displace() leaves these: the shape the springs rest in
        self._v.append(v)
        self._mass.append(mass)
        self._pinned.append(pinned)
        ids = np.arange(self._count, self._count + k)
        self._count += k
        return ids

    def displace(self, dx) -> None:
        """Move every particle added so far by ``dx`` ((n, 3) m), e.g. seeded noise on a grid.
        Rest lengths of springs already added keep their values; pinned particles stay put."""
        dx = np.asarray(dx, float).reshape(self._count, 3)
        start = 0
        for k, x in enumerate(self._x):
            stop = start + len(x)
            moved = dx[start:stop] * ~self._pinned[k][:, None]
            self._x[k] = x + moved
            start = stop

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

    def declare_grid(self, first: int, nx: int, ny: int) -> None:
        """Say that particles ``first + i * ny + j`` (0 <= i < nx, 0 <= j < ny) form a grid.
        When every spring joins two of them at a stencil offset and nothing tears them,
        ``finalize`` sums the springs through the grid stencil
        (:class:`~taichi_sim.forces.springs.grid.GridSprings`); otherwise, silently, through
        the spring list."""
        self._grid = (int(first), int(nx), int(ny))

    def _particle(self, i, what: str) -> int:
        i = int(i)
        if not 0 <= i < self._count:
            raise ValueError(f"{what} must be the id of a particle already added, got {i}")
        return i

    def add_circle_wire(self, particle: int, center, normal, radius: float) -> None:
        """Keep ``particle`` on the circle of ``radius`` (m, > 0) about ``center`` (m) in the
        plane through it with ``normal``: a bead on a wire, as two constraint rows (on the
        sphere of that radius, and on the plane)."""
        i = self._particle(particle, "the bead")
        radius = float(radius)
        if not (np.isfinite(radius) and radius > 0):
            raise ValueError(f"wire radius must be > 0, got {radius}")
        center = np.asarray(center, float).reshape(3)
        normal = np.asarray(normal, float).reshape(3)
        if not np.linalg.norm(normal) > 0:
            raise ValueError("wire normal must be a nonzero vector")
        normal = normal / np.linalg.norm(normal)
        self._constraints.append((POINT, i, -1, center, np.zeros(3), radius))
        self._constraints.append((PLANE, i, -1, center, normal, 0.0))

    def add_rod(self, a: int, b: int, length: float | None = None) -> None:
        """A rigid rod: the distance between particles ``a`` and ``b`` stays ``length`` (m,
        > 0; default their current distance)."""
        a, b = self._particle(a, "a rod's end"), self._particle(b, "a rod's end")
        if a == b:
            raise ValueError("a rod must join two different particles")
        if length is None:
            x = self.positions()
            length = float(np.linalg.norm(x[a] - x[b]))
        length = float(length)
        if not (np.isfinite(length) and length > 0):
            raise ValueError(f"rod length must be > 0, got {length}")
        self._constraints.append((ROD, a, b, np.zeros(3), np.zeros(3), length))

    def add_plane_constraint(self, particle: int, point, normal) -> None:
        """Keep ``particle`` on the plane through ``point`` (m) with ``normal``."""
        i = self._particle(particle, "the particle on a plane")
        normal = np.asarray(normal, float).reshape(3)
        if not np.linalg.norm(normal) > 0:
            raise ValueError("plane normal must be a nonzero vector")
        self._constraints.append((PLANE, i, -1, np.asarray(point, float).reshape(3),
                                  normal / np.linalg.norm(normal), 0.0))

    def set_constraint_feedback(self, ks: float, kd: float) -> None:
        """Feedback gains of the constraints: stiffness ``ks`` (1/s², >= 0) and damping ``kd``
        (1/s, >= 0), pulling a drifted C back as C̈ + kd Ċ + ks C = 0."""
        self._feedback = check_gains(ks, kd)

    def add_triangles(self, triangles) -> None:
        """Surface triangles ((T, 3) particle ids, counter-clockwise from the front): the cloth
        mesh that wind acts on, that tearing opens and that the renderer draws."""
        triangles = np.asarray(triangles, np.int64).reshape(-1, 3)
        self._triangles.append(triangles)

    def set_membrane(self, material: MembraneMaterial, *, bending: float = 0.0, bending_model: str = "isometric",
                     bending_poisson: float = 0.0) -> None:
        """Make the triangles (:meth:`add_triangles`) a membrane of ``material`` (see
        :class:`~taichi_sim.forces.membrane.Membrane`), with ``bending`` stiffness (N m, >= 0;
        0 for none) across their interior edges: ``bending_model`` ``isometric``
        (:class:`~taichi_sim.forces.membrane.IsometricBending`, flat at rest), ``dihedral`` or
        ``shape_operator`` (:class:`~taichi_sim.forces.membrane.HingeBending`, resting in the
        shape as added; ``bending_poisson``, the plate's Poisson's ratio, for the latter). Both
        rest in the particles' positions as added (before :meth:`displace`), each triangle
        flattened to its own frame."""
        self._membrane = (material, float(bending), check_bending_model(bending_model), float(bending_poisson))

    def set_gravity(self, g) -> None:
        """Gravity: a magnitude (m/s^2, pointing -y) or a 3-vector."""
        g = np.asarray(g, dtype=float)
        self._gravity = np.array([0.0, -float(g), 0.0]) if g.ndim == 0 else g.reshape(3).copy()

    def set_drag(self, k_drag: float) -> None:
        """Viscous drag coefficient (N s/m, >= 0)."""
        if k_drag < 0:
            raise ValueError("drag must be >= 0")
        self._drag = float(k_drag)

    def set_wind(self, **wind) -> None:
        """Aerodynamic wind on the triangles (see :class:`taichi_sim.forces.Wind` for the keyword
        arguments: speed, heading, gust, gust_frequency, drag_coefficient, seed, enabled)."""
        self._wind = wind

    def set_turbulence(self, *, amplitude: float, scale: float, frequency: float) -> None:
        """A seeded random acceleration field on every particle (see
        :class:`taichi_sim.forces.Turbulence`): ``amplitude`` (m/s^2, > 0 to add it), eddy
        ``scale`` (m), ``frequency`` (Hz). Its waves come from the scene's seed."""
        if amplitude > 0:
            self._turbulence = {"amplitude": float(amplitude), "scale": float(scale), "frequency": float(frequency)}

    def add_part(self, spec: PartSpec) -> None:
        """Add an object of any collider kind: ``spec`` (a :class:`~taichi_sim.part.PartSpec`)
        names its part class, which ``finalize`` builds once over every object of that kind."""
        if not isinstance(spec, PartSpec):
            raise TypeError(f"add_part takes a PartSpec, got {type(spec).__name__}")
        self._part_specs.append(spec)

    def add_sphere(self, path: SpherePath, radius: float, friction: float = 0.0, *,
                   continuous: bool = True) -> None:
        """A sphere collider of ``radius`` (m) moving (and maybe spinning) along ``path``, with
        Coulomb ``friction``. ``continuous=False`` tests only step ends (every sphere of the
        scene; kept to compare: a sphere moving more than its radius per step then tunnels)."""
        self.add_part(Sphere(path, float(radius), float(friction), bool(continuous)))

    def set_object_faces(self, on: bool) -> None:
        """Whether the object colliders test the cloth's triangles as well as its vertices
        (default on; needs triangles; see :class:`~taichi_sim.scene.colliders.faces.FaceContact`).
        Off, an object smaller than the cloth's spacing can pass between vertices, through a face."""
        self._object_faces = bool(on)

    def add_capsule(self, path: SpherePath, radius: float, half_axis, friction: float = 0.0) -> None:
        """A capsule collider: the points within ``radius`` (m) of the segment from centre -
        ``half_axis`` to centre + ``half_axis`` (m), the centre translating along ``path``."""
        self.add_part(Capsule(path, float(radius), tuple(float(c) for c in half_axis), float(friction)))

    def add_box(self, path: SpherePath, half_extents, friction: float = 0.0) -> None:
        """An axis-aligned box collider of ``half_extents`` (m, 3 values > 0) centred on ``path``."""
        self.add_part(Box(path, tuple(float(c) for c in half_extents), float(friction)))

    def add_mesh_collider(self, vertices, triangles, path: SpherePath | None = None, friction: float = 0.0,
                          skin: float = 0.005, fps: float = 30.0) -> None:
        """A triangle mesh collider (see :class:`~taichi_sim.scene.colliders.mesh_collider.MeshCollider`):
        ``vertices`` (V, 3) (m) in its own frame, or (F, V, 3) for an animated mesh whose F
        frames play at ``fps`` (frames per second; the last is held); its origin follows
        ``path`` (default: fixed at the world's origin); ``triangles`` (T, 3) vertex ids,
        Coulomb ``friction`` and the ``skin`` (m) particles keep from it."""
        self.add_part(MeshObstacle(np.asarray(vertices, float), np.asarray(triangles, np.int64),
                                   path or SpherePath((0.0, 0.0, 0.0)), float(friction), float(skin), float(fps)))

    def set_plane(self, point, normal, restitution: float, friction: float = 0.0) -> None:
        """A ground plane through ``point`` with upward ``normal`` (nonzero); restitution in [0, 1]
        (:class:`~taichi_sim.scene.colliders.plane.GroundPlane`; the last one set is the scene's)."""
        self._plane = GroundPlane(point, normal, float(restitution), float(friction))

    def enable_self_collision(self, thickness: float, friction: float = 0.0, iterations: int = 4, *,
                              fit: bool = False) -> None:
        """Keep the cloth's vertices ``thickness`` (m) off its other triangles after every step
        (see :class:`~taichi_sim.collide.SelfCollision`; needs triangles). ``fit``: the user gave
        no thickness and ``thickness`` is the scene's default: ``finalize`` takes half the rest
        shape's smallest distance between non-adjacent parts where that is less, at least
        :data:`~taichi_sim.collide.mesh_check.THICKNESS_FLOOR`
        (:func:`~taichi_sim.collide.mesh_check.contact_thickness`), says so in one
        :class:`~taichi_sim.errors.InputNote`, and the scene's ``params["thickness"]`` holds the
        thickness taken (what the npz records and vbd's in-solve contact follows)."""
        self._self_collision = (float(thickness), float(friction), int(iterations), bool(fit))

    def add_kinematic(self, ids, path) -> None:
        """Move pinned particles ``ids`` along a script between steps (see
        :class:`~taichi_sim.scene.kinematic.KinematicPins`): ``path.at(t)`` gives their
        positions (m) and velocities (m/s) at time t (s), ``path.at(0)`` where they are now;
        ``path.fastest_speed()`` (m/s) and ``path.farthest_travel()`` (m) bound them for the
        blow-up guard."""
        ids = np.asarray(ids, np.int64).reshape(-1)
        if len(ids) == 0:
            raise ValueError("kinematic pins need at least one particle")
        if ids.min() < 0 or ids.max() >= self._count:
            raise ValueError("kinematic pins must be ids of particles already added")
        if not np.concatenate(self._pinned)[ids].all():
            raise ValueError("kinematic pins must be pinned particles (integrators would move them)")
        start, _ = path.at(0.0)
        if not np.allclose(start, self.positions()[ids], rtol=0.0, atol=1e-9):
            raise ValueError("a kinematic path must start where its particles are")
        if self._kinematic is not None:
            raise ValueError("a scene has at most one set of kinematic pins")
        self._kinematic = (ids, path)

    def set_tearing(self, tear_strain) -> None:
        """Springs break past this strain: a scalar or one value per spring (in the order added)."""
        self._tear_strain = tear_strain

    def set_emitter(self, spec: EmitterSpec, particle_mass: float) -> None:
        """A sprinkler: adds ``spec.capacity`` inactive particles of ``particle_mass`` (kg) that
        the emitter launches."""
        if self._emitter is not None:
            raise ValueError("a scene has at most one emitter")
        ids = self.add_particles(np.broadcast_to(np.asarray(spec.position, float), (spec.capacity, 3)),
                                 particle_mass)
        self._emitter = (spec, int(ids[0]))

    def enable_grab(self, stiffness: float, damping: float) -> None:
        """Let a user pull a particle with a stiff spring (see :class:`~taichi_sim.scene.grab.Grabber`)."""
        self._grab = (float(stiffness), float(damping))

    def finalize(self, *, name: str, params: dict[str, Any], default_dt: float,
                 default_integrator: str, seed: int = 0,
                 integrator_options: dict[str, dict[str, Any]] | None = None) -> Scene:
        """Allocate every field and return the Scene (only what was asked for);
        ``integrator_options``: see :attr:`Scene.integrator_options`."""
        if self._count == 0:
            raise ValueError("a scene needs at least one particle")
        x0, v0 = self.positions(), np.concatenate(self._v)
        mass, pinned = np.concatenate(self._mass), np.concatenate(self._pinned)
        active = np.ones(self._count, bool)
        if self._emitter is not None:
            spec, first = self._emitter
            active[first:first + spec.capacity] = False

        system = ParticleSystem(mass, pinned, active=active)
        features: dict[str, Any] = {"particles": self._count, "pinned": int(pinned.sum()),
                                    "gravity": False, "drag": False, "springs": 0, "grid_stencil": False,
                                    "dashpots": False, "wind": False, "turbulence": False, "object_faces": False,
                                    "plane": False, "tearing": False, "emitter": 0, "grab": False, "triangles": 0,
                                    "self_collision": False, "constraints": 0, "kinematic": 0}
        arrays: dict[str, np.ndarray] = {
            "mass": mass, "pinned": pinned,
            "gravity": np.zeros(3) if self._gravity is None else self._gravity,
            "drag": np.float64(self._drag or 0.0),
        }
        parts: list = []
        if self._kinematic is not None:
            from .kinematic import KinematicPins

            parts.append(KinematicPins(*self._kinematic))
        if self._gravity is not None and np.any(self._gravity != 0):
            system.add_term(Gravity(self._gravity, system.mass, system.free))
            features["gravity"] = True
        if self._drag:
            system.add_term(Drag(self._drag))
            features["drag"] = True
        springs = None
        if self._springs:
            ends, rest, k, c, kind = (np.concatenate(parts) for parts in zip(*self._springs))
            tear = None
            if self._tear_strain is not None:
                tear = np.broadcast_to(np.asarray(self._tear_strain, float), (len(ends),))
            layout = None
            if self._grid is not None and tear is None and not _GENERAL_PATHS.get():
                layout = grid_layout(ends, *self._grid)
            if layout is not None:
                springs = GridSprings(self._count, ends, rest, k, c, kind, layout=layout)
            else:
                springs = Springs(self._count, ends, rest, k, c, kind, tear_strain=tear)
            system.add_term(springs)
            features.update(springs=springs.spring_count, dashpots=springs.damped,
                            tearing=springs.tearable, grid_stencil=layout is not None)
        if self._membrane is not None:
            if not self._triangles:
                raise ValueError("a membrane acts on triangles: add_triangles first")
            material, bending, bending_model, bending_poisson = self._membrane
            triangles, rest = np.concatenate(self._triangles), np.concatenate(self._rest_x)
            membrane = Membrane(self._count, triangles, rest, material)
            system.add_term(membrane)
            arrays.update(membrane.arrays())
            features.update(membrane=material.model, bending=False)
            if bending > 0 and len(bending_stencils(rest, triangles)[0]):
                bending_term = IsometricBending(self._count, triangles, rest, bending) \
                    if bending_model == "isometric" else \
                    HingeBending(self._count, triangles, rest, bending, bending_model, bending_poisson)
                system.add_term(bending_term)
                arrays.update(bending_term.arrays())
                features["bending"] = True
        mesh = None
        faces = None  # the mesh the object colliders test, when they test faces
        if self._triangles:
            mesh = TriangleMesh(self._count, np.concatenate(self._triangles), springs)
            features["triangles"] = mesh.triangle_count
            faces = mesh if self._object_faces else None
        if self._wind is not None:
            if mesh is None:
                raise ValueError("wind acts on triangles: add_triangles first")
            system.add_term(Wind(mesh, **self._wind))
            features["wind"] = True
        if self._turbulence is not None:
            turbulence = Turbulence(**self._turbulence, seed=seed)
            system.add_term(turbulence)
            features["turbulence"] = True
            arrays.update(turbulence.arrays())
        grabber = None
        if self._grab is not None:
            grab_term = GrabSpring(*self._grab)
            system.add_term(grab_term)
            features["grab"] = True
        constraints = None
        if self._constraints:
            kind, a, b, point, normal, length = zip(*self._constraints)
            moving = ~pinned
            for row, (i, j) in enumerate(zip(a, b)):
                if not (moving[i] or (j >= 0 and moving[j])):
                    raise ValueError(f"constraint {row} holds only pinned particles")
            constraints = Constraints(self._count, kind, np.stack([a, b], axis=1), np.stack(point),
                                      np.stack(normal), length, *self._feedback)
            constraints.scene = name
            system.set_constraints(constraints)
            features["constraints"] = constraints.row_count
        context = PartContext(system=system, faces=faces, seed=seed)
        kinds: dict[type, list] = {}
        for spec in self._part_specs:
            kinds.setdefault(spec.part_class, []).append(spec)
        parts += [kind.from_specs(specs, context) for kind, specs in kinds.items()]
        plane = None
        if self._plane is not None:
            plane = self._plane.part_class.from_specs([self._plane], context)
            parts.append(plane)
        # last of the position changes, so that nothing moves the cloth after its guarantee
        if self._self_collision is not None:
            if mesh is None:
                raise ValueError("self_collision acts on triangles: add_triangles first")
            from ..collide import SelfCollision
            from ..collide.mesh_check import THICKNESS_FLOOR, contact_thickness

            asked, friction, iterations, fit = self._self_collision
            # The thickness is checked against the rest shape (before displace(): a seeded jitter
            # is a disturbance the contacts may smooth out, not a shape the cloth returns to);
            # the start is checked for coincident points and flat triangles all the same.
            thickness, gap = contact_thickness(x0, mesh.triangles_np, asked, rest=np.concatenate(self._rest_x),
                                               fit=fit)
            if thickness != asked:
                params = {**params, "thickness": thickness}
                floor = f", at least {THICKNESS_FLOOR:g} m" if thickness == THICKNESS_FLOOR else ""
                warnings.warn(f"{name}: self_collision takes thickness {thickness:.3g} m from the mesh (half the "
                              f"{gap:.3g} m between its closest non-adjacent parts at rest{floor}), not the default "
                              f"{asked:g} m; give thickness to choose", InputNote, stacklevel=2)
            floor = None if plane is None else (plane.point_np, plane.normal_np)
            obstacles = sorted((p for p in parts if p.is_obstacle), key=lambda p: p.order)
            parts.append(SelfCollision(system, mesh, x0, thickness=thickness, friction=friction,
                                       iterations=iterations, floor=floor, obstacles=obstacles))
        if springs is not None and springs.tearable:
            parts.append(Tearing(springs))
        if self._emitter is not None:
            spec, first = self._emitter
            parts.append(Emitter(spec, first, system.free, seed, particle_mass=float(mass[first])))
        parts.sort(key=lambda p: p.order)  # (stable: objects of one order keep the order asked)
        for part in parts:
            features.update(part.features())

        state = system.make_state()
        scene = Scene(name=name, system=system, state=state, x0=x0, v0=v0, params=params,
                      features=features, static_arrays=arrays, default_dt=default_dt,
                      default_integrator=default_integrator, seed=seed, parts=parts, post_step=list(parts),
                      springs=springs, mesh=mesh, constraints=constraints,
                      rest_x=np.concatenate(self._rest_x) if self._rest_x else None,
                      integrator_options={k: dict(v) for k, v in (integrator_options or {}).items()})
        if self._grab is not None:
            grabber = Grabber(scene, grab_term)
            scene.grabber = grabber
        scene.reset()
        return scene
