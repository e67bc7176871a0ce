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
