"""Vertex block descent's continuum cloth terms: the force and 3x3 block one vertex takes from
its membrane triangles and bending stencils at the iterate; :class:`~.solver.VBD` owns them."""

import numpy as np
import taichi as ti

from .... import field_io, runtime
from ....forces.membrane.material import sym_matrix
from ..colouring import element_pairs

#: A triangle corner's share of a sweep against a spring's, for the rule that picks serial or
#: parallel sweeps (kernels.SERIAL_WORK). Serial sweeps measure less now (docs/materials.md: a
#: grid vertex's 6 corners without damping cost what its 12 springs do, with the viscous stress
#: about 1.5 times that); the parallel break-even, which this sets, was not measured again.
CORNER_WORK = 8


@ti.data_oriented
class MembraneTerms:
    """The membrane's and bending's part of a vertex's solve in :class:`~.solver.VBD`.

    Vertex i takes, from each triangle it is a corner of, the triangle's force on it and its
    positive semi-definite block -(df_i/dx_i + df_i/dv_i / dt) at the iterate
    (:meth:`Membrane.corner_terms <taichi_sim.forces.membrane.Membrane.corner_terms>`: the
    elastic block projected to PSD, the viscous stress's block, PSD as it is, over dt, as a
    spring's dashpot c / dt enters), and from the bending stencils it is in their force
    -D (L x)_i and block D L_ii I, L the bending's constant Hessian over D
    (:meth:`IsometricBending.operator <taichi_sim.forces.membrane.IsometricBending.operator>`:
    its rows sum the stencils, so a vertex reads each neighbour once, not once per stencil);
    or, with hinge bending, its elements' force and Gauss-Newton block at the iterate
    (:meth:`HingeBending.vertex_terms <taichi_sim.forces.membrane.HingeBending.vertex_terms>`).
    The stress, the Hessians and L are the terms' own, written once in
    :mod:`taichi_sim.forces.membrane`.

    What a vertex reads is laid out for it: its corners contiguously, each with the other two
    vertices, their shape gradients, its own and the rest area (:meth:`Membrane.corner_layout
    <taichi_sim.forces.membrane.Membrane.corner_layout>`, one field per component so that a
    component of consecutive corners is contiguous), so F = (x_j - x_i) g_j^T + (x_k - x_i)
    g_k^T and Fdot likewise from the velocities; the bending's rows without their diagonals,
    which are kept apart. The blocks are summed as their six entries. :meth:`merit` gives the
    sweeps' start test the membrane's and the bending's energy element by element.

    The sweep is Gauss-Seidel over a vertex colouring: the vertices of one triangle or one
    stencil must lie in different colours (:meth:`pairs`), so that a colour's vertices, solved
    at once, never read each other's positions (a shape-operator element's six vertices too).

    Args:
        membrane: the system's :class:`~taichi_sim.forces.membrane.Membrane` term, or None.
        bending: the system's :class:`~taichi_sim.forces.membrane.IsometricBending` or
            :class:`~taichi_sim.forces.membrane.HingeBending` term, or None.
    """

    names = ("membrane", "bending")  # the system's terms these stand for (solver: not in its others)

    def __init__(self, membrane, bending):
        if membrane is None and bending is None:
            raise ValueError("MembraneTerms needs a membrane or a bending term")
        self.membrane = membrane
        self.bending = bending
        self.has_membrane = membrane is not None
        self.has_bending = bending is not None
        self.hinged = self.has_bending and not hasattr(bending, "operator")  # no constant Hessian
        real, npr = runtime.real(), runtime.np_real()
        if self.has_membrane:
            offsets, others, rest = membrane.corner_layout()
            self.corner_offsets = ti.field(ti.i32, shape=len(offsets))
            self.corner_others = ti.field(ti.i32, shape=(2, len(others)))
            self.corner_rest = ti.field(real, shape=(rest.shape[1], len(rest)))
            field_io.write((self.corner_offsets, offsets), (self.corner_others, others.T),
                           (self.corner_rest, rest.T.astype(npr)))
        if self.has_bending and not self.hinged:
            # L's rows without their diagonals, which are kept apart (the block D L_ii I and
            # the force's D L_ii x_i need no test for j == i in the row's loop)
            offsets, columns, values = bending.operator()
            self.bending_entries = len(columns)
            row = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
            diagonal = np.zeros(len(offsets) - 1)
            np.add.at(diagonal, row[columns == row], values[columns == row])
            off = columns != row
            counts = np.bincount(row[off], minlength=len(offsets) - 1)
            offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
            columns, values = columns[off], values[off]
            self.bending_offsets = ti.field(ti.i32, shape=len(offsets))
            self.bending_columns = ti.field(ti.i32, shape=max(1, len(columns)))
            self.bending_values = ti.field(real, shape=max(1, len(values)))
            self.bending_diagonal = ti.field(real, shape=len(diagonal))
            pairs = [(self.bending_offsets, offsets), (self.bending_diagonal, diagonal.astype(npr))]
            if len(columns):
                pairs += [(self.bending_columns, columns), (self.bending_values, values.astype(npr))]
            field_io.write(*pairs)

    def pairs(self) -> np.ndarray:
        """(P, 2) int64: the pairs of vertices that share a triangle or a bending stencil."""
        parts = [element_pairs(self.membrane.triangles_np)] if self.has_membrane else []
        if self.has_bending:
            parts.append(element_pairs(self.bending.vertices_np))
        return np.unique(np.concatenate(parts), axis=0)

    @property
    def work(self) -> int:
        """A sweep's work in springs' worth (:data:`CORNER_WORK` per triangle corner, one per
        entry of the bending's rows)."""
        corners = 3 * self.membrane.triangle_count if self.has_membrane else 0
        reach = self.bending_entries if self.has_bending and not self.hinged else 0
        if self.hinged:  # a hinge angle and its gradient: about a corner's work
            reach = CORNER_WORK * self.bending.per * self.bending.incident.shape[0]
        return CORNER_WORK * corners + reach

    @ti.func
    def merit(self, y, dt):
        """U + dt R of the membrane and the bending at the state ``y`` (J), each triangle and
        each stencil once (:meth:`Membrane.triangle_stress
        <taichi_sim.forces.membrane.Membrane.triangle_stress>`, :meth:`IsometricBending.edge_energy
        <taichi_sim.forces.membrane.IsometricBending.edge_energy>`); top-level loops where called
        at a kernel's top level."""
        total = ti.cast(0.0, y.x.dtype)
        if ti.static(self.has_membrane):
            membrane = self.membrane
            for t in range(membrane.triangle_count):
                energy, dissipation, p0, p1 = membrane.triangle_stress(t, y, membrane.shape_gradients(t))
                total += energy + dt * dissipation
        if ti.static(self.hinged):
            for e in range(self.bending.element_count):
                total += self.bending.element_energy(e, y.x)
        elif ti.static(self.has_bending):
            for b in range(self.bending.edge_count):
                total += self.bending.edge_energy(b, y.x)
        return total

    @ti.func
    def corner(self, e, y, xi, vi, inv_dt):
        """The force (N) and the block's six entries (N/m) of corner entry e of the vertex at
        ``xi`` (m), ``vi`` (m/s) in the state ``y`` (:meth:`Membrane.corner_terms
        <taichi_sim.forces.membrane.Membrane.corner_terms>`)."""
        membrane = self.membrane
        others = ti.Vector([self.corner_others[0, e], self.corner_others[1, e]])
        rest = ti.Vector([self.corner_rest[c, e] for c in ti.static(range(7))])
        ej = y.x[others[0]] - xi
        ek = y.x[others[1]] - xi
        f0 = rest[0] * ej + rest[2] * ek
        f1 = rest[1] * ej + rest[3] * ek
        d0, d1 = ti.Vector.zero(y.x.dtype, 3), ti.Vector.zero(y.x.dtype, 3)
        if ti.static(membrane.damped):
            wj = y.v[others[0]] - vi
            wk = y.v[others[1]] - vi
            d0 = rest[0] * wj + rest[2] * wk
            d1 = rest[1] * wj + rest[3] * wk
        return membrane.corner_terms(f0, f1, d0, d1, ti.Vector([rest[4], rest[5]]), rest[6], inv_dt)

    @ti.func
    def at(self, i, y, dt):
        """The force on vertex i (N) and its block of H (3x3, N/m) from its triangles and
        bending stencils at the state ``y`` (positions (m) and velocities (m/s): the iterate)."""
        f = ti.Vector.zero(y.x.dtype, 3)
        H = ti.Matrix.zero(y.x.dtype, 3, 3)
        xi = y.x[i]
        if ti.static(self.has_membrane):
            inv_dt = 1.0 / dt
            vi = y.v[i]
            block = ti.Vector.zero(y.x.dtype, 6)  # the blocks' six entries (sym_entries)
            first, last = self.corner_offsets[i], self.corner_offsets[i + 1]
            # Two corners an iteration: a corner's work is one long chain (its normal's square
            # root and division, then the stress and the block), and two independent chains
            # side by side keep the core busy (64 x 64 cloth-membrane: about 10 % faster than
            # one corner an iteration, slower with three or four; docs/lab/vbd.md)
            for pair in range((last - first) // 2):
                for k in ti.static(range(2)):
                    force, corner = self.corner(first + 2 * pair + k, y, xi, vi, inv_dt)
                    f += force
                    block += corner
            for e in range(first + (last - first) // 2 * 2, last):
                force, corner = self.corner(e, y, xi, vi, inv_dt)
                f += force
                block += corner
            H = sym_matrix(block)
        if ti.static(self.hinged):
            force, block = self.bending.vertex_terms(i, y.x)
            f += force
            H += block
        elif ti.static(self.has_bending):
            d = self.bending.stiffness[None]
            diagonal = self.bending_diagonal[i]
            lx = diagonal * xi
            for e in range(self.bending_offsets[i], self.bending_offsets[i + 1]):
                lx += self.bending_values[e] * y.x[self.bending_columns[e]]
            f -= d * lx
            H += (d * diagonal) * ti.Matrix.identity(y.x.dtype, 3)
        return f, H
