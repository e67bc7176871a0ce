"""The precision study: every method on a stiff and a soft cloth, in f32 and in f64, from the
same start for the same simulated time. It reports how far the f32 run ends from the f64 one
(largest particle distance, and that distance over the cloth's size), each run's status and
its solver residual (:mod:`taichi_sim.convergence`: the worst relative residual of the
equation a solving method claims to solve, NaN for explicit methods).

A finding is an f32 run that ends more than ``DISAGREE`` (relative to the cloth's size) from
the f64 run of the same method while both say ``ok``: single precision changed the answer and
nothing said so. Both runs use the same method and step, so the distance is what rounding
does, not the method's truncation error.
"""
from __future__ import annotations

import math

import numpy as np

from ..scene.cloth import fixed_particle_cloth

STUDY_VERSION = 1
DISAGREE = 1e-3  # relative to the cloth's size: a millimetre on a metre of cloth
SIZE = 8
SCENES = {  # label -> (structural stiffness N/m, step s)
    "stiff": (1e4, 2.5e-4),  # omega_max <= 3.7e3 rad/s: inside every explicit method's limit
    "soft": (10.0, 1e-3),
}
T_END = 0.25
QUICK_T_END = 0.02


def study():
    from .sweep import Study

    return Study("precision", STUDY_VERSION)


def cloth_params(k: float) -> dict:
    # 0.01 kg and 0.005 N s/m a particle, the study's cloth since before the grid's mass became per area
    return {"nx": SIZE, "ny": SIZE, "stiffness": k, "shear_stiffness": k / 2, "flex_stiffness": k / 5,
            **fixed_particle_cloth(SIZE, SIZE)}


def plan_cases(integrators: list[str], scenes: list[str], t_end: float):
    """One case per (scene, method): its f64 and f32 runs in one fresh process, one after the
    other (the f32 run is compared with the f64 one)."""
    from .sweep import Case

    return [Case("taichi_sim.bench.precision:run_case",
                 {"scene": label, "k": SCENES[label][0], "dt": SCENES[label][1], "integrator": name,
                  "t_end": t_end}, {"scene": label, "integrator": name})
            for label in scenes for name in integrators]


def _one_run(precision: str, k: float, dt: float, integrator: str, t_end: float) -> tuple[dict, np.ndarray | None]:
    import taichi_sim as ts

    from .. import runtime
    from ..errors import ConfigError

    runtime.init(arch="cpu", precision=precision)
    scene = ts.build_scene("cloth", cloth_params(k))
    row = {"precision": precision, "k": k, "dt": dt}
    try:
        result = ts.run(scene, integrator, dt=dt, t_end=t_end, energy_every=0)
    except ConfigError as exc:  # an exact method refusing f32 on a stiff cloth says so up front
        row.update(status="refused", message=str(exc).splitlines()[0][:300])
        return row, None
    x = np.asarray(scene.state.to_numpy()[0], float)
    row.update(status=result.status.value, steps=result.steps, t=result.t, message=result.message[:300],
               worst_residual=result.worst_residual, max_residual=result.max_residual,
               residual_note=result.residual_note)
    return row, x if np.isfinite(x).all() else None


def run_case(scene: str, k: float, dt: float, integrator: str, t_end: float) -> list[dict]:
    """The f64 row and the f32 row (module docstring); the f32 row says how far it ended from
    the f64 one and whether that is a finding."""
    row64, x64 = _one_run("f64", k, dt, integrator, t_end)
    row32, x32 = _one_run("f32", k, dt, integrator, t_end)
    return [row64, compare(row64, row32, x64, x32)]


def compare(row64: dict, row32: dict, x64: np.ndarray | None, x32: np.ndarray | None,
            disagree: float = DISAGREE) -> dict:
    """``row32`` with the largest distance (m) of its final positions (n, 3) from the f64
    run's, that over the cloth's size, and a ``finding`` when both runs say ok yet the
    relative distance exceeds ``disagree``. None positions: a run that ended without a
    finite state (nothing to compare)."""
    row32 = dict(row32)
    if x64 is None or x32 is None:
        return row32
    size = max(float(np.linalg.norm(np.ptp(x64, axis=0))), 1e-9)
    distance = float(np.linalg.norm(x32 - x64, axis=1).max())
    row32.update(f32_vs_f64_m=distance, f32_vs_f64_rel=distance / size)
    if row32["status"] == "ok" and row64["status"] == "ok" and distance / size > disagree:
        row32["finding"] = f"f32 ends {distance:.3g} m ({distance / size:.2%} of the cloth) from f64 and says ok"
    return row32


def findings(rows: list[dict]) -> list[dict]:
    return [r for r in rows if isinstance(r.get("finding"), str) and r["finding"]]


def summary_rows(rows: list[dict]) -> list[list]:
    """The summary table: per scene and method, the two statuses, the distance and residuals."""
    pairs: dict[tuple, dict] = {}
    for r in rows:
        pairs.setdefault((r["scene"], r["integrator"]), {})[r.get("precision") or "?"] = r
    table = []
    for (scene, name), pair in pairs.items():
        r64, r32 = pair.get("f64", {}), pair.get("f32", {})
        rel = r32.get("f32_vs_f64_rel")
        table.append([scene, name, r64.get("status"), r32.get("status"),
                      None if rel is None or (isinstance(rel, float) and math.isnan(rel)) else f"{rel:.2e}",
                      r64.get("worst_residual"), r32.get("worst_residual"),
                      "FINDING" if r32.get("finding") else ""])
    return table
