"""The force model in plain numpy, rebuilt from a run's .npz (or a Scene's arrays).

This is the exported statement of DESIGN.md section 4: anyone can rebuild the exact ODE from
the npz with this module (or their own code) and check a run, e.g. against scipy's DOP853.
It is written for clarity, not speed, and is independent of the Taichi kernels.
"""
from __future__ import annotations

from typing import Callable, Mapping

import numpy as np


def particle_rhs(data: Mapping[str, np.ndarray]) -> Callable[[float, np.ndarray], np.ndarray]:
    """f(t, y) for a particle system, with y = concat(x.ravel(), v.ravel()) of length 6n.

    ``data`` needs mass (n,), pinned (n,), gravity (3,), drag (), and optionally springs (S, 2),
    rest_length, stiffness, spring_damping (S,), and turbulence_amplitude () with its waves
    turbulence_k, turbulence_direction (M, 3), turbulence_omega, turbulence_phase (M,) (see
    :class:`taichi_sim.forces.Turbulence`).
    """
    mass = np.asarray(data["mass"], float)
    free = ~np.asarray(data["pinned"], bool)
    gravity = np.asarray(data["gravity"], float)
    drag = float(data["drag"])
    n = len(mass)
    has_springs = "springs" in data and len(data["springs"]) > 0
    if has_springs:
        ends = np.asarray(data["springs"], int)
        rest = np.asarray(data["rest_length"], float)
        k = np.asarray(data["stiffness"], float)
        c = np.asarray(data["spring_damping"], float)
    turbulence = None
    if "turbulence_amplitude" in data:
        amplitude = float(data["turbulence_amplitude"])
        k_t, d_t = np.asarray(data["turbulence_k"], float), np.asarray(data["turbulence_direction"], float)
        omega_t, phase_t = np.asarray(data["turbulence_omega"], float), np.asarray(data["turbulence_phase"], float)

        def turbulence(x, t):  # written out here, so the reference does not import the simulator
            return amplitude / len(omega_t) * np.sin(x @ k_t.T - omega_t * t + phase_t) @ d_t

    def rhs(t: float, y: np.ndarray) -> np.ndarray:
        x, v = y[: 3 * n].reshape(n, 3), y[3 * n:].reshape(n, 3)
        force = mass[:, None] * gravity - drag * v
        if turbulence is not None:
            force += mass[:, None] * turbulence(x, t)
        if has_springs:
            d = x[ends[:, 0]] - x[ends[:, 1]]
            length = np.linalg.norm(d, axis=1)
            u = d / np.where(length > 0, length, 1.0)[:, None]
            dv = v[ends[:, 0]] - v[ends[:, 1]]
            magnitude = k * (length - rest) + c * np.einsum("ij,ij->i", dv, u)
            f_i = -magnitude[:, None] * u * (length > 0)[:, None]
            np.add.at(force, ends[:, 0], f_i)
            np.add.at(force, ends[:, 1], -f_i)
        dx = np.where(free[:, None], v, 0.0)
        dv_dt = np.where(free[:, None], force / mass[:, None], 0.0)
        return np.concatenate([dx.ravel(), dv_dt.ravel()])

    return rhs


def particle_energy(data: Mapping[str, np.ndarray], x: np.ndarray, v: np.ndarray) -> float:
    """Kinetic + gravitational + spring energy (J) of positions x and velocities v, (n, 3).

    Pinned particles, which never move, are left out of the gravitational term (a constant).
    Broken springs (``alive`` false, when present) store no energy.
    """
    mass = np.asarray(data["mass"], float)
    free = ~np.asarray(data["pinned"], bool)
    energy = 0.5 * np.sum(mass * np.sum(v * v, axis=1))
    energy -= np.sum((mass * (x @ np.asarray(data["gravity"], float)))[free])
    if "springs" in data and len(data["springs"]) > 0:
        ends = np.asarray(data["springs"], int)
        stretch = np.linalg.norm(x[ends[:, 0]] - x[ends[:, 1]], axis=1) - data["rest_length"]
        intact = np.asarray(data["alive"], bool) if "alive" in data else True
        energy += 0.5 * np.sum((data["stiffness"] * stretch**2)[intact])
    return float(energy)


def solve_reference(data: Mapping[str, np.ndarray], t_end: float, *, rtol: float = 1e-12,
                    atol: float = 1e-12, method: str = "DOP853") -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities at ``t_end`` from (x0, v0), by scipy's ``method``.

    Needs scipy (a test/benchmark dependency, never needed by the simulator itself).
    """
    from scipy.integrate import solve_ivp

    n = len(data["mass"])
    y0 = np.concatenate([np.asarray(data["x0"], float).ravel(), np.asarray(data["v0"], float).ravel()])
    sol = solve_ivp(particle_rhs(data), (0.0, t_end), y0, method=method, rtol=rtol, atol=atol)
    if not sol.success:
        raise RuntimeError(f"reference solve failed: {sol.message}")
    y = sol.y[:, -1]
    return y[: 3 * n].reshape(n, 3), y[3 * n:].reshape(n, 3)
