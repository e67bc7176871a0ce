"""Work-precision: error against cost for every (scene, integrator), and observed orders.

For each scene (``simple``, ``spring``, ``pendulum``, a small ``cloth``) and each integrator,
the step size is swept (fixed-step methods: h = T / n for n doubling; adaptive methods: rtol =
atol over decades) and each run is compared at the end time T with the truth:

* ``simple``: the exact rotation; ``spring`` (no drag, no dashpot): the exact harmonic
  oscillator about the sagged equilibrium;
* ``pendulum`` and ``cloth``: an independent reference, scipy's DOP853 at rtol = atol = 1e-13
  on the numpy force model (:mod:`taichi_sim.reference`), cross-checked with Radau at
  rtol = atol = 1e-12; their discrepancy is reported, and errors below 10x it are left out of
  the order fits.

Metrics (at T): ``pos_error`` = max over particles of |x - x_true| (m); ``state_error`` = max
over particles of sqrt(|dx|^2 + (|dv| / omega_max)^2) (m; omega_max is the Gershgorin bound,
sqrt(k/m) for the spring: the error of an oscillator's phase and amplitude together, which,
unlike the position error alone, does not cross zero as T moves); ``energy_error`` =
|E - E_true(T)| / E_scale with E_scale = max(|E(0)|, kinetic energy of the truth at T) (the
drift for the conservative scenes); ``strain_error`` = max over springs of
|strain - strain_true|, strain = |d| / r - 1.

Cost: evaluations of f plus, for implicit methods, linear-solver iterations; and wall time:
the median of ``repeats`` runs after one warm-up run per (scene, integrator) that compiles
the kernels (one scene and one integrator are reused for every step size: a new instance
would recompile). Runs that fail (diverged, not converged) are kept, with their status.

The observed order of a fixed-step method is the least-squares slope of log(state_error)
against log(h) over the finest (up to four) runs whose error lies between the truth's floor
and a tenth of the scene's size; for an adaptive method it is minus the slope against cost.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..scene.cloth import fixed_particle_cloth
from .common import fit_slope

FIT_CEILING = 0.1  # errors above this fraction of the scene's size are pre-asymptotic
FIT_POINTS = 4


@dataclass(frozen=True)
class Problem:
    """One scene of the sweep: its parameters, end time T and step grid.

    A fixed-step method of order p runs n = base_steps * m * 2^k steps, k < levels, with
    m = 4 for p = 1, 2 for p = 2, 3 and 1 otherwise (low orders need smaller steps to reach the
    asymptotic range). Adaptive methods run at each of ``rtols`` (atol = rtol).
    """

    scene: str
    params: dict
    t_end: float
    base_steps: int
    levels: int
    rtols: tuple[float, ...]
    seed: int = 0

    def step_counts(self, order: int) -> list[int]:
        factor = 4 if order <= 1 else 2 if order <= 3 else 1
        return [self.base_steps * factor * 2**k for k in range(self.levels)]


FULL_RTOLS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
PROBLEMS = {
    "simple": Problem("simple", {}, 2 * math.pi, 16, 6, FULL_RTOLS),
    "spring": Problem("spring", {}, 1.0, 16, 6, FULL_RTOLS),
    "pendulum": Problem("pendulum", {"particle_count": 5}, 0.5, 40, 6, FULL_RTOLS),
    "cloth": Problem("cloth", {"nx": 6, "ny": 6, **fixed_particle_cloth(6, 6)}, 0.2, 64, 6,
                     FULL_RTOLS),
}
QUICK_RTOLS = (1e-4, 1e-6, 1e-8)
QUICK_PROBLEMS = {
    "simple": Problem("simple", {}, 2 * math.pi, 16, 3, QUICK_RTOLS),
    "spring": Problem("spring", {}, 1.0, 25, 4, QUICK_RTOLS),
    "pendulum": Problem("pendulum", {"particle_count": 3}, 0.2, 32, 3, QUICK_RTOLS),
    "cloth": Problem("cloth", {"nx": 3, "ny": 3, **fixed_particle_cloth(3, 3)}, 0.1, 32, 3,
                     QUICK_RTOLS),
}


@dataclass
class Truth:
    """The solution at T that runs are compared with."""

    kind: str
    x: np.ndarray
    v: np.ndarray | None
    energy: float
    energy_scale: float
    floor: float  # errors below this are the truth's own uncertainty (m)
    size: float  # the scene's size (m): errors above FIT_CEILING * size are pre-asymptotic
    omega: float  # rad/s, weighs velocity errors in state_error
    info: dict = field(default_factory=dict)


EXACT_SCENES = ("simple", "spring")  # closed-form truths; the others need scipy


def exact_or_reference(scene, t_end: float) -> Truth:
    """The truth at ``t_end`` for a freshly reset ``scene`` (see the module docstring)."""
    from ..theory import scene_omega_max

    omega = scene_omega_max(scene, "bound") or 1.0
    x0 = np.asarray(scene.x0, float)
    size = max(float(np.ptp(x0, axis=0).max()), float(np.abs(x0).max()), 1e-3)
    energy0 = scene.energy()
    if scene.name == "simple":
        c, s = math.cos(t_end), math.sin(t_end)
        x = x0 @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        return Truth("exact (rotation)", x, None, energy0, abs(energy0), 1e-14 * size, size, 1.0)
    data = dict(scene.arrays)
    data.update(x0=x0, v0=np.asarray(scene.v0, float))
    from ..reference import particle_energy

    p = scene.params
    if scene.name == "spring" and p["drag"] == 0 and p["damping"] == 0:
        k, m, g = p["stiffness"], p["particle_mass"], p["gravity"]
        w = math.sqrt(k / m)
        sag = m * g / k
        amplitude = p["stretch"] - sag
        x, v = x0.copy(), np.zeros_like(x0)
        x[1, 1] = -(p["rest_length"] + sag) - amplitude * math.cos(w * t_end)
        v[1, 1] = amplitude * w * math.sin(w * t_end)
        energy = particle_energy(data, x, v)
        return Truth("exact (harmonic oscillator)", x, v, energy, max(abs(energy0), 1e-300),
                     1e-14 * size, size, omega)
    from ..reference import solve_reference

    start = time.perf_counter()
    x, v = solve_reference(data, t_end, rtol=1e-13, atol=1e-13, method="DOP853")
    seconds = time.perf_counter() - start
    start = time.perf_counter()
    x2, v2 = solve_reference(data, t_end, rtol=1e-12, atol=1e-12, method="Radau")
    seconds2 = time.perf_counter() - start
    dx = float(np.abs(x - x2).max())
    dv = float(np.abs(v - v2).max())
    energy = particle_energy(data, x, v)
    kinetic = 0.5 * float(np.sum(np.asarray(data["mass"]) * np.sum(v * v, axis=1)))
    info = {"method": "scipy DOP853", "rtol": 1e-13, "atol": 1e-13, "seconds": seconds,
            "cross_check": {"method": "scipy Radau", "rtol": 1e-12, "atol": 1e-12, "seconds": seconds2,
                            "max_position_discrepancy": dx, "max_velocity_discrepancy": dv}}
    floor = max(10.0 * math.hypot(dx, dv / omega), 1e-14 * size)
    return Truth("reference (DOP853, checked by Radau)", x, v, energy,
                 max(abs(energy0), kinetic, 1e-300), floor, size, omega, info)


def errors_against(scene, truth: Truth) -> dict[str, float]:
    """The four error metrics of the scene's current state against ``truth``."""
    x, v = scene.state.to_numpy()
    x = np.asarray(x, float)
    dx = np.linalg.norm(x - truth.x, axis=1)
    out = {"pos_error": float(dx.max())}
    if v is not None and truth.v is not None:
        dv = np.linalg.norm(np.asarray(v, float) - truth.v, axis=1)
        out["state_error"] = float(np.sqrt(dx**2 + (dv / truth.omega) ** 2).max())
    else:
        out["state_error"] = out["pos_error"]
    energy = scene.energy()
    out["energy_error"] = abs(energy - truth.energy) / truth.energy_scale if energy is not None else math.nan
    if scene.springs is not None:
        arrays = scene.springs.arrays()
        ends, rest = arrays["springs"], arrays["rest_length"]

        def strain(p):
            return np.linalg.norm(p[ends[:, 0]] - p[ends[:, 1]], axis=1) / rest - 1.0

        out["strain_error"] = float(np.abs(strain(x) - strain(truth.x)).max())
    else:
        out["strain_error"] = math.nan
    if not math.isfinite(out["state_error"]):
        out = {k: math.nan for k in out}
    return out


