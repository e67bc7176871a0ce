"""Check the stiff cloth's converged motion three independent ways, and how far the backward
Euler step at 1/60 s ends from it.

The cloth of ``bench_vbd.py`` (size x size, structural k, shear k/2, flex k/5, 0.01 kg a
particle, pinned at two corners) falls from rest for 0.5 s. Its motion is computed in f64 by

* symplectic Euler at a quarter of its stable step (the reference of ``bench stiff-cloth`` and
  of ``bench_vbd.py``'s "motion" columns);
* backward Euler (``implicit_euler``, newton_tolerance 1e-8) at 1/(60 m) and 1/(120 m) s,
  Richardson-extrapolated, 2 x(h/2) - x(h): backward Euler is first order, so that cancels its
  leading error term;
* XPBD at 1/(60 s) s with many sweeps a substep (``--xpbd-substeps``, ``--xpbd-sweeps``).

It prints the rms and largest distance (m) between each pair, and from each to backward Euler
at 1/60 s (newton_tolerance 1e-6, the step ``bench_vbd.py``'s "BE" columns measure from).

    python benchmarks/check_motion_reference.py                # k = 1e6, 64 x 64: about 5 minutes
    python benchmarks/check_motion_reference.py --stiffness 1e8 --size 32
"""
import argparse
import itertools
import time

import numpy as np
from bench_vbd import DT, distances, reference

import taichi_sim as ts
from taichi_sim.bench.stiffcloth import cloth_params, reference_solution


def backward_euler(size: int, k: float, divisions: int, steps: int) -> np.ndarray:
    """Positions after ``steps`` steps of 1/60 s, each taken as ``divisions`` backward Euler steps."""
    ts.init(arch="cpu", precision="f64")
    scene = ts.build_scene("cloth", cloth_params(size, k))
    method = ts.create_integrator("implicit_euler", scene.system, newton_tolerance=1e-8)
    result = ts.run(scene, method, dt=DT / divisions, steps=steps * divisions, energy_every=0)
    if result.status.value != "ok":
        raise RuntimeError(f"backward Euler at 1/{60 * divisions} s: {result.status.value} {result.message}")
    return scene.state.to_numpy()[0].astype(float)


def fine_xpbd(size: int, k: float, substeps: int, sweeps: int, steps: int) -> np.ndarray:
    """Positions after ``steps`` XPBD steps of 1/60 s with ``substeps`` substeps of ``sweeps`` sweeps."""
    ts.init(arch="cpu", precision="f64")
    scene = ts.build_scene("cloth", cloth_params(size, k))
    method = ts.create_integrator("xpbd", scene.system, substeps=substeps, iterations=sweeps)
    result = ts.run(scene, method, dt=DT, steps=steps, energy_every=0)
    if result.status.value != "ok":
        raise RuntimeError(f"xpbd: {result.status.value} {result.message}")
    return scene.state.to_numpy()[0].astype(float)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--stiffness", type=float, default=1e6)
    parser.add_argument("--t-end", type=float, default=0.5)
    parser.add_argument("--divisions", type=int, default=20,
                        help="m: backward Euler at 1/(60 m) and 1/(120 m) s (default 20)")
    parser.add_argument("--xpbd-substeps", type=int, default=200, help="XPBD substeps a 1/60 s step (default 200)")
    parser.add_argument("--xpbd-sweeps", type=int, default=40, help="XPBD sweeps a substep (default 40)")
    args = parser.parse_args()
    steps = max(1, round(args.t_end / DT))
    solutions, started = {}, time.perf_counter()

    def keep(name, x):
        solutions[name] = x
        print(f"  {name}: done at {time.perf_counter() - started:.0f} s", flush=True)

    keep("symplectic Euler, 1/4 stable step", reference_solution(args.size, args.stiffness, steps * DT)[0])
    coarse = backward_euler(args.size, args.stiffness, args.divisions, steps)
    fine = backward_euler(args.size, args.stiffness, 2 * args.divisions, steps)
    keep(f"backward Euler 1/{60 * args.divisions}, 1/{120 * args.divisions} s, Richardson", 2 * fine - coarse)
    keep(f"xpbd {args.xpbd_substeps} x {args.xpbd_sweeps}, f64",
         fine_xpbd(args.size, args.stiffness, args.xpbd_substeps, args.xpbd_sweeps, steps))
    step = reference(cloth_params(args.size, args.stiffness), steps)
    print(f"{args.size}x{args.size} cloth, k = {args.stiffness:g} N/m, {steps * DT:g} s; distances (m): rms, largest")
    for (a, xa), (b, xb) in itertools.combinations(solutions.items(), 2):
        rms, largest = distances(xa, xb)
        print(f"  {a}  <->  {b}: {rms:.4f}, {largest:.4f}")
    for name, x in solutions.items():
        rms, largest = distances(step, x)
        print(f"  backward Euler at 1/60 s  <->  {name}: {rms:.4f}, {largest:.4f}")


if __name__ == "__main__":
    main()
