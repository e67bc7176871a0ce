"""What a scene puts in vbd's solve: :func:`contact_setup` reads the scene's
:class:`~taichi_sim.scene.handoff.ContactInputs` (its objects, its self-collision stage, its
scripted pins) and returns a :class:`ContactSetup`, the one object through which
:class:`~.solver.VBD` learns what its solve meets and what it takes over."""
from dataclasses import dataclass, field

from ....scene.handoff import NOTHING_TAKEN, ContactInputs, ContactTakeover
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
        takeover: what the solve takes over from the scene (the parts whose post-step events
            are left out: ``self_collision``, ``kinematic``, ``collider_mesh``; whether the
            objects' face pass waits), the answer of :meth:`~.solver.VBD.bind_contact`.
        work_weight: a sweep's cost in sweeps over springs alone (the convergence monitor's
            sampling plan).
    """

    contact: SolveContact | None = None
    pins: DrivenPins | None = None
    takeover: ContactTakeover = field(default=NOTHING_TAKEN)
    work_weight: float = 1.0

    @property
    def has_self_contact(self) -> bool:
        return self.contact is not None and self.contact.self_contact


def contact_setup(inputs: ContactInputs, options: dict, self_contact: bool | None, delta) -> ContactSetup:
    """The solve's contact for a scene's ``inputs``.

    Args:
        inputs: what the scene offers (:meth:`~taichi_sim.scene.scene.Scene.contact_inputs`).
        options: vbd's contact options (``objects``, ``object_faces``, ``radius`` (m) or None,
            ``stiffness``, ``bound_fraction``, ``friction_epsilon``, ``refresh``).
        self_contact: vbd's option: None follows the scene's self-collision stage (taken over
            by the solve), True or False as given.
        delta: the solve's displacement field ((n,) vec3, m), which the contact bounds read.

    Raises ConfigError for a contact radius the mesh cannot take or a start that intersects.
    """
    options = dict(options)
    cloth = inputs.cloth
    # Following the scene, the solve takes over its self-collision stage (the scene leaves it
    # out), except on a cloth that tears: the solve cannot take one, the stage can.
    stage = inputs.self_collision
    follows = self_contact is None and stage is not None and cloth is not None and not cloth.tearable
    options["self_contact"] = follows if self_contact is None else self_contact
    if not ((options["objects"] and inputs.has_objects) or options["self_contact"]):
        return ContactSetup()
    if options["radius"] is None:
        options["radius"] = inputs.thickness
    options["self_friction"] = inputs.self_friction
    contact = SolveContact(inputs, delta, **options)
    # Scripted pins jump between steps, past the bounds that keep the cloth from crossing
    # itself: with self-contact in the solve, the solve moves them itself (pins.py).
    pins = inputs.pins
    drives = contact.self_contact and pins is not None and pins.count > 0
    return ContactSetup(
        contact=contact,
        pins=DrivenPins(pins, contact, inputs.system.particle_count) if drives else None,
        takeover=ContactTakeover(
            parts=({stage.name} if follows else set())
            | ({pins.name} if drives else set())
            # its post-step pass would move vertices past the solve's bounds
            | ({inputs.collider_mesh.name} if contact.has_body else set()),
            # the objects' face pass would move vertices past the self-contact bounds; it
            # waits only where the solve meets the objects itself (option ``contact``)
            pauses_object_faces=contact.self_contact and contact.has_objects),
        # a sweep that sums contact pairs costs several times one over springs (cloth-fold,
        # 32 x 32: 0.9 us a vertex against about 0.1), which the monitor's sampling plan counts
        work_weight=SELF_CONTACT_WORK if contact.self_contact else 1.0)
