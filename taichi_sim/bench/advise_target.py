"""``taichi-sim advise --target-error E``: the (integrator, step) that reaches a position error
of E m at ``--t-end`` in the least wall time on this machine, found by measuring.

1. A reference run: RK4 at a quarter of its stable step over the whole run, and at half that
   step; their difference estimates the reference's own error (order 4: d / 15). On a scene
   with post-step events (contact, colliders, tearing, emitters) a step's error no longer
   shrinks as h^p (the events are applied between steps, and contact switches on and off), so
   a third run at a quarter of the step measures the order the runs actually show; the error
   is estimated with that order, and below order 0.8 (the answers do not settle as the step
   shrinks) there is no estimate: ``advise`` says so rather than print a number. The
   reference is refined (once) until its error is below a tenth of the target. Without a
   reference (no stable RK4 step, too many steps, or too close to the target) each error is a
   Richardson estimate from runs at h and h/2, which is refused on scenes with events.
2. Each candidate (every fixed-step method of the stability table) has a largest step: 0.9 of
   its stable step (for Euler, trapezoid, midpoint: the step at which the fastest mode's energy
   doubles over the run), and at most t_end / 20 (the unconditionally stable methods). A
   fixed-work method's time at that step, T / h_max steps of its f-evaluations at the wall time
   per f evaluation (measured bare, then as the pilots step: overhead and machine load
   included), is a lower bound on any run of it: a candidate whose bound is above the best time
   shown is skipped without compiling its kernels (explicit Euler on a cloth: hundreds of s).
3. A pilot is one run of the whole horizon at the step tried, measured against the reference
   (so an error that grows faster than linearly in time, or that the method's own step hides,
   is seen as it is). The first is at h_max; if it misses the target, the step to try is
   h (0.7 E / e)^(1/p) (p the declared order, at most 1 on a scene with events; later pilots
   use the order the last two show), and its time is estimated (step 4). The next pilot is
   always the cheapest that could beat the best time shown: a fixed-work method's first (its
   bound) or a second or third pilot at an estimated step (its estimate); the iterative
   methods (Newton, projective dynamics, XPBD, VBD), whose work per step is unknown before
   they run, come once the fixed-work ones have set a time to beat. Every pilot gives up once
   its steps have taken longer than the best time shown or the budget left.
4. The time of a run is measured, not counted in f-evaluations: a pilot's steps after its first
   (the integrator is bound once per candidate, so its kernels are compiled by then), or, for a
   step not yet run, a probe of PROBE_STEPS steps at that step through a
   :class:`~taichi_sim.stepper.Stepper` after a warm-up step (an implicit method's Newton work
   grows with h). Candidates are ranked by that time: those shown to meet the target first,
   then the estimated ones.

The pilots spend at most ``budget`` seconds, compiling included (``--budget``); a candidate not
reached within it is listed as such. A reference run that would need more than
REFERENCE_MAX_STEPS steps is not made.
"""
from __future__ import annotations

import math
import time

import numpy as np

MARGIN = 0.7  # aim below the target: the step to try is chosen for MARGIN x the target error
MAX_PILOTS = 3  # runs of the whole horizon per candidate
REFERENCE = "rk4"
REFERENCE_FRACTION = 0.25  # of RK4's stable step
REFERENCE_ACCURACY = 0.1  # the reference is refined until its own error is below this x the target
REFERENCE_MAX_STEPS = 200_000
MAX_STEPS = 10_000_000  # a candidate needing more steps than this for the target has failed
PROBE_STEPS = 10  # timed steps (after one warm-up step) that measure a step size's cost
UNCAPPED_SHARE = 20  # the largest step tried: t_end / 20 (an unconditionally stable method's)
SAFETY = 0.9
BUDGET = 20.0  # seconds of pilot runs, their compiling included (--budget)
SETTLE_FINER = 8  # a reference that does not settle is tried once more at steps this many times shorter ...
REFERENCE_RETRY_S = 20.0  # ... when that would take at most this many seconds
MIN_ORDER = 0.8  # a reference's observed order below this: its answers do not settle as the step shrinks
PILOT_MIN_ORDER = 0.5  # the least order a candidate's pilots are extrapolated with


def has_events(scene) -> bool:
    """Whether the scene applies post-step events (contact, colliders, tearing, emitters): a
    step's error then need not shrink as h^p."""
    return bool(scene.post_step)


