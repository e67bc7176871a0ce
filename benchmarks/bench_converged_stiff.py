"""Which method gives a converged answer on the stiff cloth, and at what speed?

A size x size cloth (default 64; the study's cloth: structural k, shear k/2, flex k/5, 0.01 kg
a particle, its dashpots and drag) falls from rest for ``--t-end`` s (default 0.25: the
reference is costly) at dt = 1/60 s. Each method runs in f32 with the options given, its work
kept as given (no --tolerance raising it, so the figure is that of those settings); for each:
steps per second (the median step, after an untimed two-step run that compiles everything),
by the clock and by the process's CPU time (on a loaded machine the clock counts other
processes' turns; CPU time counts every thread's, so it reads low for a method whose loops run
in parallel, and is a quiet machine's rate for one that runs serially: xpbd below 2M springs),
and the rms and largest distance of its final positions from converged backward Euler at the
same step (implicit_euler, newton_tolerance 1e-7, f64), the issue's reference for "converged".

    python benchmarks/bench_converged_stiff.py                       # 64 x 64, k = 1e8
    python benchmarks/bench_converged_stiff.py --size 32 --methods "xpbd(substeps=100),vbd"
    python benchmarks/bench_converged_stiff.py --reference out/be-64-1e8.npz   # computes and keeps it
    python benchmarks/bench_converged_stiff.py --preset cloth-stiff --t-end 1   # the scene as simulate runs it

``--preset NAME`` instead runs that scene at this size with all its defaults (method, options,
tolerance: the work the tolerance raises is raised) through a Stepper, as ``simulate`` does,
and prints its steps/s (median step, the sampled steps left out), its warnings and the worst
estimate; no reference.

The 1-minute load average is printed first: other processes on the machine slow every figure.
"""
import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np
import taichi as ti

import taichi_sim as ts
from taichi_sim.atomic import write_atomically
from taichi_sim.bench.stiffcloth import cloth_params
from taichi_sim.integrators import parse_method_label, split_method_labels

DT = 1 / 60
METHODS = ("xpbd(substeps=50)", "xpbd(substeps=100)", "xpbd(substeps=200)", "xpbd(substeps=50, iterations=4)",
           "vbd", "projective_dynamics", "implicit_euler_linearised")


def reference(params: dict, steps: int, path: Path | None) -> np.ndarray:
    """Converged backward Euler's positions ((n, 3), m) after ``steps`` steps; read from / kept
    in ``path`` (its key must match)."""
    key = f"{params['nx']}:{params['stiffness']:g}:{steps}"
    if path is not None and path.exists():
        with np.load(path) as kept:
            if str(kept["key"]) != key:
                raise SystemExit(f"{path} holds the reference for {kept['key']} (size:k:steps), not {key}")
            return kept["x"]
    ts.init(arch="cpu", precision="f64")
    scene = ts.build_scene("cloth", params)
    integrator = ts.create_integrator("implicit_euler", scene.system, newton_tolerance=1e-7)
    result = ts.run(scene, integrator, dt=DT, steps=steps, energy_every=0)
    if result.status.value != "ok":
        raise RuntimeError(f"reference: {result.status.value} {result.message}")
    x = scene.state.to_numpy()[0].astype(float)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomically(path, lambda f: np.savez(f, key=key, x=x))
    return x


def measure(params: dict, method: str, steps: int, exact: np.ndarray) -> dict:
    name, options = parse_method_label(method)
    ts.init(arch="cpu", precision="f32")
    scene = ts.build_scene("cloth", params)
    integrator = ts.create_integrator(name, scene.system, **options)
    t = 0.0
    for _ in range(2):  # compile
        integrator.step(scene.state, t, DT)
        t += DT
    scene.reset()
    integrator.reset()
    times, cpu, t, status = [], [], 0.0, "ok"
    for _ in range(steps):
        start, start_cpu = time.perf_counter(), time.process_time()
        report = integrator.step(scene.state, t, DT)
        ti.sync()
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
        t += DT
        if report.status.value != "ok":
            status = report.status.value
            break
    x = scene.state.to_numpy()[0].astype(float)
    distance = np.linalg.norm(x - exact, axis=1)
    return {"status": status, "steps_per_s": 1.0 / statistics.median(times),
            "cpu_steps_per_s": 1.0 / max(statistics.median(cpu), 1e-9),
            "rms": float(np.sqrt(np.mean(distance ** 2))), "max": float(distance.max())}


def run_preset(name: str, size: int, steps: int) -> None:
    from taichi_sim.scene.presets import scene_preset
    from taichi_sim.stepper import Stepper, bind_integrator

    ts.init(arch="cpu", precision="f32")
    scene = ts.build_scene(name, {"nx": size, "ny": size})
    method = scene_preset(name).default_integrator
    integrator = bind_integrator(scene, method)
    stepper = Stepper(scene, integrator, DT)
    times, cpu = [], []
    for s in range(steps):
        sampled = len(stepper.monitor.times)
        start, start_cpu = time.perf_counter(), time.process_time()
        stepper.step(check=s == steps - 1)
        if s >= 2 and len(stepper.monitor.times) == sampled:  # compiled, and not sampled
            times.append(time.perf_counter() - start)
            cpu.append(time.process_time() - start_cpu)
        if stepper.failure is not None:
            print(stepper.failure.message)
            break
    option = integrator.work_option
    print(f"{name} {size}x{size}: {stepper.steps} steps of {method} ({option} now {getattr(integrator, option)}), "
          f"{1 / statistics.median(times):.1f} steps/s ({1 / statistics.median(cpu):.1f} by CPU time), worst estimate "
          f"{1e3 * stepper.monitor.worst_distance:.3g} mm of --tolerance {1e3 * stepper.monitor.tolerance:g} mm "
          f"over {len(stepper.monitor.times)} samples, {len(stepper.warnings)} warnings")
    for warning in stepper.warnings:
        print("warning:", warning)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--stiffness", type=float, default=1e8)
    parser.add_argument("--t-end", type=float, default=0.25)
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--reference", type=Path, default=None, metavar="FILE.npz",
                        help="read the reference from FILE.npz, or compute it and write it there")
    parser.add_argument("--preset", default=None, help="run this scene at its defaults instead (no reference)")
    args = parser.parse_args()
    steps = max(1, round(args.t_end / DT))
    if args.preset:
        run_preset(args.preset, args.size, steps)
        return
    params = cloth_params(args.size, args.stiffness)
    print(f"load average (1 min): {os.getloadavg()[0]:.2f} on {os.cpu_count()} cpus")
    start = time.perf_counter()
    exact = reference(params, steps, args.reference)
    print(f"{args.size}x{args.size} cloth, k = {args.stiffness:g} N/m, {steps} steps of 1/60 s, f32; distance (m) "
          f"from implicit_euler (newton_tolerance 1e-7, f64; {time.perf_counter() - start:.0f} s)")
    print("| method | status | steps/s | steps/s by CPU time | rms (m) | max (m) |\n|---|---|---|---|---|---|")
    for method in split_method_labels(args.methods):
        row = measure(params, method, steps, exact)
        print(f"| {method} | {row['status']} | {row['steps_per_s']:.1f} | {row['cpu_steps_per_s']:.1f} | "
              f"{row['rms']:.4f} | {row['max']:.4f} |",
              flush=True)


if __name__ == "__main__":
    main()