def observed_order(rows: list[dict], truth: Truth, adaptive: bool) -> dict:
    """The fitted order of one (scene, integrator) (module docstring), with the points used."""
    ceiling = FIT_CEILING * truth.size
    usable = [r for r in rows if r["status"] == "ok" and truth.floor < r["state_error"] < ceiling]
    if adaptive:
        usable.sort(key=lambda r: r["cost"])
        chosen = usable[-FIT_POINTS:]
        xs = [r["cost"] for r in chosen]
    else:
        usable.sort(key=lambda r: -r["h"])
        chosen = usable[-FIT_POINTS:]
        xs = [r["h"] for r in chosen]
    if len(chosen) < 3:
        return {"observed": math.nan, "points": len(chosen), "basis": "cost" if adaptive else "h"}
    slope = fit_slope(xs, [r["state_error"] for r in chosen])
    return {"observed": -slope if adaptive else slope, "points": len(chosen),
            "basis": "cost" if adaptive else "h", "x": xs, "errors": [r["state_error"] for r in chosen]}


def _run_once(scene, integrator, *, dt, t_end):
    from ..run import run

    scene.reset()
    integrator.reset()
    return run(scene, integrator, dt=dt, t_end=t_end, energy_every=0, progress=False, raise_work=False)


def sweep_method(scene, problem: Problem, name: str, truth: Truth, *, repeats: int,
                 budget_s: float, tick=lambda: None) -> list[dict]:
    """Rows of one (scene, integrator) sweep (module docstring); ``tick()`` after each point."""
    from ..integrators import create_integrator, integrator_class

    cls = integrator_class(name)
    points: list[dict[str, Any]]
    if cls.adaptive:
        points = [{"h": math.nan, "rtol": r, "dt": None} for r in problem.rtols]
    else:
        points = [{"h": problem.t_end / n, "rtol": math.nan, "dt": problem.t_end / n}
                  for n in problem.step_counts(cls.order)]
    base = {"scene": problem.scene, "integrator": name, "order": cls.order, "adaptive": cls.adaptive,
            "implicit": cls.implicit}
    rows: list[dict] = []
    if cls.requires_second_order and not scene.system.second_order:
        for p in points:
            rows.append({**base, "h": p["h"], "rtol": p["rtol"], "status": "not applicable",
                         "message": f"{name} needs a second-order (particle) system"})
            tick()
        return rows
    spent = 0.0
    try:
        options = {"rtol": points[0]["rtol"], "atol": points[0]["rtol"]} if cls.adaptive else {}
        integrator = create_integrator(name, scene.system, **options)
        warm = _run_once(scene, integrator, dt=points[0]["dt"], t_end=problem.t_end)  # compiles
        spent += warm.wall_time
        per_step = warm.wall_time / max(warm.steps + warm.rejected_steps, 1)
    except Exception as exc:  # an integrator that cannot run here: record why, keep going
        for p in points:
            rows.append({**base, "h": p["h"], "rtol": p["rtol"], "status": "error",
                         "message": f"{type(exc).__name__}: {exc}".splitlines()[0][:300]})
            tick()
        return rows
    for p in points:
        row = {**base, "h": p["h"], "rtol": p["rtol"]}
        expected_steps = problem.t_end / p["h"] if not cls.adaptive else (warm.steps or 1)
        if spent + per_step * expected_steps * repeats > budget_s and rows:
            rows.append({**row, "status": "skipped", "message": f"over the time budget of {budget_s:g} s"})
            tick()
            continue
        if cls.adaptive:
            integrator.rtol = integrator.atol = p["rtol"]
        walls, result, metrics = [], None, None
        try:
            for k in range(repeats):
                r = _run_once(scene, integrator, dt=p["dt"], t_end=problem.t_end)
                walls.append(r.wall_time)
                if k == 0:
                    result = r
                    metrics = errors_against(scene, truth) if r.status.value == "ok" else None
                if r.status.value != "ok":
                    break
        except Exception as exc:
            rows.append({**row, "status": "error", "message": f"{type(exc).__name__}: {exc}".splitlines()[0][:300]})
            tick()
            continue
        spent += sum(walls)
        per_step = min(walls) / max(result.steps + result.rejected_steps, 1)  # compiled now: no warm-up cost
        nan_metrics = {"pos_error": math.nan, "state_error": math.nan, "energy_error": math.nan,
                       "strain_error": math.nan}
        row.update(steps=result.steps, rejected=result.rejected_steps, f_evals=result.f_evals,
                   linear_iterations=result.linear_iterations,
                   cost=result.f_evals + result.linear_iterations,
                   wall_s=float(np.median(walls)), wall_min_s=min(walls), wall_max_s=max(walls),
                   repeats=len(walls), status=result.status.value, message=result.message,
                   **(metrics or nan_metrics))
        rows.append(row)
        tick()
    return rows


