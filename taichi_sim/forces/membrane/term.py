"""Constant-strain triangle membranes: the force term (forces, energy, dissipation)."""

import numpy as np
import taichi as ti

from ... import runtime
from ..base import ForceTerm
from ..springs.topology import incidence_of
from .geometry import rest_frames, shape_gradients
from .jacobian import MembraneJacobians
from .material import (
    MembraneMaterial,
    neohookean,
    neohookean_corner,
    neohookean_hessian,
    stvk,
    stvk_corner,
    stvk_hessian,
    viscous,
)


@ti.data_oriented
class Membrane(MembraneJacobians, ForceTerm):
    """Hyperelastic constant-strain triangles with an optional viscous stress.

    Triangle t = (v0, v1, v2) has the deformation gradient F = Ds Dm^-1 (3x2), with
    Ds = [x1 - x0, x2 - x0] and Dm its rest edges in a 2D frame of its own
    (:func:`~taichi_sim.forces.membrane.geometry.rest_frames`), and stores A psi(F) (J) for its
    rest area A (m^2) and the material's energy density psi (J/m^2; see
    :mod:`~taichi_sim.forces.membrane.material`). The force on its vertex a is
    -A (P + P_v) g_a, with P = dpsi/dF, P_v the viscous stress and g_a = dF/dx_a's 2-vector
    (F = sum_a x_a g_a^T). Rigid motions give zero force; every triangle's forces sum to zero.

    A whole-system evaluation computes each triangle's three forces once (:meth:`precompute`,
    triangle-parallel), then each vertex sums its triangles' entries (CSR incidence): no
    atomics, bit-reproducible. :meth:`force` evaluates one vertex on its own.

    Args:
        particle_count: n.
        triangles: (T, 3) vertex ids.
        rest_x: (n, 3) rest positions (m): the flat grid, or a mesh as loaded (each triangle
            flattened to its own frame).
        material: a :class:`~taichi_sim.forces.membrane.material.MembraneMaterial`.
    """

    name = "membrane"
    reads_other_particles = True
    precomputes = True
    has_jacobian = True
    couples_particles = True
    caches_jacobian = True
    topology_version = 0

    def __init__(self, particle_count: int, triangles, rest_x, material: MembraneMaterial):
        triangles = np.asarray(triangles, np.int32).reshape(-1, 3)
        self.triangle_count = T = len(triangles)
        if T == 0:
            raise ValueError("Membrane needs at least one triangle")
        self.material = material
        self.model = self.elastic_model = material.model
        self.damped = material.damping > 0
        inverse, area = rest_frames(rest_x, triangles)
        self.triangles_np, self.inverse_np, self.area_np = triangles, inverse, area
        real = runtime.real()
        self.vertices = ti.Vector.field(3, ti.i32, shape=T)
        self.inverse = ti.Matrix.field(2, 2, real, shape=T)
        self.area = ti.field(real, shape=T)
        offsets, element, slot = incidence_of(particle_count, triangles)
        self.offsets = ti.field(ti.i32, shape=particle_count + 1)
        self.incident = ti.field(ti.i32, shape=3 * T)
        self.slot = ti.field(ti.i32, shape=3 * T)
        # mu, lam (N/m) and the damping time (s): fields, so a change recompiles nothing
        self.moduli = ti.Vector.field(3, real, shape=())
        self.triangle_force = ti.Vector.field(3, real, shape=(T, 3))  # each triangle's force on each corner
        self.entry_block = None  # the Jacobian cache, allocated by bind_jacobian_cache
        # each triangle's 3x3 blocks a df_r/dv_s + b df_r/dx_s, filled by precompute_jacobian
        self.triangle_block = ti.Matrix.field(3, 3, real, shape=(T, 3, 3))
        npr = runtime.np_real()
        self._upload(triangles, inverse.astype(npr), area.astype(npr), offsets, element, slot,
                     np.array([material.mu, material.lam, material.damping], npr))

    @ti.kernel
    def _upload(self, triangles: ti.types.ndarray(dtype=ti.i32, ndim=2), inverse: ti.types.ndarray(ndim=3),
                area: ti.types.ndarray(ndim=1), offsets: ti.types.ndarray(dtype=ti.i32, ndim=1),
                element: ti.types.ndarray(dtype=ti.i32, ndim=1), slot: ti.types.ndarray(dtype=ti.i32, ndim=1),
                moduli: ti.types.ndarray(ndim=1)):
        for t in range(self.triangle_count):
            self.vertices[t] = ti.Vector([triangles[t, 0], triangles[t, 1], triangles[t, 2]])
            self.inverse[t] = ti.Matrix([[inverse[t, 0, 0], inverse[t, 0, 1]], [inverse[t, 1, 0], inverse[t, 1, 1]]])
            self.area[t] = area[t]
        for i in range(offsets.shape[0]):
            self.offsets[i] = offsets[i]
        for e in range(element.shape[0]):
            self.incident[e] = element[e]
            self.slot[e] = slot[e]
        self.moduli[None] = ti.Vector([moduli[0], moduli[1], moduli[2]])

    @property
    def variational(self) -> bool:
        """Elastic forces are the gradient of the energy; the viscous stress's dissipation
        depends on F (so on positions): see :attr:`ForceTerm.variational`."""
        return not self.damped

    def arrays(self) -> dict:
        """The membrane's data for the run's npz: its triangles (T, 3), their rest areas (T,)
        (m^2) and rest frames Dm^-1 (T, 2, 2) (1/m), the model's name and (mu, lambda (N/m),
        the damping time (s)); enough to recompute its energy
        (:func:`taichi_sim.reference.membrane_energy`)."""
        return {"membrane_triangles": self.triangles_np.astype(np.int64), "membrane_rest_area": self.area_np,
                "membrane_rest_inverse": self.inverse_np, "membrane_model": np.array(self.model),
                "membrane_moduli": np.array([self.material.mu, self.material.lam, self.material.damping])}

    def set_material(self, material: MembraneMaterial) -> None:
        """Take ``material``'s moduli and damping time in place (fields: nothing recompiles).
        ValueError for another model, or for switching damping on or off (both are compiled
        into the kernels)."""
        if material.model != self.model or (material.damping > 0) != self.damped:
            raise ValueError(f"set_material: a {self.model} membrane {'with' if self.damped else 'without'} damping "
                             f"cannot take {material}")
        self.material = material
        self.moduli[None] = [material.mu, material.lam, material.damping]

    def corner_layout(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The triangles' corners grouped by vertex, with what a corner's terms read of its
        triangle's rest shape, so that a vertex's solve reads its corners contiguously
        (:class:`~taichi_sim.integrators.positional.vbd.membranes.MembraneTerms`):
        (offsets (n+1,) int32: vertex i's corners are ``offsets[i]:offsets[i+1]``; others
        (E, 2) int32: the corner's triangle's two other vertices j, k; rest (E, 7) float64:
        g_j, g_k, the corner's own shape gradient u (2-vectors, 1/m) and the rest area A (m^2)).
        F = (x_j - x_i) g_j^T + (x_k - x_i) g_k^T, as the shape gradients sum to zero."""
        offsets, element, slot = incidence_of(self.offsets.shape[0] - 1, self.triangles_np)
        g = shape_gradients(self.inverse_np)
        j, k = (slot + 1) % 3, (slot + 2) % 3
        others = np.stack([self.triangles_np[element, j], self.triangles_np[element, k]], axis=1)
        rest = np.concatenate([g[element, j], g[element, k], g[element, slot], self.area_np[element, None]], axis=1)
        return offsets, others.astype(np.int32), rest

    def anchored_fields(self) -> tuple:
        return (self.offsets, self.incident, self.slot, self.triangle_force)

    # -- one triangle ---------------------------------------------------------------------

    @ti.func
    def shape_gradients(self, t):
        """g (3x2, 1/m): row a is vertex a's gradient, F = sum_a x_a g_a^T."""
        b = self.inverse[t]
        return ti.Matrix([[-b[0, 0] - b[1, 0], -b[0, 1] - b[1, 1]], [b[0, 0], b[0, 1]], [b[1, 0], b[1, 1]]])

    @ti.func
    def columns(self, t, x, g):
        """The columns (f0, f1) of sum_a x_a g_a^T for a (n,) vec3 field ``x`` (F for
        positions, Fdot for velocities)."""
        v = self.vertices[t]
        f0 = x[v[0]] * g[0, 0] + x[v[1]] * g[1, 0] + x[v[2]] * g[2, 0]
        f1 = x[v[0]] * g[0, 1] + x[v[1]] * g[1, 1] + x[v[2]] * g[2, 1]
        return f0, f1

    @ti.func
    def elastic(self, f0, f1):
        """(psi (J/m^2), P's columns (N/m)) of the term's material."""
        m = self.moduli[None]
        psi, p0, p1 = 0.0 * m[0], ti.Vector.zero(float, 3), ti.Vector.zero(float, 3)
        if ti.static(self.model == "stvk"):
            psi, p0, p1 = stvk(f0, f1, m[0], m[1])
        else:
            psi, p0, p1 = neohookean(f0, f1, m[0], m[1])
        return psi, p0, p1

    @ti.func
    def elastic_hessian(self, f0, f1):
        """d^2 psi / dF^2 (6x6, N/m) of the term's material."""
        m = self.moduli[None]
        h = ti.Matrix.zero(float, 6, 6)
        if ti.static(self.model == "stvk"):
            h = stvk_hessian(f0, f1, m[0], m[1])
        else:
            h = neohookean_hessian(f0, f1, m[0], m[1])
        return h

    @ti.func
    def elastic_corner(self, f0, f1, u, scale):
        """A corner's share of the term's material for its shape gradient u (2-vector, 1/m),
        times ``scale`` (the rest area, m^2): (scale P u (3, N), its own block of the
        triangle's Hessian projected to PSD (N/m), six entries (xx, yy, zz, xy, xz, yz)) (the
        material's ``*_corner``)."""
        m = self.moduli[None]
        stress, h = ti.Vector.zero(float, 3), ti.Vector.zero(float, 6)
        if ti.static(self.model == "stvk"):
            stress, h = stvk_corner(f0, f1, m[0], m[1], u, scale)
        else:
            stress, h = neohookean_corner(f0, f1, m[0], m[1], u, scale)
        return stress, h

    @ti.func
    def triangle_stress(self, t, y, g):
        """(A psi (J), A R (W), the columns of A (P + P_v) (N m)) of triangle t at ``y``."""
        f0, f1 = self.columns(t, y.x, g)
        return self.stress_at(t, y, g, f0, f1)

    @ti.func
    def stress_at(self, t, y, g, f0, f1):
        """:meth:`triangle_stress` given the triangle's F = [f0 f1] at ``y``."""
        psi, p0, p1 = self.elastic(f0, f1)
        r = 0.0 * psi
        if ti.static(self.damped):
            d0, d1 = self.columns(t, y.v, g)
            m = self.moduli[None]
            r, q0, q1 = viscous(f0, f1, d0, d1, m[0], m[1], m[2])
            p0 += q0
            p1 += q1
        a = self.area[t]
        return a * psi, a * r, a * p0, a * p1

    @ti.func
    def corner_force(self, t, corner, y):
        """Force (N) of triangle t on its vertex ``corner`` (0, 1, 2) at ``y``."""
        g = self.shape_gradients(t)
        energy, dissipation, p0, p1 = self.triangle_stress(t, y, g)
        return -(p0 * g[corner, 0] + p1 * g[corner, 1])

    # -- the ForceTerm protocol -------------------------------------------------------------

    @ti.func
    def precompute(self, y):
        """Each triangle's force on each corner at ``y`` into ``triangle_force``."""
        ti.loop_config(serialize=self.serial_loops)
        for t in range(self.triangle_count):
            g = self.shape_gradients(t)
            energy, dissipation, p0, p1 = self.triangle_stress(t, y, g)
            for corner in ti.static(range(3)):
                self.triangle_force[t, corner] = -(p0 * g[corner, 0] + p1 * g[corner, 1])

    @ti.func
    def precomputed_force(self, i, y, mass_i, t):
        f = ti.Vector.zero(y.x.dtype, 3)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            f += self.triangle_force[self.incident[e], self.slot[e]]
        return f

    @ti.func
    def force(self, i, y, mass_i, t):
        f = ti.Vector.zero(y.x.dtype, 3)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            f += self.corner_force(self.incident[e], self.slot[e], y)
        return f

    @ti.func
    def energy_at(self, i, y, free_i):
        """A third of the energy of each of i's triangles (J)."""
        total = ti.cast(0.0, y.x.dtype)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            t = self.incident[e]
            f0, f1 = self.columns(t, y.x, self.shape_gradients(t))
            psi, p0, p1 = self.elastic(f0, f1)
            total += self.area[t] * psi / 3.0
        return total

    @ti.func
    def dissipation_at(self, i, y, free_i):
        """A third of the viscous dissipation function of each of i's triangles (W)."""
        total = ti.cast(0.0, y.x.dtype)
        if ti.static(self.damped):
            for e in range(self.offsets[i], self.offsets[i + 1]):
                t = self.incident[e]
                energy, r, p0, p1 = self.triangle_stress(t, y, self.shape_gradients(t))
                total += r / 3.0
        return total

    def energy(self, y) -> float:
        """Elastic energy sum_t A_t psi(F_t) (J)."""
        return float(self._totals(y)[0])

    def dissipation(self, y) -> float | None:
        """Dissipation function sum_t A_t R_t (W), or None without damping."""
        return float(self._totals(y)[1]) if self.damped else None

    @ti.kernel
    def _totals(self, y: ti.template()) -> (float, float):
        energy = 0.0
        dissipation = 0.0
        for t in range(self.triangle_count):
            u, r, p0, p1 = self.triangle_stress(t, y, self.shape_gradients(t))
            energy += u
            dissipation += r
        return energy, dissipation
