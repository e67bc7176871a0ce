"""Benchmark: one exact backward Euler step (``implicit_euler``) on the issue's stiff cloth, before
and after the step-splitting change, in one run.

    .venv/bin/python benchmarks/bench_exact_step.py [--stiffness 1e4,1e8] [--size 64]
        [--warmup 5] [--batches 5] [--batch-steps 5] [--threads 2]

Scene: ``cloth`` with nx = ny = ``--size`` and ``stiffness`` (structural springs; shear and flex
keep their defaults), f64, dt = 1/60 s, CPU, the integrator's defaults (CG with block SSOR,
forcing terms, newton_tolerance 1e-3). Two variants run from the same start, in turn:

* ``before``: a step solved in pieces lets the next step try pieces twice as long at once
  (``coarsen_after = 1``, the previous behaviour);
* ``after``: it waits for ``coarsen_after`` (4) steps solved at one piece size first.

Each variant steps ``--warmup`` steps (compilation), then ``--batches`` batches of
``--batch-steps`` steps; reported: ms per step (median over batches, min-max), Newton
iterations, linear (CG) iterations and solved pieces per step over the timed steps, and the
largest relative nonlinear residual |g|/|s| a timed step ended with. The 1-minute load average
is printed first: other processes on the machine slow every figure.
"""
import argparse
import os
import statistics
import time

import taichi as ti

import taichi_sim as ts
from taichi_sim.integrators.implicit import ImplicitStageMethod
from taichi_sim.scene.cloth import fixed_particle_cloth

DT = 1 / 60
VARIANTS = {"before": 1, "after": ImplicitStageMethod.coarsen_after}


def run_variant(scene, coarsen_after: int, args) -> dict:
    scene.reset()
    integrator = ts.create_integrator("implicit_euler", scene.system)
    integrator.coarsen_after = coarsen_after
    stats = integrator.stats
    t = 0.0
    worst = 0.0

    def advance(count: int) -> None:
        nonlocal t, worst
        for _ in range(count):
            report = integrator.step(scene.state, t, DT)
            if report.status is not ts.Status.OK:
                raise RuntimeError(f"{report.status.value} at t = {t:.3f} s: {report.message}")
            worst = max(worst, integrator.last_relative_residual)
            t += DT

    advance(args.warmup)
    ti.sync()
    worst = 0.0
    newton0, linear0, pieces0 = stats.newton_iterations, stats.iterations, stats.substeps
    times = []
    for _ in range(args.batches):
        start = time.perf_counter()
        advance(args.batch_steps)
        ti.sync()
        times.append(1e3 * (time.perf_counter() - start) / args.batch_steps)
    steps = args.batches * args.batch_steps
    return {"ms": statistics.median(times), "min": min(times), "max": max(times),
            "newton": (stats.newton_iterations - newton0) / steps,
            "linear": (stats.iterations - linear0) / steps,
            "pieces": (stats.substeps - pieces0) / steps, "residual": worst,
            "tolerance": integrator.newton_tolerance}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--stiffness", default="1e4,1e8")
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--batches", type=int, default=5)
    parser.add_argument("--batch-steps", type=int, default=5)
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()
    print(f"load average (1 min) {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    ts.init(arch="cpu", precision="f64", cpu_max_num_threads=args.threads)
    print(f"cloth {args.size} x {args.size}, f64, dt = 1/60 s, steps {args.warmup} warm-up + "
          f"{args.batches} x {args.batch_steps} timed")
    print(f"{'k (N/m)':>9} {'variant':<8}{'ms/step':>9}{'(min-max)':>17}{'Newton/step':>13}"
          f"{'linear it/step':>16}{'pieces/step':>13}{'max |g|/|s|':>13}")
    for stiffness in (float(k) for k in args.stiffness.split(",")):
        scene = ts.build_scene("cloth", {"nx": args.size, "ny": args.size, "stiffness": stiffness,
                                          **fixed_particle_cloth(args.size, args.size)})
        for name, coarsen_after in VARIANTS.items():
            r = run_variant(scene, coarsen_after, args)
            spread = f"({r['min']:.0f}-{r['max']:.0f})"
            print(f"{stiffness:>9.0e} {name:<8}{r['ms']:>9.1f}{spread:>17}"
                  f"{r['newton']:>13.1f}{r['linear']:>16.0f}{r['pieces']:>13.2f}"
                  f"{r['residual']:>13.1e}", flush=True)
        print(f"{'':>9} (newton_tolerance {r['tolerance']:g})")


if __name__ == "__main__":
    main()