def run_work_precision(problems: dict[str, Problem], integrators: list[str], *, repeats: int,
                       budget_s: float, progress=None) -> tuple[list[dict], dict]:
    """Sweep every problem with every integrator (Taichi must be initialised, f64 preferred).

    Returns (rows, details) with details = {"problems": {...}, "orders": [...]}."""
    from ..integrators import integrator_class
    from ..scene import build_scene
    from ..theory import scene_omega_max

    rows: list[dict] = []
    details: dict[str, Any] = {"problems": {}, "orders": []}

    def tick():
        if progress is not None:
            progress.update(1)

    for problem in problems.values():
        try:
            scene = build_scene(problem.scene, problem.params, seed=problem.seed)
            truth = exact_or_reference(scene, problem.t_end)
        except Exception as exc:  # record it, measure the other scenes
            note = f"{type(exc).__name__}: {exc}".strip().splitlines()[0][:300]
            details["problems"][problem.scene] = {"params": problem.params, "t_end": problem.t_end,
                                                  "truth": "unavailable", "error": note}
            for name in integrators:
                cls = integrator_class(name)
                for _ in (problem.rtols if cls.adaptive else range(problem.levels)):
                    tick()
                rows.append({"scene": problem.scene, "integrator": name, "order": cls.order,
                             "status": "error", "message": note})
            continue
        details["problems"][problem.scene] = {
            "params": problem.params, "t_end": problem.t_end, "particles": scene.particle_count,
            "springs": scene.features.get("springs", 0), "truth": truth.kind, "truth_info": truth.info,
            "error_floor": truth.floor, "size": truth.size, "omega_max_bound": scene_omega_max(scene, "bound"),
            "energy_scale": truth.energy_scale}
        for name in integrators:
            method_rows = sweep_method(scene, problem, name, truth, repeats=repeats, budget_s=budget_s, tick=tick)
            rows.extend(method_rows)
            cls = integrator_class(name)
            fit = observed_order([r for r in method_rows if "state_error" in r], truth, cls.adaptive)
            details["orders"].append({"scene": problem.scene, "integrator": name, "declared": cls.order, **fit})
    return rows, details


