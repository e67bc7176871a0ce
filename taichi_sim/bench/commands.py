"""What ``taichi-sim bench ...`` and ``taichi-sim advise`` do (the CLI parses, this runs)."""
from __future__ import annotations

import math
import sys

from ..errors import ConfigError
from . import common
from .options import _fmt, _integrator_names, _meta, _names

BENCH_NAMES = ("work-precision", "stability", "throughput")  # what `bench all` runs


def bench_main(args) -> int:
    """Dispatch ``taichi-sim bench NAME``; every name checks its options before any work."""
    which = list(BENCH_NAMES) if args.bench_command == "all" else [args.bench_command]
    plans = [(name, _planners()[name](args)) for name in which]  # validate every option first
    out = common.prepare_out_dir(args.out)
    code = 0
    for name, run in plans:
        code = max(code, run(out) or 0)
    return code


def _int_list(text: str, what: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"--{what} expects comma-separated integers, got {text!r}") from None
    if not values or min(values) < 2:
        raise ConfigError(f"--{what} expects integers >= 2, got {text!r}")
    return values


def _plan_throughput(args):
    from .throughput import ThroughputConfig

    sizes = _int_list(args.sizes, "sizes") if getattr(args, "sizes", None) else \
        ([8, 16] if args.quick else [32, 64, 128, 256, 512])
    precisions = _names(getattr(args, "precisions", None), ["f32", "f64"], "precisions") or \
        (["f32"] if args.quick else ["f32", "f64"])
    integrators = _integrator_names(getattr(args, "integrators", None))
    features_size = getattr(args, "features_size", None)
    if features_size is None:
        features_size = 128 if 128 in sizes else sizes[min(len(sizes) - 1, 2)]
    if getattr(args, "no_features", False):
        features_size = None
    config = ThroughputConfig(sizes=tuple(sizes), precisions=tuple(precisions), integrators=tuple(integrators),
                              dt=getattr(args, "dt", None) or 1e-4,
                              repeats=getattr(args, "repeats", None) or (5 if args.quick else 7),
                              batch_seconds=getattr(args, "batch_seconds", None) or (0.02 if args.quick else 0.25),
                              features_size=features_size, peers=not getattr(args, "no_peers", False),
                              cli_size=None if args.quick else 128, profile_size=None if args.quick else 128,
                              start_up=not args.quick, variants=not args.quick)

    def run(out):
        from . import plots
        from .throughput import run_throughput, task_count

        with common.progress_bar(task_count(config), "throughput", args.quiet) as bar:
            rows, details = run_throughput(config, progress=bar)
        cfg = {k: getattr(config, k) for k in ("sizes", "precisions", "integrators", "dt", "repeats",
                                               "batch_seconds", "max_step_seconds", "features_size", "peers",
                                               "cli_size", "cli_steps", "profile_size", "start_up",
                                               "variants")}
        payload = {**_meta("throughput", args, cfg), **details}
        paths = common.write_outputs(out, "throughput", rows, payload, lambda f: plots.throughput(rows, details, f))
        if not args.quiet:
            print_throughput(rows, details)
        common.report_written(paths, args.quiet)

    return run


