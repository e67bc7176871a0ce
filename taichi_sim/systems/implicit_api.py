"""What the implicit methods read of a particle system: force Jacobians, the system matrix of
an implicit step, and per-particle forces with their scales, potential and dissipation."""

import taichi as ti

from ..state import State


class ImplicitAPI:
    """Mixin of :class:`~taichi_sim.systems.ParticleSystem` (which provides ``terms``, ``mass``,
    ``free``, ``particle_count`` and ``constraints``): the force-Jacobian API that the implicit
    integrators and their linear solvers call, one ``@ti.func`` per particle or a kernel over
    all of them."""

    # The force-Jacobian API of the implicit integrators. A is the matrix of an implicit step,
    # A = M - a df/dv - b df/dx (a = tau, b = tau**2 for a step of size tau), restricted to the
    # free particles: a pinned particle's row and column are those of the identity, so it is
    # filtered out of the solve exactly (no penalty) and its unknown comes out exactly zero.

    @property
    def supports_jacobian(self) -> bool:
        """Whether every force term provides its Jacobians (:attr:`ForceTerm.has_jacobian`);
        never with constraints (their force has no Jacobian here)."""
        return self.constraints is None and all(term.has_jacobian for term in self.terms)

    @property
    def jacobian_pattern_version(self) -> int:
        """Changes whenever the sparsity pattern of A changes (springs added or torn)."""
        return sum(getattr(term, "topology_version", 0) for term in self.terms if term.couples_particles)

    @property
    def system_matrix_triplet_capacity(self) -> int:
        """Most entries :meth:`assemble_system_matrix` adds: the 6 lower-triangle entries of each
        particle's diagonal block and 9 per coupling block below the diagonal (half of the
        coupling blocks)."""
        couplings = sum(term.coupling_block_capacity for term in self.terms if term.couples_particles)
        return 6 * self.particle_count + 9 * ((couplings + 1) // 2)

    @ti.func
    def prepare_jacobian(self, y, a, b, t):
        """Every term's whole-system Jacobian pass at ``y``, ``a``, ``b`` (terms with
        ``precomputes_jacobian``: a membrane's per-triangle blocks). Call at the top level of
        every kernel that reads Jacobians (products, blocks, cached rows, the assembly), before
        the loop that reads them; nothing for a system of springs alone."""
        for term in ti.static(self.terms):
            if ti.static(getattr(term, "precomputes_jacobian", False)):
                term.precompute_jacobian(y, a, b)

    @ti.func
    def force_jacobian_product(self, i, y, p, a, b, t):
        """a (df/dv p)_i + b (df/dx p)_i (N) at state ``y`` and time ``t`` (s); zero for a pinned
        particle. ``p``: (n,) vec3 field, zero on pinned particles."""
        out = ti.Vector.zero(y.x.dtype, 3)
        if self.free[i]:
            for term in ti.static(self.terms):
                out += term.jacobian_product(i, y, p, a, b, t)
        return out

    @ti.func
    def system_matrix_row(self, i, y, p, a, b, t):
        """(A p)_i (N s for a = tau s, b = tau**2 s**2, p in m/s); zero for a pinned particle.
        ``p``: (n,) vec3 field, zero on pinned particles."""
        out = ti.Vector.zero(y.x.dtype, 3)
        if self.free[i]:
            out = self.mass[i] * p[i] - self.force_jacobian_product(i, y, p, a, b, t)
        return out

    @ti.func
    def system_matrix_diagonal_block(self, i, y, a, b, t):
        """A_ii (3x3): m_i I - a df_i/dv_i - b df_i/dx_i, or the identity for a pinned particle."""
        block = ti.Matrix.identity(y.x.dtype, 3)
        if self.free[i]:
            block *= self.mass[i]
            for term in ti.static(self.terms):
                block -= term.jacobian_diagonal_block(i, y, a, b, t)
        return block

    # The cached form of A, for solvers that apply it many times at one state (Krylov
    # iterations): fill once per Newton iteration with :meth:`cache_system_matrix_row`, which
    # returns A_ii and stores each coupling term's off-diagonal blocks of row i (see
    # :meth:`taichi_sim.forces.Springs.bind_jacobian_cache`); then
    # (A p)_i = A_ii p_i + sum_j A_ij p_j by :meth:`cached_system_matrix_row`, a pure gather.
    # A term that does not couple particles has a block-diagonal Jacobian, entirely in A_ii.

    def bind_jacobian_cache(self) -> None:
        """Allocate the caches of the terms that have one (once; an integrator calls it when
        bound)."""
        for term in self.terms:
            if getattr(term, "caches_jacobian", False):
                term.bind_jacobian_cache()

    @ti.func
    def cache_system_matrix_row(self, i, y, a, b, t):
        """A_ii (3x3) at state ``y``, as :meth:`system_matrix_diagonal_block`, while storing the
        off-diagonal blocks of row i for :meth:`cached_system_matrix_row` (nothing is stored
        for a pinned particle: its row is the identity's)."""
        block = ti.Matrix.identity(y.x.dtype, 3)
        if self.free[i]:
            block *= self.mass[i]
            for term in ti.static(self.terms):
                if ti.static(getattr(term, "caches_jacobian", False)):
                    block -= term.cache_jacobian_row(i, y, a, b, t, self.free)
                else:
                    block -= term.jacobian_diagonal_block(i, y, a, b, t)
        return block

    @ti.func
    def cached_system_matrix_row(self, i, y, p, a, b, t, diagonal):
        """(A p)_i from ``diagonal`` = A_ii and the blocks stored by :meth:`cache_system_matrix_row`
        at the same ``y``, ``a``, ``b``, ``t`` (a coupling term without a cache is evaluated at
        ``y``); zero for a pinned particle. ``p``: (n,) vec3 field, zero on pinned particles."""
        out = ti.Vector.zero(y.x.dtype, 3)
        if self.free[i]:
            out = diagonal @ p[i]
            for term in ti.static(self.terms):
                if ti.static(getattr(term, "caches_jacobian", False)):
                    out += term.cached_coupling_product(i, p, 0)
                elif ti.static(term.couples_particles):
                    out -= (term.jacobian_product(i, y, p, a, b, t)
                            - term.jacobian_diagonal_block(i, y, a, b, t) @ p[i])
        return out

    @property
    def caches_all_couplings(self) -> bool:
        """Whether every term that couples particles caches its blocks, so that
        :meth:`cached_triangle_product` is available (Gauss-Seidel-type sweeps need it)."""
        return all(getattr(term, "caches_jacobian", False) for term in self.terms if term.couples_particles)

    @ti.func
    def cached_triangle_product(self, i, p, side: ti.template()):
        """sum of A_ij p_j over j < i (``side`` -1) or j > i (+1), from the blocks
        :meth:`cache_system_matrix_row` stored; zero for a pinned particle. Only when
        :attr:`caches_all_couplings`."""
        out = ti.Vector.zero(p.dtype, 3)
        if self.free[i]:
            for term in ti.static(self.terms):
                if ti.static(getattr(term, "caches_jacobian", False)):
                    out += term.cached_coupling_product(i, p, side)
        return out

    @ti.func
    def force_and_scale(self, i, y, t):
        """(net force on particle i (N, 3-vector), the sum of the magnitudes of the pieces it
        adds up (N), the scale of its rounding error (N): times eps, the floor a residual of
        this force cannot go below). All zero when pinned. The second is what convergence
        tests measure the residual against; the third is larger where a term loses digits
        (stiff springs near rest length: see ``Springs.force_magnitudes``)."""
        f = ti.Vector.zero(y.x.dtype, 3)
        scale = ti.cast(0.0, y.x.dtype)
        rounding = ti.cast(0.0, y.x.dtype)
        if self.free[i]:
            m = self.mass[i]
            for term in ti.static(self.terms):
                piece = term.force(i, y, m, t)
                f += piece
                if ti.static(hasattr(term, "force_magnitudes")):
                    magnitude, error_scale = term.force_magnitudes(i, y, m, t)
                    scale += magnitude
                    rounding += error_scale
                else:
                    scale += piece.norm()
                    rounding += piece.norm()
        return f, scale, rounding

    @ti.func
    def evaluate_at(self, i, y, t):
        """At particle i of ``y``: (net force (N, zero when pinned), :meth:`force_and_scale`'s two
        scales (N), the potential energy and the dissipation attributed to i (J, W; see
        :meth:`potential_and_dissipation_at`)), each term evaluated once (a term with
        ``force_pieces`` gives all of its parts in one pass)."""
        f = ti.Vector.zero(y.x.dtype, 3)
        scale = ti.cast(0.0, y.x.dtype)
        rounding = ti.cast(0.0, y.x.dtype)
        potential = ti.cast(0.0, y.x.dtype)
        dissipation = ti.cast(0.0, y.x.dtype)
        free_i = self.free[i]
        m = self.mass[i]
        for term in ti.static(self.terms):
            if ti.static(hasattr(term, "force_pieces")):
                piece, magnitude, error, u, r = term.force_pieces(i, y, m, t)
                potential += u
                dissipation += r
                if free_i:
                    f += piece
                    scale += piece.norm()
                    rounding += error
            else:
                if free_i:
                    piece = term.force(i, y, m, t)
                    f += piece
                    scale += piece.norm()
                    rounding += piece.norm()
                if ti.static(hasattr(term, "energy_at")):
                    potential += term.energy_at(i, y, free_i)
                if ti.static(hasattr(term, "dissipation_at")):
                    dissipation += term.dissipation_at(i, y, free_i)
        return f, scale, rounding, potential, dissipation

    @ti.func
    def potential_and_dissipation_at(self, i, y, skip: ti.template() = ()):
        """(the potential energy (J) and the Rayleigh dissipation (W) every term attributes to
        particle i at ``y``): summed over all particles, :meth:`potential_energy` and
        :meth:`dissipation`, in one gather. The terms named in ``skip`` (a tuple of names) are
        left out, for a caller that sums them element by element."""
        potential = ti.cast(0.0, y.x.dtype)
        dissipation = ti.cast(0.0, y.x.dtype)
        free_i = self.free[i]
        for term in ti.static(self.terms):
            if ti.static(term.name not in skip):
                if ti.static(hasattr(term, "energy_at")):
                    potential += term.energy_at(i, y, free_i)
                if ti.static(hasattr(term, "dissipation_at")):
                    dissipation += term.dissipation_at(i, y, free_i)
        return potential, dissipation

    def assemble_system_matrix(self, y: State, a: float, b: float, t: float,
                               builder: ti.linalg.SparseMatrixBuilder) -> None:
        """Add the lower triangle of A (3n x 3n, row and column 3i + k for component k of
        particle i; the entries with row >= column) at state ``y`` and time ``t`` into
        ``builder`` (capacity :attr:`system_matrix_triplet_capacity`).

        A is symmetric and the sparse Cholesky factorisation reads only its lower triangle, so
        the upper one is not assembled: half the triplets to add and to sort in
        ``builder.build()``. The entries added depend only on the pinned set and
        :attr:`jacobian_pattern_version`, never on the state (zeros are added as entries), so a
        factorisation's symbolic analysis stays valid until the version changes."""
        self._assemble_system_matrix(y, a, b, t, builder)

    @ti.kernel
    def _assemble_system_matrix(self, y: ti.template(), a: float, b: float, t: float,
                                builder: ti.types.sparse_matrix_builder()):
        self.prepare_jacobian(y, a, b, t)
        for i in range(self.particle_count):
            block = self.system_matrix_diagonal_block(i, y, a, b, t)
            for r, c in ti.static(ti.ndrange(3, 3)):
                if ti.static(r >= c):
                    builder[3 * i + r, 3 * i + c] += block[r, c]
            if self.free[i]:
                for term in ti.static(self.terms):
                    if ti.static(term.couples_particles):
                        term.add_coupling_blocks(i, y, a, b, t, -1.0, self.free, builder)
