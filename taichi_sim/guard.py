"""Blow-up detection: one guard for every path that steps a scene.

Every :class:`~taichi_sim.stepper.Stepper` watches its run with a :class:`Guard`: ``run`` (and
through it ``simulate``, ``advise`` and ``bench work-precision``), the launcher's and the
recorder's :class:`~taichi_sim.app.runner.Runner`, the throughput worker.
Besides the non-finite values the integrators report, a run has *diverged* when

* **energy**: its total energy E rose above the reference E_ref (the start, or the last time
  the system was changed from outside) by more than ``energy_growth`` times the scene's energy
  scale S plus what its sources may inject (:func:`injectable_energy`), where

      S = |E_ref| + kinetic + spring energy at the reference + sum over moving particles of
          m |g| L,   L = the scene's size (the diagonal of its bounding box, which holds
          the wires beads are constrained to), at least 1 m;

  and never below the energy the springs get from rounding alone, sum k (eps L)^2 / 2 with eps
  the precision's machine epsilon (a scene at rest with no weight and unstretched springs has
  S = 0 otherwise, and its first step's rounding read as a blow-up);

  a scene without sources cannot gain energy at all, so a rise of ten times everything it had
  is not an inaccuracy but a blow-up;
* **reach**: a particle is farther from the centre of the scene's bounding box at the reference
  than ``reach`` x (L + V t) + |g| t^2 / 2 after t seconds, where V is the fastest the scene
  could move (its fastest particle at the reference, its sources' speeds, or the speed its whole
  energy allowance would give its whole mass): far outside anywhere it can get to;
* **strain** (scenes without tearing): a spring is stretched past ``strain`` (|d|/r - 1), or
  past ``strain`` x W / (k_min r_min) for springs so soft that the scene's weight W alone could
  stretch one that far.

The check is a few reductions (one kernel over the particles, one per conservative force term:
:meth:`~taichi_sim.systems.base.System.health`), run after 1, 2, 4, ... units of work (f
evaluations plus linear-solver iterations) since the start or the last rebase, then after
every ``check_work`` units, and whenever the caller asks (the end of a run, each launcher frame): about one force evaluation per hundred, whatever
the integrator. A state that passes is copied into a snapshot, so that a run that fails can
return its last good state instead of garbage.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import runtime
from .errors import ConfigError
from .part import LaunchSource, MovingSource

ENERGY_GROWTH = 10.0
REACH = 10.0
MAX_STRAIN = 10.0
CHECK_WORK = 100


@dataclass(frozen=True)
class GuardLimits:
    """How far a run may go before it is called diverged (see the module docstring).

    Attributes:
        energy_growth: E - E_ref may reach this many energy scales (plus source allowances).
        reach: a particle may move this many (L + V t) from the scene's centre.
        strain: springs may stretch to this strain (|d|/r - 1) in scenes without tearing.
        check_work: units of work (f evaluations + linear iterations) between checks, once the
            first checks (after 1, 2, 4, ... units) have passed.
    """

    energy_growth: float = ENERGY_GROWTH
    reach: float = REACH
    strain: float = MAX_STRAIN
    check_work: int = CHECK_WORK

    def __post_init__(self):
        for name in ("energy_growth", "reach", "strain"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                    math.isfinite(value) and value > 0):
                raise ConfigError(f"guard limit {name} must be a finite number > 0, got {value!r}")
        if isinstance(self.check_work, bool) or not isinstance(self.check_work, (int, np.integer)) \
                or self.check_work < 1:
            raise ConfigError(f"guard limit check_work must be an integer >= 1, got {self.check_work!r}")


@dataclass(frozen=True)
class Breach:
    """Why a check failed: ``what`` grew (``"non-finite"``, ``"energy"``, ``"reach"``,
    ``"strain"``), its ``value`` and ``bound``, and one line saying so (``detail``)."""

    what: str
    value: float
    bound: float
    detail: str


@dataclass(frozen=True)
class SceneFacts:
    """What the bounds are derived from, read once from a scene's model (numpy)."""

    moving_mass: float  # kg, particles that are not pinned (emitter slots included)
    smallest_mass: float  # kg
    spring_stiffness_sum: float  # N/m, live springs with k > 0
    softest: float  # N/m, smallest k > 0 of a spring (inf without springs)
    shortest: float  # m, smallest rest length of such a spring (inf without springs)
    tearing: bool