def f_seconds(scene, repeats: int = 5) -> float:
    """Wall time (s) of one evaluation of the scene's f, warm (the first call compiles)."""
    system = scene.system
    out = system.make_state()
    system.eval_f(scene.state, 0.0, out)
    batches = []
    for _ in range(3):  # the least of three batches: other work on the machine only adds
        _sync()
        start = time.perf_counter()
        for _ in range(repeats):
            system.eval_f(scene.state, 0.0, out)
        _sync()
        batches.append((time.perf_counter() - start) / repeats)
    return min(batches)


def _sync() -> None:
    import taichi as ti

    ti.sync()


def candidates(scene, table: list[dict], t_end: float, integrators=None) -> list[dict]:
    """One row per fixed-step method of ``table`` (those of ``integrators`` when given) with
    its largest step ``h_max`` (s) and what limits it."""
    from ..integrators import integrator_class

    rows = []
    for entry in table:
        name = entry["integrator"]
        if integrators is not None and name not in integrators:
            continue
        if entry["note"].startswith(("needs", "adaptive", "no prediction")):
            continue
        cls = integrator_class(name)
        limit = entry["limit"]
        if limit == 0.0:  # grows every step: the step whose fastest mode doubles its energy
            limit = entry.get("horizon_limit") or scene.default_dt
        h_max, by = (SAFETY * limit, "stability") if math.isfinite(limit) else (math.inf, "")
        if h_max > t_end / UNCAPPED_SHARE:
            h_max, by = t_end / UNCAPPED_SHARE, f"t_end / {UNCAPPED_SHARE}"
        rows.append({"integrator": name, "order": cls.order, "evals": cls.f_evals_per_step,
                     "h_max": h_max, "max_by": by, "pilots": [], "status": "waiting"})
    return rows


def lower_bounds(rows: list[dict], t_end: float, f_time: float) -> None:
    """Each row's ``bound`` (s): its steps at ``h_max`` times its f evaluations per step (one
    where they vary) at ``f_time`` s each; no run of it can be faster."""
    for row in rows:
        steps = math.ceil(t_end / row["h_max"] - 1e-9)
        row["bound"] = steps * (row["evals"] or 1) * f_time


def reference_steps(table: list[dict], t_end: float) -> int | None:
    """Steps of the reference run's coarser half (None: RK4 has no stable step here)."""
    entry = next((r for r in table if r["integrator"] == REFERENCE), None)
    limit = None if entry is None else entry["limit"]
    if not limit:  # None (no prediction) or 0 (grows at every step)
        return None
    # nothing oscillates (no springs: a sprinkler): no limit, and the refinement finds the step
    return math.ceil(t_end / min(REFERENCE_FRACTION * limit, t_end / UNCAPPED_SHARE) - 1e-9)


def cost_line(scene, table, rows, t_end: float, f_time: float, budget: float) -> str:
    """What advising will cost, said before it starts: the reference runs, the candidates and
    a rough time (compiling each candidate's kernels, about a second or a few, comes on top)."""
    steps = reference_steps(table, t_end)
    runs = 3 if has_events(scene) else 2
    if steps is not None and steps * 2 ** (runs - 1) <= REFERENCE_MAX_STEPS:
        units = 2 ** runs - 1  # runs at h, h/2 (and h/4): 1 + 2 (+ 4) times the steps
        reference = units * steps * 4 * f_time
        what = f"a reference run of {REFERENCE} ({runs} runs, {units * steps} steps, about {reference:.2g} s)"
    else:
        reference = 0.0
        what = "no reference run (Richardson estimates instead)"
    pilots = min(budget, sum(min(r["bound"], budget) for r in rows) * 2)
    compile_s = 1.5 * len(rows)
    total = reference + pilots + compile_s
    return (f"advising: {what}, then pilot runs of the whole {t_end:g} s for up to {len(rows)} candidates "
            f"(at most {MAX_PILOTS} each, at most {budget:g} s of pilot runs in all); roughly {total:.0f} s here, "
            f"compiling included (--budget S to change)")


