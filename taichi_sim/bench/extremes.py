"""Stability at the extremes: every integrator on stiff and soft springs at tiny and huge steps,
each run either bounded-and-``ok`` or reported, never a silent blow-up.

The matrix: integrators x spring stiffness (cloth: shear k/2, flex k/5) x step size x scenes (the
``spring``, a 10-particle ``pendulum``, a small ``cloth``, and the small cloth as a membrane,
``membrane-stvk`` and ``membrane-neohookean`` with Poisson's ratio 0.49, whose "stiffness" is the
stretch modulus E t: 1 N/m is a 1 um sheet of E = 1 MPa, 1e8 N/m one of 1e11 Pa at 1 mm, both
with bending across the interior edges, and ``membrane-shells``, the StVK one with the
shape-operator bending; docs/materials.md), each run ``steps`` accepted steps
from the scene's start (an adaptive method starts at the step size given). Every run is judged
twice: by its status, and by an *audit* that shares no code with the blow-up guard
(:mod:`taichi_sim.guard`): the numpy force model of :mod:`taichi_sim.reference` recomputes the
energy of the state the run returned, and the audit checks every recorded energy, the positions
and the spring strains against bounds ten times looser than the guard's:

* energy more than ``AUDIT_ENERGY_GROWTH`` (100) energy scales above the start, the scale being
  |E0| + kinetic + spring energy at the start + sum of m |g| L (L the scene's size, >= 1 m);
* a particle farther than ``AUDIT_REACH`` (1000) L + |g| t^2 / 2 from where the scene started;
* a spring stretched past strain ``AUDIT_STRAIN`` (100), or past 100 times the strain the
  scene's weight alone would give its softest spring (:func:`sag_strain`: a 1 N/m cloth hangs
  stretched hundreds of times its rest length without blowing up);
* a non-finite value, or a recorded final energy that the reference model does not confirm.

Outcomes: ``ok`` (status ok and the audit passes), ``reported`` (status not ok, with a message,
and a finite returned state), ``refused`` (the method does not take the scene's material and
said so before running: xpbd and projective dynamics on a membrane), ``silent`` (status ok but the audit fails: a blow-up that said
``ok``), ``error`` (an exception, or a worker process that died), ``timeout`` (the bench's case
ran past its time limit and was stopped: one row for the case's scene and integrator). The CI
suite (tests/test_extremes.py) runs a small matrix and requires no ``silent`` and no ``error``;
``taichi-sim bench extremes`` runs the full one and writes the table of outcomes.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from ..scene.cloth import KIND_RATIOS, fixed_particle_cloth, kind_stiffness

AUDIT_ENERGY_GROWTH = 100.0
AUDIT_REACH = 1000.0
AUDIT_STRAIN = 100.0

SCENES = {
    "spring": ("spring", {}),
    "pendulum": ("pendulum", {"particle_count": 10}),
    "cloth": ("cloth", {"nx": 6, "ny": 6, **fixed_particle_cloth(6, 6)}),
    "membrane-stvk": ("cloth", {"nx": 6, "ny": 6, **fixed_particle_cloth(6, 6), "material": "stvk"}),
    "membrane-neohookean": ("cloth", {"nx": 6, "ny": 6, **fixed_particle_cloth(6, 6), "material": "neohookean",
                                      "poisson_ratio": 0.49}),
    "membrane-shells": ("cloth", {"nx": 6, "ny": 6, **fixed_particle_cloth(6, 6), "material": "stvk",
                                  "bending_model": "shape_operator"}),
}
QUICK_SCENES = {
    "spring": ("spring", {}),
    "pendulum": ("pendulum", {"particle_count": 4}),
    "cloth": ("cloth", {"nx": 3, "ny": 3, **fixed_particle_cloth(3, 3)}),
    "membrane-neohookean": ("cloth", {"nx": 3, "ny": 3, **fixed_particle_cloth(3, 3), "material": "neohookean",
                                      "poisson_ratio": 0.49}),
}
STIFFNESSES = (1.0, 1e4, 1e8)
STEP_SIZES = (1e-6, 1 / 60, 1.0)
STEPS = 30


@dataclass(frozen=True)
class Verdict:
    """One run: ``outcome`` (ok, reported, refused, silent, error) and why."""

    outcome: str
    reason: str = ""


def energy_scale(arrays: dict, x: np.ndarray, v: np.ndarray) -> tuple[float, float]:
    """(E0, the energy scale (J)) of a particle scene's state, by the numpy reference model."""
    from ..reference import particle_energy

    mass = np.asarray(arrays["mass"], float)
    free = ~np.asarray(arrays["pinned"], bool)
    energy = particle_energy(arrays, x, v)
    kinetic = 0.5 * float(np.sum(mass * np.sum(v * v, axis=1)))
    springs = 0.0
    if "springs" in arrays and len(arrays["springs"]):
        ends = np.asarray(arrays["springs"], int)
        stretch = np.linalg.norm(x[ends[:, 0]] - x[ends[:, 1]], axis=1) - np.asarray(arrays["rest_length"])
        springs = 0.5 * float(np.sum(np.asarray(arrays["stiffness"]) * stretch**2))
    size = max(float(np.linalg.norm(np.ptp(x, axis=0))), 1.0)
    weight = float(np.sum(mass[free])) * float(np.linalg.norm(arrays["gravity"]))
    return energy, abs(energy) + kinetic + springs + weight * size