def scene_facts(scene) -> SceneFacts:
    """Read the :class:`SceneFacts` of ``scene`` (numpy copies of its masses and springs)."""
    static = scene.static_arrays
    mass = np.asarray(static.get("mass", np.ones(1)), np.float64)
    pinned = np.asarray(static.get("pinned", np.zeros(len(mass), bool)), bool)
    moving = mass[~pinned] if (~pinned).any() else mass
    k = rest = np.zeros(0)
    live = np.zeros(0, bool)
    if scene.springs is not None:
        arrays = scene.springs.arrays()
        k, rest = arrays["stiffness"], arrays["rest_length"]
        live = (k > 0) & (rest > 0) & arrays.get("alive", True)
    return SceneFacts(moving_mass=float(moving.sum()), smallest_mass=float(moving.min()),
                      spring_stiffness_sum=float(k[live].sum()),
                      softest=float(k[live].min()) if live.any() else math.inf,
                      shortest=float(rest[live].min()) if live.any() else math.inf,
                      tearing=bool(scene.features.get("tearing")))


def gravity_magnitude(scene) -> float:
    """|g| (m/s^2) as the scene's gravity term has it now (0 without gravity)."""
    term = scene.system.term("gravity") if hasattr(scene.system, "term") else None
    return 0.0 if term is None else float(np.linalg.norm(term.get()))


def injectable_energy(scene, facts: SceneFacts, elapsed: float) -> dict[str, tuple[float, float]]:
    """What the scene's energy sources may add within ``elapsed`` seconds, by source:
    name -> (energy (J), speed (m/s) they may give the cloth). Read at each check, since the
    launcher changes sources while running.

    * wind: its kinetic energy, 1/2 M w_max^2 with w_max = speed (1 + 2 gust), the fastest gust
      (a wind cannot drive cloth faster than itself);
    * turbulence: 1/2 M w^2 with w = amplitude x time, the most speed its bounded acceleration
      gives a particle within ``elapsed``, or within a lifetime in a scene with an emitter;
    and what the scene's parts declare (:meth:`~taichi_sim.part.ScenePart.energy_sources`):

    * a part that launches particles (:class:`~taichi_sim.part.LaunchSource`, an emitter): a
      full ring buffer of particles, each at its launch energy 1/2 m speed^2 + m |g|
      max(nozzle height, 0) (nothing it launches gains energy later);
    * a scripted part that pushes (:class:`~taichi_sim.part.MovingSource`: a moving collider,
      kinematic pins), at its fastest speed V > 0: what it gives the cloth moving at twice its
      speed, 1/2 M (2V)^2, plus the stretch of every spring by its travel V t, 1/2 sum(k) (V t)^2,
      the travel capped by the farthest it ever gets from its start (a loose bound; scenes with
      tearing break their springs first).

    A grab target moved by the user is not a source here: the launcher re-bases its guard
    whenever the target moves, and a target that stays put is a conservative spring whose
    energy counts in E.
    """
    out: dict[str, tuple[float, float]] = {}
    mass = facts.moving_mass
    wind = scene.system.term("wind") if hasattr(scene.system, "term") else None
    if wind is not None and wind.is_enabled:
        w = wind.fastest_speed()
        out["wind"] = (0.5 * mass * w * w, w)
    sources = [source for part in getattr(scene, "parts", ()) for source in part.energy_sources()]
    turbulence = scene.system.term("turbulence") if hasattr(scene.system, "term") else None
    if turbulence is not None:
        # what it launched lives only a lifetime: no particle of it is pushed for longer
        duration = min([elapsed] + [s.lifetime for s in sources if isinstance(s, LaunchSource)])
        w = turbulence.get() * duration
        out["turbulence"] = (0.5 * mass * w * w, w)
    for source in sources:
        if isinstance(source, LaunchSource):
            out[source.label] = (source.count * source.mass * (0.5 * source.speed**2
                                                               + gravity_magnitude(scene) * max(source.height, 0.0)),
                                 source.speed)
        elif isinstance(source, MovingSource) and source.speed > 0:
            speed = source.speed
            travel = min(speed * elapsed, source.farthest)
            out[source.label] = (0.5 * mass * (2 * speed) ** 2 + 0.5 * facts.spring_stiffness_sum * travel**2,
                                 2 * speed)
    return out


