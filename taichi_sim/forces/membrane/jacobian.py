"""The membrane's force Jacobians for the implicit methods: per-vertex 3x3 blocks of each
triangle's Hessian, projected to positive semi-definite, as products, diagonal blocks, the
cached rows CG and Gauss-Seidel sweeps read, and the sparse blocks the direct solver
assembles (the protocol of :class:`~taichi_sim.forces.ForceTerm`)."""
import taichi as ti

from ... import runtime
from .material import project_psd, viscous_corner, viscous_jacobian


@ti.func
def corner_pair_block(k, r0, r1, s0, s1):
    """sum_cd r_c s_d K_cd (3x3) of a 6x6 ``k`` in F's columns (K_cd its 3x3 blocks), for two
    corners' shape gradients r = (r0, r1) and s = (s0, s1) (1/m): the (r, s) block of a
    triangle's Hessian in its vertices, per unit area."""
    block = ti.Matrix.zero(float, 3, 3)
    r = ti.Vector([r0, r1])
    s = ti.Vector([s0, s1])
    for c, d in ti.static(ti.ndrange(2, 2)):
        w = r[c] * s[d]
        for p, q in ti.static(ti.ndrange(3, 3)):
            block[p, q] += w * k[3 * c + p, 3 * d + q]
    return block


