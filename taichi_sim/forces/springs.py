
import numpy as np
import taichi as ti

from .. import runtime
from .base import ForceTerm

SPRING_KINDS = ("structural", "shear", "flex")


def incidence_of(particle_count: int, elements: np.ndarray):
    """CSR incidence of elements (springs (S, 2), triangles (T, 3)) on particles.

    Returns (offsets (n+1,), element_ids, slots): particle i belongs to the elements
    ``element_ids[offsets[i]:offsets[i+1]]``, as vertex ``slots[...]`` of each.
    """
    count, arity = elements.shape
    owner = elements.T.ravel()
    element = np.tile(np.arange(count), arity)
    slot = np.repeat(np.arange(arity), count)
    order = np.argsort(owner, kind="stable")
    offsets = np.zeros(particle_count + 1, dtype=np.int32)
    np.cumsum(np.bincount(owner, minlength=particle_count), out=offsets[1:])
    return offsets, element[order].astype(np.int32), slot[order].astype(np.int32)


def incidence(particle_count: int, ends: np.ndarray):
    """CSR incidence of springs on particles.

    Returns (offsets (n+1,), spring_ids (2S,), others (2S,)): particle i's springs are
    ``spring_ids[offsets[i]:offsets[i+1]]``, joining it to ``others[...]``.
    """
    offsets, sid, slot = incidence_of(particle_count, ends)
    return offsets, sid, ends[sid, 1 - slot].astype(np.int32)


