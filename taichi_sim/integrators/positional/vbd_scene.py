"""vbd and its scene: what :meth:`SceneAttachment.attach_scene` puts in the solve (the scene's
objects, its self-contact, the energy cap on a closed scene) and what a run says about it
afterwards (warnings, and its contact forces for the convergence monitor)."""
from ...collide.self_contact import SelfCollision
from ...scene.kinematic import KinematicPins
from .vbd_contact import SolveContact
from .vbd_contact_model import solve_forces
from .vbd_energy import closed_scene
from .vbd_pins import DrivenPins

SELF_CONTACT_WORK = 8.0  # a sweep's cost with self-contact pairs, in sweeps over springs alone


class SceneAttachment:
    """Mixin of :class:`~.vbd.VBD` (reads its ``contact_options``, ``self_contact``,
    ``energy_cap``, ``delta`` and ``capped``; sets ``contact``, ``has_contact``,
    ``has_self_contact``, ``pins``, ``drives_pins``, ``cap_active`` and ``replaces_parts``)."""

    def attach_scene(self, scene) -> None:
        """Put the scene's objects (and, with ``self_contact``, its mesh) in the solve. Raises
        ConfigError for a contact radius the mesh cannot take or a start that intersects; the
        method is then left unattached (a later attach tries again), never half-bound."""
        if getattr(self, "_attached", None) is scene:
            return  # already bound to it (a launcher switching methods back)
        self._attached = None
        options = dict(self.contact_options)
        mesh = scene.mesh
        # Following the scene, the solve takes over its self-collision stage (the Stepper skips
        # it), except on a cloth that tears: the solve cannot take one, the stage can.
        follows = (self.self_contact is None and any(part.name == SelfCollision.name for part in scene.parts)
                   and mesh is not None and not mesh.tearable)
        options["self_contact"] = follows if self.self_contact is None else self.self_contact
        has_objects = options["objects"] and (
            scene.plane is not None or any(getattr(p, "shape_functions", False) for p in scene.parts))
        contact = None
        if has_objects or options["self_contact"]:
            if options["radius"] is None:
                options["radius"] = float(scene.params.get("thickness", 0.005))
            options["self_friction"] = float(scene.params.get("self_friction", 0.0))
            contact = SolveContact(scene, self.delta, **options)  # may raise: nothing bound yet
        # Scripted pins jump between steps, past the bounds that keep the cloth from crossing
        # itself: with self-contact in the solve, the solve moves them itself (vbd_pins).
        pins = scene.part(KinematicPins.name)
        drives = contact is not None and contact.self_contact and pins is not None and pins.count > 0
        self.contact = contact
        self.has_contact = contact is not None
        self.has_self_contact = contact is not None and contact.self_contact
        self.pins = DrivenPins(pins, contact, scene.system.particle_count) if drives else None
        self.drives_pins = drives
        # the objects' face pass would move vertices past the self-contact bounds; it waits only
        # where the solve meets the objects itself (option ``contact``)
        self.pauses_object_faces = self.has_self_contact and contact.has_objects
        # a sweep that sums contact pairs costs several times one over springs (cloth-fold,
        # 32 x 32: 0.9 us a vertex against about 0.1), which the monitor's sampling plan counts
        self.work_weight = SELF_CONTACT_WORK if self.has_self_contact else 1.0
        self.replaces_parts = frozenset(({SelfCollision.name} if follows else set())
                                        | ({KinematicPins.name} if drives else set()))
        # Not with contact in the solve: its penalty energy is not in E, and a vertex pushed
        # out of a contact would read as a gain (the folds measured never rose, docs/vbd.md).
        self.cap_active = self.energy_cap and contact is None and closed_scene(scene)
        self._kernels = {}  # the kernels compile the contact terms and the cap in
        self._attached = scene

    def run_warning(self) -> str:
        """Contact pairs found but not kept (a vertex's list of CONTACTS_PER_VERTEX, or the
        pair list, full): their repulsion was left out of the solve; substeps the energy cap
        shortened: they stopped short of the solved step."""
        capped = int(self.capped[None])
        lines = []
        if capped:
            lines.append(f"vbd: {capped} substep(s) would have ended with more energy than they started with and "
                         "were shortened toward their start (energy_cap); many mean the sweeps stop short: raise "
                         "--iterations or --substeps, or lower --dt")
        dropped = getattr(self.contact, "dropped_total", 0)  # (self-contact keeps lists; objects do not)
        if dropped:
            lines.append(self._dropped_warning(dropped))
        return "; ".join(lines)

    def _dropped_warning(self, dropped: int) -> str:
        return (f"vbd: {dropped} contact pair(s) found but dropped from the solve (a vertex keeps "
                f"{self.contact.per_vertex} between detections): the cloth may intersect itself (taichi-sim check "
                "FILE.npz tells)")

    def solve_forces(self, state, t: float, h: float):
        """The in-solve contact's forces at ``state`` (the result of a piece of ``h`` s ending at
        ``t`` s), for the convergence monitor (:mod:`.vbd_contact_model`); None without contact."""
        if not self.has_contact:
            return None
        return solve_forces(self.contact, self.system, state, self.delta.to_numpy().astype(float), h, t)