class Judge:
    """The error (m) at ``t_end`` of a run at a given step: against the reference run, or a
    Richardson estimate from the run at h and h/2 (``reference`` None)."""

    def __init__(self, scene, t_end: float, reference: dict | None):
        self.scene, self.t_end, self.reference = scene, t_end, reference

    def __call__(self, integrator, h: float, order: float, *, give_up: float = math.inf) -> "Pilot":
        """The run at ``h`` with its error; it stops (``timed_out``) once its steps after the
        first have taken ``give_up`` s (compiling is in the first)."""
        pilot = run_to(self.scene, integrator, h, self.t_end, give_up)
        if pilot.x is None:
            return pilot
        if self.reference is not None:
            pilot.error = _distance(pilot.x, self.reference["x"])
            return pilot
        half = run_to(self.scene, integrator, h / 2, self.t_end, give_up)
        if half.x is None:
            return half
        pilot.error = _distance(pilot.x, half.x) / (1 - 2.0 ** -order)
        return pilot


class Pilot:
    """A run of the whole horizon: the final positions ``x`` (n, 3) (None when it failed or
    timed out), why not (``message``), its wall seconds per step after the first
    (``per_step``), the integrator's warnings, and the ``error`` (m) once judged."""

    def __init__(self, x=None, message="", per_step=math.nan, warnings=(), timed_out=False):
        self.x, self.message, self.per_step = x, message, per_step
        self.warnings, self.timed_out, self.error = warnings, timed_out, None


def run_to(scene, integrator, h: float, t_end: float, give_up: float = math.inf) -> Pilot:
    """Step ``integrator`` at ``h`` from the scene as built (torn springs mended) to ``t_end``
    through a :class:`~taichi_sim.stepper.Stepper` (the run's guard and order of events),
    giving up once the steps after the first have taken ``give_up`` s."""
    from ..run import integrator_warnings
    from ..stepper import Stepper

    scene.restore()
    integrator.reset()
    stepper = Stepper(scene, integrator, h, raise_work=False)  # the candidate at its settings
    if stepper.refusal:
        return Pilot(message=stepper.refusal)
    clock = _GiveUp(give_up)
    stepper.add_observer(clock)
    stepper.run_until(t_end=t_end, check_last=True)  # the end is checked, as run() checks it
    if clock.gave_up:
        return Pilot(message=f"gave up after {stepper.steps} steps", timed_out=True)
    if stepper.failure is None and not stepper.checked:
        stepper.check()
    if stepper.failure is not None:
        return Pilot(message=stepper.failure.message)
    _sync()
    taken = stepper.steps - clock.steps0
    per_step = (time.perf_counter() - clock.first) / taken if taken else math.nan
    x, _ = scene.state.to_numpy()
    warnings = tuple(stepper.warnings) + integrator_warnings(integrator, stepper.monitor)
    return Pilot(np.asarray(x, float), per_step=per_step, warnings=warnings)


class _GiveUp:
    """A pilot's clock, observing its stepper: when the first accepted step ended (its
    compiling left out) and the steps until then; it stops the loop once the steps after the
    first have taken ``give_up`` s."""

    def __init__(self, give_up: float):
        self.give_up, self.first, self.steps0, self.gave_up = give_up, None, 0, False

    def after_step(self, stepper, report) -> None:
        now = time.perf_counter()
        if self.first is None:
            self.first, self.steps0 = now, stepper.steps
        elif now - self.first > self.give_up:
            self.gave_up = True
            stepper.stop()


def _distance(x: np.ndarray, y: np.ndarray) -> float:
    return float(np.linalg.norm(x - y, axis=1).max())


def probe_step(scene, integrator, h: float) -> float:
    """Wall seconds per step at ``h``: PROBE_STEPS steps through a Stepper after one warm-up
    step (whose compiling, if any, is left out), from the scene as built."""
    from ..stepper import Stepper

    scene.restore()
    integrator.reset()
    stepper = Stepper(scene, integrator, h, raise_work=False)
    stepper.step()
    _sync()
    start = time.perf_counter()
    stepper.run_until(max_calls=PROBE_STEPS)
    _sync()
    return (time.perf_counter() - start) / PROBE_STEPS


