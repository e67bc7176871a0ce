"""Chebyshev semi-iterative acceleration of an iteration (Wang 2015, "A Chebyshev Semi-Iterative
Approach for Accelerating Projective and Position-based Dynamics"): after iteration k the iterate
moves to omega_k (x_k - x_{k-2}) + x_{k-2}, with the weights of a spectral radius estimate rho,

    omega_0 = 1,   omega_1 = 2 / (2 - rho^2),   omega_k = 4 / (4 - rho^2 omega_{k-1}).

Projective dynamics weights its global solves with :func:`chebyshev_weight`; vbd its sweeps,
keeping each vertex's last two displacements in a :class:`ChebyshevHistory`.
"""
import taichi as ti


@ti.pyfunc
def chebyshev_weight(rho2, k, omega):
    """omega_k from omega_{k-1} (``omega``) for rho^2 = ``rho2`` (module docstring); in Python
    and in Taichi's scope alike."""
    out = 1.0
    if k == 1:
        out = 2.0 / (2.0 - rho2)
    elif k > 1:
        out = 4.0 / (4.0 - rho2 * omega)
    return out


@ti.data_oriented
class ChebyshevHistory:
    """Each vertex's displacement one and two iterations back, and the over-relaxed step from
    them.

    Args:
        n: particles; real: the field precision.
    """

    def __init__(self, n: int, real):
        self.earlier = ti.Vector.field(3, real, shape=n)  # two iterations back
        self.last = ti.Vector.field(3, real, shape=n)  # one iteration back

    @ti.func
    def start(self, i, delta):
        """Vertex i begins at ``delta``: both earlier iterates are it."""
        self.earlier[i] = delta
        self.last[i] = delta

    @ti.func
    def relaxed(self, i, delta, omega):
        """The over-relaxed displacement of vertex i from the iteration's own ``delta``."""
        return omega * (delta - self.earlier[i]) + self.earlier[i]

    @ti.func
    def shift(self, i, delta):
        """The history moves on by one: ``delta`` is vertex i's displacement now."""
        self.earlier[i] = self.last[i]
        self.last[i] = delta
