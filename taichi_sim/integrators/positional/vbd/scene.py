"""What a scene puts in vbd's solve: :func:`contact_setup` reads the scene (its objects, its
self-collision stage, its scripted pins) and returns a :class:`ContactSetup`, the one object
through which :class:`~.solver.VBD` learns what its solve meets and what it takes over."""
from dataclasses import dataclass

from ....collide.self_contact import SelfCollision
from ....scene.colliders.mesh_collider import MeshCollider
from ....scene.kinematic import KinematicPins
from .contact import SolveContact
from .pins import DrivenPins

SELF_CONTACT_WORK = 8.0  # a sweep's cost with self-contact pairs, in sweeps over springs alone


@dataclass(frozen=True)
class ContactSetup:
    """What the solve holds of one scene.

    Attributes:
        contact: the contact terms in the solve (the scene's objects, its self-contact), or
            None where the solve meets nothing.
        pins: the scene's scripted pins the solve moves itself (with self-contact), or None.
        replaces_parts: names of the scene parts whose work the solve does (the Stepper skips
            their post-step events: ``self_collision``, ``kinematic``, ``collider_mesh``).
        pauses_object_faces: whether the objects' post-step face pass waits (it would move
            vertices past the self-contact bounds).
        work_weight: a sweep's cost in sweeps over springs alone (the convergence monitor's
            sampling plan).
    """

    contact: SolveContact | None = None
    pins: DrivenPins | None = None
    replaces_parts: frozenset = frozenset()
    pauses_object_faces: bool = False
    work_weight: float = 1.0

    @property
    def has_self_contact(self) -> bool:
        return self.contact is not None and self.contact.self_contact


def contact_setup(scene, options: dict, self_contact: bool | None, delta) -> ContactSetup:
    """The solve's contact for ``scene``.

    Args:
        scene: the scene (``mesh``, ``parts``, ``plane``, ``params``, ``system``).
        options: vbd's contact options (``objects``, ``object_faces``, ``radius`` (m) or None,
            ``stiffness``, ``bound_fraction``, ``friction_epsilon``, ``refresh``).
        self_contact: vbd's option: None follows the scene's self-collision stage (taken over
            by the solve), True or False as given.
        delta: the solve's displacement field ((n,) vec3, m), which the contact bounds read.

    Raises ConfigError for a contact radius the mesh cannot take or a start that intersects.
    """
    options = dict(options)
    mesh = scene.mesh
    # Following the scene, the solve takes over its self-collision stage (the Stepper skips
    # it), except on a cloth that tears: the solve cannot take one, the stage can.
    follows = (self_contact is None and any(part.name == SelfCollision.name for part in scene.parts)
               and mesh is not None and not mesh.tearable)
    options["self_contact"] = follows if self_contact is None else self_contact
    has_objects = options["objects"] and (
        scene.plane is not None or any(getattr(p, "shape_functions", False) for p in scene.parts)
        or scene.part(MeshCollider.name) is not None)
    if not (has_objects or options["self_contact"]):
        return ContactSetup()
    if options["radius"] is None:
        options["radius"] = float(scene.params.get("thickness", 0.005))
    options["self_friction"] = float(scene.params.get("self_friction", 0.0))
    contact = SolveContact(scene, delta, **options)
    # Scripted pins jump between steps, past the bounds that keep the cloth from crossing
    # itself: with self-contact in the solve, the solve moves them itself (pins.py).
    pins = scene.part(KinematicPins.name)
    drives = contact.self_contact and pins is not None and pins.count > 0
    return ContactSetup(
        contact=contact,
        pins=DrivenPins(pins, contact, scene.system.particle_count) if drives else None,
        replaces_parts=frozenset(({SelfCollision.name} if follows else set())
                                 | ({KinematicPins.name} if drives else set())
                                 # its post-step pass would move vertices past the solve's bounds
                                 | ({MeshCollider.name} if contact.has_body else set())),
        # the objects' face pass would move vertices past the self-contact bounds; it waits only
        # where the solve meets the objects itself (option ``contact``)
        pauses_object_faces=contact.self_contact and contact.has_objects,
        # a sweep that sums contact pairs costs several times one over springs (cloth-fold,
        # 32 x 32: 0.9 us a vertex against about 0.1), which the monitor's sampling plan counts
        work_weight=SELF_CONTACT_WORK if contact.self_contact else 1.0)
