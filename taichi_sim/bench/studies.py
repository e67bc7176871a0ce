"""The benches that run on the sweep engine (:mod:`taichi_sim.bench.sweep`): ``bench
extremes``, ``bench stiff-cloth`` and ``bench precision``. Each plans its cases, runs those its
table does not hold yet (``--jobs`` at once, or on ``--scheduler``), then writes the JSON and
the plot and prints its summary from the table as written."""
from __future__ import annotations

import math
import sys

from ..errors import ConfigError
from . import common
from .options import _float_list, _fmt, _integrator_names, _meta, _names


def open_sweep(args, study, planned, out):
    """The :class:`Sweep` for the bench's sweep options (all checked here, before any case)."""
    from .sweep import Sweep

    return Sweep(study, planned, out, jobs=getattr(args, "jobs", None), scheduler=getattr(args, "scheduler", None),
                 timeout_s=getattr(args, "case_timeout", None), fresh=getattr(args, "fresh", False),
                 quiet=args.quiet)


def sweep_meta(sweep, rows: list[dict]) -> dict:
    """What the JSON says about how the cases ran (timings depend on it)."""
    overlap = [r.get("concurrency") for r in rows if isinstance(r.get("concurrency"), int)]
    return {"sweep": {"where": sweep.pool.where, "case_timeout_s": sweep.timeout_s, "table": str(sweep.path),
                      "cases_run_now": len(sweep.ran), "most_at_once": max(overlap, default=None)}}


def timing_note(rows: list[dict], column: str) -> None:
    """Say when timed cases shared the machine (their ``column`` then measures a loaded one)."""
    shared = [r for r in rows if isinstance(r.get("concurrency"), int) and r["concurrency"] > 1
              and r.get(column) is not None]
    if shared:
        most = max(r["concurrency"] for r in shared)
        print(f"note: {len(shared)} timed rows ran with up to {most} cases at once (column `concurrency`): their "
              f"{column} are slower than alone; --jobs 1 times each case alone")


def plan_extremes(args):
    from .extremes import QUICK_SCENES, SCENES, STEP_SIZES, STEPS, STIFFNESSES

    scenes_all = dict(QUICK_SCENES if args.quick else SCENES)
    asked = getattr(args, "scenes", None)
    for name in (asked or "").split(","):  # clothN: an N x N cloth
        name = name.strip()
        if name.startswith("cloth") and name[5:].isdigit():
            if not 2 <= int(name[5:]) <= 256:
                raise ConfigError(f"--scenes: {name} needs a side from 2 to 256")
            scenes_all[name] = ("cloth", {"nx": int(name[5:]), "ny": int(name[5:])})
    try:
        scenes = _names(asked, list(scenes_all), "scenes") or list(scenes_all)
    except ConfigError as exc:
        raise ConfigError(f"{str(exc)[:-1]}, or clothN for an N x N cloth)") from None
    integrators = _integrator_names(getattr(args, "integrators", None))
    stiffnesses = _float_list(getattr(args, "stiffnesses", None), "stiffnesses", STIFFNESSES)
    step_sizes = _float_list(getattr(args, "step_sizes", None), "step-sizes", STEP_SIZES)
    steps = getattr(args, "steps", None) or (10 if args.quick else STEPS)

    def run(out):
        from . import plots
        from .extremes import outcome_table, plan_cases, study

        chosen = {s: scenes_all[s] for s in scenes}
        cases = plan_cases(chosen, integrators, stiffnesses, step_sizes, steps)
        sweep = open_sweep(args, study(), cases, out)
        try:
            rows = sweep.run(cases, "extremes")
        finally:
            sweep.close()
        table = outcome_table(rows)
        payload = {**_meta("extremes", args, {"scenes": {s: list(scenes_all[s]) for s in scenes},
                                               "integrators": integrators, "stiffnesses": stiffnesses,
                                               "step_sizes": step_sizes, "steps": steps, "precision": "f64"}),
                   **sweep_meta(sweep, rows), "outcomes": table}
        paths = common.write_outputs(out, "extremes", rows, payload, lambda f: plots.extremes(rows, f))
        if not args.quiet:
            print_extremes(rows, table)
        common.report_written(paths, args.quiet)
        bad = sum(c["silent"] + c["error"] + c["timeout"] for c in table.values())
        if bad:
            print(f"taichi-sim: {bad} runs blew up silently, crashed or timed out (see extremes.csv)", file=sys.stderr)
        return 1 if bad else 0

    return run


