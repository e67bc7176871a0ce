"""Benchmark: vertex block descent against XPBD and projective dynamics on the stiff cloth.

A size x size cloth (default 64, structural k, shear k/2, flex k/5, the scene's dashpots and
drag) falls from rest for ``--t-end`` s (default 0.5) at dt = 1/60 s in f32. For each method:
steps per second (median over the timed steps, after a warm-up run of two steps that compiles
everything; the state is reset before the timed run), the rms and largest distance of the
final positions from backward Euler solved tightly (implicit_euler, newton_tolerance 1e-6,
f64, the same step), the same from the cloth's converged motion (symplectic Euler at a quarter
of its stable step in f64, the reference of `taichi-sim bench stiff-cloth`; the backward Euler
step is itself a first-order approximation of that motion, and its row says how far it ends
from it), and the worst relative solver residual of a second, untimed run
(taichi_sim/convergence.py; the bound is 1e-2 or three times f32's rounding floor).

    python benchmarks/bench_vbd.py                          # 64 x 64, k = 1e6 and 1e8
    python benchmarks/bench_vbd.py --size 32 --stiffnesses 1e6 --methods "vbd,vbd(iterations=40)"
    python benchmarks/bench_vbd.py --references out/stiff-refs.npz --methods xpbd   # computes and keeps them
    python benchmarks/bench_vbd.py --references out/stiff-refs.npz --arch gpu --methods "xpbd(substeps=50)"
    python benchmarks/bench_vbd.py --per-area --size 32 --stiffnesses 1e6 --methods "xpbd,xpbd(substeps=50)"

``--per-area`` studies the scenes' own cloth instead (``cloth-stiff`` at this size: the
preset's area density, 0.01 kg a particle at 32 x 32 and a quarter of that at 64 x 64).

``--arch gpu`` runs the methods on a GPU (each timed step ends with ``ti.sync()``, so a step's
time includes its kernels); the references are always computed on the CPU in f64, and
``--references`` keeps them in a file (for the same size, stiffnesses and t-end) so a GPU
machine can take them from the development machine instead of computing them again.

The 1-minute load average is printed first: other processes on the machine slow every figure.
"""
import argparse
import math
import os
import statistics
import time
from pathlib import Path

import numpy as np
import taichi as ti

import taichi_sim as ts
from taichi_sim.atomic import write_atomically
from taichi_sim.bench.stiffcloth import cloth_params, reference_solution
from taichi_sim.integrators import parse_method_label, split_method_labels
from taichi_sim.scene.cloth import swept_stiffness

DT = 1 / 60
METHODS = ("vbd(iterations=10)", "vbd", "vbd(iterations=40)", "vbd(chebyshev_rho=0.9)",
           "vbd(substeps=5, iterations=4)", "vbd(substeps=20, iterations=1)", "vbd(augmented=True)",
           "xpbd", "projective_dynamics")


def studied_cloth(size: int, k: float, per_area: bool) -> dict:
    """The ``cloth`` scene's parameters: the study's cloth (0.01 kg a particle at every size),
    or with ``per_area`` the scenes' own (``cloth-stiff``'s at k = 1e6)."""
    return {"nx": size, "ny": size, **swept_stiffness(k)} if per_area else cloth_params(size, k)


def reference(params: dict, steps: int) -> np.ndarray:
    ts.init(arch="cpu", precision="f64")
    scene = ts.build_scene("cloth", params)
    integrator = ts.create_integrator("implicit_euler", scene.system, newton_tolerance=1e-6)
    result = ts.run(scene, integrator, dt=DT, steps=steps, energy_every=0)
    if result.status.value != "ok":
        raise RuntimeError(f"reference: {result.status.value} {result.message}")
    return scene.state.to_numpy()[0].astype(float)


def load_references(path: Path | None, size: int, stiffnesses: list[float], steps: int,
                    per_area: bool = False) -> dict:
    """{k: (backward Euler's positions, the motion's positions)}, each (n, 3) in m; read from
    ``path`` when it exists (it must hold them for this size, these stiffnesses and this many
    steps: else the script stops and names both), else computed (on the CPU, f64) and written
    there when a path is given."""
    key = f"{size}:{steps}:" + ",".join(f"{k:g}" for k in stiffnesses) + (":per-area" if per_area else "")
    if path is not None and path.exists():
        with np.load(path) as kept:
            if str(kept["key"]) != key:
                raise SystemExit(f"{path} holds references for {kept['key']} (size:steps:stiffnesses), not {key}")
            return {k: (kept[f"be_{i}"], kept[f"motion_{i}"]) for i, k in enumerate(stiffnesses)}
    out = {k: (reference(studied_cloth(size, k, per_area), steps),
               reference_solution(size, k, steps * DT, studied_cloth(size, k, per_area))[0]) for k in stiffnesses}
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {f"{kind}_{i}": out[k][j] for i, k in enumerate(stiffnesses) for j, kind in enumerate(("be", "motion"))}
        write_atomically(path, lambda f: np.savez(f, key=key, **arrays))
    return out


