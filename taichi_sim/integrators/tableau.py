"""Butcher tableaux for explicit Runge-Kutta methods, validated on construction."""
from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

import numpy as np


@dataclass(frozen=True)
class ButcherTableau:
    """An explicit RK method: stages k_i = f(t + c_i h, y + h sum_j a_ij k_j), y += h sum b_i k_i.

    Args:
        a: strictly lower-triangular stage matrix as rows (row i has i entries).
        b: weights (len s).
        c: nodes (len s).
        order: the order the method is claimed to have; checked against the order conditions.
        citation: where the coefficients come from.
    """

    a: tuple
    b: tuple
    c: tuple
    order: int
    citation: str = ""

    def __post_init__(self):
        s = len(self.b)
        if len(self.c) != s or len(self.a) != s:
            raise ValueError("tableau: a, b and c must describe the same number of stages")
        for i, row in enumerate(self.a):
            if len(row) != i:
                raise ValueError(f"tableau: row {i} of a must have {i} entries (explicit method)")
            if abs(sum(row) - self.c[i]) > 1e-14:
                raise ValueError(f"tableau: row {i} of a sums to {sum(row)}, not c[{i}] = {self.c[i]}")
        if abs(sum(self.b) - 1.0) > 1e-14:
            raise ValueError(f"tableau: weights sum to {sum(self.b)}, not 1")
        met = self.conditions_met()
        if met < self.order:
            raise ValueError(f"tableau: declared order {self.order} but only order {met} conditions hold")

    @property
    def stage_count(self) -> int:
        return len(self.b)

    def matrix(self) -> np.ndarray:
        s = self.stage_count
        A = np.zeros((s, s))
        for i, row in enumerate(self.a):
            A[i, :i] = row
        return A

    def conditions_met(self, tol: float = 1e-12) -> int:
        """Highest order p <= 4 whose order conditions (for rooted trees up to p) all hold."""
        A, b, c = self.matrix(), np.asarray(self.b, float), np.asarray(self.c, float)
        conditions = {
            1: [(b.sum(), 1)],
            2: [(b @ c, Fraction(1, 2))],
            3: [(b @ c**2, Fraction(1, 3)), (b @ A @ c, Fraction(1, 6))],
            4: [(b @ c**3, Fraction(1, 4)), (b @ (c * (A @ c)), Fraction(1, 8)),
                (b @ A @ c**2, Fraction(1, 12)), (b @ A @ A @ c, Fraction(1, 24))],
        }
        met = 0
        for p in range(1, 5):
            if all(abs(value - float(target)) <= tol for value, target in conditions[p]):
                met = p
            else:
                break
        return met


EULER = ButcherTableau(a=((),), b=(1.0,), c=(0.0,), order=1,
                       citation="Euler (1768); Hairer, Norsett & Wanner, Solving ODEs I, II.1")
MIDPOINT = ButcherTableau(a=((), (0.5,)), b=(0.0, 1.0), c=(0.0, 0.5), order=2,
                          citation="Runge (1895), explicit midpoint rule")
# The seed's trapezoid rule: f0 = f(X), f1 = f(X + h f0), X += h/2 (f0 + f1)  (Heun's method).
TRAPEZOID = ButcherTableau(a=((), (1.0,)), b=(0.5, 0.5), c=(0.0, 1.0), order=2,
                           citation="Heun (1900), explicit trapezoid rule")
RK4 = ButcherTableau(a=((), (0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)),
                     b=(1 / 6, 1 / 3, 1 / 3, 1 / 6), c=(0.0, 0.5, 0.5, 1.0), order=4,
                     citation="Kutta (1901), the classical fourth-order Runge-Kutta method")