def print_extremes(rows: list[dict], table: dict) -> None:
    print("Runs at the extremes: ok (bounded, status ok), reported (status not ok, with a message), "
          "refused (the method does not take the material, said before running), silent (status ok, but the audit finds a blow-up), error (a crash), timeout (a stopped case):")
    print(common.format_table(["integrator", "ok", "reported", "refused", "silent", "error", "timeout"],
                              [[name, c["ok"], c["reported"], c["refused"], c["silent"], c["error"], c["timeout"]]
                               for name, c in table.items()]))
    for row in rows:
        if row["outcome"] in ("silent", "error", "timeout"):
            where = "" if row.get("stiffness") is None else f" k={row['stiffness']:g} dt={row['dt']:g}"
            print(f"  {row['outcome']}: {row['scene']} {row['integrator']}{where}: {row['reason']}")


def plan_stiff_cloth(args):
    from .stiffcloth import METHODS, STEPS

    size = getattr(args, "size", None) or (8 if args.quick else 64)
    if not 2 <= size <= 256:
        raise ConfigError(f"--size must be from 2 to 256, got {size}")
    stiffnesses = _float_list(getattr(args, "stiffnesses", None), "stiffnesses",
                              (1e4,) if args.quick else (1e2, 1e4, 1e8))
    steps = _float_list(getattr(args, "step_sizes", None), "step-sizes", STEPS[:2] if args.quick else STEPS)
    t_end = getattr(args, "t_end", None) or (0.1 if args.quick else 0.5)
    budget = getattr(args, "budget", None) or (10.0 if args.quick else 60.0)
    studied = list(dict.fromkeys(name for name, _ in METHODS))
    chosen = _integrator_names(getattr(args, "integrators", None)) if getattr(args, "integrators", None) else studied
    # a method outside the study (another built-in, a plug-in) runs with its default options
    methods = tuple(m for m in METHODS if m[0] in chosen) + tuple((n, {}) for n in chosen if n not in studied)

    def run(out):
        from . import plots
        from .stiffcloth import plan_cases, split_rows, study, with_reference

        references, studied_cases = plan_cases(size, stiffnesses, steps, methods, t_end=t_end, budget_s=budget)
        sweep = open_sweep(args, study(), references + studied_cases, out)
        try:
            sweep.run(references, "stiff-cloth references", needs_arrays=True)
            solved = {case.params["k"]: sweep.arrays(case)["x"] for case in references
                      if sweep.finished(case, needs_arrays=True)}
            missing = sorted(set(c.params["k"] for c in references) - set(solved))
            if missing:
                print(f"taichi-sim: stiff-cloth: no reference for k = {', '.join(f'{k:g}' for k in missing)} "
                      f"(see the reference rows): those stiffnesses are not studied", file=sys.stderr)
            runnable = [with_reference(c, solved[c.params["k"]]) for c in studied_cases if c.params["k"] in solved]
            sweep.run(runnable, "stiff-cloth")
            rows = sweep.rows(references + studied_cases)
        finally:
            sweep.close()
        accuracy, details = split_rows(rows, size, t_end, budget)
        payload = {**_meta("stiff-cloth", args, {"size": size, "stiffnesses": stiffnesses, "step_sizes": steps,
                                                  "t_end": t_end, "budget_s": budget, "precision": "f64"}),
                   **sweep_meta(sweep, rows), **details}
        paths = common.write_outputs(out, "stiff-cloth", rows, payload,
                                     lambda f: plots.stiff_cloth(accuracy, details, f))
        if not args.quiet:
            print_stiff_cloth(accuracy, details)
            timing_note(accuracy + details["damping"], "wall_s")
        common.report_written(paths, args.quiet)

    return run


