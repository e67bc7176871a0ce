"""Particle systems: Newton's second law for particles under composable force terms."""

import numpy as np
import taichi as ti

from .. import runtime
from ..forces.base import ForceTerm
from ..state import State, finite
from .base import Health, System


def _given(hook) -> bool:
    # "is not" is not allowed inside a kernel, even under ti.static
    return hook is not None


@ti.data_oriented
class ParticleSystem(System):
    """dx/dt = v, dv/dt = F(x, v, t) / m, with F the sum of the force terms.

    Pinned particles have zero derivative (they neither move nor accelerate), whatever their
    forces.

    Args:
        mass: (n,) particle masses in kg, all > 0.
        pinned: (n,) bool.
        active: (n,) bool, default all: an inactive particle (a dead sprinkler slot) is frozen
            like a pinned one until an event activates it (``free`` field).
        terms: force terms (see :class:`taichi_sim.forces.ForceTerm`); more may be added with
            :meth:`add_term` before the first evaluation (one kernel sums them, compiled then).
    """

    second_order = True

    def __init__(self, mass: np.ndarray, pinned: np.ndarray, terms: list[ForceTerm] = (),
                 active: np.ndarray | None = None):
        mass = np.asarray(mass, dtype=float).reshape(-1)
        pinned = np.asarray(pinned, dtype=bool).reshape(-1)
        if len(mass) != len(pinned):
            raise ValueError("mass and pinned must have the same length")
        if not np.all(mass > 0):
            raise ValueError("mass must be > 0 for every particle")
        self.particle_count = n = len(mass)
        self.mass_np = mass
        self.pinned_np = pinned
        self.terms = list(terms)
        self._launchers: dict[tuple, object] = {}
        self.mass = ti.field(runtime.real(), shape=n)
        self.free = ti.field(ti.i32, shape=n)
        moving = ~pinned if active is None else (~pinned & np.asarray(active, bool).reshape(n))
        self._upload(mass.astype(runtime.np_real()), moving.astype(np.int32))

    @ti.kernel
    def _upload(self, mass: ti.types.ndarray(ndim=1), free: ti.types.ndarray(dtype=ti.i32, ndim=1)):
        for i in range(self.particle_count):
            self.mass[i] = mass[i]
            self.free[i] = free[i]

    def add_term(self, term: ForceTerm) -> None:
        """Add a force term; only before the first eval_f (its kernel is compiled then)."""
        self.terms.append(term)

    def term(self, name: str) -> ForceTerm | None:
        """The force term called ``name`` (``"gravity"``, ``"drag"``, ``"springs"``), if any."""
        return next((t for t in self.terms if t.name == name), None)

    def eval_f(self, y: State, t: float, out: State) -> None:
        self._launcher(("eval_f", y, out), lambda: self._bind_eval_f(y, out))(t)

    def _launcher(self, key: tuple, bind):
        """The kernel bound to the objects in ``key`` (made by ``bind()`` the first time).

        The hot kernels (a force evaluation, a fused step) are closures over the states they
        work on, taking only floats: a method kernel with template arguments costs about
        100 us of Python per call on the development machine, a closure about 50, which is a
        fifth of a symplectic Euler step at 64 x 64. Each binding compiles once; the closure
        keeps its objects alive, so their ids stay theirs."""
        ids = tuple(id(k) if not isinstance(k, str) else k for k in key)
        launch = self._launchers.get(ids)
        if launch is None:
            launch = self._launchers[ids] = bind()
        return launch

    def _bind_eval_f(self, y, out):
        system = self

        @ti.kernel
        def eval_f(t: float):
            system._eval_f_body(y, out, t)

        return eval_f

    @ti.func
    def _precompute(self, y):
        """Every term's whole-system pass (see :attr:`ForceTerm.precomputes`); call at the top
        level of a kernel, before the loop that sums the forces at the same ``y``."""
        for term in ti.static(self.terms):
            if ti.static(term.precomputes):
                term.precompute(y)

    @ti.func
    def _summed_force(self, i, y, mass_i, t):
        """The net force on i (N), in a kernel that ran :meth:`_precompute` at ``y`` first."""
        f = ti.Vector.zero(y.x.dtype, 3)
        for term in ti.static(self.terms):
            if ti.static(term.precomputes):
                f += term.precomputed_force(i, y, mass_i, t)
            else:
                f += term.force(i, y, mass_i, t)
        return f

    @ti.func
    def _derivative(self, i, y, out, t):
        """out's entry i: (v_i, F_i / m_i), zero when i is pinned (after :meth:`_precompute`)."""
        if self.free[i]:
            m = self.mass[i]
            out.x[i] = y.v[i]
            out.v[i] = self._summed_force(i, y, m, t) / m
        else:
            out.x[i] = ti.Vector.zero(y.x.dtype, 3)
            out.v[i] = ti.Vector.zero(y.x.dtype, 3)

    @ti.func
    def _eval_f_body(self, y, out, t):
        self._precompute(y)
        for i in y.x:
            self._derivative(i, y, out, t)

    def eval_f_staged(self, y: State, t: float, out: State, h: float, after=None) -> None:
        """:meth:`eval_f` with a Runge-Kutta stage's bookkeeping in the same kernel launch.

        ``after`` (or None): an object with ``@ti.func apply(i, h)``, run for each particle
        right after its derivative is written into ``out`` (the next stage's input
        y0 + h sum_j a_j k_j, or the final update). It may read particle i of any state and
        must not write ``y``, or anything a term reads, since other particles may still be
        reading it, unless every term reads only particle i after its precompute
        (:meth:`sums_locally`). One launch instead of two saves the Python-side cost that
        each kernel call has on a CPU."""
        self._launcher(("staged", y, out, after), lambda: self._bind_staged(y, out, after))(t, h)

    def _bind_staged(self, y, out, after):
        system = self

        @ti.kernel
        def eval_f_staged(t: float, h: float):
            system._eval_f_staged_body(y, out, t, h, after)

        return eval_f_staged

    @ti.func
    def _eval_f_staged_body(self, y, out, t, h, after: ti.template()):
        self._precompute(y)
        for i in y.x:
            self._derivative(i, y, out, t)
            if ti.static(_given(after)):
                after.apply(i, h)

    def sums_locally(self) -> bool:
        """Whether, after the precompute, particle i's force reads no other particle's state,
        so a kernel may move each particle as soon as its force is summed."""
        return all(term.precomputes or not term.reads_other_particles for term in self.terms)

    def symplectic_euler_step(self, y: State, t: float, h: float, scratch: State) -> None:
        """One symplectic Euler step of ``y`` in place (v += h F/m, then x += h v), in one
        kernel launch and without reading anything back: the same arithmetic as
        :meth:`eval_f` followed by the update (the same result up to how the compiler fuses
        multiply-adds).
        ``scratch``'s ``v`` holds the accelerations when a term reads other particles after
        its precompute (wind), so that no particle moves before every force is summed."""
        self._launcher(("symplectic", y, scratch), lambda: self._bind_symplectic(y, scratch))(t, h)

    def _bind_symplectic(self, y, scratch):
        system = self

        @ti.kernel
        def symplectic_euler(t: float, h: float):
            system._symplectic_body(y, scratch, t, h)

        return symplectic_euler

    @ti.func
    def _symplectic_body(self, y, scratch, t, h):
        self._precompute(y)
        if ti.static(self.sums_locally()):
            for i in y.x:
                v = y.v[i]
                if self.free[i]:
                    v += h * (self._summed_force(i, y, self.mass[i], t) / self.mass[i])
                    y.v[i] = v
                y.x[i] += h * v
        else:
            for i in y.x:
                if self.free[i]:
                    scratch.v[i] = self._summed_force(i, y, self.mass[i], t) / self.mass[i]
            for i in y.x:
                v = y.v[i]
                if self.free[i]:
                    v += h * scratch.v[i]
                    y.v[i] = v
                y.x[i] += h * v

    def forces(self, y: State, out: ti.Field, t: float = 0.0) -> None:
        """Net force (N) on every particle at ``y`` and time ``t`` (s) into a (n,) vec3 field;
        zero when pinned."""
        self._forces(y, out, t)

    @ti.kernel
    def _forces(self, y: ti.template(), out: ti.template(), t: float):
        self._precompute(y)
        for i in y.x:
            f = ti.Vector.zero(y.x.dtype, 3)
            if self.free[i]:
                f = self._summed_force(i, y, self.mass[i], t)
            out[i] = f

    def kinetic_energy(self, y: State) -> float:
        return float(self._kinetic(y))

    @ti.kernel
    def _kinetic(self, y: ti.template()) -> float:
        total = 0.0
        for i in y.v:
            total += 0.5 * self.mass[i] * y.v[i].norm_sqr()
        return total

    def energy(self, y: State) -> float:
        """Kinetic plus the potential energy of every conservative term (J)."""
        total = self.kinetic_energy(y)
        for term in self.terms:
            e = term.energy(y)
            if e is not None:
                total += e
        return total

    def health(self, y: State, center) -> Health:
        """:class:`Health` of ``y`` in one kernel: a gather over the particles of the non-finite
        count, the farthest distance from ``center``, the kinetic energy, the potential energy
        each term attributes to each particle (the springs' and gravity's also apart), and the
        springs' largest strain."""
        nonfinite, farthest2, kinetic, potential, spring_energy, gravity_energy, strain = self._health(
            y, float(center[0]), float(center[1]), float(center[2]))
        return Health(nonfinite=int(nonfinite), farthest=float(farthest2) ** 0.5,
                      energy=float(kinetic) + float(potential), kinetic=float(kinetic),
                      spring_energy=float(spring_energy), gravity_energy=float(gravity_energy),
                      max_strain=float(strain))

    @ti.kernel
    def _health(self, y: ti.template(), cx: float, cy: float, cz: float) -> (
            ti.i32, float, float, float, float, float, float):
        bad = 0
        farthest2 = 0.0
        kinetic = 0.0
        potential = 0.0
        spring_energy = 0.0
        gravity_energy = 0.0
        worst = 0.0
        c = ti.Vector([cx, cy, cz])
        for i in y.x:
            if finite(y.x[i]) and finite(y.v[i]):
                ti.atomic_max(farthest2, (y.x[i] - c).norm_sqr())
                kinetic += 0.5 * self.mass[i] * y.v[i].norm_sqr()
                free_i = self.free[i]
                for term in ti.static(self.terms):
                    if ti.static(hasattr(term, "energy_at")):
                        u = term.energy_at(i, y, free_i)
                        potential += u
                        if ti.static(hasattr(term, "strain_at")):
                            spring_energy += u
                            ti.atomic_max(worst, term.strain_at(i, y))
                        if ti.static(term.name == "gravity"):
                            gravity_energy += u
            else:
                bad += 1
        return bad, farthest2, kinetic, potential, spring_energy, gravity_energy, worst

    def potential_energy(self, y: State) -> float:
        """Potential energy (J) of every conservative term at ``y``."""
        return float(sum(e for e in (term.energy(y) for term in self.terms) if e is not None))

    def dissipation(self, y: State) -> float:
        """Rayleigh dissipation function (W) of every dissipative term at ``y`` (see
        :meth:`ForceTerm.dissipation`)."""
        return float(sum(r for r in (term.dissipation(y) for term in self.terms) if r is not None))

    # The force-Jacobian API of the implicit integrators. A is the matrix of an implicit step,
    # A = M - a df/dv - b df/dx (a = tau, b = tau**2 for a step of size tau), restricted to the
    # free particles: a pinned particle's row and column are those of the identity, so it is
    # filtered out of the solve exactly (no penalty) and its unknown comes out exactly zero.

    @property
    def supports_jacobian(self) -> bool:
        """Whether every force term provides its Jacobians (:attr:`ForceTerm.has_jacobian`)."""
        return all(term.has_jacobian for term in self.terms)

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
                    scale += magnitude
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
    def potential_and_dissipation_at(self, i, y):
        """(the potential energy (J) and the Rayleigh dissipation (W) every term attributes to
        particle i at ``y``): summed over all particles, :meth:`potential_energy` and
        :meth:`dissipation`, in one gather."""
        potential = ti.cast(0.0, y.x.dtype)
        dissipation = ti.cast(0.0, y.x.dtype)
        free_i = self.free[i]
        for term in ti.static(self.terms):
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
        for i in range(self.particle_count):
            block = self.system_matrix_diagonal_block(i, y, a, b, t)
            for r, c in ti.static(ti.ndrange(3, 3)):
                if ti.static(r >= c):
                    builder[3 * i + r, 3 * i + c] += block[r, c]
            if self.free[i]:
                for term in ti.static(self.terms):
                    if ti.static(term.couples_particles):
                        term.add_coupling_blocks(i, y, a, b, t, -1.0, self.free, builder)
