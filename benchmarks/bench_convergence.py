"""What each solving method says about its own convergence, beside how far it really is.

For a cloth at frame-sized steps, every method that solves a system per step runs in f32 and
f64; the table gives its status, its worst relative solver residual (taichi_sim/convergence.py),
whether it said it had not converged (status, or a warning), and the rms distance of its final
positions from a tightly solved backward Euler run (implicit_euler, newton_tolerance 1e-8, f64).
A run far from the answer that says nothing would be a finding.

    python benchmarks/bench_convergence.py                      # 16 x 16, k = 1e4, 1e6, 1e8
    python benchmarks/bench_convergence.py --size 8 --stiffnesses 1e6
"""
import argparse
import math

import numpy as np

import taichi_sim as ts
from taichi_sim.errors import ConfigError
from taichi_sim.scene.cloth import fixed_particle_cloth

METHODS = ("implicit_euler", "implicit_midpoint", "implicit_euler_linearised", "projective_dynamics", "xpbd")


def final_positions(size, k, method, precision, steps, dt, **options):
    ts.init(arch="cpu", precision=precision)
    scene = ts.build_scene("cloth", {"nx": size, "ny": size, "stiffness": k, **fixed_particle_cloth(size, size)})
    try:
        result = ts.run(scene, ts.create_integrator(method, scene.system, **options), dt=dt, steps=steps)
    except ConfigError as exc:
        return None, f"refused: {str(exc).split(':')[0]}"
    return result, scene.state.x.to_numpy().astype(float)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=16)
    parser.add_argument("--stiffnesses", default="1e4,1e6,1e8")
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--dt", type=float, default=1 / 60)
    args = parser.parse_args()
    print(f"{args.size}x{args.size} cloth, {args.steps} steps of {args.dt:.4g} s; rms distance from "
          f"implicit_euler (newton_tolerance 1e-8, f64)")
    print(f"{'k (N/m)':>8} {'method':<26} {'prec':<4} {'status':<14} {'worst residual':>14} "
          f"{'said so':>7} {'rms (m)':>8}")
    for k in (float(v) for v in args.stiffnesses.split(",")):
        _, reference = final_positions(args.size, k, "implicit_euler", "f64", args.steps, args.dt,
                                       newton_tolerance=1e-8)
        for method in METHODS:
            for precision in ("f64", "f32"):
                result, x = final_positions(args.size, k, method, precision, args.steps, args.dt)
                if result is None:
                    print(f"{k:8.0e} {method:<26} {precision:<4} {x}")
                    continue
                said = result.status.value != "ok" or bool(result.warnings)
                rms = (math.sqrt(np.mean(np.sum((x - reference) ** 2, axis=1)))
                       if result.steps == args.steps else math.nan)
                print(f"{k:8.0e} {method:<26} {precision:<4} {result.status.value:<14} "
                      f"{result.worst_residual:14.3g} {'yes' if said else 'no':>7} {rms:8.3f}")


if __name__ == "__main__":
    main()
