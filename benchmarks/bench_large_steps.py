"""Benchmark: the large-step methods on a cloth at one step per 60 Hz frame, against the
targets of the stiff-cloth issue (steps/s at 64 x 64 and 128 x 128, f32; energy never above its
start on a conservative scene; no blow-up at k = 1e8).

Run from the repository root (outside pytest):

    .venv/bin/python benchmarks/bench_large_steps.py [--sizes 64,128] [--stiffness 1e2,1e4,1e8]
        [--precision f32] [--batches 5] [--batch-steps 10] [--energy-seconds 2] [--threads N]
        [--methods xpbd,xpbd:substeps=100,projective_dynamics,implicit_euler]

For every (size, stiffness, method) a fresh scene is stepped 3 times (compilation), then timed
over ``--batches`` batches of ``--batch-steps`` raw steps (``integrator.step`` and ``ti.sync``,
no guard, no energy): steps/s is the median over batches with the min-max range. Then a
conservative copy (no dashpots, no drag) runs ``--energy-seconds`` s through ``taichi_sim.run``
(the blow-up guard on) with the energy sampled every step: its status and the largest rise of
the energy above its start. Symplectic Euler's step (at 1 ms) is timed alongside as the unit
of cost: "x SE" is a method's step in symplectic Euler steps. The 1-minute load average is
printed first: other processes on the machine slow every figure.
"""
import argparse
import os
import statistics
import time

import numpy as np
import taichi as ti

import taichi_sim as ts
from taichi_sim.bench.stiffcloth import cloth_params
from taichi_sim.guard import GuardLimits
from taichi_sim.integrators import method_label

DT = 1 / 60  # s


def parse_method(text: str) -> tuple[str, dict]:
    """``xpbd:substeps=100+iterations=2`` -> ("xpbd", {"substeps": 100, "iterations": 2})."""
    name, _, rest = text.partition(":")
    options = {}
    for item in filter(None, rest.split("+")):
        key, _, value = item.partition("=")
        options[key] = float(value) if "." in value or "e" in value else int(value)
    return name, options


def step_rate(n: int, k: float, name: str, options: dict, h: float, args) -> list[float]:
    scene = ts.build_scene("cloth", cloth_params(n, k))
    integrator = ts.create_integrator(name, scene.system, **options)
    for _ in range(3):
        integrator.step(scene.state, 0.0, h)
    ti.sync()
    rates = []
    for _ in range(args.batches):
        start = time.perf_counter()
        for _ in range(args.batch_steps):
            integrator.step(scene.state, 0.0, h)
        ti.sync()
        rates.append(args.batch_steps / (time.perf_counter() - start))
    return rates


def energy_check(n: int, k: float, name: str, options: dict, args) -> tuple[str, float, float]:
    scene = ts.build_scene("cloth", cloth_params(n, k, conservative=True))
    result = ts.run(scene, ts.create_integrator(name, scene.system, **options), dt=DT,
                    steps=round(args.energy_seconds / DT), energy_every=1, guard=GuardLimits())
    energy = np.asarray(result.energy)
    return result.status.value, float(energy.max() - energy[0]), float(energy[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="64,128")
    parser.add_argument("--stiffness", default="1e2,1e4,1e8")
    parser.add_argument("--precision", default="f32", choices=("f32", "f64"))
    parser.add_argument("--methods", default="xpbd,xpbd:substeps=100,projective_dynamics,implicit_euler")
    parser.add_argument("--batches", type=int, default=5)
    parser.add_argument("--batch-steps", type=int, default=10)
    parser.add_argument("--energy-seconds", type=float, default=2.0)
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()
    ts.init(arch="cpu", precision=args.precision, cpu_max_num_threads=args.threads)
    print(f"load average (1 min): {os.getloadavg()[0]:.2f}; {args.precision}; dt = 1/60 s")
    print(f"{'size':>5} {'k':>7} {'method':<36} {'steps/s':>8} {'range':>15} {'x SE':>6} "
          f"{'status':>9} {'E rise (J)':>11} {'E0 (J)':>8}", flush=True)
    for n in (int(s) for s in args.sizes.split(",")):
        for k in (float(s) for s in args.stiffness.split(",")):
            se = statistics.median(step_rate(n, k, "symplectic_euler", {}, 1e-3, args))
            for text in args.methods.split(","):
                name, options = parse_method(text)
                rates = step_rate(n, k, name, options, DT, args)
                median = statistics.median(rates)
                status, rise, e0 = energy_check(n, k, name, options, args)
                print(f"{n:>5} {k:>7.0e} {method_label(name, options):<36} {median:>8.1f} "
                      f"{min(rates):>7.1f}-{max(rates):<7.1f} {se / median:>6.1f} {status:>9} "
                      f"{max(rise, 0.0):>11.3g} {e0:>8.3g}", flush=True)


if __name__ == "__main__":
    main()
