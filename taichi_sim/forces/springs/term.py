"""Hookean springs with dashpots over a spring list: the general path for any topology."""
import numpy as np
import taichi as ti

from ... import field_io, runtime
from ..base import ForceTerm
from .jacobian import SpringJacobians
from .topology import incidence

SPRING_KINDS = ("structural", "shear", "flex")


@ti.data_oriented
class Springs(SpringJacobians, ForceTerm):
    """Hookean springs with optional dashpots, evaluated as a per-particle gather.

    Spring s joins particles (i, j) = ends[s] with stiffness k (N/m), rest length r (m) and
    dashpot coefficient c (N s/m). With d = x_i - x_j and u = d/|d|, the force on i is
    ``-k (|d| - r) u - c ((v_i - v_j) . u) u`` and the opposite on j. A spring of zero length
    exerts no force (its direction is undefined).

    A whole-system force evaluation computes each spring's force once, in a spring-parallel
    loop, into ``spring_force`` (:meth:`precompute`); each particle then sums the entries of the
    springs it touches (CSR incidence, :meth:`precomputed_force`), so the result does not depend
    on thread scheduling (no float atomics) and is bit-reproducible. :meth:`force` evaluates one
    particle on its own (each of its springs from its end), for per-particle callers.

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
    reads_other_particles = True
    precomputes = True
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
        self._allocate_force_buffer()
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
        fields = (self.rest, self.stiffness, self.damping) + ((self.alive, self.tear_strain) if self.tearable else ())
        rest, stiffness, damping, *torn = field_io.read(*fields)  # one kernel, not one per field
        tearing = {"alive": torn[0].astype(bool), "tear_strain": torn[1].astype(np.float64)} if torn else {}
        return tearing | {
            "springs": self.ends_np.astype(np.int64),
            "rest_length": rest.astype(np.float64),
            "stiffness": stiffness.astype(np.float64),
            "spring_damping": damping.astype(np.float64),
            "spring_kind": self.kind_np.astype(np.int64),
        }

    @ti.func
    def is_alive(self, s):
        alive = True
        if ti.static(self.tearable):
            alive = self.alive[s] != 0
        return alive

    def _allocate_force_buffer(self) -> None:
        # The force of spring s on its first end, ends[s][0] (the second gets the opposite).
        self.spring_force = ti.Vector.field(3, runtime.real(), shape=self.spring_count)

    def anchored_fields(self) -> tuple:
        return (self.offsets, self.incident, self.ends, self.spring_force)

    @ti.func
    def pair_force(self, d, dv, k, rest, c):
        """Force (N) on end i of a spring (stiffness k, rest length r, dashpot c) with
        d = x_i - x_j and dv = v_i - v_j: -(k (1 - r/|d|) + c (dv . d)/|d|^2) d, the same force as
        :meth:`force` with one square root and one division; zero when |d| = 0. Exactly odd in
        (d, dv), so both ends get exactly opposite forces."""
        length2 = d.dot(d)
        # a select, not a branch, so that loops over springs vectorise; with d = 0 the force is
        # -k d = 0 whatever 1/|d| would have been
        inverse = ti.select(length2 > 0.0, 1.0 / ti.sqrt(length2), 0.0)
        scale = k * (1.0 - rest * inverse)
        if ti.static(self.damped):
            scale += c * dv.dot(d) * (inverse * inverse)
        return -scale * d

    @ti.func
    def precompute(self, y):
        """Each live spring's force on its first end at ``y`` into ``spring_force`` (a
        spring-parallel loop: see :attr:`ForceTerm.precomputes`)."""
        ti.loop_config(serialize=self.serial_loops)
        for s in range(self.spring_count):
            g = ti.Vector.zero(y.x.dtype, 3)
            if self.is_alive(s):
                e = self.ends[s]
                g = self.pair_force(y.x[e[0]] - y.x[e[1]], y.v[e[0]] - y.v[e[1]], self.stiffness[s],
                                    self.rest[s], self.damping[s])
            self.spring_force[s] = g

    @ti.func
    def precomputed_force(self, i, y, mass_i, t):
        """The springs' force on i from :meth:`precompute`'s buffer (N)."""
        f = ti.Vector.zero(y.x.dtype, 3)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            s = self.incident[e]
            if self.ends[s][0] == i:
                f += self.spring_force[s]
            else:
                f -= self.spring_force[s]
        return f

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
    def energy_and_strain_at(self, i, y):
        """(:meth:`energy_at`, the largest strain |d|/r - 1 of i's live springs with k > 0 and
        r > 0, or 0 if none) in one pass over i's springs: what the blow-up guard's check reads."""
        total = ti.cast(0.0, y.x.dtype)
        worst = ti.cast(0.0, y.x.dtype)
        for e in range(self.offsets[i], self.offsets[i + 1]):
            s = self.incident[e]
            if self.is_alive(s):
                k, r = self.stiffness[s], self.rest[s]
                length = (y.x[i] - y.x[self.other[e]]).norm()
                total += 0.25 * k * (length - r) * (length - r)
                if k > 0.0 and r > 0.0:
                    worst = ti.max(worst, length / r - 1.0)
        return total, worst

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
        ti.loop_config(serialize=self.serial_loops)  # each spring its own; the count is an integer
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
