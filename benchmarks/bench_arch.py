"""The same runs on the CPU and on a GPU: steps/s, the first step's time (compiling), and how far
the GPU's final positions end from the CPU's.

    python benchmarks/bench_arch.py --arch cpu --out out/arch-cpu     # here: the reference
    python benchmarks/bench_arch.py --arch gpu --out out/arch-gpu --reference out/arch-cpu

Each case builds a scene, takes one step (which compiles the kernels: "first step"), then
``--repeats`` batches of a fixed number of steps with ``ti.sync()`` around each; steps/s is the
median batch's. All runs are f32 with the guard on, through :class:`taichi_sim.Stepper`, as
``simulate`` steps. The number of steps is fixed per case, so the final positions of the two
runs can be compared (``--reference``: the rms and largest distance per particle). A case with
contact is chaotic: there the distance says only that both runs stayed in one piece.
Writes ``arch-ARCH.json`` and ``arch-ARCH.npz`` (final positions) into ``--out``.
"""
import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import taichi as ti

import taichi_sim as ts

# name, scene, parameters, integrator, options, dt (s), steps per batch, contact (chaotic)
CASES = [
    ("symplectic 256", "cloth", {"nx": 256, "ny": 256}, "symplectic_euler", {}, 1e-4, 200, False),
    ("symplectic 512", "cloth", {"nx": 512, "ny": 512}, "symplectic_euler", {}, 1e-4, 100, False),
    ("symplectic 1024", "cloth", {"nx": 1024, "ny": 1024}, "symplectic_euler", {}, 2e-5, 40, False),
    ("rk4 256", "cloth", {"nx": 256, "ny": 256}, "rk4", {}, 1e-4, 50, False),
    ("xpbd stiff 64", "cloth-stiff", {"nx": 64, "ny": 64}, "xpbd", {}, 1 / 60, 10, False),
    ("implicit_euler 64", "cloth", {"nx": 64, "ny": 64}, "implicit_euler", {}, 1 / 60, 3, False),
    ("vbd stiff 64", "cloth-stiff", {"nx": 64, "ny": 64}, "vbd", {}, 1 / 60, 10, False),
    ("vbd stiff 256", "cloth-stiff", {"nx": 256, "ny": 256}, "vbd", {}, 1 / 60, 4, False),
    ("vbd fold 64", "cloth-fold", {"nx": 64, "ny": 64}, "vbd", {}, 1 / 60, 10, True),
    ("vbd fold 128", "cloth-fold", {"nx": 128, "ny": 128, "thickness": 0.005, "jitter": 0.001},
     "vbd", {}, 1 / 60, 5, True),
    ("symplectic+stage fold 64", "cloth-fold", {"nx": 64, "ny": 64}, "symplectic_euler", {}, 1e-3, 20, True),
]


def run_case(case, repeats: int) -> tuple[dict, np.ndarray]:
    name, scene_name, params, integrator, options, dt, batch, contact = case
    scene = ts.build_scene(scene_name, dict(params))
    method = ts.create_integrator(integrator, scene.system, **options)
    stepper = ts.Stepper(scene, method, dt)
    start = time.perf_counter()
    stepper.step()
    ti.sync()
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(batch):
            stepper.step()
        ti.sync()
        times.append(time.perf_counter() - start)
        if stepper.failure is not None:
            break
    x = scene.state.to_numpy()[0].astype(np.float64)
    row = {"case": name, "particles": int(x.shape[0]), "dt": dt, "steps": stepper.steps,
           "first_step_s": first, "steps_per_s": batch / statistics.median(times),
           "status": "ok" if stepper.failure is None else stepper.failure.summary, "contact": contact}
    return row, x


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arch", choices=("cpu", "gpu"), required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--reference", type=Path, default=None,
                        help="an --out folder of another run: compare final positions with its npz")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cases", default=None, help="comma-separated case names (default: all)")
    args = parser.parse_args()
    cases = CASES
    if args.cases:
        wanted = [c.strip() for c in args.cases.split(",")]
        unknown = sorted(set(wanted) - {c[0] for c in CASES})
        if unknown:
            parser.error(f"unknown case(s) {unknown}; known: {[c[0] for c in CASES]}")
        cases = [c for c in CASES if c[0] in wanted]
    args.out.mkdir(parents=True, exist_ok=True)
    ts.init(arch=args.arch, precision="f32")
    backend = str(ti.lang.impl.current_cfg().arch)
    reference = None
    if args.reference is not None:
        ref_path = args.reference / "arch-cpu.npz"
        reference = dict(np.load(ref_path))
    rows, positions = [], {}
    meta = {"arch": args.arch, "backend": backend, "machine": platform.processor() or platform.machine(),
            "cpus": os.cpu_count(), "date": time.strftime("%Y-%m-%d"), "repeats": args.repeats}
    print(f"# {meta}", flush=True)
    for case in cases:
        row, x = run_case(case, args.repeats)
        positions[case[0]] = x.astype(np.float32)
        if reference is not None and case[0] in reference:
            d = np.linalg.norm(x - reference[case[0]].astype(np.float64), axis=1)
            row["rms_vs_reference_m"], row["max_vs_reference_m"] = float(np.sqrt(np.mean(d * d))), float(d.max())
        rows.append(row)
        print(json.dumps(row), flush=True)
        (args.out / f"arch-{args.arch}.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
        np.savez_compressed(args.out / f"arch-{args.arch}.npz", **positions)
    print()
    print("| case | particles | first step (s) | steps/s | status | rms / max vs reference (m) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        ref = (f"{r['rms_vs_reference_m']:.2e} / {r['max_vs_reference_m']:.2e}"
               if "rms_vs_reference_m" in r else "-")
        print(f"| {r['case']} | {r['particles']} | {r['first_step_s']:.2f} | {r['steps_per_s']:.4g} "
              f"| {r['status']} | {ref} |")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
