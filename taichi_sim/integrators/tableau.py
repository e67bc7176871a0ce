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
        b: weights (len s) of the propagated solution.
        c: nodes (len s).
        order: the order the method is claimed to have; checked against the order conditions
            (which are coded up to order 4, so a fifth-order claim is checked to order 4).
        citation: where the coefficients come from.
        b_hat: weights of an embedded solution y_hat = y + h sum b_hat_i k_i (adaptive pairs only);
            y_new - y_hat estimates the local error.
        embedded_order: the order of ``b_hat`` (given exactly when ``b_hat`` is).
    """

    a: tuple
    b: tuple
    c: tuple
    order: int
    citation: str = ""
    b_hat: tuple | None = None
    embedded_order: int | None = None

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
        if met < min(self.order, 4):
            raise ValueError(f"tableau: declared order {self.order} but only order {met} conditions hold")
        if (self.b_hat is None) != (self.embedded_order is None):
            raise ValueError("tableau: b_hat and embedded_order go together")
        if self.b_hat is not None:
            if len(self.b_hat) != s:
                raise ValueError("tableau: b_hat must have one weight per stage")
            if abs(sum(self.b_hat) - 1.0) > 1e-14:
                raise ValueError(f"tableau: embedded weights sum to {sum(self.b_hat)}, not 1")
            if tuple(self.b_hat) == tuple(self.b):
                raise ValueError("tableau: b_hat equals b, so the error estimate would be zero")
            met_hat = self.conditions_met(weights=self.b_hat)
            if met_hat < min(self.embedded_order, 4):
                raise ValueError(f"tableau: declared embedded order {self.embedded_order} but only "
                                 f"order {met_hat} conditions hold for b_hat")

    @property
    def stage_count(self) -> int:
        return len(self.b)

    def matrix(self) -> np.ndarray:
        s = self.stage_count
        A = np.zeros((s, s))
        for i, row in enumerate(self.a):
            A[i, :i] = row
        return A

    def stability_polynomial(self) -> np.ndarray:
        """Coefficients c_0..c_s of R(z) = sum_k c_k z^k, the factor the method multiplies y by
        per step on y' = lambda y (z = h lambda): c_0 = 1, c_k = b^T A^(k-1) 1."""
        A, coefficients, v = self.matrix(), [1.0], np.ones(self.stage_count)
        for _ in range(self.stage_count):
            coefficients.append(float(np.dot(self.b, v)))
            v = A @ v
        return np.asarray(coefficients)

    def real_stability_boundary(self) -> float:
        """The largest x such that |R(-s)| <= 1 for every s in [0, x]: how far along the negative
        real axis h lambda may go (2 for Euler, 2.785 for RK4, 3.307 for Dormand-Prince)."""
        xs = np.arange(1, 100001) * 1e-4  # to 10, in steps of 1e-4
        outside = np.abs(np.polyval(self.stability_polynomial()[::-1], -xs)) > 1.0 + 1e-12
        return float(xs[np.argmax(outside) - 1]) if outside.any() else float(xs[-1])

    @property
    def fsal(self) -> bool:
        """First Same As Last: the last stage is f at the new solution (last row of a equals b,
        c = 1), so it is the next step's first stage."""
        return (self.stage_count > 1 and tuple(self.a[-1]) == tuple(self.b[:-1])
                and self.b[-1] == 0.0 and self.c[-1] == 1.0)

    def conditions_met(self, tol: float = 1e-12, weights: tuple | None = None) -> int:
        """Highest order p <= 4 whose order conditions (for rooted trees up to p) all hold, for
        ``weights`` (default ``b``; pass ``b_hat`` to check the embedded solution)."""
        A, c = self.matrix(), np.asarray(self.c, float)
        b = np.asarray(self.b if weights is None else weights, float)
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

# Embedded pairs for adaptive stepping. Dormand-Prince propagates its fifth-order solution (local
# extrapolation) and its last stage is f at the new solution (FSAL).
DORMAND_PRINCE = ButcherTableau(
    a=((),
       (1 / 5,),
       (3 / 40, 9 / 40),
       (44 / 45, -56 / 15, 32 / 9),
       (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
       (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
       (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84)),
    b=(35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0.0),
    c=(0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0),
    order=5,
    b_hat=(5179 / 57600, 0.0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100, 1 / 40),
    embedded_order=4,
    citation="Dormand & Prince (1980), A family of embedded Runge-Kutta formulae, "
             "J. Comput. Appl. Math. 6(1):19-26 (RK5(4)7M)")
# Fehlberg propagates the fourth-order solution, as he proposed; the fifth-order one only
# estimates its error.
FEHLBERG = ButcherTableau(
    a=((),
       (1 / 4,),
       (3 / 32, 9 / 32),
       (1932 / 2197, -7200 / 2197, 7296 / 2197),
       (439 / 216, -8.0, 3680 / 513, -845 / 4104),
       (-8 / 27, 2.0, -3544 / 2565, 1859 / 4104, -11 / 40)),
    b=(25 / 216, 0.0, 1408 / 2565, 2197 / 4104, -1 / 5, 0.0),
    c=(0.0, 1 / 4, 3 / 8, 12 / 13, 1.0, 1 / 2),
    order=4,
    b_hat=(16 / 135, 0.0, 6656 / 12825, 28561 / 56430, -9 / 50, 2 / 55),
    embedded_order=5,
    citation="Fehlberg (1969), Low-order classical Runge-Kutta formulas with stepsize control "
             "and their application to some heat transfer problems, NASA TR R-315 (RKF4(5))")