def audit(arrays0: dict, x0: np.ndarray, v0: np.ndarray, arrays: dict, x: np.ndarray, v: np.ndarray,
          result) -> str:
    """Why a run that reports ``ok`` is not bounded ("" when it is): see the module docstring.
    ``arrays0``, ``x0``, ``v0``: the model and state at the start; ``arrays``, ``x``, ``v``: at
    the end (springs may have torn); ``result``: the run's RunResult."""
    from ..reference import particle_energy

    if not (np.isfinite(x).all() and np.isfinite(v).all()):
        return "non-finite state"
    energy0, scale = energy_scale(arrays0, x0, v0)
    recorded = np.asarray(result.energy, float)
    if len(recorded) and not np.isfinite(recorded).all():
        return "non-finite energy recorded"
    final = particle_energy(arrays, x, v)
    if not math.isfinite(final):
        return "non-finite energy"
    if len(recorded) and abs(recorded[-1] - final) > 1e-6 * (scale + abs(final)):
        return f"recorded final energy {recorded[-1]:.6g} J, the reference model says {final:.6g} J"
    peak = max([final] + recorded.tolist())
    if peak - energy0 > AUDIT_ENERGY_GROWTH * scale:
        return f"energy rose to {peak:.3g} J from {energy0:.3g} J (scale {scale:.3g} J)"
    size = max(float(np.linalg.norm(np.ptp(x0, axis=0))), 1.0)
    center = 0.5 * (x0.min(axis=0) + x0.max(axis=0))
    reach = AUDIT_REACH * size + 0.5 * float(np.linalg.norm(arrays0["gravity"])) * result.t**2
    far = float(np.linalg.norm(x - center, axis=1).max())
    if far > reach:
        return f"a particle is {far:.3g} m from the start (bound {reach:.3g} m)"
    if "springs" in arrays and len(arrays["springs"]) and "alive" not in arrays:
        ends = np.asarray(arrays["springs"], int)
        rest = np.asarray(arrays["rest_length"], float)
        strain = np.linalg.norm(x[ends[:, 0]] - x[ends[:, 1]], axis=1) / rest - 1.0
        bound = AUDIT_STRAIN * max(1.0, sag_strain(arrays0))
        if strain.max() > bound:
            return f"a spring is stretched to strain {strain.max():.3g} (bound {bound:.3g})"
    return ""


def sag_strain(arrays: dict) -> float:
    """The strain the scene's whole weight W would give its softest, shortest spring,
    W / (k_min r_min): so soft a cloth may hang that far stretched without blowing up."""
    stiffness = np.asarray(arrays["stiffness"], float)
    live = stiffness > 0
    if not live.any():
        return 0.0
    mass = np.asarray(arrays["mass"], float)
    weight = float(np.sum(mass[~np.asarray(arrays["pinned"], bool)])) * float(np.linalg.norm(arrays["gravity"]))
    return weight / (float(stiffness[live].min()) * float(np.asarray(arrays["rest_length"], float)[live].min()))


def judge(status, message: str, problem: str, x: np.ndarray, v: np.ndarray) -> Verdict:
    """The outcome of a run from its status and the audit's ``problem`` ("" when none)."""
    if status.value == "ok":
        return Verdict("silent", problem) if problem else Verdict("ok")
    if not message:
        return Verdict("silent", f"status {status.value} without a message")
    if not (np.isfinite(x).all() and np.isfinite(v).all()):
        return Verdict("silent", f"status {status.value}, but the state returned is not finite")
    return Verdict("reported", message)


def set_stiffness(scene, k: float) -> None:
    """Every spring to its kind's share of k (N/m), or a membrane's stretch modulus E t to k
    (N/m), in place (nothing recompiles)."""
    membrane = scene.system.term("membrane")
    if membrane is not None:
        membrane.set_material(replace(membrane.material, stretch_modulus=float(k)))
        return
    springs = scene.springs
    springs.set_parameters(stiffness=k * kind_stiffness(springs.kind_np, KIND_RATIOS))


