"""The spring network of a scene's arrays and a bound on its highest frequency, in numpy: what
a scene needs to choose a stable default step and what the stability theory
(:mod:`taichi_sim.theory`) builds on."""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np


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
