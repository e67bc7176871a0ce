"""Benchmark: what the blow-up guard costs a run. ``ts.run`` of an n x n cloth with symplectic Euler
at dt = 1e-4 s (the throughput benchmark's setting), energy sampling off, with the guard as every
run has it (a check every 100 units of work) against the guard checking only at the end.

Run from the repository root (outside pytest):

    .venv/bin/python benchmarks/bench_guard.py [--sizes 32,64,128] [--precision f32]
        [--integrator symplectic_euler] [--steps 2000] [--rounds 7]

Both configurations share one scene and one integrator; after a warm-up run of each, they are
timed in ``--rounds`` rounds, one run of each per round (so load on the machine hits both alike).
Reported: median ms per step of each, the overhead (median of the per-round ratios minus 1),
the guard's checks per run, and, less noisy, the cost of one check measured alone (median of
``--rounds`` timings of 100 checks) as a fraction of the 100 steps between two checks.
"""
import argparse
import statistics
import time

import taichi_sim as ts
from taichi_sim.guard import Guard, GuardLimits
from taichi_sim.scene.cloth import fixed_particle_cloth

NEVER = 2**62  # check_work no run reaches: the guard checks only at the end


def timed_run(scene, integrator, steps: int, limits: GuardLimits, dt: float):
    scene.reset()
    integrator.reset()
    start = time.perf_counter()
    result = ts.run(scene, integrator, dt=dt, steps=steps, energy_every=0, progress=False, guard=limits)
    elapsed = time.perf_counter() - start
    if result.status is not ts.Status.OK:
        raise SystemExit(f"run not ok: {result.message}")
    return elapsed / steps, result.guard_checks


def check_cost(scene, rounds: int) -> float:
    """Median seconds of one guard check (health reduction + snapshot) on ``scene``'s state."""
    import taichi as ti

    guard = Guard(scene)
    samples = []
    for _ in range(rounds):
        ti.sync()
        start = time.perf_counter()
        for _ in range(100):
            guard.check(0.0, 0)
        ti.sync()
        samples.append((time.perf_counter() - start) / 100)
    return statistics.median(samples)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--sizes", default="32,64,128")
    parser.add_argument("--precision", default="f32", choices=("f32", "f64"))
    parser.add_argument("--integrator", default="symplectic_euler")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--dt", type=float, default=1e-4)
    args = parser.parse_args()
    ts.init(arch="cpu", precision=args.precision)
    guarded, end_only = GuardLimits(), GuardLimits(check_work=NEVER)
    print(f"{args.integrator}, {args.precision}, dt = {args.dt:g} s, {args.steps} steps per run, "
          f"{args.rounds} rounds")
    print(f"{'n':>5} {'guarded ms/step':>16} {'end-only ms/step':>17} {'overhead':>9} {'checks':>7} "
          f"{'ms/check':>9} {'check / 100 steps':>18}")
    for n in (int(s) for s in args.sizes.split(",")):
        scene = ts.build_scene("cloth", {"nx": n, "ny": n, **fixed_particle_cloth(n, n)})
        integrator = ts.create_integrator(args.integrator, scene.system)
        for limits in (guarded, end_only):  # warm-up: compiles every kernel of both
            timed_run(scene, integrator, args.steps // 10, limits, args.dt)
        with_guard, without, ratios = [], [], []
        for _ in range(args.rounds):
            a, checks = timed_run(scene, integrator, args.steps, guarded, args.dt)
            b, _ = timed_run(scene, integrator, args.steps, end_only, args.dt)
            with_guard.append(a)
            without.append(b)
            ratios.append(a / b)
        one = check_cost(scene, args.rounds)
        print(f"{n:>5} {1e3 * statistics.median(with_guard):>16.4f} {1e3 * statistics.median(without):>17.4f} "
              f"{100 * (statistics.median(ratios) - 1):>8.1f}% {checks:>7} {1e3 * one:>9.4f} "
              f"{100 * one / (100 * statistics.median(without)):>17.2f}%")


if __name__ == "__main__":
    main()