@ti.data_oriented
class Springs(ForceTerm):
    """Hookean springs with optional dashpots, evaluated as a per-particle gather.

    Spring s joins particles (i, j) = ends[s] with stiffness k (N/m), rest length r (m) and
    dashpot coefficient c (N s/m). With d = x_i - x_j and u = d/|d|, the force on i is
    ``-k (|d| - r) u - c ((v_i - v_j) . u) u`` and the opposite on j. A spring of zero length
    exerts no force (its direction is undefined).

    Each particle sums the springs it touches (CSR incidence), so the result is independent of
    thread scheduling (no float atomics) and bit-reproducible; every spring is evaluated twice,
    once from each end, which on a CPU costs less than atomic scatter.

    Args:
        particle_count: n.
        ends: (S, 2) int particle indices.
        rest_length, stiffness, damping: (S,) floats.
        kind: (S,) int, 0 structural, 1 shear, 2 flex (metadata for cloth; any value allowed).
        tear_strain: None (springs never break), or (S,) strain thresholds: after each accepted
            step, :meth:`tear` breaks every live spring whose strain |d|/r - 1 exceeds its
            threshold (``inf`` = unbreakable). Broken springs exert no force, for good.
    """

    name = "springs"
    has_jacobian = True
    couples_particles = True
    caches_jacobian = True
    """Provides the cached-Jacobian API of the implicit integrators: :meth:`bind_jacobian_cache`,
    :meth:`cache_jacobian_row` and :meth:`cached_coupling_product` (see the first)."""

    def __init__(self, particle_count, ends, rest_length, stiffness, damping, kind, tear_strain=None):
        ends = np.asarray(ends, dtype=np.int32).reshape(-1, 2)
        self.spring_count = S = len(ends)
        if S == 0:
            raise ValueError("Springs needs at least one spring (a scene without springs adds no term)")
        self.ends_np = ends
        self.kind_np = np.asarray(kind, dtype=np.int8).reshape(S)
        self.damped = bool(np.any(np.asarray(damping) != 0))
        real = runtime.real()
        self.ends = ti.Vector.field(2, ti.i32, shape=S)
        self.rest = ti.field(real, shape=S)
        self.stiffness = ti.field(real, shape=S)
        self.damping = ti.field(real, shape=S)
        offsets, sid, other = incidence(particle_count, ends)
        self.offsets = ti.field(ti.i32, shape=particle_count + 1)
        self.incident = ti.field(ti.i32, shape=2 * S)
        self.other = ti.field(ti.i32, shape=2 * S)
        self.tearable = tear_strain is not None
        # Bumped whenever the set of live springs changes (a direct solver re-analyses then).
        self.topology_version = 0
        # Bumped by set_parameters (a solver that factorised a matrix of the stiffnesses refreshes it).
        self.parameters_version = 0
        if self.tearable:
            self.alive = ti.field(ti.i32, shape=S)
            self.tear_strain = ti.field(real, shape=S)
        self.entry_block = None  # the Jacobian cache, allocated by bind_jacobian_cache
        # One upload kernel per term: Field.from_numpy would compile a kernel for every field.
        self._upload_topology(ends, offsets, sid, other)
        self._upload_columns(rest_length, stiffness, damping, tear_strain)

    @ti.kernel
    def _upload_topology(self, ends: ti.types.ndarray(dtype=ti.i32, ndim=2),
                         offsets: ti.types.ndarray(dtype=ti.i32, ndim=1),
                         incident: ti.types.ndarray(dtype=ti.i32, ndim=1),
                         other: ti.types.ndarray(dtype=ti.i32, ndim=1)):
        for s in range(self.spring_count):
            self.ends[s] = ti.Vector([ends[s, 0], ends[s, 1]])
            if ti.static(self.tearable):
                self.alive[s] = 1
        for i in range(offsets.shape[0]):
            self.offsets[i] = offsets[i]
        for e in range(incident.shape[0]):
            self.incident[e] = incident[e]
            self.other[e] = other[e]

    @ti.kernel
    def _upload_parameters(self, rest: ti.types.ndarray(), stiffness: ti.types.ndarray(),
                           damping: ti.types.ndarray(), tear_strain: ti.types.ndarray()):
        for s in range(self.spring_count):
            self.rest[s] = rest[s]
            self.stiffness[s] = stiffness[s]
            self.damping[s] = damping[s]
            if ti.static(self.tearable):
                self.tear_strain[s] = tear_strain[s]

    def set_parameters(self, *, rest_length=None, stiffness=None, damping=None, tear_strain=None) -> None:
        """Replace per-spring values (arrays of shape (S,) or scalars; None keeps the current
        ones). Dashpots must have been present at construction for a nonzero ``damping`` to
        take effect, and tearing for ``tear_strain``."""
        current = self.arrays()
        self._upload_columns(current["rest_length"] if rest_length is None else rest_length,
                             current["stiffness"] if stiffness is None else stiffness,
                             current["spring_damping"] if damping is None else damping,
                             current.get("tear_strain", 0.0) if tear_strain is None else tear_strain)
        self.parameters_version += 1

    def _upload_columns(self, rest_length, stiffness, damping, tear_strain) -> None:
        npr = runtime.np_real()

        def column(value):
            return np.ascontiguousarray(np.broadcast_to(np.asarray(value, npr), (self.spring_count,)))

        self._upload_parameters(column(rest_length), column(stiffness), column(damping),
                                column(0.0 if tear_strain is None else tear_strain))

    @property
    def variational(self) -> bool:
        """Springs are the gradient of their energy; dashpots are not quite (their direction u
        depends on positions): see :attr:`ForceTerm.variational`."""
        return not self.damped

    def arrays(self) -> dict:
        """Spring data as numpy arrays (the npz schema's spring keys)."""
        tearing = {"alive": self.alive.to_numpy().astype(bool),
                   "tear_strain": self.tear_strain.to_numpy().astype(np.float64)} if self.tearable else {}
        return tearing | {
            "springs": self.ends_np.astype(np.int64),
            "rest_length": self.rest.to_numpy().astype(np.float64),
            "stiffness": self.stiffness.to_numpy().astype(np.float64),
            "spring_damping": self.damping.to_numpy().astype(np.float64),
            "spring_kind": self.kind_np.astype(np.int64),
        }

    @ti.func
    def is_alive(self, s):
        alive = True
        if ti.static(self.tearable):
            alive = self.alive[s] != 0
        return alive

    @ti.func
    def force(self, i, y, mass_i, t):
        f = ti.Vector.zero(y.x.dtype, 3)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            s = self.incident[e]
            if not self.is_alive(s):
                continue
            j = self.other[e]
            d = y.x[i] - y.x[j]
            length = d.norm()
            if length > 0.0:
                u = d / length
                f -= self.stiffness[s] * (length - self.rest[s]) * u
                if ti.static(self.damped):
                    f -= self.damping[s] * (y.v[i] - y.v[j]).dot(u) * u
        return f

    @ti.func
    def force_pieces(self, i, y, mass_i, t):
        """Everything an implicit Newton iteration evaluates at particle i, in one pass over its
        springs: (force (N), :meth:`force_magnitudes`' two values (N), :meth:`energy_at` (J),
        :meth:`dissipation_at` (W))."""
        f = ti.Vector.zero(y.x.dtype, 3)
        total = ti.cast(0.0, y.x.dtype)
        rounding2 = ti.cast(0.0, y.x.dtype)
        energy = ti.cast(0.0, y.x.dtype)
        dissipation = ti.cast(0.0, y.x.dtype)
        norm_i = y.x[i].norm()
        for e in range(self.offsets[i], self.offsets[i + 1]):
            s = self.incident[e]
            if self.is_alive(s):
                j = self.other[e]
                d = y.x[i] - y.x[j]
                length = d.norm()
                k = self.stiffness[s]
                stretch = length - self.rest[s]
                energy += 0.25 * k * stretch * stretch
                if length > 0.0:
                    u = d / length
                    f -= k * stretch * u
                    total += k * ti.abs(stretch)
                    error = k * (norm_i + y.x[j].norm())
                    if ti.static(self.damped):
                        rate = (y.v[i] - y.v[j]).dot(u)
                        c = self.damping[s]
                        f -= c * rate * u
                        total += c * ti.abs(rate)
                        error += c * ti.abs(rate)
                        dissipation += 0.25 * c * rate * rate
                    rounding2 += error * error
        return f, total, ti.sqrt(rounding2), energy, dissipation

    @ti.func
    def energy_at(self, i, y, free_i):
        """Half the energy of each of i's live springs (J): every spring counted once over its
        two ends."""
        total = ti.cast(0.0, y.x.dtype)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            s = self.incident[e]
            if self.is_alive(s):
                stretch = (y.x[i] - y.x[self.other[e]]).norm() - self.rest[s]
                total += 0.25 * self.stiffness[s] * stretch * stretch
        return total

    @ti.func
    def strain_at(self, i, y):
        """The largest strain |d|/r - 1 of i's live springs with k > 0 and r > 0 (0 if none)."""
        worst = ti.cast(0.0, y.x.dtype)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            s = self.incident[e]
            if self.is_alive(s) and self.stiffness[s] > 0.0 and self.rest[s] > 0.0:
                strain = (y.x[i] - y.x[self.other[e]]).norm() / self.rest[s] - 1.0
                worst = ti.max(worst, strain)
        return worst

    @ti.func
    def dissipation_at(self, i, y, free_i):
        """Half the Rayleigh dissipation of each of i's live dashpots (W)."""
        total = ti.cast(0.0, y.x.dtype)
        if ti.static(self.damped):
            for e in range(self.offsets[i], self.offsets[i + 1]):
                s = self.incident[e]
                if self.is_alive(s):
                    j = self.other[e]
                    d = y.x[i] - y.x[j]
                    length = d.norm()
                    if length > 0.0:
                        rate = (y.v[i] - y.v[j]).dot(d / length)
                        total += 0.25 * self.damping[s] * rate * rate
        return total

    @ti.func
    def force_magnitudes(self, i, y, mass_i, t):
        """(sum over i's live springs of the magnitude of each one's force on i (N), the scale
        of the rounding error of that force (N)).

        The net force is a sum of these pieces, so its rounding error is relative to this sum,
        not to the net force (which is ~0 at equilibrium): convergence tests scale by it. A
        spring's force k (|d| - r) carries more than that: d = x_i - x_j is a difference of
        coordinates rounded relative to |x_i| and |x_j|, so its error is about k (|x_i| + |x_j|)
        rounding units, which for stiff springs near rest length exceeds the force itself. The
        second value is the root sum of squares of those errors over i's springs (independent
        roundings): times eps, about the floor a residual of this force cannot go below."""
        total = ti.cast(0.0, y.x.dtype)
        rounding2 = ti.cast(0.0, y.x.dtype)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            s = self.incident[e]
            if self.is_alive(s):
                j = self.other[e]
                d = y.x[i] - y.x[j]
                length = d.norm()
                if length > 0.0:
                    total += self.stiffness[s] * ti.abs(length - self.rest[s])
                    error = self.stiffness[s] * (y.x[i].norm() + y.x[j].norm())
                    if ti.static(self.damped):
                        damper = self.damping[s] * ti.abs((y.v[i] - y.v[j]).dot(d / length))
                        total += damper
                        error += damper
                    rounding2 += error * error
        return total, ti.sqrt(rounding2)

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

    def energy(self, y) -> float:
        return float(self._energy(y))

    @ti.kernel
    def _energy(self, y: ti.template()) -> float:
        total = 0.0
        for s in range(self.spring_count):
            if self.is_alive(s):
                e = self.ends[s]
                stretch = (y.x[e[0]] - y.x[e[1]]).norm() - self.rest[s]
                total += 0.5 * self.stiffness[s] * stretch * stretch
        return total

    def dissipation(self, y) -> float | None:
        """R = 1/2 sum over live dashpots of c ((v_i - v_j) . u)^2 (W), or None without dashpots."""
        return float(self._dissipation(y)) if self.damped else None

    @ti.kernel
    def _dissipation(self, y: ti.template()) -> float:
        total = 0.0
        for s in range(self.spring_count):
            if self.is_alive(s):
                e = self.ends[s]
                d = y.x[e[0]] - y.x[e[1]]
                length = d.norm()
                if length > 0.0:
                    rate = (y.v[e[0]] - y.v[e[1]]).dot(d / length)
                    total += 0.5 * self.damping[s] * rate * rate
        return total

    def tear(self, y) -> int:
        """Break every live spring strained beyond its threshold at ``y``; returns how many broke."""
        torn = int(self._tear(y)) if self.tearable else 0
        if torn:
            self.topology_version += 1
        return torn

    @ti.kernel
    def _tear(self, y: ti.template()) -> ti.i32:
        torn = 0
        for s in range(self.spring_count):
            if self.alive[s]:
                e = self.ends[s]
                strain = (y.x[e[0]] - y.x[e[1]]).norm() / self.rest[s] - 1.0
                if strain > self.tear_strain[s]:
                    self.alive[s] = 0
                    torn += 1
        return torn

    def restore(self) -> None:
        """Mend every torn spring (a tearing scene back to how it was built)."""
        if self.tearable:
            self.alive.fill(1)
            self.topology_version += 1

    def alive_count(self) -> int:
        """Springs still intact."""
        return int(self.alive.to_numpy().sum()) if self.tearable else self.spring_count

