"""vbd on a membrane cloth against vbd on the spring net (docs/materials.md): steps per second of
the ``cloth-membrane`` preset (a Neo-Hookean or StVK membrane with bending) and of the ``cloth``
preset (its springs), both at size x size, one vbd step of 1/60 s (its defaults: 20 sweeps) in
f32, in one process. After a warm-up of two steps each (compiling, or loading Taichi's cache),
``--rounds`` rounds alternate the two: each resets its scene and times ``--steps`` steps one by
one (the cloth's fall from rest). Prints each side's median step, the ratio of steps/s
(membrane / springs) per round and its median, and which sweeps ran (serial or parallel:
vbd's rule, or ``--sweeps`` for both). ``--clock cpu`` times the process's CPU time instead
of the wall's, for serial sweeps on a machine others share.

    .venv/bin/python benchmarks/bench_vbd_membrane.py                  # 64 x 64, neohookean
    .venv/bin/python benchmarks/bench_vbd_membrane.py --material stvk --size 32
    .venv/bin/python benchmarks/bench_vbd_membrane.py --clock cpu --parts   # what the membrane's parts cost

``--parts`` adds the membrane without its viscous damping, without its bending and without
either, timed in the same rounds.

The 1-minute load average is printed first: other processes on the machine slow every figure.
"""
import argparse
import os
import statistics
import time

import taichi as ti

import taichi_sim as ts


def timed_steps(scene, integrator, dt: float, steps: int, clock=time.perf_counter) -> list[float]:
    """Reset ``scene`` and ``integrator`` and time ``steps`` steps of dt (s each) by ``clock``."""
    scene.reset()
    integrator.reset()
    times = []
    t = 0.0
    for _ in range(steps):
        start = clock()
        report = integrator.step(scene.state, t, dt)
        ti.sync()
        times.append(clock() - start)
        if not report.accepted:
            raise SystemExit(f"{integrator.name}: step at t = {t} not accepted: {report.message}")
        t += dt
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--material", default="neohookean", choices=("neohookean", "stvk"))
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--precision", default="f32", choices=("f32", "f64"))
    parser.add_argument("--sweeps", default="rule", choices=("rule", "serial", "parallel"),
                        help="serial or parallel sweeps on both sides, or vbd's own rule (default)")
    parser.add_argument("--clock", default="wall", choices=("wall", "cpu"),
                        help="wall time, or the process's CPU time (with serial sweeps on a shared "
                             "machine: what other processes take from it is not counted)")
    parser.add_argument("--parts", action="store_true",
                        help="also the membrane without damping, without bending, without either")
    args = parser.parse_args()
    clock = time.perf_counter if args.clock == "wall" else time.process_time
    print(f"load average (1 min): {os.getloadavg()[0]:.2f}")
    ts.init(arch="cpu", precision=args.precision)
    dt = 1 / 60
    size = {"nx": args.size, "ny": args.size}
    sides = {
        "springs": ts.build_scene("cloth", size),
        args.material: ts.build_scene("cloth-membrane", {**size, "material": args.material}),
    }
    if args.parts:
        for label, left_out in (("no damping", {"membrane_damping": 0.0}), ("no bending", {"bending_stiffness": 0.0}),
                                ("neither", {"membrane_damping": 0.0, "bending_stiffness": 0.0})):
            sides[label] = ts.build_scene("cloth-membrane", {**size, "material": args.material, **left_out})
    methods = {}
    for label, scene in sides.items():
        start = time.perf_counter()
        methods[label] = ts.create_integrator("vbd", scene.system)
        if args.sweeps != "rule":
            methods[label].serial = args.sweeps == "serial"
        timed_steps(scene, methods[label], dt, 2)
        print(f"{label}: warm-up (two steps, compiling or loading the cache) {time.perf_counter() - start:.1f} s, "
              f"{'serial' if methods[label].serial else 'parallel'} sweeps, {methods[label].colour_count} colours")
    medians = {label: [] for label in sides}
    ratios = []
    for r in range(args.rounds):
        for label, scene in sides.items():
            medians[label].append(statistics.median(timed_steps(scene, methods[label], dt, args.steps, clock)))
        ratios.append(medians["springs"][-1] / medians[args.material][-1])
        print(f"round {r + 1}: " + ", ".join(f"{label} {1e3 * medians[label][-1]:.2f} ms" for label in sides)
              + f"; steps/s {args.material} / springs {ratios[-1]:.3f}")
    for label in sides:
        step = statistics.median(medians[label])
        print(f"{label}: median step {1e3 * step:.2f} ms ({1 / step:.1f} steps/s)")
    print(f"steps/s {args.material} / springs: median {statistics.median(ratios):.3f} "
          f"(rounds {min(ratios):.3f} .. {max(ratios):.3f})")


if __name__ == "__main__":
    main()
