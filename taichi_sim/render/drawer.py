"""Per-scene GPU staging and the kernels that turn a scene's state into GGUI geometry.

A :class:`SceneDrawer` owns f32 staging fields sized once for one :class:`SceneVisual` (GGUI
wants 1-D f32 vertex fields; the simulation may run in f64). Every frame it copies the positions
in with one kernel that also sanitises them, recomputes the cloth's smooth normals and colours,
rebuilds index buffers when springs can tear, and declares meshes, lines and particles on a
``ti.ui`` scene. It reads the scene; it never steps it.
"""
from dataclasses import dataclass

import numpy as np
import taichi as ti

from ..forces.springs import incidence_of
from ..geometry.primitives import rod
from ..scene.visual import SceneVisual
from .chart import STRAIN_STOPS
from .effects import EffectDrawer

#: Coordinates beyond this magnitude (m), NaN or infinite are not drawn (the previous frame's
#: position of that particle is kept instead).
DRAWABLE_LIMIT = 1e8

FRONT = (0.92, 0.46, 0.22)      # cloth, the side its triangles' normals point to: warm gingham
BACK = (0.26, 0.52, 0.84)       # the other side: cool gingham
PARTICLE = (0.90, 0.90, 0.84)
PINNED = (0.95, 0.22, 0.22)
LINE = (0.68, 0.73, 0.80)
TRAIL = (1.00, 0.80, 0.28)
GUIDE = (0.36, 0.40, 0.48)
SOLID = (0.62, 0.66, 0.72)     # the scene's objects (colliders)
POLE = (0.80, 0.76, 0.68)
PALE = 0.35  # share of the fabric's colour in the pale squares of the gingham (the rest: light grey)
FLOOR = ((0.30, 0.32, 0.36), (0.22, 0.24, 0.28))


@dataclass
class DrawOptions:
    """What to show (the launcher's toggles).

    Attributes:
        mesh: the cloth surface.
        springs: springs as lines (a cloth's structural springs only).
        particles: particles as spheres.
        strain: colour the cloth by the stretch of its structural springs instead of the fabric.
        strain_scale: stretch ((length - rest) / rest) drawn in the hottest colour.
        trail: the fading trail of a first-order system's points.
        energy: the energy plot under each panel (drawn by the launcher and ``record --energy``
            over the scenes: :mod:`taichi_sim.app.energy_view`).
        contacts: the contacts a method's solve holds (the launcher's, drawn by
            :mod:`taichi_sim.app.contacts_view`; ``vbd`` only).
    """

    mesh: bool = True
    springs: bool = False
    particles: bool = True
    strain: bool = False
    strain_scale: float = 0.1
    trail: bool = True
    energy: bool = True
    contacts: bool = False

    @classmethod
    def for_visual(cls, visual: SceneVisual) -> "DrawOptions":
        """Defaults that suit the scene: a cloth shows its surface, anything else its particles
        and springs."""
        surface = visual.mesh is not None
        return cls(mesh=surface, springs=not surface, particles=not surface)


@ti.func
def _drawable(p):
    ok = True
    for k in ti.static(range(3)):
        if ti.math.isnan(p[k]) or not (ti.abs(p[k]) <= DRAWABLE_LIMIT):
            ok = False
    return ok


@ti.func
def _colormap(s):
    """Blue -> teal -> yellow -> red for s in [0, 1] (clamped): ``chart.STRAIN_STOPS``, which
    the legend (``chart.strain_colours``) draws too."""
    c0 = ti.Vector(STRAIN_STOPS[0])
    c1 = ti.Vector(STRAIN_STOPS[1])
    c2 = ti.Vector(STRAIN_STOPS[2])
    c3 = ti.Vector(STRAIN_STOPS[3])
    u = ti.math.clamp(s, 0.0, 1.0) * 3.0
    out = c0
    if u < 1.0:
        out = c0 + (c1 - c0) * u
    elif u < 2.0:
        out = c1 + (c2 - c1) * (u - 1.0)
    else:
        out = c2 + (c3 - c2) * (u - 2.0)
    return out


