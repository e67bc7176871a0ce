"""The launcher's contacts toggle: what each panel's solve holds in contact, drawn over its scene.

A method that keeps contacts in its solve exposes them as its ``contact`` attribute (``vbd``:
:class:`~taichi_sim.integrators.positional.vbd.contact.SolveContact`, set once it is attached to
a scene with objects or with ``self_contact``). For each such panel a
:class:`~taichi_sim.render.contacts.ContactDrawer` (made once per contact object and kept:
Taichi never gives fields or kernels back) gathers the marked vertices and the pairs' closest
points in one kernel a frame, only while the toggle is on. A panel whose method holds no
contacts gets a line saying why instead of silently drawing nothing.
"""
from __future__ import annotations

from typing import Sequence

from ..render.contacts import RADIUS_SCALE, SELF, ContactDrawer

GREY = (0.6, 0.6, 0.6)  # a line about something that cannot be shown


def unavailable(integrator) -> str | None:
    """Why ``integrator`` has no contacts to show (one line), or None when it has some."""
    if getattr(integrator, "contact", None) is not None:
        return None
    if not hasattr(integrator, "contact"):
        return f"{integrator.name} keeps no contacts (only vbd has contact in its solve)"
    return (f"{integrator.name} has no contact in its solve here: the scene has no objects (or "
            "contact=0) and no self-contact (--set self_collision=1 or --option self_contact=1)")


class ContactsView:
    """What the contacts toggle draws and says, per panel."""

    def __init__(self):
        self._drawers: dict[int, ContactDrawer] = {}  # id(contact object) -> its drawer
        self.shown: list[ContactDrawer] = []  # the drawers gathered this frame
        self.notes: list[tuple[str, tuple | None]] = []  # (line, RGB or None), one per panel
        self.reasons: list[str] = []  # why panels of the last update had nothing to show

    def drawer_for(self, contact, particle_count: int, radius: float) -> ContactDrawer:
        """The drawer of ``contact`` (made at its first use; the drawer keeps the object alive,
        so its id is never reused)."""
        drawer = self._drawers.get(id(contact))
        if drawer is None:
            drawer = self._drawers[id(contact)] = ContactDrawer(contact, particle_count, radius=radius)
        return drawer

    def update(self, runners: Sequence, renderer, *, on: bool) -> None:
        """Gather this frame's contacts of each panel (``runners`` and the ``renderer`` drawing
        them: its visuals give the particle size, its offsets the panels' shifts); nothing when
        ``on`` is False."""
        self.shown, self.notes, self.reasons = [], [], []
        if not on:
            return
        many = len(runners) > 1
        for k, (r, visual, offset) in enumerate(zip(runners, renderer.visuals, renderer.offsets)):
            prefix = f"contacts, panel {k + 1}: " if many else "contacts: "
            why = unavailable(r.integrator)
            if why is not None:
                self.notes.append((prefix + why, GREY))
                self.reasons.append(why)
                continue
            if r.frozen:  # its state may be what the failed step left, not a drawable one
                self.notes.append((prefix + "the run stopped: no contacts drawn", GREY))
                continue
            contact = r.integrator.contact
            drawer = self.drawer_for(contact, visual.particle_count, RADIUS_SCALE * visual.particle_radius)
            drawer.gather(r.scene.state.x, r.t, offset)
            self.shown.append(drawer)
            self.notes.append((prefix + summary(drawer), SELF))

    def panel_note(self) -> str | None:
        """The control panel's greyed line under the toggle when it is on and no panel has
        contacts to show (why), else None."""
        if self.shown or not self.reasons:
            return None
        return "nothing to show: " + "; ".join(dict.fromkeys(self.reasons))

    def draw(self, scene) -> None:
        """Declare the gathered contacts on a ``ti.ui`` scene (the renderer's 3D hook)."""
        for drawer in self.shown:
            drawer.draw(scene)


def summary(drawer: ContactDrawer) -> str:
    """One line: vertices in self-contact (magenta), pairs held and drawn, vertices on objects
    (green)."""
    objects = f"{drawer.object_count} touching objects (green)"
    if not drawer.self_contact:
        return objects + "; self_contact off"
    pairs = f"{drawer.pair_count} pairs"
    if drawer.segment_count < drawer.pair_count:
        pairs += f", {drawer.segment_count} drawn"
    line = f"{drawer.self_count} vertices in self-contact (magenta, {pairs})"
    return line + (", " + objects if drawer.contact.has_objects else "")
