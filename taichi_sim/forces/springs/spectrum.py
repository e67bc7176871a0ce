"""The spring network of a scene's arrays, its highest frequency and damping rate (Gershgorin
bounds and power iteration), and symplectic Euler's stable step from them, in numpy: what a
scene needs to choose a stable default step and what the stability theory
(:mod:`taichi_sim.theory`) builds on."""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from ...memory import POWER_PARTICLES


def spring_network(arrays: Mapping[str, np.ndarray]):
    """(ends (S, 2), stiffness (S,), rest (S,), mass (n,), free (n,)) of the live springs with
    k > 0 of a scene's ``arrays`` (the npz model keys)."""
    mass = np.asarray(arrays["mass"], float)
    free = ~np.asarray(arrays["pinned"], bool)
    if "springs" not in arrays or len(arrays["springs"]) == 0:
        return np.zeros((0, 2), int), np.zeros(0), np.zeros(0), mass, free
    ends = np.asarray(arrays["springs"], int).reshape(-1, 2)
    k = np.asarray(arrays["stiffness"], float)
    rest = np.asarray(arrays["rest_length"], float)
    keep = k > 0
    if "alive" in arrays:
        keep &= np.asarray(arrays["alive"], bool)
    return ends[keep], k[keep], rest[keep], mass, free


def omega_max_bound(arrays: Mapping[str, np.ndarray]) -> float:
    """Block-Gershgorin upper bound on omega_max (rad/s) of a particle scene (see
    :mod:`taichi_sim.theory`);
    0 when no free particle is held by a spring."""
    ends, k, _, mass, free = spring_network(arrays)
    n = len(mass)
    if len(k) == 0 or not free.any():
        return 0.0
    i, j = ends[:, 0], ends[:, 1]
    diagonal = np.bincount(i, k, n) + np.bincount(j, k, n)
    coupling = k / np.sqrt(mass[i] * mass[j])
    off = np.bincount(i, coupling * free[j], n) + np.bincount(j, coupling * free[i], n)
    row = diagonal / mass + off
    return float(math.sqrt(max(float(np.max(row[free])), 0.0)))


def damping_rate_bound(arrays: Mapping[str, np.ndarray]) -> float:
    """Block-Gershgorin upper bound on gamma_max (1/s), the largest eigenvalue of M^-1 D for the
    damping matrix D of the springs' dashpots (spring s, coefficient c_s along its axis: the
    pattern of the stiffness with c_s for k_s) plus each particle's drag (N s/m); 0 when
    nothing damps a free particle. On x'' = -omega^2 x - gamma x' an explicit step is limited by
    gamma as well as omega (:meth:`~taichi_sim.integrators.base.Integrator.damped_limit`)."""
    mass = np.asarray(arrays["mass"], float)
    free = ~np.asarray(arrays["pinned"], bool)
    n = len(mass)
    if not free.any():
        return 0.0
    row = np.zeros(n)
    if "drag" in arrays:
        row += np.broadcast_to(np.asarray(arrays["drag"], float), (n,)) / mass
    if "springs" in arrays and len(arrays["springs"]) and "spring_damping" in arrays:
        ends = np.asarray(arrays["springs"], int).reshape(-1, 2)
        c = np.broadcast_to(np.asarray(arrays["spring_damping"], float), (len(ends),)).copy()
        if "alive" in arrays:
            c = c * np.asarray(arrays["alive"], bool)
        i, j = ends[:, 0], ends[:, 1]
        diagonal = np.bincount(i, c, n) + np.bincount(j, c, n)
        coupling = c / np.sqrt(mass[i] * mass[j])
        row += diagonal / mass + np.bincount(i, coupling * free[j], n) + np.bincount(j, coupling * free[i], n)
    return float(max(float(np.max(row[free])), 0.0))


def symplectic_euler_limit(omega: float, gamma: float) -> float:
    """Symplectic Euler's largest stable step (s) on x'' = -omega^2 x - gamma x' (omega rad/s,
    gamma 1/s): a step maps (x, v) by a matrix with trace 2 - h gamma - h^2 omega^2 and
    determinant 1 - h gamma, whose roots lie in the unit disc (Jury) while
    h^2 omega^2 + 2 h gamma < 4, i.e. h < 4 / (gamma + sqrt(gamma^2 + 4 omega^2)): 2 / omega
    undamped, 2 / gamma for pure damping."""
    if omega <= 0 and gamma <= 0:
        return math.inf
    return 4.0 / (gamma + math.sqrt(gamma * gamma + 4.0 * omega * omega))


class StiffnessOperator:
    """y = S p for S = W K W (module docstring), p and y of shape (n, 3), in numpy."""

    def __init__(self, arrays: Mapping[str, np.ndarray], x: np.ndarray):
        ends, k, rest, mass, free = spring_network(arrays)
        x = np.asarray(x, float).reshape(len(mass), 3)
        d = x[ends[:, 0]] - x[ends[:, 1]]
        length = np.linalg.norm(d, axis=1)
        live = length > 0  # a zero-length spring exerts no force: no stiffness
        ends, k, rest, d, length = ends[live], k[live], rest[live], d[live], length[live]
        self.u = d / length[:, None]
        tau = np.maximum(1.0 - rest / length, 0.0)
        # B_s w = k (tau w + (1 - tau) u (u . w)): no 3x3 blocks stored
        self.k_tau, self.k_axial = k * tau, k * (1.0 - tau)
        self.i, self.j = ends[:, 0], ends[:, 1]
        self.weight = np.where(free, 1.0 / np.sqrt(mass), 0.0)
        self.n = len(mass)
        self.free = free

    def __call__(self, p: np.ndarray) -> np.ndarray:
        q = p * self.weight[:, None]
        w = q[self.i] - q[self.j]
        force = self.k_tau[:, None] * w + (self.k_axial * np.einsum("sa,sa->s", self.u, w))[:, None] * self.u
        out = np.empty_like(q)
        for c in range(3):
            out[:, c] = np.bincount(self.i, force[:, c], self.n) - np.bincount(self.j, force[:, c], self.n)
        return out * self.weight[:, None]