@ti.func
def _gingham(colour, weave):
    """The fabric's colour at ``weave`` in [0, 1]: from a pale tint of ``colour`` (0) to the
    full colour (1); plain cloth (no grid) has weave 1."""
    pale = PALE * colour + (1.0 - PALE) * 0.85
    return pale + (colour - pale) * weave


@ti.data_oriented
class SceneDrawer:
    """Staging fields and kernels for drawing one scene, shifted by ``offset`` (m).

    Args:
        visual: what to draw (see :func:`taichi_sim.scene.visual.describe`).
        offset: (3,) world-space shift of this scene (side-by-side layouts), m.
        trail_capacity: samples kept per point of a trail (one sample per drawn frame).
    """

    def __init__(self, visual: SceneVisual, offset=(0.0, 0.0, 0.0), *, trail_capacity: int = 600):
        self.visual = visual
        self.offset = np.asarray(offset, np.float64).reshape(3)
        self.n = n = visual.particle_count
        # GGUI's line call drops the last vertex of an odd-sized vertex field: pad to even.
        self.padded = n + n % 2
        self.pos = ti.Vector.field(3, ti.f32, self.padded)
        x0 = np.zeros((self.padded, 3), np.float32)
        self.pos.from_numpy(x0)

        colours = np.tile(np.asarray(PARTICLE, np.float32), (self.padded, 1))
        colours[:n][visual.pinned] = PINNED
        self.point_colors = ti.Vector.field(3, ti.f32, self.padded)
        self.point_colors.from_numpy(colours)

        self.alive = visual.spring_alive
        self.tearing = self.alive is not None
        self._init_surface()
        self._init_lines()
        self._init_trail(trail_capacity)
        self._init_extras()

    # -- set-up -------------------------------------------------------------------------------

    def _init_surface(self) -> None:
        v = self.visual
        self.surface = v.mesh is not None
        if not self.surface:
            return
        tris = v.triangles
        self.triangle_total = T = len(tris)
        self.tri_idx = ti.field(ti.i32, 3 * T)
        v.mesh.fill_index_buffer(self.tri_idx)
        offsets, incident, _ = incidence_of(self.n, tris)
        self.tri_offsets = ti.field(ti.i32, self.n + 1)
        self.tri_offsets.from_numpy(offsets)
        self.tri_incident = ti.field(ti.i32, 3 * T)
        self.tri_incident.from_numpy(incident)
        self.normals = ti.Vector.field(3, ti.f32, self.padded)
        self.colors = ti.Vector.field(3, ti.f32, self.padded)
        self.strain = ti.field(ti.f32, self.padded)
        weave = np.ones(self.n, np.float32)
        if v.grid is not None:  # gingham: stripes of grid rows and columns, about 10 per side
            nx, ny = v.grid
            i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
            stripe = max(1, round(max(nx, ny) / 10))
            # Full colour where stripes cross, half where one runs, pale between: contrast
            # strong enough that the check pattern bends visibly along the cloth's folds.
            weave[:nx * ny] = (0.5 * ((i // stripe) % 2) + 0.5 * ((j // stripe) % 2)).ravel()
        self.weave = ti.field(ti.f32, self.n)
        self.weave.from_numpy(weave)

    def _init_lines(self) -> None:
        v = self.visual
        ids = v.line_springs
        self.line_total = L = len(ids)
        if L == 0:
            return
        ends = v.springs[ids].astype(np.int32)
        self.line_ends = ti.Vector.field(2, ti.i32, L)
        self.line_ends.from_numpy(ends)
        self.line_rest = ti.field(ti.f32, L)
        self.line_rest.from_numpy(np.maximum(v.rest_length[ids], 1e-12).astype(np.float32))
        self.line_ids = ti.field(ti.i32, L)
        self.line_ids.from_numpy(ids.astype(np.int32))
        self.line_idx = ti.field(ti.i32, 2 * L)
        self.line_count = self._build_lines()

    def _init_trail(self, capacity: int) -> None:
        self.has_trail = self.visual.trail
        if not self.has_trail:
            return
        self.trail_capacity = capacity
        m = self.n
        self.trail = ti.Vector.field(3, ti.f32, capacity * m)
        self.trail_colors = ti.Vector.field(3, ti.f32, capacity * m)
        self.trail_idx = ti.field(ti.i32, 2 * (capacity - 1) * m)
        self.trail_eps = 1e-6 * max(float(np.linalg.norm(self.visual.extent)), 1e-3)
        self.clear_trail()

    def _init_extras(self) -> None:
        v = self.visual
        guides = [np.stack([g[:-1], g[1:]], axis=1).reshape(-1, 3) for g in v.guides]
        self.guide_vertices = None
        if guides:
            segs = np.concatenate(guides) + self.offset
            self.guide_vertices = ti.Vector.field(3, ti.f32, len(segs))
            self.guide_vertices.from_numpy(segs.astype(np.float32))
        self.solid_vertices = None
        if v.solids:
            # Triangle meshes, not GGUI particles: a particle is a flat impostor whose depth
            # would cut through cloth draped over it. One mesh for every part's solid; each
            # frame moves each solid's vertices by where its part places it.
            counts = [len(s.vertices) for s in v.solids]
            firsts = np.cumsum([0] + counts[:-1])
            self.solid_shape = np.concatenate([s.vertices for s in v.solids]).astype(np.float64)
            self.solid_owner = np.repeat(np.arange(len(v.solids)), counts)
            self.solid_vertices = ti.Vector.field(3, ti.f32, len(self.solid_shape))
            self.solid_normals = ti.Vector.field(3, ti.f32, len(self.solid_shape))
            self.solid_normals.from_numpy(np.concatenate([s.normals for s in v.solids]).astype(np.float32))
            tris = np.concatenate([np.asarray(s.triangles) + f for s, f in zip(v.solids, firsts)])
            self.solid_indices = ti.field(ti.i32, tris.size)
            self.solid_indices.from_numpy(tris.ravel().astype(np.int32))
            # deforming solids (an animated collider mesh): their rows of the shape and normals
            self.solid_poses = [(s.pose, slice(f, f + c)) for s, f, c in zip(v.solids, firsts, counts)
                                if s.pose is not None]
            self.solid_normals_np = np.concatenate([s.normals for s in v.solids]).astype(np.float64)
        self.pole = None
        if v.pole is not None:
            verts, normals, tris = rod(v.pole.bottom + self.offset, v.pole.top + self.offset, v.pole.radius)
            # Drawn like the cloth (per-vertex colour, two-sided) and only with it: GGUI 1.7.4
            # reuses mesh slots from frame to frame, and after a frame whose only mesh was the
            # pole, later frames on the window lost meshes now and then.
            self.pole = tuple(ti.Vector.field(3, ti.f32, len(verts)) for _ in range(3)) + (ti.field(ti.i32, tris.size),)
            self.pole[0].from_numpy(verts.astype(np.float32))
            self.pole[1].from_numpy(normals.astype(np.float32))
            self.pole[2].from_numpy(np.tile(np.asarray(POLE, np.float32), (len(verts), 1)))
            self.pole[3].from_numpy(tris.ravel().astype(np.int32))
        self.floor = None
        if v.plane is not None:
            self.floor = self._floor_mesh()
        self.emitter = v.emitter
        self.effect = None
        if self.emitter is not None:
            self.effect = EffectDrawer(self.emitter, self.pos, v.particle_radius)

    def _floor_mesh(self):
        """A checkerboard square on the plane, 3x the scene's size, centred below it."""
        v = self.visual
        nrm = v.plane.normal
        centre = v.center - np.dot(v.center - v.plane.point, nrm) * nrm
        helper = np.array([1.0, 0.0, 0.0]) if abs(nrm[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
        e1 = np.cross(nrm, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(nrm, e1)
        cells = 16
        half = 1.5 * max(float(np.max(v.extent)), 1e-3)
        s = np.linspace(-half, half, cells + 1)
        ci, cj = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
        ci, cj = ci.ravel(), cj.ravel()
        corners = [(0, 0), (1, 0), (0, 1), (1, 1)]
        verts = np.stack([centre + s[ci + di, None] * e1 + s[cj + dj, None] * e2 for di, dj in corners], axis=1)
        verts = verts.reshape(-1, 3) + self.offset - 1e-4 * half * nrm  # just below contact
        base = 4 * np.arange(cells * cells)[:, None]
        tris = (base + np.array([0, 2, 1, 1, 2, 3])).ravel()
        colour = np.where(((ci + cj) % 2)[:, None], FLOOR[0], FLOOR[1])
        fields = (ti.Vector.field(3, ti.f32, len(verts)), ti.field(ti.i32, len(tris)),
                  ti.Vector.field(3, ti.f32, len(verts)), ti.Vector.field(3, ti.f32, len(verts)))
        fields[0].from_numpy(verts.astype(np.float32))
        fields[1].from_numpy(tris.astype(np.int32))
        fields[2].from_numpy(np.tile(nrm, (len(verts), 1)).astype(np.float32))
        fields[3].from_numpy(np.repeat(colour, 4, axis=0).astype(np.float32))
        return fields

    # -- per frame ----------------------------------------------------------------------------

    def sync(self, source) -> int:
        """Copy positions into the f32 staging field, shifted by the offset.

        ``source`` is the scene's (n,) vec3 position field (copied by a kernel) or an (n, 3)
        array. A particle with a NaN, infinite or huge (> DRAWABLE_LIMIT) coordinate keeps its
        previous staged position. Returns how many particles were held back that way.
        """
        if isinstance(source, np.ndarray):
            x = np.asarray(source, np.float64).reshape(self.n, 3)
            with np.errstate(invalid="ignore"):
                ok = np.all(np.abs(x) <= DRAWABLE_LIMIT, axis=1)
            staged = self.pos.to_numpy()
            staged[:self.n][ok] = (x[ok] + self.offset).astype(np.float32)
            self.pos.from_numpy(staged)
            return int(self.n - ok.sum())
        return int(self._copy(source, ti.Vector(self.offset.tolist(), ti.f32)))

    @ti.kernel
    def _copy(self, src: ti.template(), offset: ti.types.vector(3, ti.f32)) -> ti.i32:
        bad = 0
        for i in range(self.n):
            p = src[i]
            if _drawable(p):
                self.pos[i] = ti.cast(p, ti.f32) + offset
            else:
                bad += 1
        return bad

    def clear_trail(self) -> None:
        """Forget the trail (after a reset)."""
        if self.has_trail:
            self.trail_head = 0
            self.trail_count = 0

    def update(self, options: DrawOptions, eye) -> None:
        """Recompute what this frame draws from the staged positions: index buffers (when springs
        can tear), cloth normals and colours, the trail, live emitter particles (far to near,
        with their effect's look). ``eye`` is the camera position (m), which decides the side
        of the cloth each vertex shows and the order of translucent particles."""
        if self.tearing:
            if self.surface and options.mesh:
                self.visual.mesh.fill_index_buffer(self.tri_idx)
            if self.line_total and options.springs:
                self.line_count = self._build_lines()
        if self.surface and options.mesh:
            strain = options.strain and self.line_total > 0
            if strain:
                self._strain()
            self._shade(ti.Vector([float(c) for c in eye], ti.f32), int(strain), float(options.strain_scale))
        if self.has_trail:
            self._push_trail()
        if self.solid_vertices is not None:
            for pose, rows in self.solid_poses:
                self.solid_shape[rows], self.solid_normals_np[rows] = pose()
            if self.solid_poses:
                self.solid_normals.from_numpy(self.solid_normals_np.astype(np.float32))
            centers = np.stack([np.asarray(s.place(), np.float64).reshape(3) for s in self.visual.solids]) + self.offset
            self.solid_vertices.from_numpy((centers[self.solid_owner] + self.solid_shape).astype(np.float32))
        if self.effect is not None and options.particles:
            self.effect.update(eye)

    def draw(self, scene, options: DrawOptions) -> None:
        """Declare this frame's geometry on a ``ti.ui`` scene (call :meth:`update` first)."""
        v = self.visual
        if self.floor is not None:
            verts, tris, nrm, col = self.floor
            scene.mesh(verts, indices=tris, normals=nrm, per_vertex_color=col, two_sided=True)
        if self.guide_vertices is not None:
            scene.lines(self.guide_vertices, width=1.0, color=GUIDE)
        if self.solid_vertices is not None:
            scene.mesh(self.solid_vertices, indices=self.solid_indices, normals=self.solid_normals,
                       color=SOLID)
        if self.pole is not None and options.mesh:  # the flag's, shown with it (see _init_extras)
            scene.mesh(self.pole[0], indices=self.pole[3], normals=self.pole[1], per_vertex_color=self.pole[2],
                       two_sided=True)
        if self.surface and options.mesh:
            scene.mesh(self.pos, indices=self.tri_idx, normals=self.normals,
                       per_vertex_color=self.colors, two_sided=True)
        if options.springs and self.line_total and self.line_count:
            scene.lines(self.pos, width=2.0, indices=self.line_idx, color=LINE,
                        vertex_count=self.padded, index_count=2 * self.line_count)
        if self.has_trail and options.trail and self.trail_count >= 2:
            scene.lines(self.trail, width=2.0, indices=self.trail_idx, per_vertex_color=self.trail_colors,
                        index_count=2 * (self.trail_count - 1) * self.n)
        if options.particles:
            regular = self.n if self.emitter is None else self.emitter.first
            if regular:
                scene.particles(self.pos, radius=v.particle_radius, per_vertex_color=self.point_colors,
                                index_count=regular)
            if self.effect is not None:
                self.effect.draw(scene)

    # -- kernels ------------------------------------------------------------------------------

    @ti.func
    def _line_intact(self, s):
        """Whether drawn spring line ``s`` has not torn."""
        intact = True
        if ti.static(self.tearing):
            intact = self.alive[self.line_ids[s]] != 0
        return intact

    @ti.kernel
    def _build_lines(self) -> ti.i32:
        """Compact the intact drawn springs into ``line_idx``; returns how many."""
        k = 0
        ti.loop_config(serialize=True)
        for s in range(self.line_total):
            if self._line_intact(s):
                self.line_idx[2 * k] = self.line_ends[s][0]
                self.line_idx[2 * k + 1] = self.line_ends[s][1]
                k += 1
        return k

    @ti.kernel
    def _strain(self):
        """Per-vertex largest stretch ((length - rest) / rest, >= 0) of its intact drawn springs."""
        for i in range(self.padded):
            self.strain[i] = 0.0
        for s in range(self.line_total):
            if self._line_intact(s):
                a, b = self.line_ends[s][0], self.line_ends[s][1]
                e = ((self.pos[a] - self.pos[b]).norm() - self.line_rest[s]) / self.line_rest[s]
                ti.atomic_max(self.strain[a], e)
                ti.atomic_max(self.strain[b], e)

    @ti.kernel
    def _shade(self, eye: ti.types.vector(3, ti.f32), strain: ti.i32, scale: ti.f32):
        """Smooth normals (area-weighted over the intact triangles around each vertex) and
        colours: warm or cool gingham as the vertex shows ``eye`` the front (the side its normal
        points to) or the back of the surface, or the strain colour map (darker on the back)."""
        for v in range(self.n):
            nrm = ti.Vector([0.0, 0.0, 0.0])
            for e in range(self.tri_offsets[v], self.tri_offsets[v + 1]):
                t = self.tri_incident[e]
                a, b, c = self.tri_idx[3 * t], self.tri_idx[3 * t + 1], self.tri_idx[3 * t + 2]
                if a != b or a != c:  # a torn triangle is degenerate (a, a, a)
                    pa = self.pos[a]
                    nrm += (self.pos[b] - pa).cross(self.pos[c] - pa)
            length = nrm.norm()
            if length > 0:
                nrm = nrm / length
            front = nrm.dot(eye - self.pos[v]) >= 0
            # GGUI lights a surface by its normal as given: flip it to the side in view.
            self.normals[v] = ti.cast(nrm if front else -nrm, ti.f32)
            colour = _gingham(ti.Vector(BACK), self.weave[v])
            if strain:
                colour = _colormap(self.strain[v] / scale)
                if not front:
                    colour = colour * 0.8
            elif front:
                colour = _gingham(ti.Vector(FRONT), self.weave[v])
            self.colors[v] = ti.cast(colour, ti.f32)

    def _push_trail(self) -> None:
        """Append the current points to the trail unless they have not moved since the last
        sample (paused or frozen), then rebuild the trail's line indices and fading colours."""
        last = (self.trail_head - 1) % self.trail_capacity
        if self.trail_count and not self._trail_moved(last, self.trail_eps):
            return
        self._trail_store(self.trail_head)
        self.trail_head = (self.trail_head + 1) % self.trail_capacity
        self.trail_count = min(self.trail_count + 1, self.trail_capacity)
        if self.trail_count >= 2:
            self._trail_build(self.trail_head, self.trail_count)

    @ti.kernel
    def _trail_moved(self, last: ti.i32, eps: ti.f32) -> ti.i32:
        moved = 0
        for p in range(self.n):
            if (self.pos[p] - self.trail[last * self.n + p]).norm() > eps:
                moved = 1
        return moved

    @ti.kernel
    def _trail_store(self, slot: ti.i32):
        for p in range(self.n):
            self.trail[slot * self.n + p] = self.pos[p]

    @ti.kernel
    def _trail_build(self, head: ti.i32, count: ti.i32):
        cap = self.trail_capacity
        m = self.n
        start = (head - count + cap) % cap
        for k, p in ti.ndrange(count - 1, m):
            a = (start + k) % cap
            b = (start + k + 1) % cap
            self.trail_idx[2 * (k * m + p)] = a * m + p
            self.trail_idx[2 * (k * m + p) + 1] = b * m + p
        for k, p in ti.ndrange(count, m):
            age = (k + 1) / count  # 1 for the newest sample
            self.trail_colors[((start + k) % cap) * m + p] = ti.cast(ti.Vector(TRAIL) * (0.15 + 0.85 * age), ti.f32)


def layout_offsets(visuals, *, gap: float = 0.25) -> list[np.ndarray]:
    """x-offsets (m) placing the scenes side by side, centred on the first one's position.

    Each panel is as wide as the widest scene (at least 0.6x its height or depth, so thin
    scenes such as a hanging spring keep room for their labels), plus ``gap`` of that.
    """
    if not visuals:
        return []
    width = max(max(float(v.extent[0]), 0.6 * float(max(v.extent[1], v.extent[2]))) for v in visuals)
    width = (width if width > 0 else 1.0) * (1.0 + gap)
    first = -0.5 * (len(visuals) - 1) * width
    return [np.array([first + k * width - (v.center[0] - visuals[0].center[0]), 0.0, 0.0])
            for k, v in enumerate(visuals)]