STUDY_VERSION = 1  # bump when a row's meaning changes: an older table is then refused
TRUTH_FIELDS = ("energy", "energy_scale", "floor", "size", "omega")  # and ``kind``, the row's ``truth``


def study():
    from .sweep import Study

    return Study("work-precision", STUDY_VERSION)


def _problem_data(problem: Problem) -> dict:
    from dataclasses import asdict

    return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(problem).items()}


def _problem(data: dict) -> Problem:
    return Problem(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


def plan_cases(problems: dict[str, Problem], integrators: list[str], *, repeats: int, budget_s: float):
    """(the truth cases, one per scene; the sweep cases, one per scene and integrator, whose
    ``inputs`` :func:`with_truth` fills from their scene's truth)."""
    from .sweep import Case

    truths = [Case("taichi_sim.bench.workprec:truth_case", {"problem": _problem_data(p)},
                   {"kind": "truth", "scene": p.scene}) for p in problems.values()]
    sweeps = [Case("taichi_sim.bench.workprec:method_case",
                   {"problem": _problem_data(p), "name": name, "repeats": repeats, "budget_s": budget_s},
                   {"kind": "run", "scene": p.scene, "integrator": name})
              for p in problems.values() for name in integrators]
    return truths, sweeps


def truth_case(problem: dict):
    """The truth of one scene: a row with its scalars and details, its positions and
    velocities as arrays ``x``, ``v`` (n, 3)."""
    from .. import runtime
    from ..scene import build_scene
    from ..theory import scene_omega_max

    runtime.init(arch="cpu", precision="f64")
    chosen = _problem(problem)
    scene = build_scene(chosen.scene, chosen.params, seed=chosen.seed)
    truth = exact_or_reference(scene, chosen.t_end)
    row = {"truth": truth.kind, **{k: getattr(truth, k) for k in TRUTH_FIELDS}, "status": "ok", "params": chosen.params,
           "t_end": chosen.t_end, "particles": scene.particle_count, "springs": scene.features.get("springs", 0),
           "truth_info": truth.info, "omega_max_bound": scene_omega_max(scene, "bound")}
    return [row], {"x": truth.x, **({"v": truth.v} if truth.v is not None else {})}


def truth_of(row: dict, arrays: dict) -> Truth:
    """The :class:`Truth` a truth case's row and arrays describe."""
    return Truth(kind=row["truth"], **{k: row[k] for k in TRUTH_FIELDS}, x=np.asarray(arrays["x"], float),
                 v=np.asarray(arrays["v"], float) if "v" in arrays else None, info=row.get("truth_info") or {})


def with_truth(case, truth: Truth):
    from dataclasses import replace

    return replace(case, inputs={"truth": {"kind": truth.kind, **{k: getattr(truth, k) for k in TRUTH_FIELDS},
                                           "x": truth.x.tolist(), "v": None if truth.v is None else truth.v.tolist()}})


def method_case(problem: dict, name: str, repeats: int, budget_s: float, truth: dict) -> list[dict]:
    """One (scene, integrator) sweep (:func:`sweep_method`) in a fresh f64 runtime."""
    from .. import runtime
    from ..scene import build_scene

    runtime.init(arch="cpu", precision="f64")
    chosen = _problem(problem)
    scene = build_scene(chosen.scene, chosen.params, seed=chosen.seed)
    known = Truth(kind=truth["kind"], **{k: truth[k] for k in TRUTH_FIELDS}, x=np.asarray(truth["x"], float),
                  v=None if truth["v"] is None else np.asarray(truth["v"], float))
    return sweep_method(scene, chosen, name, known, repeats=repeats, budget_s=budget_s)


def orders(rows: list[dict], truths: dict[str, Truth]) -> list[dict]:
    """The observed order of each (scene, integrator) of the table's run rows."""
    from ..integrators import integrator_class

    fits = []
    for scene, truth in truths.items():
        names = dict.fromkeys(r["integrator"] for r in rows if r["scene"] == scene)
        for name in names:
            cls = integrator_class(name)
            mine = [r for r in rows if r["scene"] == scene and r["integrator"] == name
                    and isinstance(r.get("state_error"), float)]
            fits.append({"scene": scene, "integrator": name, "declared": cls.order,
                         **observed_order(mine, truth, cls.adaptive)})
    return fits
