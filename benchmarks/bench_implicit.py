"""Benchmark: implicit Euler (exact, and the one-step Baraff-Witkin linearisation) on a 64 x 64
cloth (``--size``) at dt = 1/60 s: CG against the sparse direct solver, in f32 and f64, at one or several
stiffnesses.

Run from the repository root (outside pytest):

    .venv/bin/python benchmarks/bench_implicit.py [--arch cpu] [--batches 7] [--batch-steps 10]
        [--integrators implicit_euler,implicit_euler_linearised] [--stiffness 1e4,1e8]
        [--cg-tolerance TOL] [--preconditioner ssor|jacobi] [--no-warm-start] [--threads N]
        [--size N] [--accuracy]

For every (integrator, stiffness, precision, solver) the scene is built fresh, stepped ``--warmup`` times (kernel
compilation, the direct solver's pattern analysis), then timed over ``--batches`` batches of
``--batch-steps`` steps. Reported: steps per second (median over batches, with the min-max
range), linear-solver iterations per step, Newton iterations and solved substeps per step (the exact
method), the linear solver's wall time per step and per
iteration (CG; the per-solve cache fill and start included), and for the direct solver the mean
time of one numeric factorisation and of the one-off symbolic analysis. A second table splits
the direct solver's time per step into its phases: assembly (the kernel filling the matrix
builder, and ``build()``), numeric factorisation, triangular solves (with the copies of their
vectors), and the rest of the linear solves (the residual check); the analysis ran in the
warm-up (it runs once per sparsity pattern) and is given once. The 1-minute load average is
printed first: other processes on the machine slow every figure.

``--accuracy`` measures instead what the CG tolerance does to the result, in each precision:
one step from the same state (t = 0.5 s) and 1 s of simulation, solved by CG at several
tolerances and by the direct solver (the exact linear solve), against the method's own error
(the direct solver at h against h/2).
"""
import argparse
import os
import statistics
import time

import numpy as np
import taichi as ti

import taichi_sim as ts
from taichi_sim.scene.cloth import fixed_particle_cloth

N = 64
STIFFNESS = 1e4  # N/m, structural, shear and flex alike (the default; --stiffness)
DT = 1 / 60  # s


def cloth_params(stiffness: float = STIFFNESS, size: int = N) -> dict:
    return {"nx": size, "ny": size, "stiffness": stiffness, "shear_stiffness": stiffness, "flex_stiffness": stiffness,
            **fixed_particle_cloth(size, size)}


def init(precision: str, args) -> None:
    ts.init(arch=args.arch, precision=precision, cpu_max_num_threads=args.threads)


def integrator_options(args, solver: str = "cg") -> dict:
    options = {"warm_start": not args.no_warm_start, "linear_solver": solver}
    if args.cg_tolerance is not None:
        options["cg_tolerance"] = args.cg_tolerance
    if args.preconditioner is not None and solver == "cg":
        options["preconditioner"] = args.preconditioner
    return options


def bench(name: str, stiffness: float, precision: str, solver: str, args) -> dict:
    init(precision, args)
    scene = ts.build_scene("cloth", cloth_params(stiffness, args.size))
    integrator = ts.create_integrator(name, scene.system, **integrator_options(args, solver))
    stats = integrator.stats
    t = 0.0

    def advance(steps: int) -> None:
        nonlocal t
        for _ in range(steps):
            report = integrator.step(scene.state, t, DT)
            if report.status is not ts.Status.OK:
                raise RuntimeError(f"{precision} {solver}: {report.status.value} at t = {t:.3f} s: "
                                   f"{report.message}")
            t += DT

    advance(args.warmup)
    ti.sync()
    iterations0, factorize0, factorize_s0 = stats.iterations, stats.factorize_count, stats.factorize_seconds
    solve_s0, newton0, substeps0 = stats.solve_seconds, stats.newton_iterations, stats.substeps
    assemble_s0, substitute_s0 = stats.assemble_seconds, stats.substitute_seconds
    rates = []
    for _ in range(args.batches):
        start = time.perf_counter()
        advance(args.batch_steps)
        ti.sync()
        rates.append(args.batch_steps / (time.perf_counter() - start))
    timed_steps = args.batches * args.batch_steps
    factorizations = stats.factorize_count - factorize0
    iterations = stats.iterations - iterations0
    solve_s = stats.solve_seconds - solve_s0
    return {
        "integrator": name, "stiffness": stiffness,
        "precision": precision, "solver": f"{stats.solver}/{stats.preconditioner}" if stats.preconditioner
        else stats.solver, "rate": statistics.median(rates),
        "newton": (stats.newton_iterations - newton0) / timed_steps,
        "substeps": (stats.substeps - substeps0) / timed_steps,
        "rate_min": min(rates), "rate_max": max(rates),
        "iterations": iterations / timed_steps,
        "solve_ms": 1e3 * solve_s / timed_steps,
        "iteration_ms": 1e3 * solve_s / iterations if stats.solver == "pcg" and iterations else None,
        "factorize_ms": (1e3 * (stats.factorize_seconds - factorize_s0) / factorizations
                         if factorizations else None),
        "analyze_ms": 1e3 * stats.analyze_seconds if stats.analyze_count else None,
        "analyze_count": stats.analyze_count, "backend": ts.runtime.backend(),
        "factorizations": factorizations / timed_steps,
        # The direct solver's phases, ms per step (all zero for CG).
        "phases": {"assemble": 1e3 * (stats.assemble_seconds - assemble_s0) / timed_steps,
                   "factorize": 1e3 * (stats.factorize_seconds - factorize_s0) / timed_steps,
                   "substitute": 1e3 * (stats.substitute_seconds - substitute_s0) / timed_steps},
        "tolerance": integrator.cg_tolerance if integrator.fixed_cg_tolerance else None,
    }


