"""``taichi-sim advise``: the predicted stability limit of every integrator on a scene and, for a
target error, the cheapest (integrator, step) expected to meet it.

Stability: h_max = C / omega_max (:mod:`.theory`), with omega_max from power iteration on the
scene's linearised stiffness at its initial positions (the sharp value; the Gershgorin bound,
which ``simulate`` uses for its warning, is shown too); for symplectic Euler and the explicit
Runge-Kutta methods shortened by the dashpots' and drag's damping rate gamma_max (power
iteration too) where that is strong enough to matter (:func:`~taichi_sim.theory.damped_step_limit`). Explicit Euler, trapezoid and midpoint
have no limit on an undamped oscillation (they grow at every step); for them the table gives
the step at which the fastest mode's energy doubles over the run (``--t-end``).

Target error (the largest position error, m, at ``--t-end``): for each fixed-step method a
short pilot run of the scene itself at a step h1 (the scene's default step, at most half the
stability limit) and at h1 / 2, over T_p = min(T, 200 h1), gives by Richardson extrapolation the
error of the finer run, e ~ |x(h1) - x(h1/2)| / (2^p - 1) with p the declared order, and an
error constant K = e / ((h1/2)^p T_p), assuming the error grows linearly in time (phase error of
oscillations; collisions, tearing and chaotic motion grow faster, so treat the advice as a
starting point and check it with a run at half the step). The step meeting the target is
h* = (E / (K T))^(1/p), capped at 0.9 of the stability limit; when h* is more than twice or
less than half of h1 the pilot is repeated at h1 = h* (up to three rounds), because the
asymptotic rate need not hold that far from where it was measured. The cost is T / h* steps times the
f evaluations (plus linear-solver iterations) per step and the wall time per step of a short
probe run (10 steps) at h* itself (an implicit method works harder at larger steps). Adaptive methods are not ranked (their step follows ``--rtol``).

Then :func:`check` runs the best-ranked choices against a reference run (RK4 at a quarter of
its stable step), since Richardson cannot see an error that does not move with the step.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..integrators.base import elastic_models
from ..theory import (
    damped_step_limit,
    horizon_limit,
    omega_max_bound,
    omega_max_power,
    scene_damping_rate,
    stability_constant,
)

PILOT_STEPS = 200
PILOT_ROUNDS = 3
CHECKED = 3  # recommendations, best first, run against a reference until one meets the target
CHECK_FACTOR = 2.0  # a checked run may miss the target by this factor and still pass
REFERENCE = "rk4"  # the reference run's method, at REFERENCE_FRACTION of its stable step
REFERENCE_FRACTION = 0.25
REFERENCE_MAX_STEPS = 200_000  # beyond this many steps (at half that step) the check is skipped
PROBE_STEPS = 10  # steps at the chosen step size that measure its cost per step
SAFETY = 0.9


def scene_omegas(scene, *, power_iterations: int = 300) -> dict:
    """omega_max of a built scene: power iteration (sharp) and the Gershgorin bound."""
    from ..theory import is_circle

    if is_circle(scene):
        return {"omega_max": 1.0, "omega_bound": 1.0, "method": "exact (circle ODE)"}
    if not scene.system.second_order:
        return {"omega_max": None, "omega_bound": None, "method": "unknown system"}
    if getattr(scene, "constraints", None) is not None:
        # the spring model's omega_max says nothing of constraint forces and their feedback
        return {"omega_max": None, "omega_bound": None, "method": "not predicted with constraint forces"}
    if elastic_models(scene.system):
        # the same spring model knows nothing of a membrane's or its bending's stiffness
        return {"omega_max": None, "omega_bound": None, "method": "not predicted for a membrane (material=...)"}
    arrays = scene.arrays
    omega, info = omega_max_power(arrays, scene.x0, max_iterations=power_iterations, tol=1e-10)
    return {"omega_max": omega, "omega_bound": omega_max_bound(arrays),
            "gamma_max": scene_damping_rate(scene, "power", power_iterations),
            "gamma_bound": scene_damping_rate(scene),
            "method": f"power iteration ({info['iterations']} iterations, last relative change "
                      f"{info['change']:.1g})"}


def stability_table(scene, omegas: dict, t_end: float, names=None) -> list[dict]:
    """One row per integrator of ``names`` (default: the built-ins): order, f-evals/step and the
    predicted largest stable step, from the facts its class declares."""
    from ..integrators import INTEGRATORS, integrator_class

    omega, bound = omegas["omega_max"], omegas["omega_bound"]
    rows = []
    for name in (list(INTEGRATORS) if names is None else names):
        cls = integrator_class(name)
        row = {"integrator": name, "order": cls.order, "evals_per_step": cls.f_evals_per_step,
               "C": stability_constant(cls), "limit": None, "limit_bound": None, "note": ""}
        if cls.requires_second_order and not scene.system.second_order:
            row["note"] = "needs a particle system"
        elif getattr(scene.system, "constraints", None) is not None and not cls.takes_constraints:
            row["note"] = "needs a system without constraints"
        elif cls.adaptive:
            row["note"] = "adaptive: the step follows --rtol"
        elif row["C"] is None or omega is None:
            row["note"] = "no prediction"
        elif omega == 0:
            row.update(limit=math.inf, limit_bound=math.inf, note="nothing oscillates: no limit")
        elif math.isinf(row["C"]):
            row.update(limit=math.inf, limit_bound=math.inf, note=cls.advice_note)
        elif row["C"] == 0:
            reach = horizon_limit(cls, omega, t_end)
            row.update(limit=0.0, limit_bound=0.0, horizon_limit=reach,
                       note=f"grows at every step; energy of the fastest mode doubles over {t_end:g} s "
                            f"above h = {reach:.3g} s")
        else:
            # with the dashpots' and drag's damping where the method states its damped limit
            row.update(limit=damped_step_limit(cls, omega, omegas.get("gamma_max", 0.0)),
                       limit_bound=damped_step_limit(cls, bound, omegas.get("gamma_bound", 0.0)))
        rows.append(row)
    return rows


def _final_positions(scene, integrator, dt, t_end):
    from ..run import run

    scene.reset()
    integrator.reset()
    result = run(scene, integrator, dt=dt, t_end=t_end, energy_every=0, progress=False)
    x, _ = scene.state.to_numpy()
    return result, np.asarray(x, float)


def recommend(scene, table: list[dict], target_error: float, t_end: float,
              integrators: list[str] | None = None, progress=None) -> list[dict]:
    """Pilot runs and predicted cost of each fixed-step method for ``target_error`` (module
    docstring); sorted cheapest first, failures last."""
    from ..integrators import create_integrator, integrator_class
    from ..run import run

    rows = []
    for entry in table:
        name = entry["integrator"]
        if integrators is not None and name not in integrators:
            continue
        cls = integrator_class(name)
        if entry["note"].startswith(("needs", "adaptive", "no prediction")):
            continue
        limit = entry["limit"]
        if limit == 0.0:  # grows every step: the horizon sets the usable step
            limit = entry.get("horizon_limit") or scene.default_dt
        cap = SAFETY * limit if math.isfinite(limit) else math.inf
        h1 = min(scene.default_dt, 0.5 * limit if math.isfinite(limit) else scene.default_dt, t_end / 20)
        row = {"integrator": name, "order": cls.order}
        p = cls.order
        try:
            integrator = create_integrator(name, scene.system)
            for _ in range(PILOT_ROUNDS):
                # Richardson at (h1, h1/2) over a short horizon; again at the new step when the
                # prediction moved far from where it was measured (the asymptotic rate may not
                # hold that far).
                t_pilot = min(t_end, PILOT_STEPS * h1)
                coarse, x1 = _final_positions(scene, integrator, h1, t_pilot)
                fine, x2 = _final_positions(scene, integrator, h1 / 2, t_pilot)
                if coarse.status.value != "ok" or fine.status.value != "ok" or not np.isfinite(x1).all():
                    break
                error = float(np.linalg.norm(x1 - x2, axis=1).max()) / (2**p - 1)
                constant = error / ((h1 / 2) ** p * t_pilot)
                h = (target_error / (constant * t_end)) ** (1 / p) if constant > 0 else math.inf
                h = min(h, cap, t_end)
                if 0.5 <= h / h1 <= 2.0 or h == cap:
                    break
                h1 = min(h, 0.5 * cap) if math.isfinite(cap) else h
        except Exception as exc:
            rows.append({**row, "status": "error", "note": f"{type(exc).__name__}: {exc}".splitlines()[0][:200]})
            continue
        finally:
            if progress is not None:
                progress.update(1)
        row.update(pilot_h=h1, pilot_t=t_pilot)
        if coarse.status.value != "ok" or fine.status.value != "ok" or not np.isfinite(x1).all():
            rows.append({**row, "status": "failed", "note": fine.message or coarse.message})
            continue
        steps = math.ceil(t_end / h - 1e-9)
        # Cost per step at h itself (an implicit method's Newton and CG work grows with h).
        probe_steps = min(steps, PROBE_STEPS)
        try:
            scene.reset()
            integrator.reset()
            start = time.perf_counter()
            probe = run(scene, integrator, dt=h, steps=probe_steps, energy_every=0, progress=False)
            wall = time.perf_counter() - start
        except Exception as exc:
            rows.append({**row, "status": "error", "note": f"{type(exc).__name__}: {exc}".splitlines()[0][:200]})
            continue
        if probe.status.value != "ok":
            rows.append({**row, "status": "failed", "h": h, "note": probe.message})
            continue
        per_step = (probe.f_evals + probe.linear_iterations) / max(probe.steps, 1)
        # A fixed-work method that leaves its step unsolved at h (its residual above the bound)
        # can be far from the answer in a way Richardson cannot see: ranked after the rest.
        converged = not probe.warnings
        if not converged:
            row["note"] = (f"its step is not solved at this step size (solver residual "
                           f"{probe.worst_residual:.2g}): the error estimate may understate its error")
        rows.append({**row, "status": "ok", "error_constant": constant, "h": h, "steps": steps,
                     "residual": probe.worst_residual, "converged": converged,
                     "limited_by": "stability" if h == cap else ("t_end" if h == t_end else "accuracy"),
                     "cost_per_step": per_step, "cost": steps * per_step,
                     "wall_s": steps * wall / max(probe.steps, 1),
                     "predicted_error": constant * h**p * t_end})
    rows.sort(key=_rank)
    return rows


def _rank(row: dict):
    """Cheapest first among the converged, then the unconverged, then failures."""
    return row["status"] != "ok", row.get("converged") is False, row.get("cost", math.inf)


def check(scene, table: list[dict], rows: list[dict], target_error: float, t_end: float) -> str:
    """Run the best-ranked recommendations at their steps to ``t_end`` against a reference and
    mark a row whose largest position error exceeds CHECK_FACTOR x ``target_error`` as failed
    (rows re-sorted in place); stop at the first that passes, after at most CHECKED. Returns a
    line saying what was checked, or why nothing was.

    Richardson sees only how a method's answer moves with its step. A method that has not
    converged for a reason of its own (projective dynamics with a fixed iteration count on a
    stiff cloth hardly moves it, at 1/60 s or 1/300 s alike) looks converged to it: on
    ``cloth-stiff`` (k = 1e6) it predicted 0.01 m at 3.2 ms where the error was 0.66 m. The
    reference is RK4 at REFERENCE_FRACTION of its stable step and at half that, whose
    difference estimates its own error (order 4): when that exceeds half the target, or the
    finer run would take over REFERENCE_MAX_STEPS steps, nothing is checked."""
    from ..integrators import create_integrator

    entry = next((r for r in table if r["integrator"] == REFERENCE), None)
    limit = None if entry is None else entry["limit"]
    if not limit or not math.isfinite(limit):
        return f"not checked against a reference run: {REFERENCE} has no stable step on this scene"
    steps = math.ceil(t_end / (REFERENCE_FRACTION * limit))
    if 2 * steps > REFERENCE_MAX_STEPS:
        return (f"not checked against a reference run: {REFERENCE} would need {2 * steps} steps "
                f"(at most {REFERENCE_MAX_STEPS})")
    reference = create_integrator(REFERENCE, scene.system)
    first, x_ref = _final_positions(scene, reference, t_end / steps, t_end)
    second, x_half = _final_positions(scene, reference, t_end / (2 * steps), t_end)
    if first.status.value != "ok" or second.status.value != "ok":
        return f"not checked against a reference run: {REFERENCE} did not finish it"
    reference_error = float(np.linalg.norm(x_ref - x_half, axis=1).max()) / (2 ** 4 - 1)
    if reference_error > 0.5 * target_error:
        return (f"not checked against a reference run: {REFERENCE} at {t_end / (2 * steps):.3g} s is "
                f"itself about {reference_error:.2g} m off, too close to the target")
    checked = []
    for row in [r for r in rows if r["status"] == "ok"][:CHECKED]:
        result, x = _final_positions(scene, create_integrator(row["integrator"], scene.system), row["h"], t_end)
        error = float(np.linalg.norm(x - x_half, axis=1).max()) if result.status.value == "ok" else math.inf
        row["checked_error"] = error
        checked.append(f"{row['integrator']} {error:.2g} m")
        if error <= CHECK_FACTOR * target_error:
            break
        row.update(status="failed", note=f"checked against the reference run: its error at this step is "
                                         f"{error:.2g} m, {error / target_error:.3g} x the target (the pilot's "
                                         f"Richardson estimate understated it)")
    rows.sort(key=_rank)
    return (f"checked against {REFERENCE} at {t_end / (2 * steps):.3g} s ({2 * steps} steps; "
            f"its own error about {reference_error:.2g} m): " + ", ".join(checked))
