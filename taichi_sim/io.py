"""The self-describing .npz a run writes (schema documented in docs/cli.md)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .atomic import check_can_create, write_atomically
from .errors import ConfigError
from .integrators import Integrator
from .run import RunResult
from .scene.scene import Scene

SCHEMA_VERSION = 1


def check_output_path(path: str | os.PathLike, suffix: str = ".npz") -> Path:
    """Fail early (ConfigError) when ``path`` cannot be written, before any work is done."""
    path = Path(path)
    if path.suffix != suffix:
        raise ConfigError(f"output path {str(path)!r} must end in {suffix}")
    parent = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise ConfigError(f"output path {str(path)!r} is a directory")
    if not parent.is_dir():
        raise ConfigError(f"cannot write {str(path)!r}: directory {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise ConfigError(f"cannot write {str(path)!r}: permission denied")
    check_can_create(path, parent)
    return path


def run_arrays(scene: Scene, result: RunResult, *, integrator: Integrator, dt: float | None) -> dict[str, np.ndarray]:
    """Everything needed to rebuild the ODE and check the result, as numpy arrays."""
    x, v = scene.state.to_numpy()
    x0, v0 = scene.x0, scene.v0
    if v is None:
        # A first-order system has no velocity state; store dx/dt so v keeps its meaning.
        v, v0 = _first_order_velocity(scene, x), _first_order_velocity(scene, x0)
    data = {
        "schema_version": np.int64(SCHEMA_VERSION),
        "scene": np.str_(scene.name),
        "system_order": np.int64(2 if scene.system.second_order else 1),
        "x0": np.asarray(x0, np.float64), "v0": np.asarray(v0, np.float64),
        "x": np.asarray(x, np.float64), "v": np.asarray(v, np.float64),
        "t": np.float64(result.t), "steps": np.int64(result.steps),
        "accepted_steps": np.int64(result.steps), "rejected_steps": np.int64(result.rejected_steps),
        "f_evals": np.int64(result.f_evals), "integrator": np.str_(integrator.name),
        "dt": np.float64(np.nan if dt is None else dt), "status": np.str_(result.status.value),
        "message": np.str_(result.message), "seed": np.int64(scene.seed),
        "energy": result.energy, "energy_t": result.energy_t,
        "failed_step": np.int64(result.failed_step), "failed_t": np.float64(result.failed_t),
        "wall_time": np.float64(result.wall_time), "steps_per_second": np.float64(result.steps_per_second),
    }
    if result.constraint_violation is not None:
        data["constraint_violation"] = result.constraint_violation
    if integrator.equation is not None:  # a method that solves a system per step
        data["solver_residual"], data["residual_t"] = result.solver_residual, result.residual_t
        data["max_residual"] = np.float64(result.max_residual)
        data["error_estimate_m"] = result.error_estimate  # (m), at residual_t
        data["tolerance_m"] = np.float64(result.tolerance)
        data["residual_note"] = np.str_(result.residual_note)
    if result.x_history is not None:
        data["x_history"], data["t_history"] = result.x_history, result.t_history
        data.update(result.object_history)
    if scene.mesh is not None:  # the cloth's surface, as built (torn ones included)
        data["triangles"] = np.asarray(scene.mesh.triangles_np, np.int64)
    if integrator.implicit:
        data["linear_iterations"] = np.int64(result.linear_iterations)
        data["linear_residual"] = np.float64(result.linear_residual)
        data["newton_iterations"] = np.int64(integrator.stats.newton_iterations)
        data["substeps"] = np.int64(integrator.stats.substeps)
    for name, value in scene.arrays.items():
        data[name] = np.asarray(value)
    data.update(scene.object_centers(result.t))  # at the run's end (a diverged run's state)
    for name, value in scene.params.items():
        data[f"param_{name}"] = np.asarray(value)
    return data


def _first_order_velocity(scene: Scene, x: np.ndarray) -> np.ndarray:
    scratch = scene.system.make_state()
    scratch.from_numpy(x)
    out = scene.system.make_state()
    scene.system.eval_f(scratch, 0.0, out)
    return out.x.to_numpy().astype(np.float64)


def save_npz(path: str | os.PathLike, arrays: dict[str, np.ndarray]) -> Path:
    """Write ``arrays`` to ``path`` atomically (:func:`taichi_sim.atomic.write_atomically`)."""
    return write_atomically(check_output_path(path), lambda f: np.savez_compressed(f, **arrays))
