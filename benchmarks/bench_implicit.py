"""Benchmark: implicit Euler (Baraff-Witkin) on a 64 x 64 cloth: CG against the sparse direct
solver, in f32 and f64.

Run from the repository root (outside pytest):

    .venv/bin/python benchmarks/bench_implicit.py [--arch cpu] [--batches 7] [--batch-steps 10]

For every (precision, solver) the scene is built fresh, stepped ``--warmup`` times (kernel
compilation, the direct solver's pattern analysis), then timed over ``--batches`` batches of
``--batch-steps`` steps. Reported: steps per second (median over batches, with the min-max
range), linear-solver iterations per step, and for the direct solver the mean time of one
numeric factorisation and of the one-off symbolic analysis.
"""
import argparse
import statistics
import time

import taichi as ti

import taichi_sim as ts

N = 64
STIFFNESS = 1e4  # N/m, structural, shear and flex alike
DT = 1 / 60  # s
PARAMS = {"nx": N, "ny": N, "stiffness": STIFFNESS, "shear_stiffness": STIFFNESS, "flex_stiffness": STIFFNESS}


def bench(precision: str, solver: str, args) -> dict:
    ts.init(arch=args.arch, precision=precision)
    scene = ts.build_scene("cloth", PARAMS)
    integrator = ts.create_integrator("implicit_euler", scene.system, linear_solver=solver)
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
    rates = []
    for _ in range(args.batches):
        start = time.perf_counter()
        advance(args.batch_steps)
        ti.sync()
        rates.append(args.batch_steps / (time.perf_counter() - start))
    timed_steps = args.batches * args.batch_steps
    factorizations = stats.factorize_count - factorize0
    return {
        "precision": precision, "solver": stats.solver, "rate": statistics.median(rates),
        "rate_min": min(rates), "rate_max": max(rates),
        "iterations": (stats.iterations - iterations0) / timed_steps,
        "factorize_ms": (1e3 * (stats.factorize_seconds - factorize_s0) / factorizations
                         if factorizations else None),
        "analyze_ms": 1e3 * stats.analyze_seconds if stats.analyze_count else None,
        "analyze_count": stats.analyze_count, "backend": ts.runtime.backend(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arch", choices=("cpu", "gpu"), default="cpu")
    parser.add_argument("--warmup", type=int, default=5, help="untimed steps first")
    parser.add_argument("--batches", type=int, default=7, help="timed batches (the median is reported)")
    parser.add_argument("--batch-steps", type=int, default=10, help="steps per timed batch")
    parser.add_argument("--solvers", default="cg,direct", help="comma-separated: cg, direct")
    args = parser.parse_args()
    print(f"implicit_euler, {N} x {N} cloth ({N * N} particles), stiffness {STIFFNESS:g} N/m, dt = 1/60 s; "
          f"median of {args.batches} batches x {args.batch_steps} steps after {args.warmup} warm-up steps")
    print(f"{'precision':<10}{'solver':<10}{'backend':<9}{'steps/s':>9}{'(min-max)':>16}{'iter/step':>11}"
          f"{'factorize':>12}{'analyze':>10}")
    for precision in ("f32", "f64"):
        for solver in args.solvers.split(","):
            r = bench(precision, solver, args)
            spread = f"({r['rate_min']:.1f}-{r['rate_max']:.1f})"
            factorize = f"{r['factorize_ms']:.1f} ms" if r["factorize_ms"] is not None else "-"
            analyze = f"{r['analyze_ms']:.1f} ms" if r["analyze_ms"] is not None else "-"
            print(f"{r['precision']:<10}{r['solver']:<10}{r['backend']:<9}{r['rate']:>9.1f}{spread:>16}"
                  f"{r['iterations']:>11.1f}{factorize:>12}{analyze:>10}")


if __name__ == "__main__":
    main()