def _said_so(row: dict) -> str:
    """Whether a run reported that it had not converged ("-" for a method that solves nothing)."""
    residual = row.get("residual")
    if residual is None or residual != residual:  # NaN: not measured
        return "-"
    return "yes" if row.get("warned") in (True, "True", 1) else "no"


def print_stiff_cloth(rows: list[dict], details: dict) -> None:
    print(f"{details['size']}x{details['size']} cloth, rms position error at T = {details['t_end']:g} s against "
          f"symplectic Euler at a quarter of its stable step (f64):")
    print(common.format_table(
        ["k (N/m)", "method", "h (s)", "status", "ms/step", "rms error (m)", "estimated error a step (m)",
         "solver residual", "said so"],
        [[f"{r['k']:g}", r["method"], _fmt(r.get("h")), r["status"], _fmt(r.get("ms_per_step")),
          _fmt(r.get("error_rms")), _fmt(r.get("error_estimate")), _fmt(r.get("residual")), _said_so(r)]
         for r in rows]))
    print("Artificial damping (no dashpots, no drag; h = 1/60 s, 1 s):")
    print(common.format_table(
        ["k (N/m)", "method", "status", "energy lost per s", "highest rise above start (J)"],
        [[f"{d['k']:g}", d["method"], d["status"],
          "-" if d.get("fraction_lost_per_s") is None else f"{100 * d['fraction_lost_per_s']:.1f} %",
          "-" if d.get("energy_rise") is None else _fmt(max(d["energy_rise"], 0.0))] for d in details["damping"]]))


def plan_precision(args):
    from .precision import QUICK_T_END, SCENES, T_END

    scenes = _names(getattr(args, "scenes", None), list(SCENES), "scenes") or list(SCENES)
    integrators = _integrator_names(getattr(args, "integrators", None))
    t_end = getattr(args, "t_end", None) or (QUICK_T_END if args.quick else T_END)

    def run(out):
        from . import plots
        from .precision import DISAGREE, findings, plan_cases, study, summary_rows

        cases = plan_cases(integrators, scenes, t_end)
        sweep = open_sweep(args, study(), cases, out)
        try:
            rows = sweep.run(cases, "precision")
        finally:
            sweep.close()
        payload = {**_meta("precision", args, {"scenes": {s: dict(zip(("stiffness", "dt"), SCENES[s])) for s in scenes},
                                                "integrators": integrators, "t_end": t_end, "disagree": DISAGREE}),
                   **sweep_meta(sweep, rows), "findings": findings(rows)}
        paths = common.write_outputs(out, "precision", rows, payload, lambda f: plots.precision(rows, DISAGREE, f))
        if not args.quiet:
            print(f"f32 against f64, same method and step, T = {t_end:g} s (distance: largest particle distance "
                  f"over the cloth's size; residual: the worst solver residual, '-' for explicit methods):")
            print(common.format_table(["scene", "integrator", "f64", "f32", "f32 vs f64", "residual f64",
                                       "residual f32", "finding"], summary_rows(rows)))
            for r in findings(rows):
                print(f"  finding: {r['scene']} {r['integrator']}: {r['finding']}")
        common.report_written(paths, args.quiet)
        return 0

    return run


