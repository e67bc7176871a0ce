"""Constraint forces with Lagrange multipliers: the post-sum stage of a particle system.

Witkin's formulation ("Constrained dynamics", SIGGRAPH course notes): scalar constraints
C(x) = 0 with Jacobian J = dC/dx are kept by the force Jᵀ λ, where λ solves

    (J W Jᵀ) λ = -J̇ q̇ - J W Q - k_s C - k_d Ċ

with W the inverse masses (zero for pinned particles), Q the sum of every other force and
q̇ the velocities. Without the feedback terms (k_s, k_d) this makes C̈ = 0, which keeps an
exact solution on the constraint but lets the numerical one drift; the feedback turns the
drift into a damped oscillator C̈ + k_d Ċ + k_s C = 0 (critically damped at k_d = 2 √k_s).

Three kinds of rows, each touching one or two particles (a, b):

* ``POINT``: |x_a - p| - L (a bead on a sphere about p; with a ``PLANE`` row through p, on a
  circle: the wire);
* ``ROD``: |x_a - x_b| - L (a rigid rod between two particles);
* ``PLANE``: n · (x_a - p) (a particle on a plane).

Every C is a length (m), so the largest |C| is the drift in metres. The solve is a dense
Cholesky factorisation of the m x m matrix J W Jᵀ in one thread of the kernel: the scenes
that use constraints have a handful of rows (a bead 2, a double pendulum 2, a chain one per
link), where a dense solve of m³/6 multiply-adds costs less than the launch of a second
kernel, and it is exact, so the drift measured is the integrator's and the feedback's, not
a linear solver's. The number of rows is capped at :data:`MAX_ROWS`.
"""

import numpy as np
import taichi as ti

from .. import runtime

POINT, ROD, PLANE = 0, 1, 2
KIND_NAMES = {POINT: "point", ROD: "rod", PLANE: "plane"}

MAX_ROWS = 256
"""Most constraint rows a system may have: the dense m x m matrix and its serial Cholesky
factorisation (m³/6 operations per force evaluation) stay small up to here."""


def check_gains(ks: float, kd: float) -> tuple[float, float]:
    """The feedback gains as floats; ValueError naming ``ks`` or ``kd`` when negative or not
    finite."""
    out = []
    for name, value in (("ks", ks), ("kd", kd)):
        value = float(value)
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"constraint feedback gain {name} must be a finite number >= 0, got {value}")
        out.append(value)
    return out[0], out[1]