def distances(x: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """(rms, largest) distance (m) of positions x ((n, 3)) from the reference's."""
    distance = np.linalg.norm(x - reference, axis=1)
    return math.sqrt(float(np.mean(distance ** 2))), float(distance.max())


def measure(params: dict, method: str, steps: int, exact: np.ndarray, motion: np.ndarray,
            arch: str = "cpu") -> dict:
    name, options = parse_method_label(method)
    ts.init(arch=arch, precision="f32")
    scene = ts.build_scene("cloth", params)
    integrator = ts.create_integrator(name, scene.system, **options)
    t = 0.0
    for _ in range(2):  # compile
        integrator.step(scene.state, t, DT)
        t += DT
    scene.reset()
    integrator.reset()
    times, t, status = [], 0.0, "ok"
    for _ in range(steps):
        ti.sync()
        start = time.perf_counter()
        report = integrator.step(scene.state, t, DT)
        ti.sync()
        times.append(time.perf_counter() - start)
        t += DT
        if report.status.value != "ok":
            status = report.status.value
            break
    x = scene.state.to_numpy()[0].astype(float)
    (rms, largest), (rms_motion, largest_motion) = distances(x, exact), distances(x, motion)
    scene.reset()
    integrator.reset()
    checked = ts.run(scene, integrator, dt=DT, steps=steps, energy_every=0)
    median = statistics.median(times)
    return {"method": method, "status": status, "steps_per_s": 1.0 / median, "ms": 1e3 * median,
            "rms": rms, "max": largest, "rms_motion": rms_motion, "max_motion": largest_motion,
            "residual": checked.worst_residual, "warned": bool(checked.warnings)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--stiffnesses", default="1e6,1e8")
    parser.add_argument("--t-end", type=float, default=0.5)
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--arch", choices=("cpu", "gpu"), default="cpu", help="where the methods run")
    parser.add_argument("--references", type=Path, default=None, metavar="FILE.npz",
                        help="read the references from FILE.npz, or compute them and write it there")
    parser.add_argument("--per-area", action="store_true",
                        help="the scenes' cloth (area density, cloth-stiff's) instead of the study's 0.01 kg a particle")
    args = parser.parse_args()
    steps = max(1, round(args.t_end / DT))
    stiffnesses = [float(v) for v in args.stiffnesses.split(",")]
    print(f"load average (1 min): {os.getloadavg()[0]:.2f} on {os.cpu_count()} cpus")
    references = load_references(args.references, args.size, stiffnesses, steps, args.per_area)
    ts.init(arch=args.arch, precision="f32")  # where the methods run: what Taichi found
    print(f"methods on {args.arch}: backend {ts.runtime.backend()}")
    print(f"{args.size}x{args.size} cloth ({'area density' if args.per_area else '0.01 kg a particle'}), {steps} steps of 1/60 s, f32; error (m) against implicit_euler "
          f"(newton_tolerance 1e-6, f64: 'BE') and against the converged motion (fine symplectic Euler, f64: "
          f"'motion')")
    print(f"{'k (N/m)':>8} {'method':<40} {'status':<8} {'steps/s':>8} {'ms/step':>8} {'rms BE':>8} "
          f"{'max BE':>8} {'rms mot.':>8} {'max mot.':>8} {'residual':>9} {'warned':>6}")
    for k in stiffnesses:
        exact, motion = references[k]
        print(f"{k:8.0e} {'implicit_euler (the BE reference)':<40} {'ok':<8} {'':>8} {'':>8} {0.0:8.4f} "
              f"{0.0:8.4f} {distances(exact, motion)[0]:8.4f} {distances(exact, motion)[1]:8.4f}", flush=True)
        for method in split_method_labels(args.methods):
            row = measure(studied_cloth(args.size, k, args.per_area), method.strip(), steps, exact, motion, args.arch)
            print(f"{k:8.0e} {row['method']:<40} {row['status']:<8} {row['steps_per_s']:8.1f} {row['ms']:8.2f} "
                  f"{row['rms']:8.4f} {row['max']:8.4f} {row['rms_motion']:8.4f} {row['max_motion']:8.4f} "
                  f"{row['residual']:9.2g} {'yes' if row['warned'] else 'no':>6}", flush=True)


if __name__ == "__main__":
    main()
