"""Can a run's distance from its converged trajectory at its end be estimated from its per-step
corrections? Two accumulations of the correction vectors d (x1 - x*, every step) are compared
with the truth (the end against converged backward Euler, f64) on the stiff-cloth study's cloth,
30 steps of 1/60 s, each fast method with its defaults, f32:

* propagated: e <- Phi e + (d, d / h), Phi the converged step's linearisation at the method's
  state (one solve with the step's Jacobian per step);
* free drift: e_x <- e_x + h e_v + d, e_v <- e_v + d / h (no restoring force).

    .venv/bin/python benchmarks/probe_run_error.py [--size 16]

The finding is in docs/lab/error-estimate.md.
"""
import argparse
import sys
from pathlib import Path

import numpy as np
import scipy.sparse.linalg as spla

import taichi_sim as ts
from taichi_sim.bench.stiffcloth import cloth_params
from taichi_sim.stepper import Stepper

sys.path.insert(0, str(Path(__file__).parent))
from bench_error_estimate import reference  # noqa: E402

H = 1 / 60
METHODS = ("vbd", "projective_dynamics", "implicit_euler_linearised")


def largest(e: np.ndarray) -> float:
    return float(np.sqrt((e.reshape(-1, 3) ** 2).sum(axis=1)).max())


def case(size: int, k: float, name: str, steps: int):
    x_ref = reference(size, k, 1, steps)
    ts.init(arch="cpu", precision="f32")
    scene = ts.build_scene("cloth", cloth_params(size, k))
    stepper = Stepper(scene, ts.create_integrator(name, scene.system), H, raise_work=False)
    monitor = stepper.monitor
    model, distance = monitor.model, monitor.distance_model
    free = distance.free
    mass3 = np.repeat(model.mass[free], 3)
    ex, ev = np.zeros(3 * len(free)), np.zeros(3 * len(free))
    fx, fv = ex.copy(), ev.copy()
    for _ in range(steps):
        stepper.step()
        x0, v0 = (a.astype(float) for a in monitor._start.to_numpy())
        x1, v1 = (a.astype(float) for a in scene.state.to_numpy())
        d = distance.correction(x0, v0, x1, v1, H)[free].ravel()
        solve = spla.splu(distance.jacobian(x1, H)).solve
        moved = solve(mass3 / H**2 * ex + mass3 / H * ev + model.drag / H * ex)
        ex, ev = moved + d, (moved - ex) / H + d / H
        fx, fv = fx + H * fv + d, fv + d / H
    true = largest(scene.state.to_numpy()[0].astype(float)[free].ravel() - x_ref[free].ravel())
    return true, largest(ex), largest(fx)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=16)
    parser.add_argument("--steps", type=int, default=30)
    args = parser.parse_args()
    print("| k (N/m) | method | end from converged BE (m) | propagated (m) | free drift (m) |")
    print("|---|---|---|---|---|")
    for k in (1e4, 1e6, 1e8):
        for name in METHODS:
            true, propagated, drift = case(args.size, k, name, args.steps)
            print(f"| {k:g} | {name} | {true:.3g} | {propagated:.3g} ({propagated / true:.2f}) "
                  f"| {drift:.3g} ({drift / true:.2f}) |", flush=True)


if __name__ == "__main__":
    main()