def make_reference(scene, table, target_error: float, t_end: float, bind) -> tuple[dict | None, str]:
    """The reference run's final positions and own error, or None, and a line saying which
    (module docstring, step 1). ``bind(name)`` gives the bound integrator (shared with the
    candidates: its kernels compile once)."""
    steps = reference_steps(table, t_end)
    if steps is None:
        return None, f"no reference run: {REFERENCE} has no stable step on this scene"
    events = has_events(scene)
    runs = 3 if events else 2
    for rounds in range(2):  # refined once when its own error is too close to the target
        if steps * 2 ** (runs - 1) > REFERENCE_MAX_STEPS:
            return None, (f"no reference run: {REFERENCE} would need {steps * 2 ** (runs - 1)} steps "
                          f"(at most {REFERENCE_MAX_STEPS})")
        integrator = bind(REFERENCE)
        finals, took = [], 0.0  # the seconds of stepping, compiling left out
        for k in range(runs):
            run = run_to(scene, integrator, t_end / (steps * 2**k), t_end)
            if run.x is None:
                return None, f"no reference run: {REFERENCE} did not finish it ({run.message})"
            finals.append(run.x)
            took += run.per_step * steps * 2**k
        d = [_distance(finals[k], finals[k + 1]) for k in range(runs - 1)]
        order = 4.0
        if events:
            if d[-1] == 0.0:
                order = 4.0
            elif d[0] <= d[-1] or math.log2(d[0] / d[-1]) < MIN_ORDER:
                if not rounds and (SETTLE_FINER * took <= REFERENCE_RETRY_S
                                   and SETTLE_FINER * steps * 2 ** (runs - 1) <= REFERENCE_MAX_STEPS):
                    steps *= SETTLE_FINER  # its steps may just be too long: once more, shorter
                    continue
                return None, (f"no error estimate: the reference runs ({REFERENCE} at {t_end / steps:.3g}, "
                              f"{t_end / (2 * steps):.3g} and {t_end / (4 * steps):.3g} s) differ by {d[0]:.2g} "
                              f"and then {d[-1]:.2g} m: the answer does not settle as the step shrinks (contact "
                              "and the scene's other events act between steps), so no step can be promised "
                              "an error; compare runs at two steps yourself")
            else:
                order = min(4.0, math.log2(d[0] / d[-1]))
        error = d[-1] / (2**order - 1)
        h = t_end / (steps * 2 ** (runs - 1))
        if error <= REFERENCE_ACCURACY * target_error:
            break
        # the step whose error would be REFERENCE_ACCURACY x the target, at the order seen
        finer = math.ceil(steps * 1.2 * (error / (REFERENCE_ACCURACY * target_error)) ** (1 / order))
        if finer * 2 ** (runs - 1) > REFERENCE_MAX_STEPS:
            if error <= 0.5 * target_error:
                break
            return None, (f"no reference run: {REFERENCE} at {h:.3g} s is itself about {error:.2g} m off "
                          + (f"(its runs converge at order {order:.2g} here) " if events else "")
                          + f"and one {REFERENCE_ACCURACY:g} x the target off would need about "
                          f"{finer * 2 ** (runs - 1):.3g} steps (at most {REFERENCE_MAX_STEPS})")
        steps = finer
    if error > 0.5 * target_error:
        return None, (f"no reference run: {REFERENCE} at {h:.3g} s is itself about {error:.2g} m off, too "
                      f"close to the target")
    shown = f"observed order {order:.2g}, " if events else ""
    return ({"x": finals[-1], "error": error, "h": h, "order": order},
            f"errors measured against {REFERENCE} at {h:.3g} s ({round(t_end / h)} steps; {shown}its own "
            f"error about {error:.2g} m)")


def recommend(scene, table: list[dict], target_error: float, t_end: float, integrators=None, *,
              budget: float = BUDGET, f_time: float | None = None, progress=None) -> tuple[list[dict], str]:
    """The candidates of ``table`` (those of ``integrators`` when given), each with the step
    ``h`` (s) estimated or shown to reach ``target_error`` (m) at ``t_end`` (s), its ``steps``,
    ``error`` (m: measured against the reference when ``measured``, else the aim), ``wall_s``
    (s, for the whole run on this machine) and ``status`` ("ok": a pilot at that step met the
    target; "estimated"; "skipped", "not piloted", "failed", "no estimate"), fastest first; and
    the line saying how errors were measured (module docstring)."""
    from ..stepper import bind_integrator

    bound: dict = {}

    def bind(name):  # one integrator per method: its kernels compile once
        if name not in bound:
            bound[name] = bind_integrator(scene, name)
        return bound[name]

    rows = candidates(scene, table, t_end, integrators)
    lower_bounds(rows, t_end, f_seconds(scene) if f_time is None else f_time)
    reference, line = make_reference(scene, table, target_error, t_end, bind)
    events = has_events(scene)
    if reference is None and (events or line.startswith("no error estimate")):
        why = line if line.startswith("no error estimate") else (
            line + "; and a Richardson estimate (runs at h and h/2) is not valid on a scene with contact "
            "or other events between steps (its error need not shrink as h^p)")
        for row in rows:
            row.update(status="no estimate", note="see below")
        return rows, why
    judge = Judge(scene, t_end, reference)
    search = _Search(scene, rows, judge, bind, target_error, t_end, budget, events)
    search.run(progress)
    rows.sort(key=_rank)
    if reference is None:
        line = line + "; errors are Richardson estimates (runs at h and h/2, each at the declared order)"
    return rows, line