class Guard:
    """Watches one scene's run for blow-ups (module docstring).

    Usage: :meth:`rebase` at the start (and whenever the system is changed from outside: a
    parameter, the grab target); after each accepted step :meth:`spend` the step's work and,
    when it says a check is due (or at the end), :meth:`check`. A failed check leaves the state
    as it is; :meth:`restore` puts back the last state that passed.

    Args:
        scene: the scene whose ``state`` is watched.
        limits: the bounds (default :class:`GuardLimits`).
    """

    def __init__(self, scene, limits: GuardLimits | None = None):
        self.scene = scene
        self.limits = limits or GuardLimits()
        self.snapshot = scene.spare_state()
        self.facts = scene_facts(scene)
        self.checks = 0
        self.good_t = 0.0
        self.good_step = 0
        self.health = None
        self.rebase()

    # -- reference ----------------------------------------------------------------------------

    def rebase(self, t: float = 0.0, step: int = 0) -> None:
        """Take the current state at time ``t`` (s), after ``step`` accepted steps, as the
        reference the bounds grow from, and as the last good state."""
        scene = self.scene
        self.facts = scene_facts(scene)  # springs may have torn, emitters changed
        x = np.asarray(scene.state.to_numpy()[0], np.float64)  # the kernel the run's arrays are read with
        finite = np.isfinite(x).all(axis=1)
        if finite.any():
            reach = x[finite]
            if getattr(scene, "constraints", None) is not None:
                # A bead starts at one point of its wire but goes round all of it: the wire
                # is the scene's size (its height is what gravity can trade for speed).
                reach = np.concatenate([reach, scene.constraints.extent()])
            low, high = reach.min(axis=0), reach.max(axis=0)
            self.center = 0.5 * (low + high)
            self.size = max(float(np.linalg.norm(high - low)), 1.0)
        else:
            self.center, self.size = np.zeros(3), 1.0
        health = scene.system.health(scene.state, self.center)
        self.gravity = gravity_magnitude(scene)
        self.reference_t = t
        self.energy0 = health.energy
        self.scale = None
        if health.energy is not None and math.isfinite(health.energy):
            weight = self.facts.moving_mass * self.gravity
            rounding = 0.5 * self.facts.spring_stiffness_sum * (runtime.epsilon() * self.size) ** 2
            self.scale = max(abs(health.energy) + health.kinetic + health.spring_energy + weight * self.size,
                             rounding, 1e-300)
        moving = max(self.facts.moving_mass, 1e-300)
        self.fastest0 = math.sqrt(2.0 * health.kinetic / max(self.facts.smallest_mass, 1e-300))
        self._moving_mass = moving
        self.work = 0
        # Checks come after 1, 2, 4, ... units of work, then every check_work: a run that
        # blows up in its first steps (the usual way for too large a step) is stopped close to
        # where it went wrong, and a long run still pays about one check per check_work.
        self.interval = 1
        self.health = health
        if health.nonfinite == 0:
            self.keep(t, step)

    # -- bounds -------------------------------------------------------------------------------

    def energy_bound(self, t: float) -> tuple[float, float, dict]:
        """(largest allowed E (J), the allowance it adds to E_ref (J), the sources' part) at
        time ``t``."""
        sources = injectable_energy(self.scene, self.facts, max(t - self.reference_t, 0.0))
        allowance = self.limits.energy_growth * (self.scale + sum(e for e, _ in sources.values()))
        return self.energy0 + allowance, allowance, sources

    def reach_bound(self, t: float, allowance: float, sources: dict) -> float:
        """Largest allowed distance (m) of a particle from the reference centre at ``t``."""
        elapsed = max(t - self.reference_t, 0.0)
        speed = max([self.fastest0, math.sqrt(2.0 * allowance / self._moving_mass)]
                    + [v for _, v in sources.values()])
        return self.limits.reach * (self.size + speed * elapsed) + 0.5 * self.gravity * elapsed**2

    def strain_bound(self) -> float | None:
        """Largest allowed spring strain, or None (tearing scenes, no springs)."""
        f = self.facts
        if f.tearing or not math.isfinite(f.softest):
            return None
        sag = self.facts.moving_mass * self.gravity / (f.softest * f.shortest)
        return self.limits.strain * max(1.0, sag)

    # -- checking -----------------------------------------------------------------------------

    def spend(self, work: int) -> bool:
        """Count ``work`` (f evaluations + linear iterations of a step); True when a check is due."""
        self.work += max(int(work), 1)
        return self.work >= self.interval

    def check(self, t: float, step: int, *, keep: bool = True) -> Breach | None:
        """Check the current state (time ``t`` s, ``step`` accepted steps): None when it is
        within every bound (then, with ``keep``, it becomes the last good state; without, the
        caller may judge it further and :meth:`keep` it), else the :class:`Breach`."""
        self.work = 0
        self.checks += 1
        health = self.scene.system.health(self.scene.state, self.center)
        breach = self._judge(health, t)
        if breach is None:
            self.health = health
            if keep:
                self.keep(t, step)
            self.interval = min(2 * self.interval, self.limits.check_work)
        return breach

    def _judge(self, health, t: float) -> Breach | None:
        if health.nonfinite:
            return Breach("non-finite", float(health.nonfinite), 0.0,
                          f"non-finite state (NaN or infinite values in {health.nonfinite} particles)")
        allowance, sources = 0.0, {}
        if self.scale is not None and health.energy is not None:
            bound, allowance, sources = self.energy_bound(t)
            if not health.energy <= bound:  # NaN and inf fail too
                extra = "".join(f" + {name} {e:.3g} J" for name, (e, _) in sources.items())
                return Breach("energy", health.energy, bound,
                              f"energy rose to {health.energy:.3g} J from {self.energy0:.3g} J, past "
                              f"the bound {bound:.3g} J (start + {self.limits.energy_growth:g} x "
                              f"(energy scale {self.scale:.3g} J{extra}))")
        else:
            allowance = self.limits.energy_growth * self._moving_mass * self.gravity * self.size
        reach = self.reach_bound(t, allowance, sources)
        if not health.farthest <= reach:
            return Breach("reach", health.farthest, reach,
                          f"a particle is {health.farthest:.3g} m from the scene's centre, past the "
                          f"bound {reach:.3g} m at t = {t:.4g} s")
        strain = self.strain_bound()
        if strain is not None and not health.max_strain <= strain:
            return Breach("strain", health.max_strain, strain,
                          f"a spring stretched to strain {health.max_strain:.3g} (|d|/r - 1), past "
                          f"the bound {strain:.3g}")
        return None

    # -- the last good state ------------------------------------------------------------------

    def keep(self, t: float, step: int) -> None:
        """Take the current state (time ``t`` s, ``step`` accepted steps) as the last good one."""
        self.snapshot.copy_from(self.scene.state)
        self.good_t, self.good_step = t, step

    def restore(self) -> None:
        """Put the last state that passed a check back into the scene."""
        self.scene.state.copy_from(self.snapshot)

    def last_good_positions(self) -> np.ndarray:
        """(n, 3) float64 positions of the last state that passed (numpy copy)."""
        return np.asarray(self.snapshot.x.to_numpy(), np.float64)
