"""vbd's energy cap on the stiff-cloth study's conservative cloth: the highest energy above the
start, the energy at the end and the substeps the cap shortened, with the cap and without.

    python benchmarks/bench_vbd_energy.py --n 64

The cloth: n x n on 1 m, 0.01 kg a particle, pinned at two corners, no dashpots, no drag,
structural stiffness k (shear k/2, flex k/5), swinging from the start (v_y = 0.5 sin(i) m/s),
stepped for 1 s by the Stepper (so the cap is on where it applies) with the default 20 sweeps,
f64. Wall times are for the whole second of steps, compilation included in the first row of
each variant.
"""
import argparse
import time

import numpy as np

import taichi_sim as ts
from taichi_sim.scene.cloth import FIXED_PARTICLE_MASS, per_particle


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=64)
    parser.add_argument("--stiffness", type=float, nargs="+", default=[1e2, 1e4, 1e6, 1e8])
    parser.add_argument("--dt", type=float, nargs="+", default=[1 / 60, 1 / 30])
    args = parser.parse_args()
    ts.init(arch="cpu", precision="f64")
    n = args.n
    scene = ts.build_scene("cloth", {"nx": n, "ny": n, "stiffness": 1.0, "shear_stiffness": 0.5,
                                     "flex_stiffness": 0.2, "damping": 0.0,
                                     **per_particle(n, n, mass=FIXED_PARTICLE_MASS, drag=0.0)})
    base = scene.springs.arrays()["stiffness"]
    print(f"{n} x {n} conservative cloth, 1 s, vbd (20 sweeps, 1 substep), f64")
    print("| k (N/m) | h (s) | energy_cap | start (J) | highest above start (J) | end (J) | substeps shortened | wall (s) |")
    print("|---|---|---|---|---|---|---|---|")
    for cap in (False, True):
        method = ts.create_integrator("vbd", scene.system, energy_cap=cap)
        stepper = ts.Stepper(scene, method, args.dt[0])
        for k in args.stiffness:
            for h in args.dt:
                scene.springs.set_parameters(stiffness=base * k)
                scene.reset()
                v = np.zeros_like(scene.x0)
                v[:, 1] = 0.5 * np.sin(np.arange(len(v)))
                v[scene.static_arrays["pinned"]] = 0.0
                scene.state.from_numpy(scene.x0, v)
                stepper.set_dt(h)
                stepper.restart()
                before = int(method.capped[None])
                start = scene.energy()
                top = start
                wall = time.perf_counter()
                for _ in range(int(round(1.0 / h))):
                    stepper.step()
                    if stepper.failure is not None:
                        break
                    top = max(top, scene.energy())
                wall = time.perf_counter() - wall
                status = "" if stepper.failure is None else f" ({stepper.failure.status.value})"
                print(f"| {k:g} | {h:.4g} | {'on' if cap else 'off'} | {start:.4g} | {top - start:.3g}{status} "
                      f"| {scene.energy():.4g} | {int(method.capped[None]) - before} of {int(round(1.0 / h))} "
                      f"| {wall:.2f} |")


if __name__ == "__main__":
    main()