RANK = {"ok": 0, "estimated": 1, "skipped": 2, "not piloted": 3}


def _rank(row: dict):
    """Shown to meet the target first, then estimated, then the rest; fastest first (a step
    left unsolved, where only Richardson judged it, after the solved)."""
    return (RANK.get(row["status"], 4), row.get("unsolved", False), row.get("wall_s", math.inf),
            row.get("bound", math.inf))


class _Search:
    """The pilots of :func:`recommend` (module docstring, steps 2-4)."""

    def __init__(self, scene, rows, judge, bind, target, t_end, budget, events):
        self.scene, self.rows, self.judge, self.bind = scene, rows, judge, bind
        self.target, self.t_end, self.budget, self.events = target, t_end, budget, events
        self.spent = 0.0
        self.best = math.inf  # wall seconds of the fastest run shown to meet the target
        self.f_step = math.inf  # the least wall time per f evaluation a fixed-work pilot stepped at
        self.scene_method = getattr(scene, "default_integrator", None)

    def run(self, progress=None) -> None:
        """Pilot, always the cheapest next run first (module docstring, step 3): a fixed-work
        method's first pilot (its cost is its lower bound) or a second or third pilot at an
        estimated step (its cost is the estimate), while it could beat the best run shown and
        fits the budget; when none is left, the iterative methods' first pilots (their work per
        step is not known before they run: they go once the fixed-work methods have set a time
        to beat, and give up when slower), and then their second and third, cheapest first."""
        while True:
            if math.isfinite(self.f_step):
                # bounds at the f time the pilots' steps showed: it carries the step's overhead
                # and the load the machine is under, which a bare f evaluation does not
                for row in self.rows:
                    if row["status"] == "waiting" and row["evals"] is not None:
                        row["bound"] = max(row["bound"], math.ceil(self.t_end / row["h_max"] - 1e-9)
                                           * row["evals"] * self.f_step)
            fixed = [(r["bound"], r, r["h_max"]) for r in self.rows
                     if r["status"] == "waiting" and r["evals"] is not None]
            again = [(r["wall_s"], r, r["h"]) for r in self.rows if r["status"] == "estimated"
                     and len(r["pilots"]) < MAX_PILOTS and not r.get("tried")]
            ready = [c for c in fixed + again if c[0] < min(self.best, self.budget - self.spent)
                     and c[1]["status"] in ("waiting", "estimated")]
            tiers = ([c for c in ready if c[1]["evals"] is not None],
                     # the scene's own method first (vbd on the contact cloths, xpbd on cloth-stiff)
                     [(float(r["integrator"] != self.scene_method), r, r["h_max"]) for r in self.rows
                      if r["status"] == "waiting" and r["evals"] is None],
                     [c for c in ready if c[1]["evals"] is None])
            tier = next((t for t in tiers if t), None)
            if tier is None or self.spent >= self.budget:
                break
            _, row, h = min(tier, key=lambda c: c[0])
            first = row["status"] == "waiting"
            self.pilot(row, h)
            if first and progress is not None:
                progress.update(1)
        for row in self.rows:
            if row["status"] != "waiting":
                continue
            if row["evals"] is not None and row["bound"] >= self.best:
                row.update(status="skipped", note=f"at least {row['bound']:.3g} s at its largest step, slower "
                                                  f"than {self.best:.3g} s already shown")
            elif row["evals"] is not None and row["bound"] >= self.budget - self.spent:
                row.update(status="not piloted", note=f"at least {row['bound']:.3g} s at its largest step, more "
                                                      f"than the pilot budget left (--budget)")
            else:
                row.update(status="not piloted", note=f"the pilot budget ({self.budget:g} s, --budget) was spent")

    def pilot(self, row: dict, h: float) -> None:
        """A run of the row's method at ``h`` judged against the reference: the row then says
        it met the target there, or the step and time estimated for it (module docstring)."""
        start = time.perf_counter()
        try:
            integrator = self.bind(row["integrator"])
            # a run slower than the best shown cannot win; nor may it outlast the budget
            give_up = min(self.best, max(self.budget - self.spent, 0.0))
            pilot = self.judge(integrator, h, row["order"], give_up=give_up)
        except Exception as exc:  # a candidate's failure must not end the advice
            row.update(status="error", note=f"{type(exc).__name__}: {exc}".splitlines()[0][:200])
            return
        finally:
            self._spend(row, start)
        if pilot.timed_out:
            if not row["pilots"]:
                slower = give_up == self.best
                row.update(status="skipped" if slower else "not piloted",
                           note=(f"a run at its largest step is slower than {self.best:.3g} s already shown"
                                 if slower else f"the pilot budget ({self.budget:g} s, --budget) was spent"))
            else:
                row["note"] += f"; a run at {h:.3g} s was stopped after {give_up:.3g} s (slower than the best)"
                row["tried"] = True
            return
        if pilot.error is None:
            if not row["pilots"] and not row.get("retried"):
                row["retried"] = True  # once more at a quarter of the step
                return self.pilot(row, h / 4)
            row.update(status="failed", note=pilot.message.split(";")[0])
            return
        row["pilots"].append((h, pilot.error))
        if row["evals"] and math.isfinite(pilot.per_step):
            self.f_step = min(self.f_step, pilot.per_step / row["evals"])
        steps = math.ceil(self.t_end / h - 1e-9)
        limited = row["max_by"] if h == row["h_max"] else "accuracy"
        note = "; ".join(w.split(";")[0] for w in pilot.warnings)
        # Richardson sees only how the answer moves with the step: a fixed-work method that
        # leaves its step unsolved may hardly move at any step and look accurate (ranked last)
        row["unsolved"] = bool(pilot.warnings) and self.judge.reference is None
        if pilot.error <= self.target:
            wall = steps * pilot.per_step
            row.update(status="ok", h=h, steps=steps, error=pilot.error, measured=True, wall_s=wall,
                       limited_by=limited, note=note)
            self.best = min(self.best, wall)
            return
        order = self._order(row)
        h_next = h * (MARGIN * self.target / pilot.error) ** (1 / order)
        steps = math.ceil(self.t_end / h_next - 1e-9)
        row.update(status="estimated", h=h_next, steps=steps, error=MARGIN * self.target, measured=False,
                   limited_by="accuracy", note=f"{pilot.error:.2g} m at {h:.3g} s; at order {order:.2g}")
        if steps > MAX_STEPS:
            row.update(status="failed", wall_s=math.inf,
                       note=row["note"] + f": the target would take about {steps:.3g} steps")
            return
        # the cost per step at that step (an iterative solve works harder at longer steps; a
        # short pilot's per-step time is mostly its guard checks, which a long run spreads out)
        start = time.perf_counter()
        try:
            row["wall_s"] = steps * probe_step(self.scene, integrator, h_next)
        finally:
            self._spend(row, start)

    def _spend(self, row: dict, start: float) -> None:
        """Count the seconds since ``start`` against the budget and the row's ``spent_s``."""
        took = time.perf_counter() - start
        self.spent += took
        row["spent_s"] = row.get("spent_s", 0.0) + took

    def _order(self, row: dict) -> float:
        """The order to extrapolate with: the declared one (at most 1 with events between the
        steps), or the one the last two pilots show, kept within [PILOT_MIN_ORDER, declared + 1]."""
        declared = min(row["order"], 1) if self.events else row["order"]
        pilots = row["pilots"]
        if len(pilots) >= 2:
            (h1, e1), (h2, e2) = pilots[-2:]
            if h1 != h2 and e1 > 0 and e2 > 0:
                seen = math.log(e1 / e2) / math.log(h1 / h2)
                return min(max(seen, PILOT_MIN_ORDER), row["order"] + 1)
        return declared
