"""Vertex block descent's spring terms (the per-vertex force and 3x3 block, the augmented
formulation after AVBD) and the checks of its options; :class:`VBD` in vbd.py uses them."""

import math

import taichi as ti

from ...errors import ConfigError


def positive_option(name: str, value, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or value < 0 or (value == 0 and not allow_zero):
        raise ConfigError(f"{name} must be a finite number {'>=' if allow_zero else '>'} 0, got {value!r}")
    return float(value)


def fraction_option(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < 1:
        raise ConfigError(f"{name} must be a number in [0, 1), got {value!r}")
    return float(value)


class VBDSprings:
    """The springs' part of a vertex's solve, mixed into :class:`~.vbd.VBD` (which owns the
    fields read here: ``springs``, ``point``, ``delta``, ``spring_penalty``, ``multiplier``,
    ``penalty_growth``, ``has_multipliers``)."""

    @ti.func
    def _springs_at(self, i, dt):
        """The springs' force on i at the iterate (N) and their block of H (N/m, 3x3): for each
        spring k u u^T + max(0, k (|d| - r) / |d|) (I - u u^T) + (c / dt) u u^T."""
        springs = self.springs
        f = ti.Vector.zero(self.delta.dtype, 3)
        H = ti.Matrix.zero(self.delta.dtype, 3, 3)
        for e in range(springs.offsets[i], springs.offsets[i + 1]):
            s = springs.incident[e]
            if springs.is_alive(s):
                j = springs.other[e]
                d = self.point.x[i] - self.point.x[j]
                length = d.norm()
                if length > 0.0:
                    u = d / length
                    k = springs.stiffness[s]
                    tension = k * (length - springs.rest[s])
                    along = k
                    if ti.static(self.has_multipliers):
                        tension, along = self._augmented_tension(s, length)
                    f -= tension * u
                    transverse = ti.max(tension / length, 0.0)
                    if ti.static(springs.damped):
                        c = springs.damping[s]
                        f -= c * (self.point.v[i] - self.point.v[j]).dot(u) * u
                        along += c / dt
                    H += transverse * ti.Matrix.identity(self.delta.dtype, 3) \
                        + (along - transverse) * u.outer_product(u)
        return f, H

    @ti.func
    def _augmented_tension(self, s, length):
        """(tension (N), its derivative in the length (N/m)) of spring s in the augmented
        formulation: T = (rho C + lambda) / (1 + rho / k), C = |d| - r. Its fixed point in
        lambda (lambda = T) is T = k C, the spring's own tension, whatever rho: converged, the
        sweeps solve the same step; on the way the vertices see the stiffness rho k / (k + rho)
        <= rho instead of k, and lambda carries the tension the stiff springs hold."""
        k = self.springs.stiffness[s]
        tension = ti.cast(0.0, self.delta.dtype)
        along = ti.cast(0.0, self.delta.dtype)
        if k > 0.0:
            rho = self.spring_penalty[s]
            scale = 1.0 / (1.0 + rho / k)
            tension = (rho * (length - self.springs.rest[s]) + self.multiplier[s]) * scale
            along = rho * scale
        return tension, along

    @ti.func
    def _update_multiplier(self, s):
        """After a sweep: lambda = T at the iterate, and rho grows by penalty_growth |C| up to k
        (the AVBD ramp)."""
        springs = self.springs
        if springs.is_alive(s):
            e = springs.ends[s]
            length = (self.point.x[e[0]] - self.point.x[e[1]]).norm()
            tension, _ = self._augmented_tension(s, length)
            self.multiplier[s] = tension
            stretch = ti.abs(length - springs.rest[s])
            self.spring_penalty[s] = ti.min(self.spring_penalty[s] + self.penalty_growth * stretch,
                                             springs.stiffness[s])