def run_extremes(scenes: dict, integrators: list[str], stiffnesses, step_sizes, *, steps: int = STEPS,
                 guard=None, progress=None) -> list[dict]:
    """Run the matrix (Taichi must be initialised); one row per run (module docstring). One
    scene and one integrator per (scene, method): stiffness changes in place, nothing recompiles.
    ``guard``: the blow-up guard's limits (default: the run's)."""
    from ..errors import ConfigError
    from ..integrators import create_integrator, integrator_class
    from ..integrators.base import elastic_models
    from ..run import run
    from ..scene import build_scene

    rows: list[dict] = []
    for label, (scene_name, params) in scenes.items():
        scene = build_scene(scene_name, params)
        for name in integrators:
            cls = integrator_class(name)
            made = None
            refusal = ""
            if elastic_models(scene.system) and not cls.takes_elastic_models:
                try:  # it must refuse, in one line, before any run
                    made = create_integrator(name, scene.system)
                except ConfigError as exc:
                    refusal = str(exc)
            for k in stiffnesses:
                set_stiffness(scene, k)
                arrays0 = scene.arrays
                for dt in step_sizes:
                    row = {"scene": label, "integrator": name, "stiffness": k, "dt": dt}
                    start = time.perf_counter()
                    if cls.requires_second_order and not scene.system.second_order:
                        if progress is not None:
                            progress.update(1)
                        continue
                    if refusal:
                        row.update(status="refused", outcome="refused", reason=refusal, seconds=0.0)
                        rows.append(row)
                        if progress is not None:
                            progress.update(1)
                        continue
                    try:
                        if made is None:
                            made = create_integrator(name, scene.system)
                        scene.reset()
                        made.reset()
                        x0, v0 = (np.asarray(a, float) for a in scene.state.to_numpy())
                        result = run(scene, made, dt=dt, steps=steps, energy_every=1, guard=guard,
                                     raise_work=False)  # each method at its defaults
                        x, v = (np.asarray(a, float) for a in scene.state.to_numpy())
                        problem = audit(arrays0, x0, v0, scene.arrays, x, v, result)
                        verdict = judge(result.status, result.message, problem, x, v)
                        row.update(status=result.status.value, steps=result.steps, t=result.t,
                                   failed_step=result.failed_step, message=result.message)
                    except Exception as exc:  # a crash is an outcome too
                        verdict = Verdict("error", f"{type(exc).__name__}: {exc}".splitlines()[0][:300])
                        row.update(status="error")
                    row.update(outcome=verdict.outcome, reason=verdict.reason,
                               seconds=time.perf_counter() - start)
                    rows.append(row)
                    if progress is not None:
                        progress.update(1)
    return rows


STUDY_VERSION = 3  # bump when a row's meaning changes: an older table is then refused


def study():
    from .sweep import Study

    return Study("extremes", STUDY_VERSION, failure_row=lambda case, status, note: {
        "status": status, "outcome": status, "reason": note})


def plan_cases(scenes: dict, integrators: list[str], stiffnesses, step_sizes, steps: int):
    """One case per (scene, integrator): its stiffness x step runs share one scene and one
    integrator (nothing recompiles between them) in one fresh process."""
    from .sweep import Case

    return [Case("taichi_sim.bench.extremes:run_case",
                 {"scene": label, "scene_name": scene_name, "scene_params": dict(params), "integrator": name,
                  "stiffnesses": [float(k) for k in stiffnesses], "step_sizes": [float(h) for h in step_sizes],
                  "steps": steps},
                 columns={"scene": label, "integrator": name})
            for label, (scene_name, params) in scenes.items() for name in integrators]


def run_case(scene: str, scene_name: str, scene_params: dict, integrator: str, stiffnesses, step_sizes,
             steps: int) -> list[dict]:
    """One case of :func:`plan_cases`, in a fresh f64 CPU runtime."""
    from .. import runtime

    runtime.init(arch="cpu", precision="f64")
    return run_extremes({scene: (scene_name, scene_params)}, [integrator], stiffnesses, step_sizes, steps=steps)


def outcome_table(rows: list[dict]) -> dict[str, dict[str, int]]:
    """integrator -> outcome -> count."""
    table: dict[str, dict[str, int]] = {}
    for row in rows:
        counts = table.setdefault(row["integrator"], {"ok": 0, "reported": 0, "refused": 0, "silent": 0,
                                                      "error": 0, "timeout": 0})
        counts[row["outcome"]] += 1
    return table
