"""A Scene: a system, the state it owns, its post-step events, and how to describe them."""
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..collide.self_contact import SelfCollision
from ..errors import ConfigError
from ..state import State
from ..systems.base import System
from .colliders.faces import FaceContact
from .colliders.mesh_collider import MeshCollider
from .handoff import DEFAULT_THICKNESS, NOTHING_TAKEN, ContactInputs, ContactTakeover, closed_scene
from .kinematic import KinematicPins


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
        integrator_options: integrator name -> the keyword options this scene runs that method
            with unless a caller sets them (``cloth-stiff``: XPBD with 50 substeps); see
            :meth:`options_for`.
        explicit_dt: the step (s) an explicit (step-limited) method takes when not told, where
            the default method is not one and takes longer steps (the contact cloths run ``vbd``
            at 1/60 s; symplectic Euler there at 1 ms, less on a fine grid); None: default_dt.
        default_tolerance: the ``--tolerance`` (m) its runs take when not told; None: the
            default of :mod:`taichi_sim.convergence` (1 mm).
        seed: the random seed the scene was built with.
        parts: the optional scene parts (:class:`~taichi_sim.part.ScenePart`: colliders, the
            ground, scripted pins, self-contact, tearing, an emitter), in the order their events
            run; reset, restore, the npz, the guard, the renderer and the run's summary loop
            over them. :meth:`part` finds one by name.
        post_step: the events applied after every accepted step, in order: the parts (a
            caller may wrap one here to watch it).
        springs, mesh, grabber, constraints: what the forces and the integrators read, or None.
        rest_x: (n, 3) float64 positions the springs rest in (before a seeded jitter), or None.
        takeover: what the integrator stepping the scene took over from it
            (:class:`~taichi_sim.scene.handoff.ContactTakeover`, set by :meth:`hand_over`):
            :meth:`after_step` leaves its parts' events out.
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
    parts: list = field(default_factory=list)
    post_step: list = field(default_factory=list)
    springs: Any = None
    mesh: Any = None
    grabber: Any = None
    constraints: Any = None
    rest_x: np.ndarray | None = None
    explicit_dt: float | None = None
    integrator_options: dict[str, dict[str, Any]] = field(default_factory=dict)
    default_tolerance: float | None = None
    takeover: ContactTakeover = NOTHING_TAKEN

    @property
    def explicit_step(self) -> float:
        """The step (s) an explicit (step-limited) method takes when not told: ``explicit_dt``
        where the scene has one, else ``default_dt``."""
        return self.default_dt if self.explicit_dt is None else self.explicit_dt

    def options_for(self, integrator: str) -> dict[str, Any]:
        """The keyword options the scene gives integrator ``integrator`` (a name) when the
        caller sets none of its own (a new dict; empty for most scenes and methods)."""
        return dict(self.integrator_options.get(integrator, {}))

    def object_centers(self, t: float) -> dict[str, np.ndarray]:
        """Where the spheres, capsules, boxes and the collider mesh are at time ``t`` (s), as the
        npz's keys: ``{"sphere_center": (K, 3), ...}`` (m; a collider mesh's
        ``collider_mesh_center`` (3,) and, animated, its ``collider_mesh_vertices``); empty
        without such objects."""
        return {k: v for part in self.parts if hasattr(part, "centers_at") for k, v in part.centers_at(t).items()}

    def start_warning(self) -> str:
        """A line naming the objects the cloth starts inside, with how many vertices each, or
        "" (also for a scene without a cloth mesh). Read it before a run, on the scene as built:
        the first steps push those vertices out, and a cloth caught across an object folds
        through itself (a fold started through a capsule intersected in 180 of its 181
        frames). Every registered collider kind is checked (spheres, capsules, boxes and the plane
        among them: :mod:`~taichi_sim.scene.colliders.shape`), not a collider mesh; pinned
        vertices are left out (no collider moves them), and so are their triangles. Triangles an
        object reaches into between their vertices (as `check` finds them:
        :func:`~taichi_sim.scene.colliders.shape.faces_inside`) are named too."""
        from .colliders.shape import faces_inside, inside_objects, shape

        if self.mesh is None:
            return ""
        objects = {**self.arrays, **self.object_centers(0.0)}  # where they start, whenever asked
        pinned = np.asarray(objects["pinned"], bool)  # no collider moves a pinned vertex
        found = [(kind, int(mask.sum())) for kind, mask in inside_objects(self.x0[~pinned], objects).items()
                 if mask.any()]
        triangles = self.mesh.triangles_np[~pinned[self.mesh.triangles_np].any(axis=1)]
        faces = [(kind, int(mask.sum())) for kind, mask in faces_inside(self.x0, triangles, objects).items()
                 if mask.any()]
        if not found and not faces:
            return ""
        where = [f"{count} inside the {shape(kind).noun}" for kind, count in found]
        if found:
            where[-1] += f", of {len(self.x0)} vertices"
        where += [f"{count} of {len(self.mesh.triangles_np)} triangles reaching into the {shape(kind).noun}"
                  for kind, count in faces]
        return (f"the cloth starts inside an object ({'; '.join(where)}): the first "
                f"steps push it out and the cloth may fold through itself (`taichi-sim "
                f"check` on the saved frames tells); move the object or the cloth")

    def part(self, name: str):
        """The part called ``name`` (e.g. ``"spheres"``, ``"plane"``), or None."""
        return next((p for p in self.parts if p.name == name), None)

    # the parts that live setters and curves change by name
    spheres = property(lambda self: self.part("spheres"))
    plane = property(lambda self: self.part("plane"))
    emitter = property(lambda self: self.part("emitter"))
    kinematic = property(lambda self: self.part("kinematic"))

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
        for part in self.parts:
            part.reset()

    def restore(self) -> None:
        """Back to the scene as built: the initial state, torn springs mended, no particle
        emitted and the emitter's random stream restarted (unlike :meth:`reset`), without
        allocating anything."""
        for part in self.parts:
            part.restore()
        self.reset()

    def energy(self) -> float | None:
        """Total energy (J) of the current state, or None when the system defines none."""
        return self.system.energy(self.state)

    def contact_inputs(self) -> ContactInputs:
        """What the scene offers an integrator that takes contact into its solve (its ground,
        shapes, collider mesh, self-collision stage, scripted pins, thickness and friction:
        :class:`~taichi_sim.scene.handoff.ContactInputs`), as the scene is now."""
        return ContactInputs(
            system=self.system, state=self.state, cloth=self.mesh, rest_x=self.rest_x, plane=self.plane,
            shapes=tuple(p for p in self.parts if getattr(p, "shape_functions", False)),
            collider_mesh=self.part(MeshCollider.name), self_collision=self.part(SelfCollision.name),
            pins=self.part(KinematicPins.name),
            thickness=float(self.params.get("thickness", DEFAULT_THICKNESS)),
            self_friction=float(self.params.get("self_friction", 0.0)),
            closed=closed_scene(self.system, self.parts))

    def hand_over(self, takeover: ContactTakeover) -> None:
        """Apply what the integrator bound to :meth:`contact_inputs` answered it took over:
        from the next step on :meth:`after_step` leaves out the events of ``takeover.parts``,
        and the object colliders' face pass waits while ``takeover.pauses_object_faces``
        (each later call replaces the one before: a method switched to hands back what the
        last one took). ConfigError for a part the scene does not have."""
        if not isinstance(takeover, ContactTakeover):
            raise ConfigError(f"an integrator's bind_contact must answer a ContactTakeover, got {takeover!r}")
        unknown = takeover.parts - {part.name for part in self.parts}
        if unknown:
            raise ConfigError(f"the integrator takes over {', '.join(sorted(unknown))}, which scene "
                              f"{self.name} does not have")
        for part in self.parts:
            if isinstance(part, FaceContact):
                part.faces_paused = takeover.pauses_object_faces
        self.takeover = takeover

    def after_step(self, t: float, h: float) -> bool:
        """Apply post-step events (collisions, tearing, emission) after an accepted step that
        ended at time ``t`` (s) and was ``h`` (s) long, except those of the parts the
        integrator took over (:meth:`hand_over`: it did their work in its solve). Returns
        whether an event changed the system itself (not just the state), so integrators that
        carry data between steps must be reset."""
        changed = False
        skip = self.takeover.parts
        for event in self.post_step:
            if skip and getattr(event, "name", None) in skip:
                continue
            changed |= bool(event(self.state, t, h))
        return changed

    @property
    def arrays(self) -> dict[str, np.ndarray]:
        """The npz's model keys as they are now (numpy copies): the static arrays plus what
        may change during a run (springs, live springs, constraints, each part's keys: collider
        centres, emitter ages, ...)."""
        out = dict(self.static_arrays)
        membrane = self.system.term("membrane") if hasattr(self.system, "term") else None
        if membrane is not None:  # its moduli may be set in place (Membrane.set_material)
            out.update(membrane.arrays())
        if self.springs is not None:
            out.update(self.springs.arrays())
        if self.constraints is not None:
            out.update(self.constraints.arrays())
        for part in self.parts:
            out.update(part.arrays())
        return out

    def constraint_violation(self) -> float | None:
        """The largest |C| (m) over the constraints at the current state, or None without
        constraints."""
        return None if self.constraints is None else self.constraints.violation(self.state)
