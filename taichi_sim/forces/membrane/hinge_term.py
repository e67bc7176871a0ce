"""Bending by the dihedral angles of the interior edges, from a rest shape that may be curved:
discrete shells (one hinge an element) or a shape operator per triangle (its three hinges an
element). The rest geometry is :mod:`.hinges`'; docs/materials.md, "Bending"."""

import numpy as np
import taichi as ti

from ... import runtime
from ..base import ForceTerm
from ..springs.topology import incidence_of
from .bending import check_bending_stiffness
from .hinges import (
    check_bending_model,
    check_poisson,
    dihedral_moduli,
    element_stencils,
    hinge_angles,
    hinge_topology,
    shape_operator_moduli,
)


def hinge_elements(triangles, rest_x, stiffness: float, model: str, poisson: float = 0.0) -> dict:
    """The numpy arrays of a :class:`HingeBending` (also the scene's arrays, which
    :func:`taichi_sim.reference.membrane_energy` reads): ``hinge_vertices`` (H, 4),
    ``hinge_rest_angle`` (H,) rad, ``bending_elements`` (E, 3) hinge ids (-1: none) and
    ``bending_moduli`` (E, 3, 3) Q (N m), an element's energy (1/2) d^T Q d for d its hinges'
    theta - theta_rest."""
    vertices, faces, face_hinges = hinge_topology(triangles)
    rest, _ = hinge_angles(rest_x, vertices)
    if model == "dihedral":
        elements = np.full((len(vertices), 3), -1, np.int64)
        elements[:, 0] = np.arange(len(vertices))
        moduli = np.zeros((len(vertices), 3, 3))
        moduli[:, 0, 0] = dihedral_moduli(rest_x, vertices, faces, triangles, stiffness)
    else:
        elements = face_hinges
        moduli = shape_operator_moduli(rest_x, triangles, vertices, face_hinges, stiffness, poisson)
        keep = (elements >= 0).any(axis=1)  # a triangle with no interior edge bends nothing
        elements, moduli = elements[keep], moduli[keep]
    return {"hinge_vertices": vertices, "hinge_rest_angle": rest, "bending_elements": elements,
            "bending_moduli": moduli}