def print_throughput(rows: list[dict], details: dict) -> None:
    table = []
    for r in rows:
        if r.get("kind") not in ("ours", "duel", "peer"):
            continue
        rate = r.get("particle_steps_per_s")
        label = f"{r.get('name')} (alternated with the peers)" if r.get("kind") == "duel" else r.get("name")
        table.append([r.get("precision"), r.get("n"), label, r.get("step_s") and 1e3 * r["step_s"],
                      rate, r.get("spring_evals_per_s"), r.get("first_step_s"),
                      r.get("status") if r.get("status") == "ok" else f"{r.get('status')}: {r.get('note', '')}"])
    print("Throughput (median ms per step; particle-steps/s; spring evaluations/s, each spring once per f):")
    print(common.format_table(["precision", "n", "method", "ms/step", "particle-steps/s", "spring-evals/s",
                               "first step (s)", "status"], table))
    feats = [r for r in rows if r.get("kind") == "feature"]
    if feats:
        print("\nFeatures (symplectic Euler, same grid):")
        print(common.format_table(["precision", "n", "scene", "ms/step", "particle-steps/s", "status"],
                                  [[r["precision"], r["n"], r["name"], r.get("step_s") and 1e3 * r["step_s"],
                                    r.get("particle_steps_per_s"), r.get("status")] for r in feats]))
    print("\nOur symplectic Euler against the peers (particle-steps/s ratio) and rk4 per-step cost:")
    summary = details.get("summary", [])
    print(common.format_table(["precision", "n", "ours / taichi example", "ours / warp", "rk4 / symplectic",
                               "general path / stencil", "run() overhead"],
                              [[s["precision"], s["n"], s.get("ratio_vs_taichi"), s.get("ratio_vs_warp"),
                                s.get("rk4_over_symplectic"), s.get("stencil_speedup"),
                                None if s.get("run_overhead") is None else f"{100 * s['run_overhead']:+.1f} %"]
                               for s in summary]))
    kernels = [r for r in rows if r.get("kind") == "kernel" and r.get("kernel")]
    if kernels:
        print(f"\nPer-kernel time (Taichi's kernel profiler, {kernels[0]['precision']}, "
              f"{kernels[0]['n']} x {kernels[0]['n']}; the profiler slows launches, so wall times here are not the "
              f"table's):")
        print(common.format_table(["integrator", "kernel loop", "launches / step", "ms / launch", "ms / step",
                                   "wall ms / step"],
                                  [[r["integrator"], r["kernel"], r["launches"] / r["steps"], 1e3 * r["mean_s"],
                                    1e3 * r["total_s"] / r["steps"], 1e3 * r["wall_step_s"]] for r in kernels]))
    for r in rows:
        if r.get("kind") == "cli":
            if r.get("status") == "ok":
                print(f"\nThrough the command line ({r['precision']}, {r['n']} x {r['n']}, symplectic Euler): "
                      f"{1e3 * r['step_s']:.3g} ms per step ({r['steps']} steps more took "
                      f"{r['long_s'] - r['short_s']:.3g} s; start-up and saving cancel out)")
            else:
                print(f"\nThrough the command line: {r.get('status')}: {r.get('note')}")
        if r.get("kind") == "start":
            if r.get("status") == "ok":
                print(f"Start-up, `taichi-sim {r['name']}` from process start to exit ({r['precision']}): "
                      f"{r['warm_s']:.2f} s with Taichi's kernel cache warm, {r['cold_s']:.2f} s with it empty")
            else:
                print(f"Start-up: {r.get('status')}: {r.get('note')}")
    for s in summary:
        if s.get("cli_overhead") is not None:
            print(f"command line per step vs the bare loop ({s['precision']}, {s['n']}): "
                  f"{100 * s['cli_overhead']:+.1f} % (separate processes, not alternated)")
    for t in details.get("targets", []):
        print(f"target: {t['target']}: {t['value']:.3g} -> {'met' if t['met'] else 'NOT met'}")
    for s in summary:
        for key in ("taichi", "warp"):
            if s.get(f"{key}_unavailable"):
                print(f"peer unavailable ({key}, {s['precision']}, n = {s['n']}): {s[f'{key}_unavailable']}")


def _planners() -> dict:
    from .studies import plan_extremes, plan_precision, plan_stability, plan_stiff_cloth, plan_work_precision

    return {"stiff-cloth": plan_stiff_cloth, "work-precision": plan_work_precision, "stability": plan_stability,
            "throughput": _plan_throughput, "extremes": plan_extremes, "precision": plan_precision}


