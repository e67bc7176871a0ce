"""The error estimate in metres against the truth, on the stiff-cloth study's cloth.

For each case (a size x size cloth of the study, k N/m, one fast method with its defaults,
steps of 1/60 s, f32) it runs --steps steps and, at --samples of them, compares the estimate
(:mod:`taichi_sim.convergence.distance`) with the true distance of the step's positions from
its equation's converged solution from the same start (Newton to 1e-10 m, f64). It then
compares the run's end with converged backward Euler at the method's inner step (f64) and
prints the largest per-step estimate beside it: what a per-step tolerance says about the end.

    .venv/bin/python benchmarks/bench_error_estimate.py [--sizes 16 32] [--stiffness 1e4 1e6 1e8]
"""
import argparse

import numpy as np

import taichi_sim as ts
from taichi_sim.bench.stiffcloth import cloth_params
from taichi_sim.stepper import Stepper

METHODS = (("vbd", 1), ("projective_dynamics", 1), ("implicit_euler_linearised", 1), ("xpbd", 20))
H = 1 / 60


def reference(size, k, inner, steps):
    ts.init(arch="cpu", precision="f64")
    scene = ts.build_scene("cloth", cloth_params(size, k))
    integrator = ts.create_integrator("implicit_euler", scene.system, newton_tolerance=1e-9)
    ts.run(scene, integrator, dt=H / inner, steps=steps * inner, energy_every=0)
    return scene.state.to_numpy()[0].astype(float)


def case(size, k, name, inner, steps, samples):
    x_ref = reference(size, k, inner, steps)
    ts.init(arch="cpu", precision="f32")
    scene = ts.build_scene("cloth", cloth_params(size, k))
    x_start = scene.state.to_numpy()[0].astype(float)
    integrator = ts.create_integrator(name, scene.system)
    stepper = Stepper(scene, integrator, H, tolerance=1e6)  # the defaults' work, never raised
    monitor = stepper.monitor
    model = monitor.distance_model
    ratios, worst = [], 0.0
    sampled = set(np.linspace(0, steps - 1, samples).round().astype(int))
    for s in range(steps):
        stepper.step()
        h = integrator.solved_h if getattr(integrator, "tracks_solved_start", False) else H
        x0, v0 = (a.astype(float) for a in monitor._start.to_numpy())
        x1, v1 = (a.astype(float) for a in scene.state.to_numpy())
        estimate = model.distance(x0, v0, x1, v1, h)
        worst = max(worst, estimate)
        if s in sampled:
            try:
                x_star, _ = model.solve_step(x0, v0, h, guess=x1)
            except RuntimeError:
                continue
            true = float(np.max(np.linalg.norm(x1 - x_star, axis=1)))
            if true > 1e-3:
                ratios.append(estimate / true)
    x = scene.state.to_numpy()[0].astype(float)
    end = float(np.max(np.linalg.norm(x - x_ref, axis=1)))
    motion = float(np.max(np.linalg.norm(x_ref - x_start, axis=1)))
    return ratios, worst, end, motion


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[16, 32])
    parser.add_argument("--stiffness", type=float, nargs="+", default=[1e4, 1e6, 1e8])
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--samples", type=int, default=6)
    args = parser.parse_args()
    print("| size | k (N/m) | method | estimate / true, steps > 1 mm | largest estimate (m) | end from converged BE (m) | motion (m) |")
    print("|---|---|---|---|---|---|---|")
    for size in args.sizes:
        for k in args.stiffness:
            for name, inner in METHODS:
                ratios, worst, end, motion = case(size, k, name, inner, args.steps, args.samples)
                shown = f"{min(ratios):.2f}-{max(ratios):.2f} ({len(ratios)})" if ratios else "none > 1 mm"
                print(f"| {size} | {k:g} | {name} | {shown} | {worst:.3g} | {end:.3g} | {motion:.3g} |", flush=True)


if __name__ == "__main__":
    main()
