"""Samples how far one integrator's steps are from the equation it solves, during a run: the
relative residual (:mod:`.residual`) and the distance in metres (:mod:`.distance`), at
deterministic samples.

When a step is sampled: whenever the work the run has done since the last sample pays for
another within ``BUDGET`` of the run's time, by a cost model rather than the clock (so
identical runs sample identical steps): a sample costs about ``SAMPLE_SECONDS_PER_DOF``
(3 n)^1.5 s (a sparse factorisation of the Jacobian: 0.5 s for a 64 x 64 grid, 1-2 s for the
5 000-vertex skirt, whose mesh fills in more, on the 2-vCPU machine of docs/integrators.md), a
unit of the method's work (an f evaluation, a sweep, a linear iteration) about
``WORK_SECONDS_PER_PARTICLE`` n s, times the method's ``work_weight`` (vbd's sweeps with
self-contact pairs cost several times a sweep over springs). The last step of a run and the steps a caller asks to check
are sampled whatever they cost, so that every run has its figure: a run shorter than the work
one sample pays for spends more than ``BUDGET`` on that one sample.

A run's start is sampled more densely, within ``EARLY_SECONDS`` of modelled sample time: the
first step, then whenever the run's work has doubled since the last sample (the steps ending
at 2, 4, 8, ... times the first step's work), until the budget's interval is the shorter. The
first step from rest is the least loaded of a run (a hanging cloth's springs take their
load over its first steps: xpbd's estimate on a 16 x 16 cloth at k = 1e8 N/m read 0.28 mm
at step 1 and 1-4 mm at steps 2-20), and the tolerance can raise a method's work only at a
sampled step: sampled at step 1 and then after some 300 steps, that run went on 4 mm off
until its stretch's energy (k C^2 / 2 of a 0.1 mm stretch) tripped the blow-up guard.
"""
from __future__ import annotations

import math
import time

from ..errors import ConfigError
from ..integrators.equation import EXACT, Equation
from .distance import REFINE_ITERATIONS, DistanceModel
from .residual import (
    BUDGET,
    FLOOR_MARGIN,
    MAX_FLOOR,
    ForceModel,
    check_max_residual,
    relative_residual,
    rounding_floor,
    unmodelled,
)
from .terms import combined, continuum_terms, term_forces

#: Default ``--tolerance`` (m): the distance a step's positions may be from the solution of the
#: equation its method declares (the largest over the particles) before the run says so.
DEFAULT_TOLERANCE = 1e-3
#: The cost model of the samples (see the module docstring), seconds.
SAMPLE_SECONDS_PER_DOF = 8e-7
WORK_SECONDS_PER_PARTICLE = 1e-7
#: The modelled sample time (s) a run may spend on its start's denser samples (module
#: docstring): all of them on a 16 x 16 cloth (0.017 s a sample), the first three on a 32 x 32
#: (0.14 s; fewer where a sample solved its step to decide), none on a 64 x 64 (1.1 s), whose
#: first sample is paid by the budget.
EARLY_SECONDS = 0.5
#: The modelled time (s) a sample may spend solving its step to decide against the tolerance
#: (:data:`~.distance.DECIDE`): up to 16 Jacobians on a 16 x 16 cloth, 7 on a 32 x 32, none on a
#: 64 x 64 (a Jacobian's factorisation there takes 1-2 s), whose estimate stands.
REFINE_SECONDS = 1.0


def check_tolerance(value) -> float:
    """A tolerance in metres: a finite number > 0 (ConfigError naming ``tolerance`` else);
    None gives :data:`DEFAULT_TOLERANCE`."""
    if value is None:
        return DEFAULT_TOLERANCE
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (0 < value < math.inf):
        raise ConfigError(f"tolerance must be a finite number of metres > 0, got {value!r}")
    return float(value)