def plan_stability(args):
    from .stability import QUICK_SYSTEMS, SYSTEMS

    systems = QUICK_SYSTEMS if args.quick else SYSTEMS
    names = _names(getattr(args, "systems", None), list(systems), "systems") or list(systems)
    integrators = _integrator_names(getattr(args, "integrators", None))
    periods = getattr(args, "periods", None) or (100.0 if args.quick else 1000.0)
    rel_tol = getattr(args, "rel_tol", None) or (1e-2 if args.quick else 1e-3)
    max_steps = getattr(args, "max_steps", None) or 20000

    def run(out):
        from . import plots
        from .stability import plan_cases, study, system_info

        chosen = {s: systems[s] for s in names}
        cases = plan_cases(chosen, integrators, periods=periods, rel_tol=rel_tol, max_steps=max_steps)
        sweep = open_sweep(args, study(), cases, out)
        try:
            rows = sweep.run(cases, "stability")
        finally:
            sweep.close()
        details = {"systems": {s: system_info(systems[s]) for s in names}, "periods": periods, "rel_tol": rel_tol,
                   "max_steps": max_steps}
        payload = {**_meta("stability", args, {"systems": names, "integrators": integrators, "periods": periods,
                                                "rel_tol": rel_tol, "max_steps": max_steps, "precision": "f64"}),
                   **sweep_meta(sweep, rows), **details}
        paths = common.write_outputs(out, "stability", rows, payload, lambda f: plots.stability(rows, details, f))
        if not args.quiet:
            print_stability(rows)
        common.report_written(paths, args.quiet)

    return run


def plan_work_precision(args):
    from .workprec import EXACT_SCENES, PROBLEMS, QUICK_PROBLEMS

    problems = QUICK_PROBLEMS if args.quick else PROBLEMS
    scenes = _names(getattr(args, "scenes", None), list(problems), "scenes") or list(problems)
    integrators = _integrator_names(getattr(args, "integrators", None))
    repeats = getattr(args, "repeats", None) or (1 if args.quick else 5)
    unsolvable = [] if common.have_scipy() else [s for s in scenes if s not in EXACT_SCENES]
    if unsolvable:
        why = (f"their truth is scipy's reference solution and scipy is not installed "
               f"({common.INSTALL_HINT})")
        scenes = [s for s in scenes if s not in unsolvable]
        if not scenes:
            raise ConfigError(f"work-precision cannot measure {', '.join(unsolvable)}: {why}")
        print(f"taichi-sim: work-precision skips {', '.join(unsolvable)}: {why}", file=sys.stderr)
    budget = getattr(args, "budget", None) or (20.0 if args.quick else 120.0)

    def run(out):
        from . import plots
        from .workprec import orders, plan_cases, study, truth_of, with_truth

        chosen = {s: problems[s] for s in scenes}
        truth_cases, sweep_cases = plan_cases(chosen, integrators, repeats=repeats, budget_s=budget)
        sweep = open_sweep(args, study(), truth_cases + sweep_cases, out)
        try:
            sweep.run(truth_cases, "work-precision truths", needs_arrays=True)
            truths = {}
            for case in truth_cases:
                row = next(iter(sweep.rows([case])), None)
                if row is not None and row.get("status") == "ok" and sweep.finished(case, needs_arrays=True):
                    truths[case.columns["scene"]] = truth_of(row, sweep.arrays(case))
                else:
                    print(f"taichi-sim: work-precision: no truth for {case.columns['scene']} "
                          f"({(row or {}).get('note', 'see the table')}): its runs are skipped", file=sys.stderr)
            sweep.run([with_truth(c, truths[c.columns["scene"]]) for c in sweep_cases
                       if c.columns["scene"] in truths], "work-precision")
            rows = sweep.rows(truth_cases + sweep_cases)
        finally:
            sweep.close()
        runs = [r for r in rows if r.get("kind") == "run"]
        details = {"problems": {}, "orders": orders(runs, truths)}
        for r in rows:
            if r.get("kind") == "truth":
                truth = truths.get(r["scene"])
                details["problems"][r["scene"]] = (
                    {"params": r.get("params"), "t_end": r.get("t_end"), "particles": r.get("particles"),
                     "springs": r.get("springs"), "truth": truth.kind, "truth_info": truth.info,
                     "error_floor": truth.floor, "size": truth.size, "omega_max_bound": r.get("omega_max_bound"),
                     "energy_scale": truth.energy_scale} if truth is not None else
                    {"params": chosen[r["scene"]].params, "t_end": chosen[r["scene"]].t_end,
                     "truth": "unavailable", "error": r.get("note")})
        payload = {**_meta("work-precision", args, {"scenes": scenes, "integrators": integrators,
                                                     "repeats": repeats, "budget_s": budget,
                                                     "precision": "f64", "backend": "cpu"}),
                   **sweep_meta(sweep, rows), **details}
        paths = common.write_outputs(out, "work-precision", rows, payload,
                                     lambda f: plots.work_precision(runs, details, f))
        if not args.quiet:
            print_orders(details, scenes, integrators)
            timing_note(runs, "wall_s")
        common.report_written(paths, args.quiet)

    return run


