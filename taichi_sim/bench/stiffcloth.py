"""The stiff-cloth study: error against wall time of the large-step methods on a cloth at
frame-sized steps, and the artificial damping each one adds.

Reference: symplectic Euler at a quarter of its stable step 2 / omega_max (omega_max bounded
from above by Gershgorin, :func:`taichi_sim.theory.omega_max_bound`), in f64. It is the right
one because it solves the same ODE as every method studied (the mass-spring model with its
dashpots, drag and gravity) and converges to its solution, with no solver tolerance in the
way; its own error is that of a step hundreds of times smaller than the studied ones (its
position error is first order in h, so about that many times smaller than a first-order
method's at the studied steps). A backward Euler reference would be biased toward the
backward Euler family (the same damping), a position-level one toward XPBD.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..integrators import method_label
from ..scene.cloth import fixed_particle_cloth, swept_stiffness

METHODS: tuple[tuple[str, dict], ...] = (
    ("implicit_euler", {}),
    ("implicit_euler_linearised", {}),
    ("projective_dynamics", {"iterations": 5}),
    ("projective_dynamics", {"iterations": 5, "chebyshev_rho": 0.9}),
    ("projective_dynamics", {"iterations": 20}),
    ("xpbd", {"substeps": 10}),
    ("xpbd", {"substeps": 50}),
    ("xpbd", {"substeps": 10, "iterations": 4}),
    ("vbd", {}),
    ("vbd", {"substeps": 5, "iterations": 4}),
)
STEPS = (1 / 60, 1 / 120, 1 / 240, 1 / 480)


def cloth_params(size: int, k: float, conservative: bool = False) -> dict:
    """A size x size cloth with structural stiffness k (N/m; shear k/2, flex k/5, the cloth
    family's ratios) and 0.01 kg, 0.005 N s/m a particle at every size (the study's cloth since
    before the grid's mass became per area); ``conservative``: no dashpots, no drag."""
    params = {"nx": size, "ny": size, **swept_stiffness(k), **fixed_particle_cloth(size, size)}
    if conservative:
        params.update(damping=0.0, area_drag=0.0)
    return params


def fresh_runtime() -> None:
    """A new Taichi runtime in the study's precision (f64): every run of the study builds a
    scene, and Taichi never frees fields; past a few hundred field trees it crashed (a
    segfault, not an error) partway through the study."""
    from .. import runtime

    runtime.init(arch="cpu", precision="f64")


def reference_solution(size: int, k: float, t_end: float,
                       params: dict | None = None) -> tuple[np.ndarray, float, float]:
    """(positions (n, 3) at t_end, the step used (s), the cloth's omega_max bound (rad/s)) of
    the reference (see the module doc), for the study's cloth or the ``cloth`` scene with
    ``params``."""
    import taichi_sim as ts

    from ..theory import omega_max_bound

    fresh_runtime()
    scene = ts.build_scene("cloth", cloth_params(size, k) if params is None else params)
    omega = omega_max_bound(scene.arrays)
    steps = math.ceil(t_end / (0.25 * 2.0 / omega))
    h = t_end / steps
    result = ts.run(scene, "symplectic_euler", dt=h, steps=steps, energy_every=0)
    if result.status.value != "ok":
        raise RuntimeError(f"reference run failed: {result.message}")
    return scene.state.to_numpy()[0].astype(float), h, omega


def timed_run(size: int, k: float, name: str, options: dict, h: float, t_end: float, *,
              conservative: bool = False) -> dict:
    """One run of ``t_end`` s at step h from a fresh scene, after an untimed two-step run
    (compilation); the state is reset before the timed run."""
    import taichi_sim as ts

    from ..integrators import create_integrator

    fresh_runtime()
    scene = ts.build_scene("cloth", cloth_params(size, k, conservative))
    integrator = create_integrator(name, scene.system, **options)
    # Warm-up through the same path (the guard's and the energy's kernels compile too).
    ts.run(scene, integrator, dt=h, steps=2, energy_every=1 if conservative else 0, raise_work=False)
    scene.reset()
    integrator.reset()
    steps = max(1, round(t_end / h))
    energy0 = scene.energy()
    start = time.perf_counter()
    # the method at the settings its label names: a tolerance does not raise them
    result = ts.run(scene, integrator, dt=h, steps=steps, energy_every=1 if conservative else 0, raise_work=False)
    wall = time.perf_counter() - start
    energy = np.asarray(result.energy) if conservative else np.zeros(0)
    return {"k": k, "h": h, "method": method_label(name, options), "integrator": name, "status": result.status.value,
            "steps": result.steps, "wall_s": wall, "ms_per_step": 1e3 * wall / max(result.steps, 1),
            "x": scene.state.to_numpy()[0].astype(float), "energy0": energy0,
            "energy_end": float(energy[-1]) if len(energy) else math.nan,
            "energy_rise": float(np.max(energy) - energy0) if len(energy) else math.nan,
            "residual": result.worst_residual, "residual_bound": result.max_residual,
            "error_estimate": result.worst_error_estimate,
            "warned": bool(result.warnings) or result.status.value == "not_converged"}


STUDY_VERSION = 3  # bump when a row's meaning changes: an older table is then refused
DAMPING_STEP, DAMPING_T = 1 / 60, 1.0


def study():
    from .sweep import Study

    return Study("stiff-cloth", STUDY_VERSION)


def plan_cases(size: int, stiffnesses, steps=STEPS, methods=METHODS, t_end: float = 0.5,
               budget_s: float = 60.0) -> tuple[list, list]:
    """(the reference cases, the cases that need them): per stiffness, the reference; per
    stiffness and method, its runs through ``steps`` (coarse to fine, in one case, since a run
    over ``budget_s`` s skips the finer ones), symplectic Euler at 0.9 of its stable step, and
    the damping run. The second list's ``inputs`` are filled by :func:`with_reference`."""
    from .sweep import Case

    references, studied = [], []
    for k in stiffnesses:
        k = float(k)
        references.append(Case("taichi_sim.bench.stiffcloth:reference_case",
                               {"size": size, "k": k, "t_end": t_end}, {"kind": "reference", "k": k}))
        plan = [(name, options, [float(h) for h in steps], None) for name, options in methods]
        plan.append(("symplectic_euler", {}, [], 0.9))
        for name, options, hs, fraction in plan:
            studied.append(Case("taichi_sim.bench.stiffcloth:accuracy_case",
                                {"size": size, "k": k, "name": name, "options": options, "steps": hs,
                                 "bound_fraction": fraction, "t_end": t_end, "budget_s": budget_s},
                                {"kind": "accuracy", "k": k, "method": method_label(name, options)}))
        for name, options in methods:
            studied.append(Case("taichi_sim.bench.stiffcloth:damping_case",
                                {"size": size, "k": k, "name": name, "options": options},
                                {"kind": "damping", "k": k, "method": method_label(name, options)}))
    return references, studied


def with_reference(case, x_ref: np.ndarray):
    """``case`` with the reference positions of its stiffness as input."""
    from dataclasses import replace

    if case.columns["kind"] != "accuracy":
        return case
    return replace(case, inputs={"x_ref": np.asarray(x_ref, float).tolist()})


def reference_case(size: int, k: float, t_end: float):
    """The reference row and its positions at ``t_end`` (array ``x``, shape (n, 3), m)."""
    x_ref, h, omega = reference_solution(size, k, t_end)
    return [{"method": "symplectic_euler", "h": h, "status": "ok", "omega_max": omega}], {"x": x_ref}


def accuracy_case(size: int, k: float, name: str, options: dict, steps: list[float], bound_fraction, t_end: float,
                  budget_s: float, x_ref: list) -> list[dict]:
    """One method's runs at ``steps`` (or at ``bound_fraction`` of its stable step 2 / omega_max),
    coarse to fine; after a run over ``budget_s`` s the finer ones are ``skipped``. Errors: rms
    and largest distance (m) of the particles from the reference at ``t_end``. Each row also has
    the run's worst relative solver residual (``residual``, :mod:`taichi_sim.convergence`; NaN for
    methods that solve nothing per step), the bound it was held to, its largest estimated error
    per step (``error_estimate``, m: :mod:`taichi_sim.convergence.distance`), and ``warned``: whether the
    run said it had not converged (a fixed-work method's warning, or status ``not_converged``),
    so the table shows whether a method far from the answer knew it."""
    import taichi_sim as ts

    from ..theory import omega_max_bound

    x_ref = np.asarray(x_ref, float)
    if bound_fraction is not None:
        fresh_runtime()
        steps = [bound_fraction * 2.0 / omega_max_bound(ts.build_scene("cloth", cloth_params(size, k)).arrays)]
    rows, over_budget = [], False
    for h in steps:
        if over_budget:
            rows.append({"h": h, "integrator": name, "status": "skipped",
                         "note": f"the coarser step took over {budget_s:g} s"})
            continue
        h_run = t_end / max(1, round(t_end / h))
        result = timed_run(size, k, name, options, h_run, t_end)
        row = {key: result[key] for key in ("h", "integrator", "status", "steps", "wall_s", "ms_per_step",
                                            "residual", "residual_bound", "error_estimate", "warned")}
        if row["status"] == "ok":
            distance = np.linalg.norm(result["x"] - x_ref, axis=1)
            row.update(error_rms=float(np.sqrt(np.mean(distance ** 2))), error_max=float(distance.max()))
        else:
            row.update(error_rms=math.nan, error_max=math.nan)
        rows.append(row)
        over_budget = row["wall_s"] > budget_s
    return rows


def damping_case(size: int, k: float, name: str, options: dict) -> list[dict]:
    """The energy a method loses on the conservative cloth (no dashpots, no drag) in
    ``DAMPING_T`` s at ``DAMPING_STEP``: its artificial damping."""
    row = timed_run(size, k, name, options, DAMPING_STEP, DAMPING_T, conservative=True)
    return [{"integrator": name, "status": row["status"], "energy0": row["energy0"], "energy_end": row["energy_end"],
             "energy_lost_per_s": (row["energy0"] - row["energy_end"]) / DAMPING_T,
             "fraction_lost_per_s": (row["energy0"] - row["energy_end"]) / abs(row["energy0"]) / DAMPING_T,
             "energy_rise": row["energy_rise"], "wall_s": row["wall_s"]}]


def split_rows(rows: list[dict], size: int, t_end: float, budget_s: float) -> tuple[list[dict], dict]:
    """The table's rows as the accuracy rows and the details (references, damping) the plot
    and the JSON show."""
    references = {str(float(r["k"])): {"method": r.get("method"), "h": r.get("h"), "status": r.get("status")}
                  for r in rows if r.get("kind") == "reference"}
    return ([r for r in rows if r.get("kind") == "accuracy"],
            {"references": references, "damping": [r for r in rows if r.get("kind") == "damping"], "size": size,
             "t_end": t_end, "budget_s": budget_s, "reference_note": __doc__.split("Reference: ", 1)[1].strip()})
