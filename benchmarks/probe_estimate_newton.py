"""How far Newton's iterates from a step's result get toward its solution, against the
estimate: the warning matrix's vbd cases, whose first steps the estimate read low.

Each case runs vbd with its defaults, its work kept (no tolerance raising it), f32, 1/60 s;
after each of the first ``--steps`` steps: the estimate alone (one Newton step and its chord
step, no tolerance), the distance of ``solve_step``'s iterate after 1, 2, 4, 8 and 16 Newton
steps (each halving a step that raises |r|) from the step's result, and the true distance
(``solve_step`` to 1e-8 m), in mm; "c" marks an iterate that converged.

    python benchmarks/probe_estimate_newton.py [--steps 2]
"""
import argparse

import numpy as np

import taichi_sim as ts
from taichi_sim.bench.stiffcloth import cloth_params
from taichi_sim.stepper import Stepper

CASES = (("pendulum, k = 1e8", "pendulum", {"particle_count": 10, "stiffness": 1e8}),
         ("16 x 16, k = 1e6", "cloth", cloth_params(16, 1e6)),
         ("16 x 16, k = 1e8", "cloth", cloth_params(16, 1e8)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2)
    parser.add_argument("--method", default="vbd")
    args = parser.parse_args()
    print("| case | step | estimate | 1 | 2 | 4 | 8 | 16 | true |\n|---|---|---|---|---|---|---|---|---|")
    for label, scene_name, params in CASES:
        ts.init(arch="cpu", precision="f32")
        scene = ts.build_scene(scene_name, params)
        stepper = Stepper(scene, ts.create_integrator(args.method, scene.system), 1 / 60, raise_work=False)
        monitor = stepper.monitor
        model = monitor.distance_model
        for s in range(args.steps):
            stepper.step(check=True)
            integrator = stepper.integrator
            h = integrator.solved_h if getattr(integrator, "tracks_solved_start", False) else 1 / 60
            x0, v0 = (a.astype(float) for a in monitor._start.to_numpy())
            x1, v1 = (a.astype(float) for a in scene.state.to_numpy())
            cells = [f"{1e3 * model.distance(x0, v0, x1, v1, h):.2f}"]
            for n in (1, 2, 4, 8, 16):
                x, _ = model.solve_step(x0, v0, h, guess=x1, tolerance=1e-5, max_iterations=n, strict=False)
                cells.append(f"{1e3 * np.max(np.linalg.norm(x1 - x, axis=1)):.2f}" + ("c" if model.converged else ""))
            x_star, _ = model.solve_step(x0, v0, h, guess=x1, tolerance=1e-8, max_iterations=3000)
            cells.append(f"{1e3 * np.max(np.linalg.norm(x1 - x_star, axis=1)):.2f}")
            print(f"| {label} | {s + 1} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
