"""The force model in plain numpy, rebuilt from a run's .npz (or a Scene's arrays).

This is the exported statement of the force model (docs/scenes.md, Force model): anyone can
rebuild the exact ODE from the npz with this module (or their own code) and check a run, e.g.
against scipy's DOP853.
It is written for clarity, not speed, and is independent of the Taichi kernels.
"""
from __future__ import annotations

from typing import Callable, Mapping

import numpy as np


def particle_rhs(data: Mapping[str, np.ndarray]) -> Callable[[float, np.ndarray], np.ndarray]:
    """f(t, y) for a particle system, with y = concat(x.ravel(), v.ravel()) of length 6n.

    ``data`` needs mass (n,), pinned (n,), gravity (3,), drag (), and optionally springs (S, 2),
    rest_length, stiffness, spring_damping (S,), the constraint rows (``constraint_kind`` ...,
    see :func:`constraint_force`), and turbulence_amplitude () with its waves turbulence_k,
    turbulence_direction (M, 3), turbulence_omega, turbulence_phase (M,) (see
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
        if "constraint_kind" in data:
            force = force + constraint_force(data, x, v, force)
        dx = np.where(free[:, None], v, 0.0)
        dv_dt = np.where(free[:, None], force / mass[:, None], 0.0)
        return np.concatenate([dx.ravel(), dv_dt.ravel()])

    return rhs


def _constraint_rows(data: Mapping[str, np.ndarray], x: np.ndarray, v: np.ndarray):
    """Per row: (C (m), Ċ (m/s), J̇ q̇ (m/s²), gradient wrt x_a (3,)) as arrays."""
    kind = np.asarray(data["constraint_kind"], int)
    ends = np.asarray(data["constraint_particles"], int)
    point = np.asarray(data["constraint_point"], float)
    normal = np.asarray(data["constraint_normal"], float)
    length = np.asarray(data["constraint_length"], float)
    a, b = ends[:, 0], ends[:, 1]
    rod = kind == 1
    d = x[a] - np.where(rod[:, None], x[np.maximum(b, 0)], point)
    dv = v[a] - np.where(rod[:, None], v[np.maximum(b, 0)], 0.0)
    dist = np.linalg.norm(d, axis=1)
    u = d / np.where(dist > 0, dist, 1.0)[:, None]
    plane = kind == 2
    grad = np.where(plane[:, None], normal, u)
    c = np.where(plane, np.einsum("ij,ij->i", normal, x[a] - point), dist - length)
    cdot = np.einsum("ij,ij->i", grad, dv)
    jdot = np.where(plane, 0.0, (np.einsum("ij,ij->i", dv, dv) - cdot**2) / np.where(dist > 0, dist, 1.0))
    return c, cdot, jdot, grad


def constraint_force(data: Mapping[str, np.ndarray], x: np.ndarray, v: np.ndarray,
                     applied: np.ndarray) -> np.ndarray:
    """The constraint force Jᵀ λ (N, (n, 3)) on positions x and velocities v given the applied
    force ``applied`` (N, (n, 3)): (J W Jᵀ) λ = -J̇ q̇ - J W Q - ks C - kd Ċ (Witkin).

    ``data``: constraint_kind (m,) (0: |x_a - p| = L, 1: |x_a - x_b| = L, 2: n . (x_a - p) = 0),
    constraint_particles (m, 2) (b = -1 unless a rod), constraint_point, constraint_normal
    (m, 3), constraint_length (m,), constraint_ks, constraint_kd (), mass, pinned (n,)."""
    n = len(x)
    kind = np.asarray(data["constraint_kind"], int)
    ends = np.asarray(data["constraint_particles"], int)
    m = len(kind)
    w = np.where(np.asarray(data["pinned"], bool), 0.0, 1.0 / np.asarray(data["mass"], float))
    c, cdot, jdot, grad = _constraint_rows(data, x, v)
    jacobian = np.zeros((m, 3 * n))
    for r in range(m):
        a, b = ends[r]
        jacobian[r, 3 * a:3 * a + 3] += grad[r]
        if kind[r] == 1:
            jacobian[r, 3 * b:3 * b + 3] -= grad[r]
    weights = np.repeat(w, 3)
    matrix = (jacobian * weights) @ jacobian.T
    rhs = (-jdot - jacobian @ (weights * applied.ravel())
           - float(data["constraint_ks"]) * c - float(data["constraint_kd"]) * cdot)
    lam = np.linalg.solve(matrix, rhs)
    return (jacobian.T @ lam).reshape(n, 3)


def constraint_violation(data: Mapping[str, np.ndarray], x: np.ndarray) -> float:
    """The largest |C| (m) over the constraint rows of ``data`` at positions x (n, 3)."""
    c, _, _, _ = _constraint_rows(data, x, np.zeros_like(x))
    return float(np.max(np.abs(c)))


def particle_energy(data: Mapping[str, np.ndarray], x: np.ndarray, v: np.ndarray) -> float:
    """Kinetic + gravitational + spring + membrane energy (J) of positions x and velocities v,
    (n, 3) (:func:`membrane_energy`).

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
    return float(energy + membrane_energy(data, x))


