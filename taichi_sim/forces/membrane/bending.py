"""Bending across the interior edges of a triangle mesh: the quadratic isometric model of
Bergou et al. 2006 ("A quadratic bending model for inextensible surfaces")."""

import math

import numpy as np
import taichi as ti

from ... import runtime
from ...errors import ConfigError
from ..base import ForceTerm
from ..springs.topology import incidence_of
from .geometry import bending_stencils


def check_bending_stiffness(value) -> float:
    """A bending stiffness (N m): finite and >= 0, else ConfigError naming it."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ConfigError(f"parameter bending_stiffness: must be a finite number >= 0 N m, got {value!r}")
    return float(value)


@ti.data_oriented
class IsometricBending(ForceTerm):
    """E = (D/2) sum_e |sum_k w_ek x_k|^2 over the interior edges e, each with its four
    vertices (the edge's two and the two opposite it) and weights w_e from the rest shape's
    cotangents (:func:`~taichi_sim.forces.membrane.geometry.bending_stencils`), for a bending
    stiffness D (N m).

    Why this model rather than discrete shells' dihedral angles: the energy is quadratic in x,
    so the force is linear, the Hessian is constant (D w_a w_b I per pair of stencil vertices)
    and positive semi-definite with no projection, and an implicit step's matrix needs no
    re-evaluation of the bending part; it is exact for the isometric (unstretched) bending that
    cloth does, which the membrane keeps close to. What it gives up: the rest shape is flat
    (a curved mesh bends back towards flat), and like discrete shells on a structured mesh its
    energy depends on the bend's direction relative to the triangles (docs/materials.md).

    Args:
        particle_count: n.
        triangles: (T, 3) vertex ids.
        rest_x: (n, 3) rest positions (m).
        stiffness: D (N m), >= 0.
    """

    name = "bending"
    elastic_model = "bending"
    reads_other_particles = True
    precomputes = True
    has_jacobian = True
    couples_particles = True
    caches_jacobian = True
    topology_version = 0

    def __init__(self, particle_count: int, triangles, rest_x, stiffness: float):
        vertices, weights = bending_stencils(rest_x, triangles)
        self.edge_count = B = len(vertices)
        if B == 0:
            raise ValueError("IsometricBending needs at least one interior edge")
        self.vertices_np, self.weights_np = vertices, weights
        self.stiffness_value = check_bending_stiffness(stiffness)
        real = runtime.real()
        self.vertices = ti.Vector.field(4, ti.i32, shape=B)
        self.weights = ti.Vector.field(4, real, shape=B)
        offsets, element, slot = incidence_of(particle_count, vertices)
        self.offsets = ti.field(ti.i32, shape=particle_count + 1)
        self.incident = ti.field(ti.i32, shape=4 * B)
        self.slot = ti.field(ti.i32, shape=4 * B)
        self.stiffness = ti.field(real, shape=())
        self.curvature = ti.Vector.field(3, real, shape=B)  # sum_k w_k x_k per edge (1 / m x m)
        self.entry_weight = None  # the Jacobian cache, allocated by bind_jacobian_cache
        self._upload(vertices.astype(np.int32), weights.astype(runtime.np_real()), offsets, element, slot,
                     self.stiffness_value)

    @ti.kernel
    def _upload(self, vertices: ti.types.ndarray(dtype=ti.i32, ndim=2), weights: ti.types.ndarray(ndim=2),
                offsets: ti.types.ndarray(dtype=ti.i32, ndim=1), element: ti.types.ndarray(dtype=ti.i32, ndim=1),
                slot: ti.types.ndarray(dtype=ti.i32, ndim=1), stiffness: float):
        for b in range(self.edge_count):
            for k in ti.static(range(4)):
                self.vertices[b][k] = vertices[b, k]
                self.weights[b][k] = weights[b, k]
        for i in range(offsets.shape[0]):
            self.offsets[i] = offsets[i]
        for e in range(element.shape[0]):
            self.incident[e] = element[e]
            self.slot[e] = slot[e]
        self.stiffness[None] = stiffness

    def operator(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The energy's constant Hessian without D, L = sum_e w_e w_e^T (n x n: the Hessian is
        D L (x) I3), as per-vertex rows: (offsets (n+1,) int32, columns (nnz,) int32, values
        (nnz,) float64 (1/m^2)), row i's entries ``offsets[i]:offsets[i+1]``, its diagonal among
        them. The force is -D (L x)_i: one term per vertex i shares a stencil with rather than
        four per stencil (a grid vertex's 12 stencils reach 13 vertices)."""
        from scipy.sparse import coo_matrix

        n = self.offsets.shape[0] - 1
        rows = np.repeat(self.vertices_np, 4, axis=1).ravel()
        columns = np.tile(self.vertices_np, (1, 4)).ravel()
        values = (self.weights_np[:, :, None] * self.weights_np[:, None, :]).ravel()
        matrix = coo_matrix((values, (rows, columns)), shape=(n, n)).tocsr()
        matrix.sum_duplicates()
        matrix.sort_indices()
        return matrix.indptr.astype(np.int32), matrix.indices.astype(np.int32), matrix.data.astype(np.float64)

    def arrays(self) -> dict:
        return {"bending_stencils": self.vertices_np, "bending_weights": self.weights_np,
                "bending_stiffness": np.float64(self.stiffness_value)}

    def anchored_fields(self) -> tuple:
        return (self.offsets, self.incident, self.slot, self.curvature, self.weights)

    @ti.func
    def edge_vector(self, b, x):
        """sum_k w_k x_k of edge b (m / m: the curvature normal times the stencil's size)."""
        v = self.vertices[b]
        w = self.weights[b]
        return w[0] * x[v[0]] + w[1] * x[v[1]] + w[2] * x[v[2]] + w[3] * x[v[3]]

    @ti.func
    def precompute(self, y):
        ti.loop_config(serialize=self.serial_loops)
        for b in range(self.edge_count):
            self.curvature[b] = self.edge_vector(b, y.x)

    @ti.func
    def precomputed_force(self, i, y, mass_i, t):
        f = ti.Vector.zero(y.x.dtype, 3)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            b = self.incident[e]
            f -= self.weights[b][self.slot[e]] * self.curvature[b]
        return self.stiffness[None] * f

    @ti.func
    def force(self, i, y, mass_i, t):
        """-D sum over i's edges of w_i (sum_k w_k x_k) (N)."""
        f = ti.Vector.zero(y.x.dtype, 3)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            b = self.incident[e]
            f -= self.weights[b][self.slot[e]] * self.edge_vector(b, y.x)
        return self.stiffness[None] * f

    @ti.func
    def energy_at(self, i, y, free_i):
        """A quarter of each of i's edges' energy (J)."""
        total = ti.cast(0.0, y.x.dtype)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            total += self.edge_vector(self.incident[e], y.x).norm_sqr()
        return 0.125 * self.stiffness[None] * total

    def energy(self, y) -> float:
        return float(self._energy(y))

    @ti.kernel
    def _energy(self, y: ti.template()) -> float:
        total = 0.0
        for b in range(self.edge_count):
            total += self.edge_energy(b, y.x)
        return total

    @ti.func
    def edge_energy(self, b, x):
        """(D/2) |sum_k w_k x_k|^2 of edge b (J)."""
        return 0.5 * self.stiffness[None] * self.edge_vector(b, x).norm_sqr()

    # -- Jacobians: df_a/dx_c = -D sum_e w_a w_c I, constant; no velocity dependence ----------

    @property
    def coupling_block_capacity(self) -> int:
        return 12 * self.edge_count

    @ti.func
    def jacobian_diagonal_block(self, i, y, a, b, t):
        total = ti.cast(0.0, y.x.dtype)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            w = self.weights[self.incident[e]][self.slot[e]]
            total += w * w
        return -b * self.stiffness[None] * total * ti.Matrix.identity(y.x.dtype, 3)

    @ti.func
    def jacobian_product(self, i, y, p, a, b, t):
        out = ti.Vector.zero(y.x.dtype, 3)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            edge = self.incident[e]
            out += self.weights[edge][self.slot[e]] * self.edge_vector(edge, p)
        return -b * self.stiffness[None] * out

    def bind_jacobian_cache(self) -> None:
        """Three entries per incidence entry (the stencil's other vertices), each the scalar c
        of A_ij = c I and j, those with j < i first up to ``lower_end[i]``."""
        if self.entry_weight is None:
            entries = 12 * self.edge_count
            self.entry_weight = ti.field(runtime.real(), shape=entries)
            self.entry_other = ti.field(ti.i32, shape=entries)
            self.lower_end = ti.field(ti.i32, shape=self.offsets.shape[0] - 1)

    @ti.func
    def cache_jacobian_row(self, i, y, a, b, t, free):
        scale = b * self.stiffness[None]
        diagonal = ti.cast(0.0, y.x.dtype)
        lower = 3 * self.offsets[i]
        upper = 3 * self.offsets[i + 1]
        for e in range(self.offsets[i], self.offsets[i + 1]):
            edge = self.incident[e]
            s = self.slot[e]
            v = self.vertices[edge]
            w = self.weights[edge]
            diagonal += w[s] * w[s]
            for step in ti.static((1, 2, 3)):
                r = (s + step) % 4
                j = v[r]
                entry = ti.cast(0.0, y.x.dtype)
                if free[j]:
                    entry = scale * w[s] * w[r]
                slot = lower
                if j < i:
                    lower += 1
                else:
                    upper -= 1
                    slot = upper
                self.entry_weight[slot] = entry
                self.entry_other[slot] = j
        self.lower_end[i] = lower
        return -scale * diagonal * ti.Matrix.identity(y.x.dtype, 3)

    @ti.func
    def cached_coupling_product(self, i, p, side: ti.template()):
        out = ti.Vector.zero(p.dtype, 3)
        first = 3 * self.offsets[i]
        last = 3 * self.offsets[i + 1]
        if ti.static(side < 0):
            last = self.lower_end[i]
        if ti.static(side > 0):
            first = self.lower_end[i]
        for e in range(first, last):
            out += self.entry_weight[e] * p[self.entry_other[e]]
        return out

    @ti.func
    def add_coupling_blocks(self, i, y, a, b, t, weight, free, builder: ti.template()):
        scale = -b * self.stiffness[None] * weight
        for e in range(self.offsets[i], self.offsets[i + 1]):
            edge = self.incident[e]
            s = self.slot[e]
            v = self.vertices[edge]
            w = self.weights[edge]
            for step in ti.static((1, 2, 3)):
                r = (s + step) % 4
                j = v[r]
                if j < i and free[j]:
                    c = scale * w[s] * w[r]
                    for k in ti.static(range(3)):
                        builder[3 * i + k, 3 * j + k] += c