def omega_max_power(arrays: Mapping[str, np.ndarray], x: np.ndarray, *, tol: float = 1e-12,
                    max_iterations: int = 3000, seed: int = 0) -> tuple[float, dict]:
    """omega_max (rad/s) by power iteration on S linearised at positions ``x`` ((n, 3), m).

    Stops when the Rayleigh quotient changes by less than ``tol`` (relative) over 10 iterations,
    or after ``max_iterations``. Returns (omega, info) with info = {"iterations", "change"}
    (the last relative change of the eigenvalue estimate). The estimate never exceeds the true
    value: an unconverged one predicts a slightly optimistic (too large) step.
    """
    op = StiffnessOperator(arrays, x)
    if len(op.i) == 0 or not op.free.any():
        return 0.0, {"iterations": 0, "change": 0.0}
    rng = np.random.default_rng(seed)
    p = rng.standard_normal((op.n, 3)) * op.free[:, None]
    p /= np.linalg.norm(p)
    history = []
    lam, change, it = 0.0, math.inf, 0
    for it in range(1, max_iterations + 1):
        y = op(p)
        lam = float(np.vdot(p, y))  # Rayleigh quotient (|p| = 1)
        norm = float(np.linalg.norm(y))
        if norm == 0.0:
            break
        p = y / norm
        history.append(lam)
        if len(history) > 10:
            change = abs(history[-1] - history[-11]) / max(abs(history[-1]), 1e-300)
            if change < tol:
                break
    return math.sqrt(max(lam, 0.0)), {"iterations": it, "change": change}


def explicit_default_step(arrays: Mapping[str, np.ndarray], x: np.ndarray | None, dt: float,
                          share: float = 0.9) -> float:
    """``dt`` (s), or ``share`` of symplectic Euler's stable step (damped oscillator, rounded down
    to 2 digits) where that is shorter. The Gershgorin bounds first (cheap, never below the
    truth); where they call ``dt`` too long and the scene has at most POWER_PARTICLES particles,
    power iteration at positions ``x`` ((n, 3), m), its estimates raised by 5 % since it
    approaches from below: the bounds of a dashpot-damped cloth are about twice the sharp values
    (cloth-wind: 3012 against 1271 /s), enough to halve a preset's step that runs."""
    omega, gamma = omega_max_bound(arrays), damping_rate_bound(arrays)
    if omega <= 0 and gamma <= 0:
        return dt
    limit = share * symplectic_euler_limit(omega, gamma)
    if dt > limit and x is not None and len(arrays["mass"]) <= POWER_PARTICLES:
        # 60 iterations come within 0.6 % of 2000 on the cloth presets (32-128 per side)
        omega = omega_max_power(arrays, x, max_iterations=60, tol=1e-6)[0]
        gamma = damping_rate_power(arrays, x, 60)
        limit = share * symplectic_euler_limit(1.05 * omega, 1.05 * gamma)
    return _round_down(limit) if dt > limit else dt


def _round_down(value: float, digits: int = 2) -> float:
    """``value`` (> 0) rounded down to ``digits`` significant digits (5.457e-4 -> 5.4e-4)."""
    scale = 10.0 ** (math.floor(math.log10(value)) - digits + 1)
    return float(f"{math.floor(value / scale) * scale:.{digits}g}")


def damping_rate_power(arrays: Mapping[str, np.ndarray], x: np.ndarray, power_iterations: int = 200) -> float:
    """gamma_max (1/s) by power iteration on W D W at positions ``x`` (the dashpots as springs
    of stiffness c_s at their current length, so only their axial part acts), plus the largest
    drag / m of a free particle."""
    mass = np.asarray(arrays["mass"], float)
    free = ~np.asarray(arrays["pinned"], bool)
    dashpots = 0.0
    if "spring_damping" in arrays and "springs" in arrays and len(arrays["springs"]):
        ends = np.asarray(arrays["springs"], int).reshape(-1, 2)
        x = np.asarray(x, float).reshape(-1, 3)
        length = np.linalg.norm(x[ends[:, 0]] - x[ends[:, 1]], axis=1)
        as_springs = dict(arrays, stiffness=np.broadcast_to(np.asarray(arrays["spring_damping"], float),
                                                            (len(ends),)), rest_length=length)
        root, _ = omega_max_power(as_springs, x, max_iterations=power_iterations, tol=1e-8)
        dashpots = root * root
    drag = np.broadcast_to(np.asarray(arrays.get("drag", 0.0), float), mass.shape) / mass
    return float(dashpots + (drag[free].max() if free.any() else 0.0))