def membrane_energy(data: Mapping[str, np.ndarray], x: np.ndarray) -> float:
    """Elastic energy (J) of a membrane cloth's triangles and bending at positions x (n, 3); 0
    without them (docs/materials.md).

    ``data``: membrane_triangles (T, 3), membrane_rest_area (T,) (m^2), membrane_rest_inverse
    (T, 2, 2) (Dm^-1, 1/m), membrane_model ("stvk" or "neohookean"), membrane_moduli (mu,
    lambda (N/m), damping (s)); bending_stencils (B, 4), bending_weights (B, 4) (1/m),
    bending_stiffness () (N m). Per triangle F = [x1 - x0, x2 - x0] Dm^-1 (3x2) and A psi(F):
    StVK psi = mu |E|^2 + lambda/2 (tr E)^2 with E = (F^T F - I) / 2; the stable Neo-Hookean
    psi = mu/2 (|F|^2 - 2) - mu (J - 1) + (lambda + mu)/2 (J - 1)^2 with J = |f0 x f1|. Bending
    stores D/2 |sum_k w_k x_k|^2 per interior edge.
    """
    energy = 0.0
    if "membrane_triangles" in data:
        tri = np.asarray(data["membrane_triangles"], int)
        edges = np.stack([x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]]], axis=2)  # (T, 3, 2)
        f = edges @ np.asarray(data["membrane_rest_inverse"], float)
        mu, lam = (float(v) for v in np.asarray(data["membrane_moduli"], float)[:2])
        if str(data["membrane_model"]) == "stvk":
            green = 0.5 * (np.einsum("tki,tkj->tij", f, f) - np.eye(2))
            psi = mu * np.sum(green**2, axis=(1, 2)) + 0.5 * lam * np.trace(green, axis1=1, axis2=2) ** 2
        else:
            jac = np.linalg.norm(np.cross(f[:, :, 0], f[:, :, 1]), axis=1)
            psi = 0.5 * mu * (np.sum(f**2, axis=(1, 2)) - 2.0) - mu * (jac - 1.0) + 0.5 * (lam + mu) * (jac - 1.0) ** 2
        energy += float(np.sum(np.asarray(data["membrane_rest_area"], float) * psi))
    if "hinge_vertices" in data:
        energy += hinge_energy(data, x)
    if "bending_stencils" in data:
        curvature = np.einsum("bk,bkj->bj", np.asarray(data["bending_weights"], float),
                              x[np.asarray(data["bending_stencils"], int)])
        energy += 0.5 * float(data["bending_stiffness"]) * float(np.sum(curvature**2))
    return energy


def hinge_energy(data: Mapping[str, np.ndarray], x: np.ndarray) -> float:
    """The hinge bending's energy (J) at positions x (n, 3): hinge_vertices (H, 4) (the edge x0
    x1, the opposite vertices x2 x3), hinge_rest_angle (H,) (rad), bending_elements (E, 3) hinge
    ids (-1: none), bending_moduli (E, 3, 3) (N m). Each hinge's theta is the angle from the
    normal of (x0, x1, x2) to that of (x0, x3, x1) about x1 - x0; an element stores
    (1/2) d^T Q d, d its hinges' theta - theta_rest wrapped into (-pi, pi]."""
    p = x[np.asarray(data["hinge_vertices"], int)]
    e = p[:, 1] - p[:, 0]
    n1 = np.cross(e, p[:, 2] - p[:, 0])
    n2 = np.cross(p[:, 3] - p[:, 0], e)
    sine = np.einsum("hi,hi->h", np.cross(n1, n2), e) / np.linalg.norm(e, axis=1)
    d = np.arctan2(sine, np.einsum("hi,hi->h", n1, n2)) - np.asarray(data["hinge_rest_angle"], float)
    d = np.append((d + np.pi) % (2 * np.pi) - np.pi, 0.0)  # a last 0 for the missing hinges (-1)
    per = d[np.asarray(data["bending_elements"], int)]
    return 0.5 * float(np.einsum("ei,eij,ej->", per, np.asarray(data["bending_moduli"], float), per))


def solve_reference(data: Mapping[str, np.ndarray], t_end: float, *, rtol: float = 1e-12,
                    atol: float = 1e-12, method: str = "DOP853") -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities at ``t_end`` from (x0, v0), by scipy's ``method``.

    Uses scipy (a dependency of the package).
    """
    from scipy.integrate import solve_ivp

    n = len(data["mass"])
    y0 = np.concatenate([np.asarray(data["x0"], float).ravel(), np.asarray(data["v0"], float).ravel()])
    sol = solve_ivp(particle_rhs(data), (0.0, t_end), y0, method=method, rtol=rtol, atol=atol)
    if not sol.success:
        raise RuntimeError(f"reference solve failed: {sol.message}")
    y = sol.y[:, -1]
    return y[: 3 * n].reshape(n, 3), y[3 * n:].reshape(n, 3)
