"""The springs' force Jacobians for the implicit integrators: products, diagonal blocks, the
cached row coefficients that CG and Gauss-Seidel sweeps read, and the sparse matrix blocks the
direct solver assembles."""
import taichi as ti

from ... import runtime


class SpringJacobians:
    """Mixin of :class:`~taichi_sim.forces.springs.Springs`: everything the implicit methods ask
    of the springs beyond their force (see :class:`~taichi_sim.forces.ForceTerm`'s
    ``has_jacobian`` and ``couples_particles``). It reads the term's CSR incidence (``offsets``,
    ``incident``, ``other``) and per-spring columns."""

    @property
    def coupling_block_capacity(self) -> int:
        """Off-diagonal 3x3 blocks of A the springs fill at most: two per spring (one on each
        side of the diagonal; :meth:`add_coupling_blocks` adds the one below it)."""
        return 2 * self.spring_count

    @ti.func
    def _jacobian_coefficients(self, s, i, j, y, a, b):
        """(u, alpha, beta) with a dF/dv_i + b dF/dx_i = alpha I + beta u u^T (3x3) for the force
        F of spring s on its end i (other end j); u = d/|d|, d = x_i - x_j.

        Stiffness: dF/dx_i = -k (u u^T + max(0, 1 - r/|d|) (I - u u^T)). The exact transverse
        factor 1 - r/|d| is negative for a compressed spring, which makes the block indefinite
        and M - a df/dv - b df/dx possibly indefinite too; clamping it at 0 (Choi & Ko 2002)
        keeps each spring's block negative semi-definite, so that matrix stays symmetric
        positive definite and CG and Cholesky apply. The clamp only changes the Jacobian, never
        the force: a Newton iteration with it is a quasi-Newton iteration that still converges
        to the exact implicit solution.
        Dashpot: dF/dv_i = -c u u^T. The dashpot force also depends on positions (through u);
        that part is not symmetric and is left out, as Baraff & Witkin (1998) do.
        So alpha = -b k max(0, 1 - r/|d|) and beta = -b k - a c - alpha. Since F depends on i
        and j only through x_i - x_j and v_i - v_j, the blocks with respect to j are the
        negatives of these. A zero-length spring exerts no force: zero coefficients.
        """
        u = ti.Vector.zero(y.x.dtype, 3)
        alpha = ti.cast(0.0, y.x.dtype)
        beta = ti.cast(0.0, y.x.dtype)
        d = y.x[i] - y.x[j]
        length = d.norm()
        if length > 0.0:
            u = d / length
            k = self.stiffness[s]
            alpha = -b * k * ti.max(1.0 - self.rest[s] / length, 0.0)
            beta = -b * k - alpha
            if ti.static(self.damped):
                beta -= a * self.damping[s]
        return u, alpha, beta

    @ti.func
    def _jacobian_block(self, s, i, j, y, a, b):
        """a dF/dv_i + b dF/dx_i (3x3) for the force F of spring s on its end i (other end j);
        see :meth:`_jacobian_coefficients`."""
        u, alpha, beta = self._jacobian_coefficients(s, i, j, y, a, b)
        return alpha * ti.Matrix.identity(y.x.dtype, 3) + beta * u.outer_product(u)

    @ti.func
    def jacobian_product(self, i, y, p, a, b, t):
        """a (df/dv p)_i + b (df/dx p)_i (N): a gather over i's springs, like :meth:`force`."""
        out = ti.Vector.zero(y.x.dtype, 3)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            s = self.incident[e]
            if self.is_alive(s):
                j = self.other[e]
                u, alpha, beta = self._jacobian_coefficients(s, i, j, y, a, b)
                w = p[i] - p[j]
                out += alpha * w + (beta * u.dot(w)) * u
        return out

    @ti.func
    def jacobian_diagonal_block(self, i, y, a, b, t):
        block = ti.Matrix.zero(y.x.dtype, 3, 3)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            s = self.incident[e]
            if self.is_alive(s):
                block += self._jacobian_block(s, i, self.other[e], y, a, b)
        return block

    def bind_jacobian_cache(self) -> None:
        """Allocate the Jacobian cache, once (an implicit integrator calls it when bound; later
        calls do nothing, so every integrator on this system shares it).

        For A = M - a df/dv - b df/dx, the cache holds the off-diagonal blocks of A that the
        springs add: A_ij = -(a df_i/dv_j + b df_i/dx_j) = J_s = a D_s + b K_s for spring s
        joining i to j, with K_s = dF/dx_i and D_s = dF/dv_i for its force F on i (as
        dF/dx_j = -K_s). Both are symmetric, with u u^T and I as their only parts, so
        J_s = alpha I + beta u u^T is stored as (u, beta, alpha): five numbers instead of nine
        (see :meth:`_jacobian_coefficients`). There is one entry per incidence entry (2S: a
        spring under each of its ends), in particle i's range offsets[i]:offsets[i+1] of the
        CSR incidence, zero where the other end is not free, with that end in ``entry_other``;
        within the range the entries with j < i come first, up to ``lower_end[i]``, then those
        with j > i (so Gauss-Seidel sweeps read one triangle without testing j).
        :meth:`cache_jacobian_row` fills particle i's entries at a state and returns its
        diagonal part; :meth:`cached_coupling_product` then gives sum_j A_ij p_j by reading
        i's entries in storage order: no norms, square roots or outer products per product, and
        each entry is written and read by its own particle (no atomics). Per entry rather than
        per spring keeps a row's blocks contiguous, for the price of computing each spring's
        coefficients twice per fill (once per Newton iteration, against dozens of products)."""
        if self.entry_block is None:
            self.entry_block = ti.Vector.field(5, runtime.real(), shape=2 * self.spring_count)
            self.entry_other = ti.field(ti.i32, shape=2 * self.spring_count)
            self.lower_end = ti.field(ti.i32, shape=self.offsets.shape[0] - 1)

    @ti.func
    def cache_jacobian_row(self, i, y, a, b, t, free):
        """Store (u, beta, alpha) of a D_s + b K_s at state ``y`` for each entry of particle i
        (zero for a dead spring or a pinned other end, whose unknown is not in the solve) and
        return the sum of the blocks of its live springs (3x3; a pinned neighbour still
        stiffens i): the term's part of a df_i/dv_i + b df_i/dx_i."""
        alpha_sum = ti.cast(0.0, y.x.dtype)
        outer_sum = ti.Matrix.zero(y.x.dtype, 3, 3)
        lower = self.offsets[i]  # entries with j < i go first, those with j > i last
        upper = self.offsets[i + 1]
        for e in range(self.offsets[i], self.offsets[i + 1]):
            s = self.incident[e]
            j = self.other[e]
            entry = ti.Vector.zero(y.x.dtype, 5)
            if self.is_alive(s):
                u, alpha, beta = self._jacobian_coefficients(s, i, j, y, a, b)
                alpha_sum += alpha
                outer_sum += beta * u.outer_product(u)
                if free[j]:
                    entry = ti.Vector([u[0], u[1], u[2], beta, alpha])
            slot = lower
            if j < i:
                lower += 1
            else:
                upper -= 1
                slot = upper
            self.entry_block[slot] = entry
            self.entry_other[slot] = j
        self.lower_end[i] = lower
        return alpha_sum * ti.Matrix.identity(y.x.dtype, 3) + outer_sum

    @ti.func
    def cached_coupling_product(self, i, p, side: ti.template()):
        """sum over particle i's entries of J_e p_j = alpha p_j + beta (u . p_j) u, from the
        coefficients :meth:`cache_jacobian_row` stored: the off-diagonal part of row i of A
        times p, over every j (``side`` 0), only j < i (-1) or only j > i (+1)."""
        out = ti.Vector.zero(p.dtype, 3)
        first = self.offsets[i]
        last = self.offsets[i + 1]
        if ti.static(side < 0):
            last = self.lower_end[i]
        if ti.static(side > 0):
            first = self.lower_end[i]
        for e in range(first, last):
            c = self.entry_block[e]
            pj = p[self.entry_other[e]]
            u = ti.Vector([c[0], c[1], c[2]])
            out += c[4] * pj + (c[3] * u.dot(pj)) * u
        return out

    @ti.func
    def add_coupling_blocks(self, i, y, a, b, t, weight, free, builder: ti.template()):
        """Add ``weight`` (a df_i/dv_j + b df_i/dx_j) for each live spring (i, j) with j free and
        j < i: the blocks below the diagonal (the matrix is symmetric; see
        :meth:`taichi_sim.systems.ParticleSystem.assemble_system_matrix`).

        Every live spring adds its block whatever its state (zero blocks included), so the
        sparsity pattern changes only with ``topology_version``."""
        for e in range(self.offsets[i], self.offsets[i + 1]):
            s = self.incident[e]
            j = self.other[e]
            if j < i and self.is_alive(s) and free[j]:
                block = -weight * self._jacobian_block(s, i, j, y, a, b)
                for r, c in ti.static(ti.ndrange(3, 3)):
                    builder[3 * i + r, 3 * j + c] += block[r, c]
