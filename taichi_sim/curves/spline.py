"""A monotone cubic Hermite spline through control points (t_i, v_i): a parameter over time.

Why this spline: it interpolates its control points (a curve drawn through the points you put
down is what you expect from an editor), it is C¹ (the derivative is continuous, so a driven
rate or speed has no kinks), and with Fritsch–Carlson tangents (the "PCHIP" choice) it never
overshoots: between two points it stays between their values. A Catmull–Rom spline
overshoots near a sharp change, which would take a rate below its minimum of 0; a cubic
B-spline does not interpolate. So if every control value respects a parameter's minimum, the
whole curve does.

Outside [t_0, t_last] the curve holds its end values. The end tangents are 0, so the held
parts join the spline with a continuous derivative too. The integral is exact (piecewise
quartic antiderivative), which the emitter uses to launch exactly ∫ rate dt particles.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass


def _tangents(ts: list[float], vs: list[float]) -> list[float]:
    """Fritsch–Carlson tangents (dv/dt at each knot): 0 at the ends and at local extrema,
    else the weighted harmonic mean of the neighbouring slopes (keeps each segment monotone)."""
    n = len(ts)
    m = [0.0] * n
    if n < 3:
        return m
    h = [ts[k + 1] - ts[k] for k in range(n - 1)]
    d = [(vs[k + 1] - vs[k]) / h[k] for k in range(n - 1)]
    for k in range(1, n - 1):
        if d[k - 1] * d[k] > 0:
            w1, w2 = 2 * h[k] + h[k - 1], h[k] + 2 * h[k - 1]
            m[k] = (w1 + w2) / (w1 / d[k - 1] + w2 / d[k])
    return m


@dataclass(frozen=True)
class Spline:
    """The curve through ``points`` ((t in s, value) pairs, times strictly increasing, at
    least one point). Evaluate with ``spline(t)``; ``integral(t0, t1)`` is ∫ value dt."""

    points: tuple[tuple[float, float], ...]

    def __post_init__(self):
        pts = tuple((float(t), float(v)) for t, v in self.points)
        if not pts:
            raise ValueError("a spline needs at least one point")
        if any(b[0] <= a[0] for a, b in zip(pts, pts[1:])):
            raise ValueError("spline times must be strictly increasing")
        object.__setattr__(self, "points", pts)
        ts, vs = [p[0] for p in pts], [p[1] for p in pts]
        m = _tangents(ts, vs)
        # Power-basis coefficients of each segment in s = (t - t_k) / h_k, and the integral
        # from t_0 to each knot.
        coeffs, cumulative = [], [0.0]
        for k in range(len(pts) - 1):
            h = ts[k + 1] - ts[k]
            a, b = vs[k], h * m[k]
            c = -3 * vs[k] - 2 * h * m[k] + 3 * vs[k + 1] - h * m[k + 1]
            d = 2 * vs[k] + h * m[k] - 2 * vs[k + 1] + h * m[k + 1]
            coeffs.append((a, b, c, d, h))
            cumulative.append(cumulative[-1] + h * (a + b / 2 + c / 3 + d / 4))
        object.__setattr__(self, "_ts", ts)
        object.__setattr__(self, "_vs", vs)
        object.__setattr__(self, "_coeffs", coeffs)
        object.__setattr__(self, "_cumulative", cumulative)

    @property
    def times(self) -> list[float]:
        return list(self._ts)

    @property
    def values(self) -> list[float]:
        return list(self._vs)

    def _segment(self, t: float) -> int:
        # bisect_right - 1: a knot belongs to the segment it starts, so s = 0 there and the
        # value is the control value exactly.
        return bisect.bisect_right(self._ts, t) - 1

    def __call__(self, t: float) -> float:
        """The value at time t (s)."""
        ts = self._ts
        if t <= ts[0]:
            return self._vs[0]
        if t >= ts[-1]:
            return self._vs[-1]
        k = self._segment(t)
        a, b, c, d, h = self._coeffs[k]
        s = (t - ts[k]) / h
        return a + s * (b + s * (c + s * d))

    def derivative(self, t: float) -> float:
        """dvalue/dt at time t (s) (0 outside the control points' span)."""
        ts = self._ts
        if t <= ts[0] or t >= ts[-1]:
            return 0.0
        k = self._segment(t)
        a, b, c, d, h = self._coeffs[k]
        s = (t - ts[k]) / h
        return (b + s * (2 * c + s * 3 * d)) / h

    def antiderivative(self, t: float) -> float:
        """∫ from t_0 to t of the curve (negative for t < t_0)."""
        ts, vs = self._ts, self._vs
        if t <= ts[0]:
            return vs[0] * (t - ts[0])
        if t >= ts[-1]:
            return self._cumulative[-1] + vs[-1] * (t - ts[-1])
        k = self._segment(t)
        a, b, c, d, h = self._coeffs[k]
        s = (t - ts[k]) / h
        return self._cumulative[k] + h * s * (a + s * (b / 2 + s * (c / 3 + s * d / 4)))

    def integral(self, t0: float, t1: float) -> float:
        """∫ from t0 to t1 (s) of the curve (value × s)."""
        return self.antiderivative(t1) - self.antiderivative(t0)

    def sample(self, t0: float, t1: float, count: int) -> list[tuple[float, float]]:
        """``count`` >= 2 evenly spaced (t, value) pairs from t0 to t1 (for drawing)."""
        step = (t1 - t0) / (count - 1)
        return [(t0 + i * step, self(t0 + i * step)) for i in range(count)]
