"""``taichi-sim advise``: the predicted stability limit of every integrator on a scene and, for a
target error, the cheapest (integrator, step) expected to meet it.

Stability: h_max = C / omega_max (:mod:`.theory`), with omega_max from power iteration on the
scene's linearised stiffness at its initial positions (the sharp value; the Gershgorin bound,
which ``simulate`` uses for its warning, is shown too); for symplectic Euler and the explicit
Runge-Kutta methods shortened by the dashpots' and drag's damping rate gamma_max (power
iteration too) where that is strong enough to matter (:func:`~taichi_sim.theory.damped_step_limit`). Explicit Euler, trapezoid and midpoint
have no limit on an undamped oscillation (they grow at every step); for them the table gives
the step at which the fastest mode's energy doubles over the run (``--t-end``).

Target error (the largest position error, m, at ``--t-end``): :mod:`.advise_target` measures,
for each fixed-step method, the step that reaches it and the wall time of the run at that step
on this machine, against a reference run, and ranks the methods by that time.
"""
from __future__ import annotations

import math

from ..integrators.base import elastic_models
from ..theory import (
    damped_step_limit,
    horizon_limit,
    omega_max_bound,
    omega_max_power,
    scene_damping_rate,
    stability_constant,
)


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
