"""What a method that solves a system per step declares about it, so its result can be checked
(:mod:`taichi_sim.convergence` measures the residual)."""
from __future__ import annotations

from dataclasses import dataclass

EXACT = "exact"
FIXED_WORK = "fixed_work"


@dataclass(frozen=True)
class Equation:
    """The equation a method's step solves, for :func:`taichi_sim.convergence.relative_residual`.

    Attributes:
        rule: ``"backward_euler"`` or ``"implicit_midpoint"``.
        promise: ``EXACT`` (the step is solved to a tolerance: a residual above the run's bound
            is ``not_converged``) or ``FIXED_WORK`` (a fixed amount of iterations: a residual
            above the bound is a warning, the run goes on).
        explicit_external: forces other than the springs and the grab are taken at the step's
            start (x0, v0), as projective dynamics and XPBD do.
        isotropic_dashpots: a spring's dashpot damps the whole relative velocity of its ends
            (projective dynamics), not only its component along the spring.
        advice: what a user changes to converge (options of the method), for messages.
    """

    rule: str
    promise: str
    explicit_external: bool = False
    isotropic_dashpots: bool = False
    advice: str = ""


@dataclass(frozen=True)
class SolveForces:
    """Forces a method puts in its own equation beyond the scene's force model (vbd's contact
    penalties and friction), linearised at the step's result x1 so that the convergence monitor
    can add them to its residual and Jacobian:

        f(x) ~ force - stiffness (x - x1)

    Attributes:
        force: (n, 3) float64, the forces at x1 (N).
        stiffness: (3 n, 3 n) scipy.sparse matrix, -df/dx at x1 (N/m), positive semi-definite,
            rows and columns ordered particle by particle (x, y, z).
    """

    force: object
    stiffness: object

    def at(self, x, x1):
        """The linearised forces at positions ``x`` ((n, 3), m)."""
        return self.force - (self.stiffness @ (x - x1).ravel()).reshape(-1, 3)


def element_stiffness(corners, blocks, n: int):
    """Per-element 3x3 blocks summed into a (3 n, 3 n) scipy.sparse matrix, particle by
    particle (x, y, z): element e couples the particles ``corners[e]`` ((E, k) ids) by
    ``blocks[e]`` ((E, k, k, 3, 3), block (a, b) between its corners a and b)."""
    import numpy as np
    import scipy.sparse as sp

    corners = np.asarray(corners, np.int64)
    shape = corners.shape + corners.shape[1:] + (3, 3)
    rows = 3 * corners[:, :, None, None, None] + np.arange(3)[None, None, None, :, None]
    cols = 3 * corners[:, None, :, None, None] + np.arange(3)[None, None, None, None, :]
    return sp.csr_matrix((np.broadcast_to(blocks, shape).ravel(),
                          (np.broadcast_to(rows, shape).ravel(), np.broadcast_to(cols, shape).ravel())),
                         shape=(3 * n, 3 * n))