@ti.data_oriented
class HingeBending(ForceTerm):
    """E = sum over elements of (1/2) d^T Q d, d the element's hinges' theta - theta_rest (up to
    three; theta the signed dihedral angle of an interior edge, wrapped into (-pi, pi]), Q from
    the rest shape (:func:`hinge_elements`):

    * ``dihedral``: one hinge an element, Q = D |e|^2 / (A0 + A1) (discrete shells, Grinspun et
      al. 2003); on a structured mesh it shares the isometric model's dependence on the bend's
      direction;
    * ``shape_operator``: a triangle's three hinges an element, Q the plate energy
      A (D/2) [(1 - nu) tr(M^2) + nu (tr M)^2] of a curvature tensor M linear in d, fitted so
      that it is exact for any uniform curvature: the same bend stores the same energy in any
      direction on any triangulation (docs/materials.md).

    The rest shape is the mesh as loaded, so a curved cloth rests curved. The implicit methods'
    blocks are Gauss-Newton's, -b sum_kl Q_kl grad theta_k grad theta_l^T (PSD; the dropped
    term d_k Q grad^2 theta vanishes at rest). An element reaches the vertices of its hinges:
    4 (dihedral) or up to 6 (a triangle and the far vertices of its neighbours).

    Args:
        particle_count: n.
        triangles: (T, 3) vertex ids.
        rest_x: (n, 3) rest positions (m).
        stiffness: D (N m), >= 0.
        model: ``dihedral`` or ``shape_operator``.
        poisson: the plate's bending Poisson's ratio nu (shape_operator), in [0, 0.5).
    """

    name = "bending"
    elastic_model = "bending"
    reads_other_particles = True
    precomputes = True
    has_jacobian = True
    couples_particles = True
    caches_jacobian = True
    precomputes_jacobian = True
    topology_version = 0

    def __init__(self, particle_count: int, triangles, rest_x, stiffness: float, model: str = "dihedral",
                 poisson: float = 0.0):
        self.model = check_bending_model(model)
        if model == "isometric":
            raise ValueError("HingeBending: model isometric is IsometricBending")
        self.stiffness_value = check_bending_stiffness(stiffness)
        self.poisson = check_poisson(poisson)
        self.arrays_np = hinge_elements(triangles, rest_x, self.stiffness_value, model, self.poisson)
        vertices, elements = self.arrays_np["hinge_vertices"], self.arrays_np["bending_elements"]
        self.hinge_count, self.element_count = H, E = len(vertices), len(elements)
        if E == 0:
            raise ValueError("HingeBending needs at least one interior edge")
        self.per = 1 if model == "dihedral" else 3  # hinges an element
        self.width = W = 4 if model == "dihedral" else 6  # vertices an element
        stencil, local = element_stencils(vertices, elements, W)
        self.vertices_np = np.where(stencil >= 0, stencil, stencil[:, :1])  # pad with a vertex of its own
        real = runtime.real()
        self.hinge_vertices = ti.Vector.field(4, ti.i32, shape=H)
        self.rest_angle = ti.field(real, shape=H)
        self.elements = ti.Vector.field(3, ti.i32, shape=E)
        self.local = ti.Vector.field(4, ti.i32, shape=(E, 3))
        self.moduli = ti.Matrix.field(3, 3, real, shape=E)
        self.vertices = ti.Vector.field(W, ti.i32, shape=E)
        self.share = ti.field(real, shape=E)  # 1 / the element's distinct vertices (energy_at)
        offsets, element, slot = incidence_of(particle_count, stencil)
        self.offsets = ti.field(ti.i32, shape=particle_count + 1)
        self.incident = ti.field(ti.i32, shape=max(1, len(element)))
        self.slot = ti.field(ti.i32, shape=max(1, len(slot)))
        # the whole-system pass: each hinge's angle and gradient, then its summed moment
        self.theta = ti.field(real, shape=H)
        self.gradient = ti.Matrix.field(4, 3, real, shape=H)
        self.element_moment = ti.Vector.field(3, real, shape=E)
        self.hinge_moment = ti.field(real, shape=H)
        refs = np.full((H, 2), -1, np.int64)  # the (element, hinge slot) pairs of each hinge, as 3 e + k
        filled = np.zeros(H, np.int64)
        for e, k in zip(*np.nonzero(elements >= 0)):
            h = elements[e, k]
            refs[h, filled[h]] = 3 * e + k
            filled[h] += 1
        self.hinge_refs = ti.Vector.field(2, ti.i32, shape=H)
        h_offsets, h_element, h_slot = incidence_of(particle_count, vertices)
        self.hinge_offsets = ti.field(ti.i32, shape=particle_count + 1)
        self.hinge_incident = ti.field(ti.i32, shape=4 * H)
        self.hinge_slot = ti.field(ti.i32, shape=4 * H)
        self.element_block = ti.Matrix.field(3, 3, real, shape=(E, W, W))
        self.slot_grad = ti.Vector.field(3, real, shape=(E, self.per, W))  # d theta_k / d x_s
        self.entry_block = None  # the Jacobian cache, allocated by bind_jacobian_cache
        i32, npr = np.int32, runtime.np_real()
        self._upload(vertices.astype(i32), self.arrays_np["hinge_rest_angle"].astype(npr), elements.astype(i32),
                     local.astype(i32), self.arrays_np["bending_moduli"].astype(npr), self.vertices_np.astype(i32),
                     (1.0 / (stencil >= 0).sum(axis=1)).astype(npr), offsets, element, slot, refs.astype(i32),
                     h_offsets, h_element, h_slot)

    @ti.kernel
    def _upload(self, hv: ti.types.ndarray(dtype=ti.i32, ndim=2), rest: ti.types.ndarray(ndim=1),
                elements: ti.types.ndarray(dtype=ti.i32, ndim=2), local: ti.types.ndarray(dtype=ti.i32, ndim=3),
                moduli: ti.types.ndarray(ndim=3), vertices: ti.types.ndarray(dtype=ti.i32, ndim=2),
                share: ti.types.ndarray(ndim=1), offsets: ti.types.ndarray(dtype=ti.i32, ndim=1),
                element: ti.types.ndarray(dtype=ti.i32, ndim=1), slot: ti.types.ndarray(dtype=ti.i32, ndim=1),
                refs: ti.types.ndarray(dtype=ti.i32, ndim=2), h_offsets: ti.types.ndarray(dtype=ti.i32, ndim=1),
                h_element: ti.types.ndarray(dtype=ti.i32, ndim=1), h_slot: ti.types.ndarray(dtype=ti.i32, ndim=1)):
        for h in range(self.hinge_count):
            for r in ti.static(range(4)):
                self.hinge_vertices[h][r] = hv[h, r]
            self.rest_angle[h] = rest[h]
            for k in ti.static(range(2)):
                self.hinge_refs[h][k] = refs[h, k]
        for e in range(self.element_count):
            for k in ti.static(range(3)):
                self.elements[e][k] = elements[e, k]
                for r in ti.static(range(4)):
                    self.local[e, k][r] = local[e, k, r]
                for c in ti.static(range(3)):
                    self.moduli[e][k, c] = moduli[e, k, c]
            for r in ti.static(range(self.width)):
                self.vertices[e][r] = vertices[e, r]
            self.share[e] = share[e]
        for i in range(offsets.shape[0]):
            self.offsets[i] = offsets[i]
            self.hinge_offsets[i] = h_offsets[i]
        for j in range(element.shape[0]):
            self.incident[j] = element[j]
            self.slot[j] = slot[j]
        for j in range(h_element.shape[0]):
            self.hinge_incident[j] = h_element[j]
            self.hinge_slot[j] = h_slot[j]

    def arrays(self) -> dict:
        return dict(self.arrays_np, bending_model=np.array(self.model))

    def anchored_fields(self) -> tuple:
        return (self.hinge_offsets, self.hinge_incident, self.hinge_slot, self.hinge_moment, self.gradient)

    # -- geometry --------------------------------------------------------------------------

    @ti.func
    def hinge(self, h, x):
        """theta - theta_rest of hinge h (rad, wrapped into (-pi, pi]) and its gradient (4x3,
        row r: d theta / d x_r, 1/m), as :func:`~taichi_sim.forces.membrane.hinges.hinge_angles`;
        finite at a flat, collapsed or zero-length hinge."""
        v = self.hinge_vertices[h]
        p0, p1, p2, p3 = x[v[0]], x[v[1]], x[v[2]], x[v[3]]
        e = p1 - p0
        n1 = e.cross(p2 - p0)
        n2 = (p3 - p0).cross(e)
        tiny = ti.cast(1e-30, x.dtype)
        length2 = ti.max(e.norm_sqr(), tiny)
        length = ti.sqrt(length2)
        a1 = ti.max(n1.norm_sqr(), tiny)
        a2 = ti.max(n2.norm_sqr(), tiny)
        u1 = n1 / ti.sqrt(a1)
        u2 = n2 / ti.sqrt(a2)
        theta = ti.atan2(u1.cross(u2).dot(e) / length, u1.dot(u2))
        g2 = -(length / a1) * n1
        g3 = -(length / a2) * n2
        s2 = (p2 - p0).dot(e) / length2
        s3 = (p3 - p0).dot(e) / length2
        g0 = -(1 - s2) * g2 - (1 - s3) * g3
        g1 = -s2 * g2 - s3 * g3
        d = theta - self.rest_angle[h]
        pi = ti.cast(np.pi, x.dtype)
        if d > pi:
            d -= 2 * pi
        elif d < -pi:
            d += 2 * pi
        return d, ti.Matrix.rows([g0, g1, g2, g3])

    @ti.func
    def element_state(self, e, s, x):
        """Element e's d (3-vector: its hinges' theta - theta_rest, 0 for a missing one) and, as
        the rows of a 3x3 matrix, d theta_k / d x of its vertex slot ``s`` (1/m; zero for s < 0).
        A loop over the hinges, not unrolled: one hinge's code to compile per caller."""
        d = ti.Vector.zero(x.dtype, 3)
        g = ti.Matrix.zero(x.dtype, 3, 3)
        hinges = self.elements[e]
        for k in range(self.per):
            h = hinges[k]
            if h >= 0:
                theta, grad = self.hinge(h, x)
                d[k] = theta
                local = self.local[e, k]
                for r in ti.static(range(4)):
                    if local[r] == s:
                        for c in ti.static(range(3)):
                            g[k, c] += grad[r, c]
        return d, g

    @ti.func
    def element_energy(self, e, x):
        """(1/2) d^T Q d of element e (J)."""
        d, g = self.element_state(e, -1, x)
        return 0.5 * d.dot(self.moduli[e] @ d)

    @ti.func
    def vertex_terms(self, i, x):
        """The force on vertex i (N) and its Gauss-Newton block sum Q_kl g_k g_l^T (3x3, N/m,
        PSD) from its elements at positions ``x``: what vertex block descent solves with."""
        f = ti.Vector.zero(x.dtype, 3)
        block = ti.Matrix.zero(x.dtype, 3, 3)
        for j in range(self.offsets[i], self.offsets[i + 1]):
            e = self.incident[j]
            d, g = self.element_state(e, self.slot[j], x)
            q = self.moduli[e]
            f -= g.transpose() @ (q @ d)
            block += g.transpose() @ q @ g
        return f, block

    # -- forces and energy -----------------------------------------------------------------

    @ti.func
    def hinge_pass(self, y):
        """Each hinge's theta - theta_rest and gradient at ``y`` into ``theta``, ``gradient``."""
        ti.loop_config(serialize=self.serial_loops)
        for h in range(self.hinge_count):
            theta, grad = self.hinge(h, y.x)
            self.theta[h] = theta
            self.gradient[h] = grad

    @ti.func
    def precompute(self, y):
        self.hinge_pass(y)
        ti.loop_config(serialize=self.serial_loops)
        for e in range(self.element_count):
            d = ti.Vector.zero(y.x.dtype, 3)
            hinges = self.elements[e]
            for k in ti.static(range(self.per)):
                if hinges[k] >= 0:
                    d[k] = self.theta[hinges[k]]
            self.element_moment[e] = self.moduli[e] @ d
        ti.loop_config(serialize=self.serial_loops)
        for h in range(self.hinge_count):
            refs = self.hinge_refs[h]
            total = ti.cast(0.0, y.x.dtype)
            for k in ti.static(range(2)):
                if refs[k] >= 0:
                    total += self.element_moment[refs[k] // 3][refs[k] % 3]
            self.hinge_moment[h] = total

    @ti.func
    def precomputed_force(self, i, y, mass_i, t):
        f = ti.Vector.zero(y.x.dtype, 3)
        for j in range(self.hinge_offsets[i], self.hinge_offsets[i + 1]):
            h = self.hinge_incident[j]
            r = self.hinge_slot[j]
            g = self.gradient[h]
            f -= self.hinge_moment[h] * ti.Vector([g[r, 0], g[r, 1], g[r, 2]])
        return f

    @ti.func
    def force(self, i, y, mass_i, t):
        """-sum over i's elements of sum_k (Q d)_k d theta_k / d x_i (N)."""
        f, block = self.vertex_terms(i, y.x)
        return f

    @ti.func
    def energy_at(self, i, y, free_i):
        """An equal share of each of i's elements' energy (J)."""
        total = ti.cast(0.0, y.x.dtype)
        for j in range(self.offsets[i], self.offsets[i + 1]):
            e = self.incident[j]
            total += self.share[e] * self.element_energy(e, y.x)
        return total

    def energy(self, y) -> float:
        return float(self._energy(y))

    @ti.kernel
    def _energy(self, y: ti.template()) -> float:
        total = 0.0
        for e in range(self.element_count):
            total += self.element_energy(e, y.x)
        return total

    # -- Jacobians: Gauss-Newton blocks per element, the membrane's protocol --------------

    @property
    def coupling_block_capacity(self) -> int:
        return self.width * (self.width - 1) * self.element_count

    @ti.func
    def precompute_jacobian(self, y, a, b):
        """Each element's blocks b df_r/dx_s = -b sum_kl Q_kl g_kr g_ls^T into ``element_block``
        (no velocity dependence): top-level loops over the hinges (their gradients), the
        elements' slots (g_ks) and the slots' pairs, so that the kernels that read the blocks
        compile one small body each (unrolled over the pairs, compiling took minutes)."""
        self.hinge_pass(y)
        ti.loop_config(serialize=self.serial_loops)
        for e, k, s in ti.ndrange(self.element_count, self.per, self.width):
            h = self.elements[e][k]
            g = ti.Vector.zero(y.x.dtype, 3)
            if h >= 0:
                grad = self.gradient[h]
                local = self.local[e, k]
                for r in ti.static(range(4)):
                    if local[r] == s:
                        g += ti.Vector([grad[r, 0], grad[r, 1], grad[r, 2]])
            self.slot_grad[e, k, s] = g
        ti.loop_config(serialize=self.serial_loops)
        for e, r, s in ti.ndrange(self.element_count, self.width, self.width):
            q = self.moduli[e]
            block = ti.Matrix.zero(y.x.dtype, 3, 3)
            for k in ti.static(range(self.per)):
                qg = ti.Vector.zero(y.x.dtype, 3)  # sum_l Q_kl g_ls
                for c in ti.static(range(self.per)):
                    qg += q[k, c] * self.slot_grad[e, c, s]
                block += self.slot_grad[e, k, r].outer_product(qg)
            self.element_block[e, r, s] = -b * block

    @ti.func
    def jacobian_diagonal_block(self, i, y, a, b, t):
        out = ti.Matrix.zero(y.x.dtype, 3, 3)
        for j in range(self.offsets[i], self.offsets[i + 1]):
            s = self.slot[j]
            out += self.element_block[self.incident[j], s, s]
        return out

    @ti.func
    def jacobian_product(self, i, y, p, a, b, t):
        out = ti.Vector.zero(y.x.dtype, 3)
        for j in range(self.offsets[i], self.offsets[i + 1]):
            e = self.incident[j]
            s = self.slot[j]
            v = self.vertices[e]
            for r in ti.static(range(self.width)):
                out += self.element_block[e, s, r] @ p[v[r]]
        return out

    def bind_jacobian_cache(self) -> None:
        """width - 1 entries per incidence entry, as :meth:`Membrane.bind_jacobian_cache
        <taichi_sim.forces.membrane.Membrane.bind_jacobian_cache>` (a padded slot's block is zero)."""
        if self.entry_block is None:
            entries = max(1, (self.width - 1) * self.incident.shape[0])
            self.entry_block = ti.Matrix.field(3, 3, runtime.real(), shape=entries)
            self.entry_other = ti.field(ti.i32, shape=entries)
            self.lower_end = ti.field(ti.i32, shape=self.offsets.shape[0] - 1)

    @ti.func
    def cache_jacobian_row(self, i, y, a, b, t, free):
        diagonal = ti.Matrix.zero(y.x.dtype, 3, 3)
        lower = (self.width - 1) * self.offsets[i]
        upper = (self.width - 1) * self.offsets[i + 1]
        for j in range(self.offsets[i], self.offsets[i + 1]):
            e = self.incident[j]
            s = self.slot[j]
            v = self.vertices[e]
            diagonal += self.element_block[e, s, s]
            for step in ti.static(range(1, self.width)):
                r = (s + step) % self.width
                other = v[r]
                entry = ti.Matrix.zero(y.x.dtype, 3, 3)
                if free[other]:
                    entry = -self.element_block[e, s, r]
                slot = lower
                if other < i:
                    lower += 1
                else:
                    upper -= 1
                    slot = upper
                self.entry_block[slot] = entry
                self.entry_other[slot] = other
        self.lower_end[i] = lower
        return diagonal

    @ti.func
    def cached_coupling_product(self, i, p, side: ti.template()):
        out = ti.Vector.zero(p.dtype, 3)
        first = (self.width - 1) * self.offsets[i]
        last = (self.width - 1) * self.offsets[i + 1]
        if ti.static(side < 0):
            last = self.lower_end[i]
        if ti.static(side > 0):
            first = self.lower_end[i]
        for j in range(first, last):
            out += self.entry_block[j] @ p[self.entry_other[j]]
        return out

    @ti.func
    def add_coupling_blocks(self, i, y, a, b, t, weight, free, builder: ti.template()):
        for j in range(self.offsets[i], self.offsets[i + 1]):
            e = self.incident[j]
            s = self.slot[j]
            v = self.vertices[e]
            for step in ti.static(range(1, self.width)):
                r = (s + step) % self.width
                other = v[r]
                if other < i and free[other]:
                    block = weight * self.element_block[e, s, r]
                    for c, d in ti.static(ti.ndrange(3, 3)):
                        builder[3 * i + c, 3 * other + d] += block[c, d]
