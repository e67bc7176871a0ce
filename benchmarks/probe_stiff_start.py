"""What a stiff cloth's first steps look like to the blow-up guard and to the error estimate.

A size x size cloth (the study's: structural k, shear k/2, flex k/5, 0.01 kg a particle) falls
from rest at 1/60 s a step in f32, stepped by a method as a user steps it (a Stepper at the
default tolerance, no checks asked for). After each step: the method's work option, the
guard's energy split (total, kinetic, springs' k C^2 / 2, J) against its bound, and the
samples of the error estimate taken so far. ``--every-step`` samples every step (the estimate
of each), ``--keep-work`` keeps the method's work as given.

    python benchmarks/probe_stiff_start.py --size 16 --stiffness 1e8 --method xpbd
    python benchmarks/probe_stiff_start.py --size 16 --stiffness 1e8 --method xpbd --option substeps=40 --every-step --keep-work
"""
import argparse

import taichi_sim as ts
from taichi_sim.bench.stiffcloth import cloth_params
from taichi_sim.stepper import Stepper


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=16)
    parser.add_argument("--stiffness", type=float, default=1e8)
    parser.add_argument("--method", default="xpbd")
    parser.add_argument("--option", action="append", default=[], help="NAME=INT, the method's option")
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--every-step", action="store_true")
    parser.add_argument("--keep-work", action="store_true")
    args = parser.parse_args()
    options = {name: int(value) for name, value in (o.split("=", 1) for o in args.option)}
    ts.init(arch="cpu", precision="f32")
    scene = ts.build_scene("cloth", cloth_params(args.size, args.stiffness))
    integrator = ts.create_integrator(args.method, scene.system, **options)
    stepper = Stepper(scene, integrator, 1 / 60, raise_work=not args.keep_work)
    option = integrator.work_option
    print(f"| step | {option} | energy (J) | kinetic | springs | bound | samples | last estimate (mm) |")
    print("|---|---|---|---|---|---|---|---|")
    for s in range(args.steps):
        stepper.step(check=args.every_step or s == args.steps - 1)
        health = scene.system.health(scene.state, stepper.guard.center)
        monitor = stepper.monitor
        last = f"{1e3 * monitor.distances[-1]:.3g}" if monitor.distances else "-"
        print(f"| {s + 1} | {getattr(integrator, option)} | {health.energy:.4g} | {health.kinetic:.3g} | "
              f"{health.spring_energy:.4g} | {stepper.guard.energy_bound(stepper.t)[0]:.4g} | "
              f"{len(monitor.distances)} | {last} |", flush=True)
        if stepper.failure is not None:
            print(stepper.failure.message)
            break
    for warning in stepper.warnings:
        print("warning:", warning)


if __name__ == "__main__":
    main()
