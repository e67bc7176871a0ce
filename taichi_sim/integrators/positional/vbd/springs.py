"""Vertex block descent's spring terms (the per-vertex force and 3x3 block, the augmented
formulation after AVBD) and the checks of its options; :class:`~.solver.VBD` owns them."""


import taichi as ti

from .... import runtime


@ti.data_oriented
class SpringTerms:
    """The springs' part of a vertex's solve in :class:`~.solver.VBD`: the force and 3x3 block
    one vertex takes from its springs at the iterate and, with ``augmented``, each spring's
    augmented Lagrangian (its penalty and multiplier, carried from sweep to sweep and step to
    step).

    Args:
        springs: the system's spring term (``offsets``, ``incident``, ``other``, ``ends``,
            ``stiffness``, ``rest``, ``damping``, ``spring_count``).
        augmented: springs in the augmented form of :meth:`augmented_tension` (after Giles,
            Diaz & Yuksel 2025, "Augmented Vertex Block Descent").
        penalty: the augmented form's penalty rho at the start of each substep (N/m).
        penalty_growth: its ramp: rho grows by this times |C| after each sweep (N/m^2).
    """

    def __init__(self, springs, *, augmented: bool, penalty: float, penalty_growth: float):
        self.springs = springs
        self.augmented = augmented
        self.penalty = penalty
        self.penalty_growth = penalty_growth
        if augmented:
            real = runtime.real()
            self.spring_penalty = ti.field(real, shape=springs.spring_count)  # rho (N/m)
            self.multiplier = ti.field(real, shape=springs.spring_count)  # lambda (N)

    def reset(self) -> None:
        """Forget the multipliers (a reset or a switch of method)."""
        if self.augmented:
            self.multiplier.fill(0)

    @ti.func
    def at(self, i, x, v, dt):
        """The springs' force on vertex i (N) and their block of H (N/m, 3x3) at positions ``x``
        (m) and velocities ``v`` (m/s), (n,) vec3 fields: for each spring
        k u u^T + max(0, k (|d| - r) / |d|) (I - u u^T) + (c / dt) u u^T."""
        springs = self.springs
        f = ti.Vector.zero(x.dtype, 3)
        H = ti.Matrix.zero(x.dtype, 3, 3)
        for e in range(springs.offsets[i], springs.offsets[i + 1]):
            s = springs.incident[e]
            if springs.is_alive(s):
                j = springs.other[e]
                d = x[i] - x[j]
                length = d.norm()
                if length > 0.0:
                    u = d / length
                    k = springs.stiffness[s]
                    tension = k * (length - springs.rest[s])
                    along = k
                    if ti.static(self.augmented):
                        tension, along = self.augmented_tension(s, length)
                    f -= tension * u
                    transverse = ti.max(tension / length, 0.0)
                    if ti.static(springs.damped):
                        c = springs.damping[s]
                        f -= c * (v[i] - v[j]).dot(u) * u
                        along += c / dt
                    H += transverse * ti.Matrix.identity(x.dtype, 3) \
                        + (along - transverse) * u.outer_product(u)
        return f, H

    @ti.func
    def augmented_tension(self, s, length):
        """(tension (N), its derivative in the length (N/m)) of spring s in the augmented
        formulation: T = (rho C + lambda) / (1 + rho / k), C = |d| - r. Its fixed point in
        lambda (lambda = T) is T = k C, the spring's own tension, whatever rho: converged, the
        sweeps solve the same step; on the way the vertices see the stiffness rho k / (k + rho)
        <= rho instead of k, and lambda carries the tension the stiff springs hold."""
        k = self.springs.stiffness[s]
        tension = ti.cast(0.0, self.multiplier.dtype)
        along = ti.cast(0.0, self.multiplier.dtype)
        if k > 0.0:
            rho = self.spring_penalty[s]
            scale = 1.0 / (1.0 + rho / k)
            tension = (rho * (length - self.springs.rest[s]) + self.multiplier[s]) * scale
            along = rho * scale
        return tension, along

    @ti.func
    def begin_penalties(self):
        """A substep's start: every spring's penalty back to min(penalty, k); a top-level loop."""
        for s in range(self.springs.spring_count):
            self.spring_penalty[s] = ti.min(self.penalty, self.springs.stiffness[s])

    @ti.func
    def update_multipliers(self, x):
        """After a sweep, at positions ``x`` (m): each spring's lambda = T there, and rho grows
        by penalty_growth |C| up to k (the AVBD ramp)."""
        for s in range(self.springs.spring_count):
            self.update_multiplier(s, x)

    @ti.func
    def update_multiplier(self, s, x):
        springs = self.springs
        if springs.is_alive(s):
            e = springs.ends[s]
            length = (x[e[0]] - x[e[1]]).norm()
            tension, _ = self.augmented_tension(s, length)
            self.multiplier[s] = tension
            stretch = ti.abs(length - springs.rest[s])
            self.spring_penalty[s] = ti.min(self.spring_penalty[s] + self.penalty_growth * stretch,
                                             springs.stiffness[s])
