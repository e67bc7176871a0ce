"""Benchmark: what ``taichi_sim.run`` (the ``simulate`` path: energy samples, the blow-up guard,
bookkeeping) adds to a bare loop of ``integrator.step`` calls that keeps the same guard checks.

Run from the repository root (outside pytest):

    .venv/bin/python benchmarks/bench_run_overhead.py [--sizes 32,64,128] [--steps 5000]
        [--rounds 7] [--precision f32] [--integrator symplectic_euler]

For each size one cloth is built and warmed up; then rounds alternate a bare loop of
``--steps`` steps (with a guard check after every ``check_work`` units of work, as every run
has) and ``run(..., steps=--steps)``. Printed: the medians per step and run / bare - 1.
``bench throughput`` measures the same thing on its short batches (0.25 s), where run()'s own
start (a guard rebase and its 1, 2, 4, ... check schedule) weighs more.
"""
import argparse
import os
import statistics
import time

import taichi as ti

import taichi_sim as ts
from taichi_sim.guard import Guard
from taichi_sim.scene.cloth import fixed_particle_cloth


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="32,64,128")
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--precision", default="f32", choices=("f32", "f64"))
    parser.add_argument("--integrator", default="symplectic_euler")
    parser.add_argument("--dt", type=float, default=1e-4)
    args = parser.parse_args()
    ts.init(arch="cpu", precision=args.precision)
    print(f"load average (1 min): {os.getloadavg()[0]:.2f}; {args.precision}; {args.integrator}; "
          f"{args.steps} steps a round, {args.rounds} rounds")
    print(f"{'size':>5} {'bare us/step':>13} {'run() us/step':>14} {'run() / bare':>13}", flush=True)
    for n in (int(s) for s in args.sizes.split(",")):
        scene = ts.build_scene("cloth", {"nx": n, "ny": n, **fixed_particle_cloth(n, n)})
        integrator = ts.create_integrator(args.integrator, scene.system)
        ts.run(scene, integrator, dt=args.dt, steps=200, progress=False)
        guard = Guard(scene)
        guard.interval = guard.limits.check_work

        def bare():
            t = 0.0
            for step in range(1, args.steps + 1):
                report = integrator.step(scene.state, t, args.dt)
                t += args.dt
                if guard.spend(report.f_evals + report.linear_iterations):
                    guard.check(t, step)
            ti.sync()

        def through_run():
            ts.run(scene, integrator, dt=args.dt, steps=args.steps, progress=False)
            ti.sync()

        times = {bare: [], through_run: []}
        for _ in range(args.rounds):
            for fn in times:
                scene.reset()
                start = time.perf_counter()
                fn()
                times[fn].append((time.perf_counter() - start) / args.steps * 1e6)
        b, r = statistics.median(times[bare]), statistics.median(times[through_run])
        print(f"{n:>5} {b:>13.1f} {r:>14.1f} {100 * (r / b - 1):>+12.1f}%", flush=True)


if __name__ == "__main__":
    main()
