"""The largest stable step of each integrator, found by bisection, against C / omega_max.

Systems (undamped: no gravity, drag or dashpots, so that theory's imaginary-axis limit is the
whole story), each swept over decades of stiffness by changing the springs' stiffness in place
(one scene and one integrator per system and method: nothing recompiles):

* ``oscillator``: the ``spring`` scene with gravity off, a pure harmonic oscillator,
  omega = sqrt(k / m) exactly (it moves along the spring only, so the force stays linear),
  started 1e-6 of the rest length from rest;
* ``chain``: the ``pendulum`` chain (first particle pinned), straight, every free particle
  displaced by seeded noise of 1e-6 of a segment;
* ``cloth``: a small ``cloth`` (corners pinned; shear and flex stiffness k/2 and k/5), every free
  particle displaced by seeded noise of 1e-6 of the grid spacing.

omega_max comes from power iteration on the linearised stiffness (:mod:`.theory`), checked
against scipy's Lanczos where scipy is installed; the Gershgorin bound is reported too.

A step h is *stable* when every state over ``periods`` periods of the fastest mode
(T = periods 2 pi / omega_max, at least 100 steps) is finite, every step reports OK, and the
energy never exceeds twice its *early maximum*, the largest energy over the first tenth of the
steps (at least 20; sampled every step there, then at least 1000 times), nor 1e4 times its
start. Two departures from the literal "never above twice its start", both needed to measure
the limits theory predicts:

* a symplectic method's energy oscillates about a conserved modified energy; for symplectic
  Euler the ratio of largest to smallest is (1 + theta/2) / (1 - theta/2), which passes 2 at
  theta = 1, half its limit of 2. Over the first tenth every mode has shown its full swing
  (sampled finely enough to catch its peak), so growth beyond it is real instability;
* the 1e4 cap catches fast growth that the early maximum would absorb: the perturbations are
  tiny (1e-6 of a rest length), so an unstable run is still growing exponentially, in the
  linear regime, when it passes the cap, instead of saturating early in nonlinear, bounded but
  meaningless motion (a cloth perturbed by 1e-3 saturates near 3000x its start energy); and a
  stable symplectic Euler run passes it only within 1e-4 of its limit.

The search starts at C / omega_max (or 0.01 / omega_max for methods with C = 0), doubles or
halves to bracket the limit, then bisects geometrically until the bracket is narrower than
``rel_tol``; the reported limit (``measured``) is the largest step found stable, and
``unstable_above`` the smallest step found unstable above it: the true limit lies between. A method stable at
h = 1000 / omega_max (checked over at least 200 steps) is reported *unconditional*; A-stable
methods (implicit) are tried only at h omega_max = 1000, 100, 10, and the largest that passes
is reported as a *solver limit* (what fails there is the nonlinear solve, e.g. Newton reporting
NOT_CONVERGED, not the method's linear stability). A method
still unstable when the horizon needs more than ``max_steps`` steps is reported *none*: on the
imaginary axis explicit Euler, trapezoid and midpoint grow at every step size
(|R(i theta)| > 1), so what a bisection finds for them, when the horizon allows it, is the step
at which the growth over the horizon reaches 2 (reported as kind *horizon* and compared with
:func:`theory.horizon_limit` over the last 90 % of the horizon), which depends on the horizon
and is not a stability limit. Adaptive methods are not bisected (their step follows rtol).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..scene.cloth import FIXED_PARTICLE_MASS, KIND_RATIOS, kind_stiffness, per_particle
from ..theory import horizon_limit, omega_max_bound, omega_max_eigsh, omega_max_power, stability_constant


@dataclass(frozen=True)
class StabilitySystem:
    name: str
    scene: str
    params: dict
    stiffnesses: tuple[float, ...]
    kind_factors: tuple[float, float, float] = (1.0, 1.0, 1.0)  # structural, shear, flex
    noise: float = 0.0  # seeded displacement, as a fraction of the smallest rest length
    description: str = ""


UNDAMPED = {"gravity": 0.0, "drag": 0.0, "damping": 0.0}
# the grid cloth's drag is per area: per_particle gives it (0) with the particles' 0.01 kg
CLOTH_UNDAMPED = {"gravity": 0.0, "damping": 0.0}
SYSTEMS = {
    "oscillator": StabilitySystem("oscillator", "spring", {**UNDAMPED, "particle_mass": 1.0, "stretch": 1e-6},
                                  (1.0, 10.0, 100.0, 1e3, 1e4),
                                  description="one spring, gravity off: omega = sqrt(k/m)"),
    "chain": StabilitySystem("chain", "pendulum", {**UNDAMPED, "particle_count": 5, "particle_mass": 0.1},
                             (10.0, 100.0, 1e3, 1e4, 1e5), noise=1e-6,
                             description="5-particle chain, top pinned, perturbed"),
    "cloth": StabilitySystem("cloth", "cloth", {**CLOTH_UNDAMPED, "nx": 6, "ny": 6, **per_particle(6, 6, FIXED_PARTICLE_MASS)},
                             (10.0, 100.0, 1e3, 1e4),
                             kind_factors=KIND_RATIOS, noise=1e-6,
                             description="6x6 cloth, corners pinned, perturbed"),
}
QUICK_SYSTEMS = {
    "oscillator": StabilitySystem("oscillator", "spring", {**UNDAMPED, "particle_mass": 1.0, "stretch": 1e-6},
                                  (1.0, 100.0),
                                  description=SYSTEMS["oscillator"].description),
    "chain": StabilitySystem("chain", "pendulum", {**UNDAMPED, "particle_count": 3, "particle_mass": 0.1},
                             (1e3,), noise=1e-6, description="3-particle chain, top pinned, perturbed"),
    "cloth": StabilitySystem("cloth", "cloth", {**CLOTH_UNDAMPED, "nx": 3, "ny": 3, **per_particle(3, 3, FIXED_PARTICLE_MASS)},
                             (100.0,),
                             kind_factors=KIND_RATIOS, noise=1e-6,
                             description="3x3 cloth, corners pinned, perturbed"),
}

UNCONDITIONAL_THETA = 1000.0  # h omega_max tried before calling a method unconditionally stable
A_STABLE_LADDER = (1000.0, 100.0, 10.0)  # h omega_max tried, largest first, for A-stable methods
MIN_STEPS = 100
UNCONDITIONAL_STEPS = 200
GROWTH_CAP = 1e4  # energy this many times its start is unstable, whatever the early maximum
GROWTH_SPAN = 0.9  # the part of the horizon after the early window, over which growth is judged


@dataclass
class Trial:
    h: float
    stable: bool
    steps: int
    reason: str


class EnergyJudge:
    """The observer that judges a trial's energy after its steps (module docstring): it
    samples every step over the first tenth of the ``steps`` (at least 20), then at least 1000
    times, and stops the Stepper at the first sample that is not finite or has grown past its
    bounds (``reason``, at ``step``)."""

    def __init__(self, scene, steps: int):
        self.scene, self.steps = scene, steps
        self.window = max(20, steps // 10)
        self.stride = max(1, steps // 1000)
        self.start = self.reference = scene.energy()
        self.reason, self.step = "", 0

    def after_step(self, stepper, report) -> None:
        s = stepper.steps
        if not (s <= self.window or s % self.stride == 0 or s == self.steps):
            return
        energy = self.scene.energy()
        if not math.isfinite(energy):
            reason = f"energy not finite at step {s}"
        elif energy > GROWTH_CAP * self.start:
            reason = f"energy {energy / self.start:.3g}x its start at step {s}"
        elif s <= self.window:
            self.reference = max(self.reference, energy)
            return
        elif energy > 2.0 * self.reference:
            reason = f"energy {energy / self.reference:.3g}x its early maximum at step {s}"
        else:
            return
        self.reason, self.step = reason, s
        stepper.stop()


def is_stable(scene, integrator, h: float, horizon: float, *, min_steps: int = MIN_STEPS) -> Trial:
    """Run ``scene`` from its initial state for ``horizon`` s (at least ``min_steps`` steps) with
    step ``h`` and judge stability (module docstring). The steps are a bare
    :class:`~taichi_sim.stepper.Stepper`'s: the method as it is, no guard, no convergence
    sampling."""
    from ..stepper import Stepper

    scene.reset()
    n = max(min_steps, math.ceil(horizon / h - 1e-9))
    judge = EnergyJudge(scene, n)
    stepper = Stepper(scene, integrator, h, observers=(judge,), bare=True)  # (resets the integrator)
    stepper.run_until(steps=n)
    failure = stepper.failure
    if failure is not None:
        detail = f" ({failure.detail})" if failure.detail else ""
        return Trial(h, False, failure.step, f"{failure.status.value} at step {failure.step}{detail}")
    if judge.reason:
        return Trial(h, False, judge.step, judge.reason)
    return Trial(h, True, n, "")


def find_limit(stable: Callable[[float], Trial], guess: float, *, h_min: float, h_max: float,
               rel_tol: float) -> tuple[str, float, list[Trial]]:
    """Bisection for the largest stable step (module docstring). Returns (kind, h, trials) with
    kind ``"limit"`` (h: the largest stable step found), ``"unconditional"`` (stable at h_max)
    or ``"none"`` (unstable down to h_min; h: the smallest step tried)."""
    trials: list[Trial] = []

    def check(h):
        trial = stable(h)
        trials.append(trial)
        return trial.stable

    lo = hi = None
    h = min(max(guess, h_min), h_max)
    if check(h):
        lo = h
        while hi is None:
            if lo >= h_max:
                return "unconditional", lo, trials
            h = min(2 * lo, h_max)
            if check(h):
                lo = h
            else:
                hi = h
    else:
        hi = h
        while lo is None:
            if hi <= h_min:
                return "none", hi, trials
            h = max(hi / 2, h_min)
            if check(h):
                lo = h
            else:
                hi = h
    while hi / lo > 1 + rel_tol:
        mid = math.sqrt(lo * hi)
        if check(mid):
            lo = mid
        else:
            hi = mid
    return "limit", lo, trials


def perturbed_start(scene, noise: float, seed: int = 0) -> None:
    """Displace every free particle of ``scene`` by seeded noise of ``noise`` times the
    shortest rest length (scene.reset() then starts there)."""
    if noise <= 0:
        return
    arrays = scene.arrays
    scale = float(np.min(arrays["rest_length"])) if "rest_length" in arrays else 1.0
    free = ~np.asarray(arrays["pinned"], bool)
    rng = np.random.default_rng(seed)
    scene.x0 = scene.x0 + noise * scale * rng.standard_normal(scene.x0.shape) * free[:, None]
    scene.reset()


def set_stiffness(scene, system: StabilitySystem, k: float) -> np.ndarray:
    """Set every spring's stiffness to k times its kind's factor; returns the new stiffness."""
    springs = scene.springs
    stiffness = k * kind_stiffness(springs.kind_np, system.kind_factors)
    springs.set_parameters(stiffness=stiffness)
    return stiffness


def run_stability(systems: dict[str, StabilitySystem], integrators: list[str], *, periods: float,
                  rel_tol: float, max_steps: int, progress=None) -> tuple[list[dict], dict]:
    """Measure every (system, stiffness, integrator) (Taichi must be initialised; f64)."""
    from ..integrators import create_integrator, integrator_class
    from ..scene import build_scene

    rows: list[dict] = []
    details: dict = {"systems": {}, "periods": periods, "rel_tol": rel_tol, "max_steps": max_steps}
    for system in systems.values():
        try:
            scene = build_scene(system.scene, system.params)
        except Exception as exc:  # record it, measure the other systems
            note = f"{type(exc).__name__}: {exc}".strip().splitlines()[0][:300]
            details["systems"][system.name] = {"scene": system.scene, "error": note,
                                               "description": system.description}
            for k in system.stiffnesses:
                for name in integrators:
                    rows.append({"system": system.name, "stiffness": k, "integrator": name, "kind": "error",
                                 "note": note})
                    if progress is not None:
                        progress.update(1)
            continue
        rest_x0 = scene.x0.copy()
        perturbed_start(scene, system.noise)
        details["systems"][system.name] = system_info(system)
        made: dict[str, object] = {}
        for k in system.stiffnesses:
            set_stiffness(scene, system, k)
            arrays = scene.arrays
            omega, info = omega_max_power(arrays, rest_x0)
            omega_bound = omega_max_bound(arrays)
            omega_lanczos = omega_max_eigsh(arrays, rest_x0)
            omega_exact = math.sqrt(k / system.params["particle_mass"]) if system.name == "oscillator" else None
            horizon = periods * 2 * math.pi / omega
            for name in integrators:
                cls = integrator_class(name)
                c = stability_constant(name)
                row = {"system": system.name, "stiffness": k, "omega_max": omega, "omega_bound": omega_bound,
                       "omega_lanczos": omega_lanczos, "omega_exact": omega_exact,
                       "power_iterations": info["iterations"], "integrator": name, "C": c,
                       "predicted": (c / omega) if c is not None and math.isfinite(c) else
                       (math.inf if c is not None else None),
                       "predicted_bound": (c / omega_bound) if c is not None and math.isfinite(c) else None}
                if cls.adaptive or c is None:
                    rows.append({**row, "kind": "n/a", "measured": None, "ratio": None, "trials": 0,
                                 "note": "adaptive: the step follows rtol" if cls.adaptive else "no theory"})
                    if progress is not None:
                        progress.update(1)
                    continue
                start = time.perf_counter()
                try:
                    if name not in made:
                        made[name] = create_integrator(name, scene.system)
                    integrator = made[name]
                    h_max = UNCONDITIONAL_THETA / omega
                    if math.isinf(c):  # A-stable: a ladder of huge steps, no bisection
                        trials, kind, h = [], "none", None
                        for theta in A_STABLE_LADDER:
                            trial = is_stable(scene, integrator, theta / omega, horizon,
                                              min_steps=UNCONDITIONAL_STEPS)
                            trials.append(trial)
                            if trial.stable:
                                kind = "unconditional" if theta == A_STABLE_LADDER[0] else "solver limit"
                                h = theta / omega
                                break
                        if h is None:
                            h = A_STABLE_LADDER[-1] / omega
                    elif c > 0:
                        kind, h, trials = find_limit(lambda s: is_stable(scene, integrator, s, horizon),
                                                     c / omega, h_min=horizon / max_steps,
                                                     h_max=h_max, rel_tol=rel_tol)
                    else:  # grows at every step: what bisection finds depends on the horizon
                        reach = horizon_limit(name, omega, GROWTH_SPAN * horizon)
                        kind, h, trials = find_limit(lambda s: is_stable(scene, integrator, s, horizon),
                                                     max(reach, horizon / max_steps), h_min=horizon / max_steps,
                                                     h_max=h_max, rel_tol=rel_tol)
                        if kind == "limit":
                            kind = "horizon"
                            row["predicted"] = reach
                except Exception as exc:
                    rows.append({**row, "kind": "error", "measured": None, "ratio": None, "trials": 0,
                                 "note": f"{type(exc).__name__}: {exc}".splitlines()[0][:300]})
                    if progress is not None:
                        progress.update(1)
                    continue
                last_fail = next((t.reason for t in reversed(trials) if not t.stable), "")
                measured = h if kind in ("limit", "horizon", "unconditional", "solver limit") else None
                predicted = row["predicted"]
                ratio = (measured / predicted) if (kind in ("limit", "horizon") and predicted
                                                   and math.isfinite(predicted) and predicted > 0) else None
                note = ""
                if kind == "horizon":
                    note = (f"not a stability limit: the largest step whose energy growth over the last 90 % "
                            f"of the horizon stays below 2 (predicted from |R(i theta)|: {row['predicted']:.3g} s)")
                if kind == "none" and math.isinf(c):
                    note = f"failed at every h omega_max in {A_STABLE_LADDER}: {last_fail}"
                elif kind == "solver limit":
                    note = f"stable at h = {h:.3g} s = {h * omega:.3g} / omega_max, failed above: {last_fail}"
                elif kind == "none":
                    reach = horizon_limit(name, omega, horizon)
                    note = (f"unstable at every step down to h = {h:.3g} s (theta = {h * omega:.3g}); theory: "
                            f"grows at every step, energy doubles over the horizon above h = {reach:.3g} s"
                            if reach else f"unstable down to h = {h:.3g} s")
                elif kind == "unconditional":
                    note = f"stable at h = {h:.3g} s = {UNCONDITIONAL_THETA:g} / omega_max"
                above = [t.h for t in trials if not t.stable and measured is not None and t.h > measured]
                unstable_above = min(above) if above else None
                ratio_above = (unstable_above / predicted) if (ratio is not None and unstable_above) else None
                rows.append({**row, "kind": kind, "measured": measured, "ratio": ratio,
                             "unstable_above": unstable_above, "ratio_above": ratio_above,
                             "theta_measured": measured * omega if measured else None,
                             "smallest_tried_s": h if kind == "none" else None,
                             "trials": len(trials), "steps_at_limit": next(
                                 (t.steps for t in trials if t.stable and t.h == h), None),
                             "horizon_s": horizon, "seconds": time.perf_counter() - start,
                             "last_failure": last_fail, "note": note})
                if progress is not None:
                    progress.update(1)
    return rows, details


def system_info(system: StabilitySystem) -> dict:
    """What the JSON says about a system."""
    return {"scene": system.scene, "params": system.params, "stiffnesses": list(system.stiffnesses),
            "kind_factors": list(system.kind_factors), "noise": system.noise, "description": system.description}


STUDY_VERSION = 1  # bump when a row's meaning changes: an older table is then refused


def study():
    from .sweep import Study

    return Study("stability", STUDY_VERSION, failure_row=lambda case, status, note: {"kind": status, "note": note})


def plan_cases(systems: dict[str, StabilitySystem], integrators: list[str], *, periods: float, rel_tol: float,
               max_steps: int):
    """One case per (system, integrator): its stiffnesses share one scene and one integrator."""
    from dataclasses import asdict

    from .sweep import Case

    return [Case("taichi_sim.bench.stability:run_case",
                 {"system": {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(system).items()},
                  "integrator": name, "periods": periods, "rel_tol": rel_tol, "max_steps": max_steps},
                 {"system": system.name, "integrator": name})
            for system in systems.values() for name in integrators]


def run_case(system: dict, integrator: str, periods: float, rel_tol: float, max_steps: int) -> list[dict]:
    """One case of :func:`plan_cases`, in a fresh f64 CPU runtime."""
    from .. import runtime

    runtime.init(arch="cpu", precision="f64")
    chosen = StabilitySystem(**{k: tuple(v) if isinstance(v, list) else v for k, v in system.items()})
    rows, _ = run_stability({chosen.name: chosen}, [integrator], periods=periods, rel_tol=rel_tol,
                            max_steps=max_steps)
    return rows