def advise_main(args) -> int:
    """``taichi-sim advise SCENE``: the stability table and, with --target-error, a recommendation."""
    from .. import runtime
    from ..integrators import INTEGRATORS, integrator_class
    from ..scene import build_scene, scene_preset
    from ..scene.params import resolve, scene_assignments
    from ..scene.presets import check_scene_memory
    from .advise import scene_omegas, stability_table

    preset = scene_preset(args.scene)
    params = scene_assignments(args.assignments)
    # ConfigError before any Taichi work; the pilot runs build one scene per candidate, in turn
    check_scene_memory(preset, resolve(preset.params, preset.name, params), precision=args.precision,
                       integrators=(integrator_class("implicit_euler"),))
    integrators = _integrator_names(args.integrators) if args.integrators else None
    if args.target_error is not None and not (math.isfinite(args.target_error) and args.target_error > 0):
        raise ConfigError(f"--target-error must be a finite number > 0, got {args.target_error}")
    if not (math.isfinite(args.budget) and args.budget > 0):
        raise ConfigError(f"--budget must be a finite number > 0, got {args.budget}")
    runtime.init(arch=args.arch, precision=args.precision)
    scene = build_scene(args.scene, params, seed=args.seed)
    omegas = scene_omegas(scene)
    table = stability_table(scene, omegas, args.t_end,
                            list(INTEGRATORS) + [n for n in integrators or () if n not in INTEGRATORS])
    springs = scene.features.get("springs", 0)
    print(f"{scene.name}: {scene.particle_count} particles, {springs} springs; omega_max = "
          f"{_fmt(omegas['omega_max'])} rad/s ({omegas['method']}), Gershgorin bound {_fmt(omegas['omega_bound'])} rad/s"
          + (f"; damping rate gamma_max = {_fmt(omegas['gamma_max'])} /s (bound {_fmt(omegas['gamma_bound'])} /s)"
             if omegas.get("gamma_max") else ""))
    print(common.format_table(
        ["integrator", "order", "f-evals/step", "C", "max stable step (s)", "with the bound (s)", "note"],
        [[r["integrator"], r["order"], r["evals_per_step"] if r["evals_per_step"] is not None else "varies",
          _fmt(r["C"]), "none" if r["C"] == 0 else _fmt(r["limit"]),
          "none" if r["C"] == 0 else _fmt(r["limit_bound"]), r["note"]] for r in table]))
    if args.target_error is None:
        return 0
    return _advise_target(args, scene, table, integrators)


def _advise_target(args, scene, table, integrators) -> int:
    """The measured recommendation for --target-error (:mod:`.advise_target`), its cost said
    first."""
    import time

    from .advise_target import candidates, cost_line, f_seconds, lower_bounds, recommend

    start = time.perf_counter()
    f_time = f_seconds(scene)
    planned = candidates(scene, table, args.t_end, integrators)
    lower_bounds(planned, args.t_end, f_time)
    if not planned:
        print("\nno candidates: no fixed-step method has a predicted step here (the table's notes say why)")
        print("no fixed-step integrator could be recommended", file=sys.stderr)
        return 1
    print("\n" + cost_line(scene, table, planned, args.t_end, f_time, args.budget), flush=True)
    with common.progress_bar(len(planned), "pilot runs", False) as bar:
        rows, measured = recommend(scene, table, args.target_error, args.t_end, integrators, budget=args.budget,
                                   f_time=f_time, progress=bar)
    if all(r["status"] == "no estimate" for r in rows):
        print(f"\n{measured}")
        print("no fixed-step integrator could be recommended", file=sys.stderr)
        return 1
    print(f"\nFor a position error of {args.target_error:g} m at t = {args.t_end:g} s, fastest run first "
          f"(wall time on this machine; see `taichi_sim.bench.advise_target`):")
    print(common.format_table(
        ["integrator", "order", "step (s)", "limited by", "steps", "error (m)", "run time (s)", "status"],
        [[r["integrator"], r["order"], r.get("h"), r.get("limited_by"), r.get("steps"), _error_cell(r),
          r.get("wall_s"), r["status"] + (f": {r['note']}" if r.get("note") else "")] for r in rows]))
    print(measured)
    print(f"advised in {time.perf_counter() - start:.0f} s")
    best = next((r for r in rows if r["status"] in ("ok", "estimated")), None)
    if best is None:
        print("no fixed-step integrator could be recommended", file=sys.stderr)
        return 1
    shown = ("shown by a pilot run at that step" if best["status"] == "ok" else
             "estimated, not shown by a run at that step: check it with a run at half the step")
    print(f"recommended: --integrator {best['integrator']} --dt {best['h']:.3g} ({best['steps']} steps, "
          f"about {best['wall_s']:.3g} s on this machine; error {_error_cell(best)} m, {shown})")
    return 0


def _error_cell(row: dict) -> str | None:
    """A measured error as it is; an estimated one marked with "~"."""
    if row.get("error") is None:
        return None
    return f"{row['error']:.2g}" if row.get("measured") else f"~{row['error']:.2g}"
