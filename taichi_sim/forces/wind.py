import math

import numpy as np
import taichi as ti

from .. import runtime
from .base import ForceTerm, ZeroJacobian

GUST_WAVES = 3


@ti.data_oriented
class Wind(ZeroJacobian, ForceTerm):
    """A gusting wind acting aerodynamically on the triangles of a mesh.

    Wind velocity at point x and time t (m/s)::

        w(x, t) = speed * (1 + gust * g(x, t)) * d + speed * gust * h(x, t) * s
        g, h   = mean of 3 travelling waves sin(kappa_j (d . x) - 2 pi f_j t + phi_j)

    where d is the horizontal direction ``heading`` (degrees from +x toward +z), s the horizontal
    direction across it, and the wave frequencies f_j (around ``gust_frequency``), wave numbers
    kappa_j = 2 pi f_j / speed (gusts travel with the wind) and phases phi_j come from ``seed``.

    Force on an intact triangle of area A and unit normal n moving with the mean velocity v of
    its vertices (quadratic pressure drag on the normal component of the relative wind)::

        F = drag_coefficient * A * (u . n) |u . n| n,    u = w(centroid, t) - v

    shared equally by its three vertices. ``drag_coefficient`` = rho C_d / 2 (kg/m^3; air with
    C_d = 1 gives 0.6). A triangle edge-on to the wind feels nothing and one facing it feels the
    most, so cloth flutters instead of being pushed uniformly. ``enabled``, ``speed`` and
    ``gust`` are 0-D fields: switchable while running without recompiling.
    """

    name = "wind"
    variational = False  # an external, time-dependent force with no potential
    source = True
    # Wind is not stiff (its velocity derivative, ~2 c A |u.n| per triangle, is about 1% of m/h
    # for cloth at 60 Hz), so implicit methods get zero Jacobians (ZeroJacobian): a linearised
    # step treats it explicitly, and Newton iterations still converge to the exact solution
    # (their residual uses the true force).

    def __init__(self, mesh, *, speed: float, heading: float, gust: float, gust_frequency: float,
                 drag_coefficient: float, seed: int = 0, enabled: bool = True):
        real = runtime.real()
        self.mesh = mesh
        self.enabled = ti.field(ti.i32, shape=())
        self.speed = ti.field(real, shape=())
        self.gust = ti.field(real, shape=())
        self.drag_coefficient = ti.field(real, shape=())
        self.direction = ti.Vector.field(3, real, shape=())
        self.across = ti.Vector.field(3, real, shape=())
        self.frequency = ti.field(real, shape=2 * GUST_WAVES)
        self.phase = ti.field(real, shape=2 * GUST_WAVES)
        rng = np.random.default_rng(seed)
        self.frequency.from_numpy((gust_frequency * rng.uniform(0.5, 1.5, 2 * GUST_WAVES)).astype(runtime.np_real()))
        self.phase.from_numpy(rng.uniform(0, 2 * math.pi, 2 * GUST_WAVES).astype(runtime.np_real()))
        self.set(enabled=enabled, speed=speed, heading=heading, gust=gust, drag_coefficient=drag_coefficient)

    def set(self, *, enabled=None, speed=None, heading=None, gust=None, drag_coefficient=None) -> None:
        """Change the wind while running (any subset)."""
        if enabled is not None:
            self.enabled[None] = int(bool(enabled))
        if speed is not None:
            self.speed[None] = float(speed)
        if gust is not None:
            self.gust[None] = float(gust)
        if drag_coefficient is not None:
            self.drag_coefficient[None] = float(drag_coefficient)
        if heading is not None:
            a = math.radians(heading)
            self.direction[None] = [math.cos(a), 0.0, math.sin(a)]
            self.across[None] = [-math.sin(a), 0.0, math.cos(a)]

    @property
    def is_enabled(self) -> bool:
        return bool(self.enabled[None])

    def fastest_speed(self) -> float:
        """The largest wind speed any gust reaches (m/s): speed (1 + 2 gust), since the along-
        and cross-wind wave sums each stay within [-1, 1]."""
        return float(self.speed[None]) * (1.0 + 2.0 * abs(float(self.gust[None])))

    @ti.func
    def velocity(self, x, t):
        """Wind velocity (m/s) at point x and time t."""
        speed = self.speed[None]
        along = self.direction[None].dot(x)
        g = 0.0
        h = 0.0
        for j in ti.static(range(GUST_WAVES)):
            f = self.frequency[j]
            g += ti.sin(2 * math.pi * f * (along / ti.max(speed, 1e-6) - t) + self.phase[j])
            f2 = self.frequency[GUST_WAVES + j]
            h += ti.sin(2 * math.pi * f2 * (along / ti.max(speed, 1e-6) - t) + self.phase[GUST_WAVES + j])
        gust = self.gust[None] / GUST_WAVES
        return speed * ((1.0 + gust * g) * self.direction[None] + gust * h * self.across[None])

    @ti.func
    def force(self, i, y, mass_i, t):
        f = ti.Vector.zero(y.x.dtype, 3)
        if self.enabled[None]:
            for e in range(self.mesh.offsets[i], self.mesh.offsets[i + 1]):
                tri = self.mesh.incident[e]
                if self.mesh.is_intact(tri):
                    v = self.mesh.triangles[tri]
                    twice_area_normal = self.mesh.area_normal(y, tri)
                    twice_area = twice_area_normal.norm()
                    if twice_area > 0.0:
                        n = twice_area_normal / twice_area
                        centroid = (y.x[v[0]] + y.x[v[1]] + y.x[v[2]]) / 3.0
                        mean_v = (y.v[v[0]] + y.v[v[1]] + y.v[v[2]]) / 3.0
                        un = (self.velocity(centroid, t) - mean_v).dot(n)
                        # one third of 0.5 * twice_area * c * un|un| n per vertex
                        f += (self.drag_coefficient[None] * twice_area / 6.0) * un * ti.abs(un) * n
        return f