@ti.data_oriented
class Constraints:
    """The constraint rows of a particle system and the fields of their force stage.

    Args:
        particle_count: n, the particles of the system.
        kind: (m,) row kinds (:data:`POINT`, :data:`ROD`, :data:`PLANE`).
        particles: (m, 2) particle ids (a, b); b is -1 except for rods.
        point: (m, 3) the fixed point p of POINT and PLANE rows (m; unused for rods).
        normal: (m, 3) the unit normal n of PLANE rows.
        length: (m,) L of POINT and ROD rows (m, > 0; unused for planes).
        ks: feedback stiffness k_s (1/s², >= 0). kd: feedback damping k_d (1/s, >= 0).

    The gains live in 0-D fields (:meth:`set_gains` changes them without recompiling).
    """

    def __init__(self, particle_count: int, kind, particles, point, normal, length, ks: float, kd: float):
        kind = np.asarray(kind, np.int32).reshape(-1)
        m = len(kind)
        if not 1 <= m <= MAX_ROWS:
            raise ValueError(f"a system has 1 to {MAX_ROWS} constraint rows, got {m}")
        particles = np.asarray(particles, np.int32).reshape(m, 2)
        point = np.asarray(point, float).reshape(m, 3)
        normal = np.asarray(normal, float).reshape(m, 3)
        length = np.asarray(length, float).reshape(m)
        ks, kd = check_gains(ks, kd)
        self.scene = ""  # the scene's name, for messages (set by the builder)
        self.row_count = m
        self.particle_count = n = int(particle_count)
        self.kind_np, self.particles_np = kind, particles
        self.point_np, self.normal_np, self.length_np = point, normal, length
        real = runtime.real()
        self.kind = ti.field(ti.i32, shape=m)
        self.a = ti.field(ti.i32, shape=m)
        self.b = ti.field(ti.i32, shape=m)
        self.point = ti.Vector.field(3, real, shape=m)
        self.normal = ti.Vector.field(3, real, shape=m)
        self.length = ti.field(real, shape=m)
        self.ks = ti.field(real, shape=())
        self.kd = ti.field(real, shape=())
        # Per evaluation: each row's gradient with respect to x_a (the one for x_b of a rod is
        # its negative), the right-hand side, the matrix (factorised in place) and λ.
        self.grad = ti.Vector.field(3, real, shape=m)
        self.rhs = ti.field(real, shape=m)
        self.matrix = ti.field(real, shape=(m, m))
        self.lam = ti.field(real, shape=m)
        # Per particle: the applied force Q (the other terms' sum) and the constraint force.
        self.applied = ti.Vector.field(3, real, shape=n)
        self.force = ti.Vector.field(3, real, shape=n)
        self.kind.from_numpy(kind)
        self.a.from_numpy(particles[:, 0].copy())
        self.b.from_numpy(particles[:, 1].copy())
        self.point.from_numpy(point.astype(runtime.np_real()))
        self.normal.from_numpy(normal.astype(runtime.np_real()))
        self.length.from_numpy(length.astype(runtime.np_real()))
        self.set_gains(ks, kd)

    def set_gains(self, ks: float, kd: float) -> None:
        """Feedback stiffness ``ks`` (1/s²) and damping ``kd`` (1/s), both >= 0."""
        ks, kd = check_gains(ks, kd)
        self.ks[None] = ks
        self.kd[None] = kd

    def gains(self) -> tuple[float, float]:
        return float(self.ks[None]), float(self.kd[None])

    def arrays(self) -> dict[str, np.ndarray]:
        """The npz keys that rebuild the constraints (see :mod:`taichi_sim.reference`)."""
        ks, kd = self.gains()
        return {"constraint_kind": self.kind_np.copy(), "constraint_particles": self.particles_np.copy(),
                "constraint_point": self.point_np.copy(), "constraint_normal": self.normal_np.copy(),
                "constraint_length": self.length_np.copy(), "constraint_ks": np.float64(ks),
                "constraint_kd": np.float64(kd)}

    @ti.func
    def _row(self, r, y):
        """(gradient g of row r wrt x_a, C (m), Ċ (m/s), J̇ q̇ (m/s²)) at state ``y``."""
        k = self.kind[r]
        a = self.a[r]
        g = ti.Vector.zero(y.x.dtype, 3)
        c = ti.cast(0.0, y.x.dtype)
        cdot = ti.cast(0.0, y.x.dtype)
        jdot = ti.cast(0.0, y.x.dtype)
        if k == 2:  # PLANE
            g = self.normal[r]
            c = g.dot(y.x[a] - self.point[r])
            cdot = g.dot(y.v[a])
        else:  # POINT, ROD: a distance
            d = y.x[a] - self.point[r]
            dv = y.v[a]
            if k == 1:
                b = self.b[r]
                d = y.x[a] - y.x[b]
                dv = y.v[a] - y.v[b]
            dist = d.norm()
            if dist > 0:
                g = d / dist
                cdot = g.dot(dv)
                # d/dt (d / |d|) . dv = (|dv|² - (g . dv)²) / |d|
                jdot = (dv.norm_sqr() - cdot * cdot) / dist
            c = dist - self.length[r]
        return g, c, cdot, jdot

    @ti.func
    def _shared(self, r, s, mass, free):
        """(J W Jᵀ)_rs: the particles rows r and s share, weighted by W = free / mass."""
        gg = self.grad[r].dot(self.grad[s])
        total = gg * 0.0
        ar, br, as_, bs = self.a[r], self.b[r], self.a[s], self.b[s]
        if ar == as_:
            total += free[ar] / mass[ar] * gg
        if br >= 0 and br == bs:
            total += free[br] / mass[br] * gg
        if bs >= 0 and ar == bs:
            total -= free[ar] / mass[ar] * gg
        if br >= 0 and br == as_:
            total -= free[br] / mass[br] * gg
        return total

    @ti.func
    def solve(self, y, mass, free):
        """Fill :attr:`force` with Jᵀ λ for state ``y``, given :attr:`applied` (N) at ``y``;
        call at the top level of a kernel (its loops are the kernel's stages)."""
        m = ti.static(self.row_count)
        for r in range(m):
            g, c, cdot, jdot = self._row(r, y)
            self.grad[r] = g
            a = self.a[r]
            jwq = g.dot(self.applied[a]) * free[a] / mass[a]
            if self.kind[r] == 1:
                b = self.b[r]
                jwq -= g.dot(self.applied[b]) * free[b] / mass[b]
            self.rhs[r] = -jdot - jwq - self.ks[None] * c - self.kd[None] * cdot
        for r, s in ti.ndrange(m, m):
            self.matrix[r, s] = self._shared(r, s, mass, free)
        for _ in range(1):  # one thread: the dense Cholesky factorisation and both solves
            for j in range(m):
                original = self.matrix[j, j]
                diag = original
                for k in range(j):
                    diag -= self.matrix[j, k] * self.matrix[j, k]
                # A row on pinned particles only (rejected when built) or one that depends
                # on the others (a bead on its wire's axis) has no pivot: its λ is then 0.
                pivot = diag * 0.0
                if diag > 1e-12 * original:
                    pivot = ti.sqrt(diag)
                self.matrix[j, j] = pivot
                for i in range(j + 1, m):
                    value = self.matrix[i, j]
                    for k in range(j):
                        value -= self.matrix[i, k] * self.matrix[j, k]
                    if pivot > 0:
                        value /= pivot
                    else:
                        value = 0.0
                    self.matrix[i, j] = value
            for i in range(m):  # L z = rhs
                value = self.rhs[i]
                for k in range(i):
                    value -= self.matrix[i, k] * self.lam[k]
                if self.matrix[i, i] > 0:
                    value /= self.matrix[i, i]
                else:
                    value = 0.0
                self.lam[i] = value
            for back in range(m):  # Lᵀ λ = z
                i = m - 1 - back
                value = self.lam[i]
                for k in range(i + 1, m):
                    value -= self.matrix[k, i] * self.lam[k]
                if self.matrix[i, i] > 0:
                    value /= self.matrix[i, i]
                else:
                    value = 0.0
                self.lam[i] = value
        for i in range(self.particle_count):
            self.force[i] = ti.Vector.zero(y.x.dtype, 3)
        for r in range(m):
            f = self.lam[r] * self.grad[r]
            self.force[self.a[r]] += f
            if self.kind[r] == 1:
                self.force[self.b[r]] -= f

    def violation(self, y) -> float:
        """The largest |C| (m) over the rows at state ``y``."""
        return float(self._violation(y))

    @ti.kernel
    def _violation(self, y: ti.template()) -> float:
        worst = 0.0
        for r in range(self.row_count):
            _gradient, c, _rate, _drift = self._row(r, y)
            ti.atomic_max(worst, ti.abs(c))
        return worst

    def extent(self) -> np.ndarray:
        """Points (k, 3) (m) a constrained particle may reach besides where particles start:
        the ends of each POINT row's sphere along the axes (a bead's wire), for the guard's
        idea of the scene's size."""
        rows = self.kind_np == POINT
        if not rows.any():
            return np.zeros((0, 3))
        offsets = np.concatenate([np.eye(3), -np.eye(3)])
        return (self.point_np[rows, None, :] + self.length_np[rows, None, None] * offsets).reshape(-1, 3)

