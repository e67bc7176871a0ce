"""Benchmark: whole steps of preset scenes as the launcher and ``simulate`` take them.

Each scene is built at its preset size with its default integrator and step, and stepped by a
:class:`~taichi_sim.stepper.Stepper` (the integrator, the guard's checks, the post-step events:
colliders, tearing, emission). After a warm-up that compiles everything, rounds of ``--steps``
steps are timed (``ti.sync`` around each round); the median over rounds, per step, is printed.
A run that ends (a blow-up) starts again from the scene's initial state.
Compare two versions of the code by running this script from each checkout in turn, e.g. with
``farm-bench --vs``; the 1-minute load average is printed first.

    python benchmarks/bench_scene_steps.py [--scenes cloth-sphere,cloth-tear]
        [--steps 200] [--rounds 7] [--precision f32]
"""
import argparse
import os
import statistics
import time

import taichi as ti

import taichi_sim as ts
from taichi_sim.stepper import Stepper

DEFAULT_SCENES = "cloth,cloth-sphere,cloth-tear,cloth-wind,spring,pendulum"


def median_step_ms(name: str, steps: int, rounds: int) -> tuple[float, str, float]:
    scene = ts.build_scene(name, {})
    integrator = scene.default_integrator
    dt = scene.default_dt
    stepper = Stepper(scene, integrator, dt)

    def run(count: int) -> None:
        for _ in range(count):
            if stepper.failure is not None:
                scene.reset()
                stepper.restart()
            stepper.step()

    run(steps)  # compiles every kernel of the step
    ti.sync()
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        run(steps)
        ti.sync()
        times.append((time.perf_counter() - start) / steps * 1e3)
    return statistics.median(times), integrator, dt


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default=DEFAULT_SCENES)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--precision", default="f32", choices=("f32", "f64"))
    args = parser.parse_args()
    print(f"load average (1 min): {os.getloadavg()[0]:.2f} on {os.cpu_count()} cpus")
    ts.init(precision=args.precision)
    print(f"{'scene':<16} {'integrator':<18} {'dt (s)':>9} {'ms/step':>9}")
    for name in args.scenes.split(","):
        ms, integrator, dt = median_step_ms(name.strip(), args.steps, args.rounds)
        print(f"{name:<16} {integrator:<18} {dt:9.2e} {ms:9.4f}")


if __name__ == "__main__":
    main()
