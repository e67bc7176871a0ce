"""Drawing the contacts an integrator's solve holds (the launcher's contacts toggle).

A :class:`ContactDrawer` reads one contact object through its public view (``mark_contacts``,
``pair_segment``, ``pair_total``: :class:`~taichi_sim.integrators.positional.vbd.contact.SolveContact`)
and turns it into GGUI geometry: the vertices in a self-contact pair and those touching an
object as small particles in their own colours, and a line between the closest points of each
pair. Its fields are allocated once; a frame costs one kernel launch (marking, compaction and
segments together) and is only gathered while the toggle is on. It reads; it never steps.
"""
import numpy as np
import taichi as ti

from ..integrators.positional.vbd.contact import OBJECT_CONTACT, SELF_CONTACT

SELF = (1.00, 0.20, 0.85)      # a vertex in a self-contact pair: magenta, on neither gingham colour
OBJECT = (0.25, 1.00, 0.35)    # a vertex within the contact radius of an object: green
SEGMENT = (1.00, 0.95, 0.30)   # a pair's closest points joined: yellow
#: Segments drawn at most, per particle: a dense pile keeps about one pair a vertex (the
#: 128 x 128 fold: 4.9 million pairs over 300 detections); pairs beyond are counted, not drawn.
SEGMENTS_PER_PARTICLE = 2
RADIUS_SCALE = 1.5  # a highlighted vertex's radius, in drawn particle radii: it shows through the cloth


@ti.data_oriented
class ContactDrawer:
    """Staging fields and the gather kernel for one contact object.

    Args:
        contact: the integrator's contact object (a ``SolveContact``; must outlive the drawer:
            its kernel is compiled against it).
        particle_count: n, the scene's particles.
        radius: drawn radius of a highlighted vertex (m).

    Attributes after :meth:`gather`: ``points`` / ``point_colours`` ((n,) f32 vec3; the first
    ``point_count`` are the marked vertices, shifted by the panel's offset), ``self_count`` and
    ``object_count`` (vertices marked for each; a vertex can be both), ``segments`` ((2 S,) f32
    vec3, S = ``segment_capacity``; the first ``2 segment_count`` are pairs' closest points),
    ``pair_count`` (pairs held, drawn or not).
    """

    def __init__(self, contact, particle_count: int, *, radius: float):
        self.contact = contact
        self.n = n = int(particle_count)
        self.radius = float(radius)
        self.self_contact = bool(getattr(contact, "self_contact", False))
        self.flags = ti.field(ti.i32, n)
        self.points = ti.Vector.field(3, ti.f32, n)
        self.point_colours = ti.Vector.field(3, ti.f32, n)
        capacity = min(contact.pair_capacity, SEGMENTS_PER_PARTICLE * n) if self.self_contact else 0
        self.segment_capacity = capacity
        self.segments = ti.Vector.field(3, ti.f32, 2 * max(1, capacity))
        self.counts = ti.field(ti.i32, 3)  # marked vertices, in self-contact, on objects (compaction slots)
        self.point_count = self.self_count = self.object_count = 0
        self.segment_count = self.pair_count = 0

    def gather(self, x, t: float, offset=(0.0, 0.0, 0.0)) -> int:
        """Mark and stage the contacts at positions ``x`` (the scene's (n,) vec3 field, m) and
        time ``t`` (s), shifted by ``offset`` ((3,) m, the panel's). Returns the vertices marked."""
        self.pair_count = self.contact.pair_total()
        self.segment_count = min(self.pair_count, self.segment_capacity)
        counts = self._gather(x, float(t), ti.Vector([float(c) for c in np.asarray(offset).reshape(3)], ti.f32),
                              self.segment_count)
        self.point_count, self.self_count, self.object_count = (int(c) for c in counts)
        return self.point_count

    @ti.kernel
    def _gather(self, x: ti.template(), t: float, offset: ti.types.vector(3, ti.f32),
                segments: ti.i32) -> ti.types.vector(3, ti.i32):
        self.contact.mark_contacts(x, t, self.flags)
        for k in range(3):
            self.counts[k] = 0
        for i in range(self.n):
            flag = self.flags[i]
            if flag != 0:
                slot = ti.atomic_add(self.counts[0], 1)
                self.points[slot] = ti.cast(x[i], ti.f32) + offset
                colour = ti.Vector(OBJECT, ti.f32)
                if flag & SELF_CONTACT:
                    colour = ti.Vector(SELF, ti.f32)
                    ti.atomic_add(self.counts[1], 1)
                if flag & OBJECT_CONTACT:
                    ti.atomic_add(self.counts[2], 1)
                self.point_colours[slot] = colour
        if ti.static(self.self_contact):
            for s in range(segments):
                a, b = self.contact.pair_segment(s, x)
                self.segments[2 * s] = ti.cast(a, ti.f32) + offset
                self.segments[2 * s + 1] = ti.cast(b, ti.f32) + offset
        return ti.Vector([self.counts[0], self.counts[1], self.counts[2]])  # read back with the launch

    def marked(self) -> np.ndarray:
        """(n,) int32 flags of the last :meth:`gather` (SELF_CONTACT | OBJECT_CONTACT bits)."""
        return self.flags.to_numpy()

    def draw(self, scene) -> None:
        """Declare the last gather's particles and segments on a ``ti.ui`` scene."""
        if self.point_count:
            scene.particles(self.points, radius=self.radius, per_vertex_color=self.point_colours,
                            index_count=self.point_count)
        if self.segment_count:
            scene.lines(self.segments, width=2.0, color=SEGMENT, vertex_count=2 * self.segment_count)