def print_orders(details: dict, scenes: list[str], integrators: list[str]) -> None:
    fits = {(o["scene"], o["integrator"]): o for o in details["orders"]}
    header = ["integrator", "declared"] + scenes
    table = []
    for name in integrators:
        row = [name, next((o["declared"] for o in details["orders"] if o["integrator"] == name), "")]
        for scene in scenes:
            o = fits.get((scene, name), {})
            value = o.get("observed")
            row.append(f"{value:.3f}" + (" (cost)" if o.get("basis") == "cost" else "")
                       if isinstance(value, float) and math.isfinite(value) else "-")
        table.append(row)
    print("Observed orders (slope of the state error against h; adaptive: against cost):")
    print(common.format_table(header, table))
    fixed = [o for o in details["orders"] if o.get("basis") == "h" and isinstance(o.get("observed"), float)
             and math.isfinite(o["observed"])]
    within = [o for o in fixed if abs(o["observed"] - o["declared"]) <= 0.1]
    print(f"fixed-step fits within +-0.1 of the declared order: {len(within)} of {len(fixed)}"
          + "".join(f"; {o['integrator']} on {o['scene']}: {o['observed']:.3f}" for o in fixed if o not in within))


def print_stability(rows: list[dict]) -> None:
    table = []
    for r in rows:
        if r["kind"] == "n/a":
            continue
        if r.get("stiffness") is None:  # a case that timed out or crashed
            table.append([r["system"], "-", None, r["integrator"], None, None, None,
                          f"{r['kind']}: {str(r.get('note', ''))[:80]}"])
            continue
        bracket = (f"{r['ratio']:.4f} - {r['ratio_above']:.4f}" if isinstance(r.get("ratio"), float)
                   and isinstance(r.get("ratio_above"), float) else r.get("ratio"))
        table.append([r["system"], f"{r['stiffness']:g}", r.get("omega_max"), r["integrator"], r.get("predicted"),
                      r.get("measured"), bracket,
                      r["kind"] if r["kind"] != "error" else f"error: {r.get('note', '')[:80]}"])
    print("Largest stable step (measured by bisection) against C / omega_max:")
    print(common.format_table(["system", "k (N/m)", "omega_max", "integrator", "C/omega_max (s)",
                               "largest stable (s)", "limit / prediction in", "kind"], table))
    for name in ("symplectic_euler", "rk4"):
        mine = [r for r in rows if r["integrator"] == name and r.get("kind") == "limit"
                and isinstance(r.get("ratio"), float)]
        if mine:
            lo = min(r["ratio"] for r in mine)
            hi = max(r.get("ratio_above") or r["ratio"] for r in mine)
            print(f"{name}: limit / prediction between {lo:.4f} and {hi:.4f} over {len(mine)} systems "
                  f"({'all' if lo >= 0.95 and hi <= 1.05 else 'NOT all'} within 5 %)")