class ConvergenceMonitor:
    """Samples one integrator's steps on one scene: how far each sampled step is from the
    equation the method solves (module docstring).

    ``unmeasured``: why the caller measures nothing ("" to measure what the method and scene
    allow); the monitor is then inactive and allocates nothing.

    Call :meth:`before_step` before every step (it keeps the step's start: one device copy,
    unless the method keeps the start of its last solved piece itself), :meth:`spend` after
    each with the step's work, and :meth:`measure` after a step that :meth:`due` (or the
    caller) wants sampled, before the post-step events move the state.

    Attributes:
        equation: the method's :class:`Equation`, or None.
        reason: why the run is not measured ("" when it is).
        tolerance: the distance a step may be from its equation's solution (m).
        max_residual: the bound asked for on the residual (see :func:`check_max_residual`);
            bound: the one applied (:meth:`check_precision`), floor: the rounding floor.
        times, values, distances: the samples (s, relative residual, estimated distance (m)).
        worst, worst_t: the largest residual and its time; worst_distance, worst_distance_t:
            the largest distance and its time (NaN before any).
        seconds: wall time the samples took (s).
    """

    def __init__(self, scene, integrator, max_residual: float | None = None, tolerance: float | None = None,
                 unmeasured: str = ""):
        self.max_residual = check_max_residual(max_residual)
        self.tolerance = check_tolerance(getattr(scene, "default_tolerance", None) if tolerance is None else tolerance)
        self.integrator = integrator
        self.equation: Equation | None = getattr(integrator, "equation", None)
        self.reason = ""
        if unmeasured:  # the caller measures nothing (a bare Stepper)
            self.reason = unmeasured
        elif self.equation is None:
            self.reason = f"{integrator.name} solves no system per step"
        elif not scene.system.second_order:
            self.reason = "a first-order system"
        elif unmodelled(scene):
            self.reason = f"the scene's {unmodelled(scene)} forces are not in the residual's model"
        elif getattr(integrator, "unmodelled_forces", ""):
            self.reason = f"{integrator.name}'s {integrator.unmodelled_forces} forces are not in the residual's model"
        self.active = not self.reason  # an attribute: read at every step
        self.times: list[float] = []
        self.values: list[float] = []
        self.distances: list[float] = []
        self.floor = math.nan
        self.bound = self.max_residual
        self._start = None
        self._solve_forces = getattr(integrator, "solve_forces", None)
        self._terms = continuum_terms(scene.system)
        self._stage = None  # a scratch state for a midpoint stage's terms
        self.clear()
        if self.active:
            self.model = ForceModel(scene)
            self.distance_model = DistanceModel(self.model, self.equation)
            self._start = scene.system.make_state()
            # A method that solves its step in pieces (substeps, halvings) keeps the start of
            # the last piece it solved, which is what its equation is about.
            self._tracked = bool(getattr(integrator, "tracks_solved_start", False))
            if self._tracked:
                integrator.solved_start = self._start
                integrator.solved_h = math.nan
            n = int(self.model.free.sum())
            # the work (method's units) that pays for one sample within BUDGET (module docstring)
            self.sample_seconds = SAMPLE_SECONDS_PER_DOF * (3 * n) ** 1.5
            self.refine = min(REFINE_ITERATIONS, int(REFINE_SECONDS / max(self.sample_seconds, 1e-12)))
            unit = WORK_SECONDS_PER_PARTICLE * max(n, 1) * float(getattr(integrator, "work_weight", 1.0))
            self.sample_work = self.sample_seconds / (BUDGET * unit)

    def check_precision(self, state, precision: str, epsilon: float) -> str:
        """Before a run: the bound samples are held to is ``max_residual`` or, where the
        precision's rounding alone leaves more (:func:`rounding_floor` at the start positions;
        single precision on stiff springs) but at most ``MAX_FLOOR``, ``FLOOR_MARGIN`` times
        that floor (``bound``). Returns why a method that promises the exact step cannot run
        in this precision (its floor is above ``MAX_FLOOR``: the answer cannot be told from a
        cloth frozen in mid-air), else ""."""
        if not self.active:
            return ""
        self.floor = rounding_floor(self.model, state.to_numpy()[0], epsilon)  # the kernel the run reads x, v with
        if math.isfinite(self.floor) and self.floor <= MAX_FLOOR:
            self.bound = max(self.max_residual, FLOOR_MARGIN * self.floor)
        if self.promises_exact and self.floor > MAX_FLOOR:
            return (f"{self.integrator.name} cannot solve this scene in {precision}: rounding of its springs' "
                    f"forces is about {self.floor:.2g} of the particles' weight (more than {MAX_FLOOR:g}), so "
                    f"the step cannot be told from one frozen in mid-air; use --precision f64, or a "
                    f"position-level method (xpbd, projective_dynamics)")
        return ""

    def clear(self) -> None:
        """Forget the samples (a restart from t = 0)."""
        self.times.clear()
        self.values.clear()
        self.distances.clear()
        self.worst, self.worst_t = math.nan, math.nan
        self.worst_distance, self.worst_distance_t = math.nan, math.nan
        self.warned = False
        self.work = 0.0  # work since the last sample
        self.total_work = 0.0  # work since the start
        self.early = 0.0  # modelled time (s) spent on samples the budget did not pay for
        self.seconds = 0.0  # wall time spent sampling (reported; it decides nothing)

    def before_step(self, state) -> None:
        if self._start is not None and not self._tracked:
            self._start.copy_from(state)

    def spend(self, work: float) -> None:
        """Count a step's work (f evaluations + linear iterations)."""
        work = max(work, 1)
        self.work += work
        self.total_work += work

    def due(self) -> bool:
        """Whether the step just counted is to be sampled (module docstring): deterministic."""
        if self.work >= self.sample_work:
            return True
        # early: the run's work doubled since the last sample (the first step: no sample yet)
        return 2 * self.work >= self.total_work and self.early + self.sample_seconds <= EARLY_SECONDS

    def measure(self, state, t: float, h: float) -> tuple[float, float]:
        """(relative residual, distance (m)) of the step that just ended at ``t`` and took
        ``h`` s; recorded."""
        if not self.active:
            return math.nan, math.nan
        start = time.perf_counter()
        paid = self.work >= self.sample_work
        if self._tracked and math.isfinite(self.integrator.solved_h):
            h = self.integrator.solved_h
        x0, v0 = self._start.to_numpy()
        x1, v1 = state.to_numpy()
        # the method's own forces (vbd's contact) and the cloth's continuum terms, at the stage
        extra = self._solve_forces(state, t, h) if self._solve_forces is not None else None
        if self._terms:
            extra = combined(extra, self._term_forces(state, x0, v0, x1, v1, t, h))
        value = relative_residual(self.model, self.equation, x0, v0, x1, v1, h, extra)
        distance = math.nan
        if h > 0:
            distance = self.distance_model.distance(x0, v0, x1, v1, h, extra, self.tolerance, self.refine)
        # a sample that solved its step to decide (distance.DECIDE) cost a sample per Jacobian:
        # the next waits for the work that pays for them (deterministic, as the rest)
        cost = getattr(self.distance_model, "jacobians", 1) if h > 0 else 1
        if paid:
            self.work = -(cost - 1) * self.sample_work
        else:
            self.early += cost * self.sample_seconds
            self.work = 0.0
        self.record(t, value, distance)
        self.seconds += time.perf_counter() - start
        return value, distance

    def record(self, t: float, value: float, distance: float) -> None:
        """Keep a sample: at time ``t`` (s), the relative residual and the distance (m)."""
        self.times.append(t)
        self.values.append(value)
        self.distances.append(distance)
        if _larger(value, self.worst):
            self.worst, self.worst_t = value, t
        if _larger(distance, self.worst_distance):
            self.worst_distance, self.worst_distance_t = distance, t

    def _term_forces(self, state, x0, v0, x1, v1, t: float, h: float):
        """The continuum terms' forces at the stage the equation is taken at: the result for
        backward Euler, the midpoint (written to a scratch state) for implicit midpoint."""
        pinned = ~self.model.free
        v0, v1 = v0.copy(), v1.copy()
        v0[pinned] = v1[pinned] = 0.0  # as the residual: a pin is at rest within a step
        x, v, tau, _ = self.distance_model.stage(x0, v0, x1, v1, h)
        if self._stage is None:
            self._stage = self.model.scene.system.make_state()
        self._stage.from_numpy(x, v)
        return term_forces(self.model.scene.system, self._terms, self._stage, tau, t)

    def forget_last(self) -> None:
        """Drop the last sample (its step is being solved again); the worst figures are
        recomputed from those left."""
        for samples in (self.times, self.values, self.distances):
            samples.pop()
        self.worst = self.worst_t = self.worst_distance = self.worst_distance_t = math.nan
        for t, value, distance in zip(self.times, self.values, self.distances):
            if _larger(value, self.worst):
                self.worst, self.worst_t = value, t
            if _larger(distance, self.worst_distance):
                self.worst_distance, self.worst_distance_t = distance, t

    def exceeds(self, distance: float) -> bool:
        """Whether a sampled distance is above the tolerance (an infinite one is; NaN, not
        measured, is not)."""
        return not math.isnan(distance) and not distance <= self.tolerance

    @property
    def promises_exact(self) -> bool:
        return self.equation is not None and self.equation.promise == EXACT

    def breach_message(self, distance: float, t: float) -> str:
        """One line: the estimate found, the tolerance, and what to change."""
        advice = f"; {self.equation.advice}" if self.equation and self.equation.advice else ""
        return (f"estimated error {format_metres(distance)} at t = {t:.6g} s exceeds --tolerance "
                f"{format_metres(self.tolerance)} (the distance of the step's positions from the solution of "
                f"the equation {self.integrator.name} solves){advice}")

    def warning_message(self, distance: float, t: float, stopped_by: str = "") -> str:
        """One line for a fixed-work method whose sample exceeded the tolerance (the run goes
        on); ``stopped_by``: the cap that kept it from iterating further, if any."""
        cap = f" ({stopped_by})" if stopped_by else ""
        return (f"{self.integrator.name} leaves its steps unsolved{cap}: " + self.breach_message(distance, t)
                + "; the run goes on, and its answer is off by about that much a step")


def _larger(value: float, worst: float) -> bool:
    """NaN-aware: the first sample, or a larger one."""
    if math.isnan(value):
        return math.isnan(worst)
    return not value <= worst


def format_metres(value: float) -> str:
    """A distance as people read it: '3.2 mm', '41 um', '1.2 m'."""
    if not math.isfinite(value):
        return f"{value} m"
    for unit, scale in (("m", 1.0), ("mm", 1e-3), ("um", 1e-6), ("nm", 1e-9)):
        if abs(value) >= scale or unit == "nm":
            scaled = value / scale
            return f"{scaled:.0f} {unit}" if abs(scaled) >= 10 else f"{scaled:.2g} {unit}"
    return f"{value:.2g} m"
