"""Benchmark: an rk4 step against a symplectic Euler step on the same cloth, alternated.

Run from the repository root (outside pytest):

    .venv/bin/python benchmarks/bench_rk4_ratio.py [--sizes 64,128,256] [--precision f32]
        [--rounds 7]

For every size, two cloths are built (one per integrator) and warmed up, then timed in
alternating rounds of raw ``integrator.step`` calls at 1e-5 s (``ti.sync`` around each round,
about 2 million particle-steps a round): the medians per step and rk4 / symplectic, the ratio
the throughput issue bounds by 4.5. ``bench throughput`` reports the same ratio from its
integrator sweep, where the two are not alternated.
"""
import argparse
import statistics
import time

import taichi as ti

import taichi_sim as ts
from taichi_sim.scene.cloth import fixed_particle_cloth

METHODS = ("symplectic_euler", "rk4")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="64,128,256")
    parser.add_argument("--precision", default="f32", choices=("f32", "f64"))
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args()
    ts.init(arch="cpu", precision=args.precision)
    print(f"{args.precision}; {args.rounds} alternated rounds")
    print(f"{'size':>5}  {'symplectic us/step':>18}  {'rk4 us/step':>11}  {'rk4 / symplectic':>16}")
    for n in (int(s) for s in args.sizes.split(",")):
        runs = {}
        for name in METHODS:
            scene = ts.build_scene("cloth", {"nx": n, "ny": n, **fixed_particle_cloth(n, n)})
            method = ts.create_integrator(name, scene.system)
            for _ in range(20):
                method.step(scene.state, 0.0, 1e-5)
            runs[name] = (method, scene.state)
        ti.sync()
        steps = max(20, 2_000_000 // (n * n))
        times = {name: [] for name in METHODS}
        for _ in range(args.rounds):
            for name, (method, state) in runs.items():
                ti.sync()
                start = time.perf_counter()
                for _ in range(steps):
                    method.step(state, 0.0, 1e-5)
                ti.sync()
                times[name].append((time.perf_counter() - start) / steps * 1e6)
        symplectic, rk4 = (statistics.median(times[name]) for name in METHODS)
        print(f"{n:>5}  {symplectic:>18.0f}  {rk4:>11.0f}  {rk4 / symplectic:>16.2f}", flush=True)


if __name__ == "__main__":
    main()