class MembraneJacobians:
    """Mixin of :class:`~taichi_sim.forces.membrane.Membrane`. Every reader takes the blocks
    :meth:`precompute_jacobian` stored, in the same kernel.

    For triangle t the 9x9 matrix -(a df/dv + b df/dx) is A g_r[c] g_s[d] K_cd summed over
    the columns c, d, with K = b proj(d^2psi/dF^2) + a dP_v/dFdot (6x6): ``proj`` sets the
    elastic Hessian's negative eigenvalues to zero (a compressed StVK triangle, Neo-Hookean's
    J term), and the viscous part is PSD as it is, so every triangle's block is PSD and
    A = M - a df/dv - b df/dx stays symmetric positive definite (CG and Cholesky apply; the
    Newton iterations still converge to the exact step, whose residual uses the true force).
    """

    @property
    def coupling_block_capacity(self) -> int:
        """Off-diagonal 3x3 blocks the triangles fill: six per triangle (both triangles of the
        matrix; two triangles on one edge each add theirs)."""
        return 6 * self.triangle_count

    precomputes_jacobian = True
    """Fills each triangle's blocks in a pass of its own (:meth:`precompute_jacobian`), which
    every kernel that reads this term's Jacobians runs first at the same state, a and b
    (:meth:`~taichi_sim.systems.ParticleSystem.prepare_jacobian`): the Hessian and its
    projection are then compiled once per kernel instead of once per reader, and computed once
    per triangle instead of once per corner (the first implicit Euler step of a 16 x 16
    Neo-Hookean cloth, nearly all of it compiling, took 106 s before and 36 s after)."""

    @ti.func
    def precompute_jacobian(self, y, a, b):
        """Each triangle's 3x3 blocks a df_r/dv_s + b df_r/dx_s = -A sum_cd g_r[c] g_s[d] K_cd
        at ``y`` into ``triangle_block``, K = b proj(d^2psi/dF^2) + a dP_v/dFdot (see the class).
        A top-level loop over the triangles."""
        ti.loop_config(serialize=self.serial_loops)
        for t in range(self.triangle_count):
            g = self.shape_gradients(t)
            f0, f1 = self.columns(t, y.x, g)
            k = b * project_psd(self.elastic_hessian(f0, f1))
            if ti.static(self.damped):
                m = self.moduli[None]
                k += a * viscous_jacobian(f0, f1, m[0], m[1], m[2])
            area = self.area[t]
            for r, s in ti.static(ti.ndrange(3, 3)):
                self.triangle_block[t, r, s] = -area * corner_pair_block(k, g[r, 0], g[r, 1], g[s, 0], g[s, 1])

    @ti.func
    def corner_terms(self, f0, f1, d0, d1, u, area, inv_dt):
        """A triangle's force on one of its corners (N) and that corner's positive
        semi-definite block of -(df/dx + inv_dt df/dv) (N/m, its six entries xx, yy, zz, xy,
        xz, yz), for the triangle's F = [f0 f1] and Fdot = [d0 d1] (1/s, read only with
        damping), the corner's shape gradient u (2-vector, 1/m) and the rest area (m^2):
        -A (P + P_v) u, and A proj(sum_cd u_c u_d d^2psi/dF_c dF_d) plus A inv_dt
        sum_cd u_c u_d dP_v/dFdot_cd, with ``proj`` on the 3x3 block (the material's
        ``*_corner``), not on the 6x6: the vertex solve of vertex block descent reads this
        block alone, at the iterate, and the nearest PSD matrix to it is the closest Newton
        model of the vertex's own energy. The stress and the block share the corner's work
        (one normal, one strain rate)."""
        stress, block = self.elastic_corner(f0, f1, u, area)
        if ti.static(self.damped):
            m = self.moduli[None]
            rate_stress, rate_block = viscous_corner(f0, f1, d0, d1, m[0], m[1], m[2], u, area, area * inv_dt)
            stress += rate_stress
            block += rate_block
        return -stress, block

    @ti.func
    def jacobian_diagonal_block(self, i, y, a, b, t):
        out = ti.Matrix.zero(y.x.dtype, 3, 3)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            s = self.slot[e]
            out += self.triangle_block[self.incident[e], s, s]
        return out

    @ti.func
    def jacobian_product(self, i, y, p, a, b, t):
        """a (df/dv p)_i + b (df/dx p)_i (N): a gather over i's triangles' blocks."""
        out = ti.Vector.zero(y.x.dtype, 3)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            tri = self.incident[e]
            s = self.slot[e]
            v = self.vertices[tri]
            for r in ti.static(range(3)):
                out += self.triangle_block[tri, s, r] @ p[v[r]]
        return out

    def bind_jacobian_cache(self) -> None:
        """Allocate the Jacobian cache, once: two entries per incidence entry (a triangle under
        one of its corners couples it to the two others), in particle i's range
        2 offsets[i] : 2 offsets[i+1], each the off-diagonal block A_ij = -(a df_i/dv_j +
        b df_i/dx_j) (zero where j is pinned) and j, those with j < i first up to
        ``lower_end[i]`` (as :meth:`Springs.bind_jacobian_cache <taichi_sim.forces.Springs.bind_jacobian_cache>`)."""
        if self.entry_block is None:
            entries = 6 * self.triangle_count
            self.entry_block = ti.Matrix.field(3, 3, runtime.real(), shape=entries)
            self.entry_other = ti.field(ti.i32, shape=entries)
            self.lower_end = ti.field(ti.i32, shape=self.offsets.shape[0] - 1)

    @ti.func
    def cache_jacobian_row(self, i, y, a, b, t, free):
        """Store particle i's off-diagonal blocks at ``y`` and return its diagonal part
        a df_i/dv_i + b df_i/dx_i (3x3)."""
        diagonal = ti.Matrix.zero(y.x.dtype, 3, 3)
        lower = 2 * self.offsets[i]
        upper = 2 * self.offsets[i + 1]
        for e in range(self.offsets[i], self.offsets[i + 1]):
            tri = self.incident[e]
            s = self.slot[e]
            v = self.vertices[tri]
            diagonal += self.triangle_block[tri, s, s]
            for step in ti.static((1, 2)):
                r = (s + step) % 3
                j = v[r]
                entry = ti.Matrix.zero(y.x.dtype, 3, 3)
                if free[j]:
                    entry = -self.triangle_block[tri, s, r]
                slot = lower
                if j < i:
                    lower += 1
                else:
                    upper -= 1
                    slot = upper
                self.entry_block[slot] = entry
                self.entry_other[slot] = j
        self.lower_end[i] = lower
        return diagonal

    @ti.func
    def cached_coupling_product(self, i, p, side: ti.template()):
        """sum of the cached A_ij p_j over i's entries: every j (``side`` 0), j < i (-1) or
        j > i (+1)."""
        out = ti.Vector.zero(p.dtype, 3)
        first = 2 * self.offsets[i]
        last = 2 * self.offsets[i + 1]
        if ti.static(side < 0):
            last = self.lower_end[i]
        if ti.static(side > 0):
            first = self.lower_end[i]
        for e in range(first, last):
            out += self.entry_block[e] @ p[self.entry_other[e]]
        return out

    @ti.func
    def add_coupling_blocks(self, i, y, a, b, t, weight, free, builder: ti.template()):
        """Add ``weight`` (a df_i/dv_j + b df_i/dx_j) for each corner j < i, free, of each of i's
        triangles, whatever the state (the pattern depends on the triangles only)."""
        for e in range(self.offsets[i], self.offsets[i + 1]):
            tri = self.incident[e]
            s = self.slot[e]
            v = self.vertices[tri]
            for step in ti.static((1, 2)):
                r = (s + step) % 3
                j = v[r]
                if j < i and free[j]:
                    block = weight * self.triangle_block[tri, s, r]
                    for p, q in ti.static(ti.ndrange(3, 3)):
                        builder[3 * i + p, 3 * j + q] += block[p, q]