def run_steps(scene, integrator, steps: int, h: float, t0: float = 0.0) -> None:
    t = t0
    for _ in range(steps):
        report = integrator.step(scene.state, t, h)
        if report.status is not ts.Status.OK:
            raise RuntimeError(f"{report.status.value} at t = {t:.3f} s: {report.message}")
        t += h


def accuracy(precision: str, args) -> None:
    """What the CG tolerance changes, against exact linear solves (the direct solver)."""
    init(precision, args)
    scene = ts.build_scene("cloth", cloth_params())
    steps = round(1.0 / DT)
    tight = 1e-8 if precision == "f64" else 1e-5
    tolerances = (1e-2, 1e-3, 1e-4, tight)
    linearised = "implicit_euler_linearised"
    integrators = {"direct": ts.create_integrator(linearised, scene.system, linear_solver="direct",
                                                  cg_tolerance=tight)}
    for tol in tolerances:
        integrators[tol] = ts.create_integrator(linearised, scene.system,
                                                **(integrator_options(args) | {"cg_tolerance": tol}))

    def trajectory(key, h: float = DT, count: int = steps):
        scene.reset()
        integrators[key].reset()
        run_steps(scene, integrators[key], count, h)
        return scene.state.to_numpy()

    def one_step(key, x, v):
        scene.state.from_numpy(x, v)
        integrators[key].reset()
        report = integrators[key].step(scene.state, 0.5, DT)
        return scene.state.v.to_numpy() - v, report

    # One step from the state at t = 0.5 s (reached with exact solves).
    x_mid, v_mid = trajectory("direct", DT, steps // 2)
    change_exact, _ = one_step("direct", x_mid, v_mid)
    # 1 s: exact solves at h, and at h / 2 for the method's own error.
    x_exact, v_exact = trajectory("direct")
    x_half, _ = trajectory("direct", DT / 2, 2 * steps)

    def deviation(a, b) -> str:
        d = np.linalg.norm(a - b, axis=1)
        return f"rms {np.sqrt(np.mean(d ** 2)):.2e} max {d.max():.2e}"

    print(f"\n{precision}: implicit_euler_linearised, 1 s of the benchmark cloth (60 steps) from rest; "
          f"one step from t = 0.5 s")
    print(f"  method error (direct, h against h/2): positions {deviation(x_exact, x_half)} m")
    print(f"  {'cg_tolerance':>12}{'it/step':>9}  {'one step: |dv - dv_exact| / |dv_exact|':>40}"
          f"  {'after 1 s: |x - x_exact| (m)':>30}")
    for tol in tolerances:
        change, report = one_step(tol, x_mid, v_mid)
        relative = np.linalg.norm(change - change_exact) / np.linalg.norm(change_exact)
        stats = integrators[tol].stats
        iterations0, solves0 = stats.iterations, stats.solves
        x, _ = trajectory(tol)
        per_step = (stats.iterations - iterations0) / (stats.solves - solves0)
        print(f"  {tol:>12.0e}{per_step:>9.1f}  {relative:>40.2e}  {deviation(x, x_exact):>30}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--arch", choices=("cpu", "gpu"), default="cpu")
    parser.add_argument("--warmup", type=int, default=5, help="untimed steps first")
    parser.add_argument("--batches", type=int, default=7, help="timed batches (the median is reported)")
    parser.add_argument("--batch-steps", type=int, default=10, help="steps per timed batch")
    parser.add_argument("--integrators", default="implicit_euler,implicit_euler_linearised",
                        help="comma-separated: implicit_euler, implicit_euler_linearised")
    parser.add_argument("--stiffness", default=f"{STIFFNESS:g}",
                        help="comma-separated spring stiffnesses (N/m), e.g. 1e4,1e8")
    parser.add_argument("--solvers", default="cg,direct", help="comma-separated: cg, direct")
    parser.add_argument("--precisions", default="f32,f64", help="comma-separated: f32, f64")
    parser.add_argument("--cg-tolerance", type=float, default=None,
                        help="relative residual of each linear solve (default: the integrator's)")
    parser.add_argument("--preconditioner", choices=("ssor", "jacobi"), default=None,
                        help="CG's preconditioner (default: the integrator's, ssor on a CPU)")
    parser.add_argument("--no-warm-start", action="store_true", help="start every CG solve from zero")
    parser.add_argument("--threads", type=int, default=None, help="CPU threads (default: all cores)")
    parser.add_argument("--size", type=int, default=N, help="particles per side of the cloth (speed only)")
    parser.add_argument("--accuracy", action="store_true",
                        help="measure the effect of the CG tolerance on the result instead of speed")
    args = parser.parse_args()
    precisions = args.precisions.split(",")
    print(f"load average (1 min) {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    if args.accuracy:
        for precision in precisions:
            accuracy(precision, args)
        return
    print(f"{args.size} x {args.size} cloth ({args.size ** 2} particles), dt = 1/60 s; median of {args.batches} batches x "
          f"{args.batch_steps} steps after {args.warmup} warm-up steps; warm start "
          f"{'off' if args.no_warm_start else 'on'}")
    print(f"{'integrator':<27}{'k (N/m)':>8} {'precision':<10}{'solver':<13}{'tolerance':>10}{'steps/s':>9}"
          f"{'(min-max)':>16}{'newton':>8}{'substeps':>9}{'iter/step':>11}{'solve/step':>12}{'ms/iter':>9}"
          f"{'factorize':>12}{'analyze':>10}")
    direct_rows = []
    for name in args.integrators.split(","):
        for stiffness in (float(k) for k in args.stiffness.split(",")):
            for precision in precisions:
                for solver in args.solvers.split(","):
                    try:
                        r = bench(name, stiffness, precision, solver, args)
                    except RuntimeError as exc:
                        print(f"{name:<27}{stiffness:>8.0e} {precision:<10}{solver:<13}  failed: {exc}")
                        continue
                    spread = f"({r['rate_min']:.1f}-{r['rate_max']:.1f})"
                    factorize = f"{r['factorize_ms']:.1f} ms" if r["factorize_ms"] is not None else "-"
                    analyze = f"{r['analyze_ms']:.1f} ms" if r["analyze_ms"] is not None else "-"
                    per_iteration = f"{r['iteration_ms']:.3f}" if r["iteration_ms"] is not None else "-"
                    tolerance = f"{r['tolerance']:.0e}" if r["tolerance"] is not None else "adaptive"
                    print(f"{name:<27}{stiffness:>8.0e} {r['precision']:<10}{r['solver']:<13}{tolerance:>10}"
                          f"{r['rate']:>9.1f}{spread:>16}{r['newton']:>8.1f}{r['substeps']:>9.2f}"
                          f"{r['iterations']:>11.1f}{r['solve_ms']:>9.2f} ms{per_iteration:>9}{factorize:>12}"
                          f"{analyze:>10}")
                    if r["solver"] == "cholesky":
                        direct_rows.append(r)
    if direct_rows:
        print_direct_phases(direct_rows)
    print(f"load average (1 min) {os.getloadavg()[0]:.2f}")


def print_direct_phases(rows: list[dict]) -> None:
    """Where the direct solver's time goes, ms per step (means over the timed steps)."""
    print("\ndirect solver, ms per step: assembly (kernel + build), numeric factorisation, triangular "
          "solves (+ vector copies), the rest of the solve (residual check); analysis once per pattern")
    print(f"{'integrator':<27}{'k (N/m)':>8} {'precision':<10}{'fact/step':>10}{'assemble':>10}{'factorize':>11}"
          f"{'solves':>8}{'rest':>8}{'total':>9}{'analysis':>10}")
    for r in rows:
        phases = r["phases"]
        rest = r["solve_ms"] - sum(phases.values())
        analyze = f"{r['analyze_ms']:.0f}" if r["analyze_ms"] is not None else "-"
        print(f"{r['integrator']:<27}{r['stiffness']:>8.0e} {r['precision']:<10}{r['factorizations']:>10.1f}"
              f"{phases['assemble']:>10.1f}{phases['factorize']:>11.1f}{phases['substitute']:>8.1f}"
              f"{rest:>8.1f}{r['solve_ms']:>9.1f}{analyze:>10}")


if __name__ == "__main__":
    main()
