"""Force terms: composable pieces of a particle system's eval_f (docs/scenes.md, Force model)."""
import taichi as ti


class ForceTerm:
    """One additive force term.

    A term is ``@ti.data_oriented`` and provides a ``@ti.func force(self, i, y, mass_i, t)`` that
    returns the force (N, a 3-vector) on particle ``i`` of state ``y`` at time ``t`` (s). The particle system sums
    its terms inside ONE kernel, with ``ti.static`` iteration, so a term that a scene does not
    add costs nothing.
    """

    name = "force"

    has_jacobian = False
    """Whether the term provides the force Jacobians the implicit integrators use, as two
    ``@ti.func``: ``jacobian_product(i, y, p, a, b, t)``, the 3-vector
    a (df/dv p)_i + b (df/dx p)_i (N) for a (n,) vec3 field ``p`` that is zero on pinned
    particles, and ``jacobian_diagonal_block(i, y, a, b, t)``, the 3x3 matrix
    a df_i/dv_i + b df_i/dx_i. Both are evaluated at state ``y``; ``a`` and ``b`` are scalars
    (an implicit step of size tau uses a = tau, b = tau**2). A term that is not stiff may
    return zero (or approximate) Jacobians: a linearised implicit step then treats it
    explicitly, while Newton iterations still converge to the exact implicit solution, since
    their residual uses the true force."""

    couples_particles = False
    """Whether the force on one particle depends on others (springs). Such a term also provides
    ``@ti.func add_coupling_blocks(i, y, a, b, t, weight, free, builder)``: for every other free
    particle j < i it couples to (``free[j] != 0``; the lower triangle of the symmetric
    matrix, the one the sparse Cholesky factorisation reads), add ``weight`` times the 3x3 block
    a df_i/dv_j + b df_i/dx_j to rows 3i..3i+2, columns 3j..3j+2 of a
    ``ti.types.sparse_matrix_builder()``; ``coupling_block_capacity``, the most off-diagonal
    blocks of the matrix it fills over all particles, in both triangles (twice those it adds);
    and ``topology_version``, an int bumped whenever the set of blocks it adds changes (a
    direct solver re-analyses the sparsity pattern then)."""

    reads_other_particles = True
    """Whether ``force(i, ...)`` may read the state of particles other than i (springs, wind):
    a kernel that moves particles while it sums their forces must then gather every force
    first. True unless a term says otherwise (gravity, drag, the grab pull), so that a new
    term is safe by default."""

    def anchored_fields(self) -> tuple:
        """The fields the term's per-particle force (``force``, or ``precomputed_force`` for a
        term that precomputes) reads, for a serial loop to look their memory trees up once
        before it (:mod:`taichi_sim.loops`); a field left out only costs a re-read per
        particle. Default: none."""
        return ()

    serial_loops = False
    """Whether the term's whole-system pass (``precompute``) runs on one thread; set by the
    system the term belongs to (see :func:`taichi_sim.runtime.serial_loops`)."""

    serial_pass = False
    """Whether the term's whole-system pass runs on one thread on a CPU whatever the system
    chooses (a grid's springs, whose pass vectorises only there); the system then leaves the
    term's items out of its own choice."""

    precomputes = False
    """Whether the term can split its force into a pass over the whole system and a cheap sum
    per particle: ``@ti.func precompute(y)`` (a loop at the top level of the calling kernel that
    fills the term's own buffer, e.g. each spring's force once) and
    ``@ti.func precomputed_force(i, y, mass_i, t)`` (the force on i from that buffer, reading no
    other particle's state). Kernels that evaluate every particle's force
    (:meth:`~taichi_sim.systems.ParticleSystem.eval_f`, the fused symplectic Euler step) run the
    precompute first in the same kernel, so the buffer always belongs to the state at hand;
    ``force`` stays valid on its own for callers that evaluate single particles (the implicit
    methods)."""

    variational = True
    """Whether the term's force is minus the gradient of its potential :meth:`energy` in x plus
    minus the gradient of its :meth:`dissipation` in v, with a dissipation that does not depend
    on x. The implicit methods' incremental potential is exact (its gradient is their
    residual) only when every term is; wind (no potential) and spring dashpots (a dissipation
    whose direction depends on x) are not."""

    # Terms with potential energy or dissipation also attribute them to particles, as
    # ``@ti.func energy_at(i, y, free_i)`` and ``@ti.func dissipation_at(i, y, free_i)`` (J and
    # W; ``free_i`` nonzero when particle i moves): summed over all particles they give
    # :meth:`energy` and :meth:`dissipation`, so one gather kernel can evaluate everything a
    # Newton iteration's merit needs (see taichi_sim.integrators.implicit.velocity_stage).

    elastic_model = ""
    """The continuum model the term discretises ("stvk", "neohookean": a membrane;
    "bending"), "" for none. The positional methods, which know the springs as constraints
    and take every other force at the step's start, refuse a system with one
    (:attr:`~taichi_sim.integrators.Integrator.takes_elastic_models`)."""

    source = False
    """Whether the term can put energy into the system (wind): then a system's energy may rise
    under any integrator, and the implicit methods do not require it to fall."""

    def energy(self, y) -> float | None:
        """Potential energy (J) of this term at state ``y``, or None if the term is dissipative."""
        return None

    def dissipation(self, y) -> float | None:
        """Rayleigh dissipation function R (W) of this term at state ``y``, or None if the term
        dissipates nothing. R is quadratic in the velocities with -dR/dv_i the term's
        dissipative force on i (so the term dissipates power 2R)."""
        return None


class ZeroJacobian:
    """Mixin for a term whose Jacobians the implicit integrators may take as zero (a constant
    force, or a force that is not stiff and so is treated explicitly by a linearised step)."""

    has_jacobian = True

    @ti.func
    def jacobian_product(self, i, y, p, a, b, t):
        return ti.Vector.zero(y.x.dtype, 3)

    @ti.func
    def jacobian_diagonal_block(self, i, y, a, b, t):
        return ti.Matrix.zero(y.x.dtype, 3, 3)
