"""The self-contact stage's broad phase: candidate pairs from spatial hashes of swept boxes.

A mixin of :class:`~.self_contact.SelfCollision` (which owns the fields it reads: positions at
the step's start, the mesh, its edges, which primitives are intact, the hashes, the lists). Its
kernels fill two pair lists, (vertex, triangle) and (edge, edge), with every pair whose swept
boxes, grown by half the thickness each, overlap; each pair once. The lists are ndarrays passed
to the kernels, so a list that fills up is replaced by a longer one without compiling anything.
"""
import taichi as ti

from .hash_grid import MAX_CELLS_PER_AXIS

MAX_PAIRS = 1 << 24  # a pair list grows no further (128 MiB); pairs beyond are dropped and counted
PairList = ti.types.ndarray(dtype=ti.math.ivec2, ndim=1)


class CandidatePairs:
    """Mixin of :class:`~.self_contact.SelfCollision`: its broad phase."""

    def _broad_phase(self, state, only_changed: bool = False, append: bool = False) -> None:
        """All candidate pairs at the current positions into the pair lists; or, with
        ``only_changed``, the pairs holding a vertex in ``changed``, in the lists' place or
        (``append``) after them. A list that fills up is replaced by a longer one, and every
        pair collected afresh into both."""
        self._fit_cells(state)
        self.triangle_grid.build(self.x_start, state.x, self.mesh.triangles, self.triangle_alive)
        self.edge_grid.build(self.x_start, state.x, self.edges, self.edge_alive)
        clipped_in_build = self.triangle_grid.overflowed()
        overflow = 0
        if only_changed:
            self.vertex_grid.build(self.x_start, state.x, self.vertex_ids, self.vertex_alive)
            overflow += self.vertex_grid.overflowed()
            self._collect_changed(state, append, self.vt_pairs, self.ee_pairs)
        else:
            self._collect(state, self.vt_pairs, self.ee_pairs)
        vt, ee = (int(c) for c in self.pair_count.to_numpy())
        while self._grow_lists(vt, ee):  # a list was full: every pair afresh into longer ones
            self.triangle_grid.overflow[None] = clipped_in_build  # the queries count theirs again
            self._collect(state, self.vt_pairs, self.ee_pairs)
            vt, ee = (int(c) for c in self.pair_count.to_numpy())
        # read after the queries: a vertex's clipped query box counts in the triangle hash's
        overflow += self.triangle_grid.overflowed() + self.edge_grid.overflowed()
        self.overflow_total += overflow + max(0, vt - self.vt_pairs.shape[0]) + max(0, ee - self.ee_pairs.shape[0])

    def _grow_lists(self, vt: int, ee: int) -> bool:
        """Replace a pair list that ``vt`` or ``ee`` pairs overflowed by one with room for half as
        many again (up to MAX_PAIRS); returns whether one was replaced."""
        grown = False
        for name, needed in (("vt_pairs", vt), ("ee_pairs", ee)):
            room = getattr(self, name).shape[0]
            if needed > room and room < MAX_PAIRS:
                setattr(self, name, ti.Vector.ndarray(2, ti.i32, shape=min(MAX_PAIRS, needed + needed // 2)))
                grown = True
        return grown

    def _fit_cells(self, state) -> None:
        """Size the hashes' cells (one side for all three, as the queries mix them) so that no
        box of this step spans more than MAX_CELLS_PER_AXIS cells on an axis: the longest edge
        of the rest mesh, or a third of the longest box where something moves or stretches
        further (a fast step), so that no box is clipped and the hash misses no pair."""
        hashes = ((self.triangle_grid, self.mesh.triangles, self.triangle_alive),
                  (self.edge_grid, self.edges, self.edge_alive),
                  (self.vertex_grid, self.vertex_ids, self.vertex_alive))
        extent = max(grid.longest_box(self.x_start, state.x, prims, alive) for grid, prims, alive in hashes)
        # a box of side at most 3 cells spans at most 4 (1e-3: room for round-off in the cells' ids)
        cell = max(self.base_cell, extent / ((MAX_CELLS_PER_AXIS - 1) * (1.0 - 1e-3)))
        for grid, _, _ in hashes:
            grid.cell[None] = cell

    @ti.kernel
    def _collect(self, y: ti.template(), vt: PairList, ee: PairList):
        """Every vertex-triangle and edge-edge pair whose swept boxes overlap (each pair once),
        into the pair lists the rounds go through."""
        self.pair_count[0], self.pair_count[1] = 0, 0
        for i in y.x:
            self.x_collected[i] = y.x[i]
        for i in y.x:
            self._vertex_pairs(vt, y, i)
        for a in range(self.edge_count):
            if self.edge_alive[a]:
                self._edge_pairs(ee, a, False)

    @ti.kernel
    def _collect_changed(self, y: ti.template(), append: ti.template(), vt: PairList, ee: PairList):
        """The pairs holding a vertex in ``changed``, each once, in place of the lists or after
        them (``append``: a pair already listed may then be listed twice, harmless to the
        fail-safe, which only asks which pairs touch): a changed vertex against every triangle, a
        triangle with a changed corner against every unchanged vertex, an edge with a changed
        end against every edge."""
        if ti.static(not append):
            self.pair_count[0], self.pair_count[1] = 0, 0
        for i in y.x:
            if self.changed[i]:
                self._vertex_pairs(vt, y, i)
        for t in range(self.mesh.triangle_count):
            tri = self.mesh.triangles[t]
            if self.triangle_alive[t] and (self.changed[tri[0]] or self.changed[tri[1]] or self.changed[tri[2]]):
                lo, hi = self.triangle_grid.lo[t], self.triangle_grid.hi[t]
                c_lo, c_hi = self.triangle_grid.cell_lo[t], self.triangle_grid.cell_hi[t]
                for ci, cj, ck in ti.ndrange((c_lo[0], c_hi[0] + 1), (c_lo[1], c_hi[1] + 1), (c_lo[2], c_hi[2] + 1)):
                    cell = ti.Vector([ci, cj, ck])
                    first_entry, end_entry = self.vertex_grid.entries(self.vertex_grid.bucket(cell))
                    for e in range(first_entry, end_entry):
                        i = self.vertex_grid.items[e]
                        if (not self.changed[i] and tri[0] != i and tri[1] != i and tri[2] != i
                                and all(lo <= self.vertex_grid.hi[i]) and all(self.vertex_grid.lo[i] <= hi)
                                and self.vertex_grid.first_shared_cell(cell, c_lo, c_hi, i)):
                            self._add_vt(vt, i, t)
        for a in range(self.edge_count):
            ea = self.edges[a]
            if self.edge_alive[a] and (self.changed[ea[0]] or self.changed[ea[1]]):
                self._edge_pairs(ee, a, True)

    @ti.func
    def _add_vt(self, vt: ti.template(), i, t):
        k = ti.atomic_add(self.pair_count[0], 1)
        if k < vt.shape[0]:
            vt[k] = ti.Vector([i, t])

    @ti.func
    def _vertex_pairs(self, vt: ti.template(), y, i):
        """Vertex i against every triangle whose box its swept box overlaps."""
        thick = self.thickness[None]
        p0, p1 = self.x_start[i], y.x[i]
        lo, hi = ti.min(p0, p1) - 0.5 * thick, ti.max(p0, p1) + 0.5 * thick
        c_lo, c_hi, clipped = self.triangle_grid.box_cells(lo, hi)
        if clipped:
            ti.atomic_add(self.triangle_grid.overflow[None], 1)
        for ci, cj, ck in ti.ndrange((c_lo[0], c_hi[0] + 1), (c_lo[1], c_hi[1] + 1), (c_lo[2], c_hi[2] + 1)):
            cell = ti.Vector([ci, cj, ck])
            first_entry, end_entry = self.triangle_grid.entries(self.triangle_grid.bucket(cell))
            for e in range(first_entry, end_entry):
                t = self.triangle_grid.items[e]
                tri = self.mesh.triangles[t]
                if (tri[0] != i and tri[1] != i and tri[2] != i and all(lo <= self.triangle_grid.hi[t])
                        and all(self.triangle_grid.lo[t] <= hi)
                        and self.triangle_grid.first_shared_cell(cell, c_lo, c_hi, t)):
                    self._add_vt(vt, i, t)

    @ti.func
    def _edge_pairs(self, ee: ti.template(), a, changed_only: ti.template()):
        """Edge a against every edge whose box its box overlaps: those after it (each pair once),
        or, with ``changed_only``, also those before it that have no changed end."""
        ea = self.edges[a]
        lo, hi = self.edge_grid.lo[a], self.edge_grid.hi[a]
        c_lo, c_hi = self.edge_grid.cell_lo[a], self.edge_grid.cell_hi[a]
        for ci, cj, ck in ti.ndrange((c_lo[0], c_hi[0] + 1), (c_lo[1], c_hi[1] + 1), (c_lo[2], c_hi[2] + 1)):
            cell = ti.Vector([ci, cj, ck])
            first_entry, end_entry = self.edge_grid.entries(self.edge_grid.bucket(cell))
            for e in range(first_entry, end_entry):
                b = self.edge_grid.items[e]
                eb = self.edges[b]
                after = b > a
                if ti.static(changed_only):
                    after = after or not (self.changed[eb[0]] or self.changed[eb[1]])
                if (after and ea[0] != eb[0] and ea[0] != eb[1] and ea[1] != eb[0] and ea[1] != eb[1]
                        and all(lo <= self.edge_grid.hi[b]) and all(self.edge_grid.lo[b] <= hi)
                        and self.edge_grid.first_shared_cell(cell, c_lo, c_hi, b)):
                    k = ti.atomic_add(self.pair_count[1], 1)
                    if k < ee.shape[0]:
                        ee[k] = ti.Vector([a, b])
