"""XPBD's time a step against its substeps on the stiff cloth, with and without a ti.sync()
every K substeps: on a GPU a 64 x 64 substep is a handful of small kernels, and a step's time
is the launches' (is it the launch queue filling that slows a step of many substeps?).

    python benchmarks/probe_gpu_substeps.py --arch gpu

The 64 x 64 cloth of bench_vbd.py at k = 1e6 (``cloth_params``: shear k/2, flex k/5), f32,
h = 1/60 s: for each number of substeps and each K (0: no sync inside a step), a fresh scene,
two steps to compile, then 30 steps each timed with ti.sync() at its end; prints the median,
fastest and slowest step and the cloth's mean height (the same for every K: a sync changes no
result).
"""
import argparse
import statistics
import time

import taichi as ti

import taichi_sim as ts
from taichi_sim.bench.stiffcloth import cloth_params

H = 1 / 60


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arch", choices=("cpu", "gpu"), default="gpu")
    parser.add_argument("--substeps", default="40,50,55,60,70,80,120")
    parser.add_argument("--sync-every", default="0,25,10", help="K values (0: no sync inside a step)")
    args = parser.parse_args()
    ts.init(arch=args.arch, precision="f32")
    params = cloth_params(64, 1e6)
    print(f"backend {ts.runtime.backend()}")
    for substeps in (int(v) for v in args.substeps.split(",")):
        for sync_every in (int(v) for v in args.sync_every.split(",")):
            scene = ts.build_scene("cloth", dict(params))
            xpbd = ts.create_integrator("xpbd", scene.system, substeps=substeps)
            substep, count = xpbd._substep, [0]

            def synced(*a, substep=substep, count=count, every=sync_every):
                substep(*a)
                count[0] += 1
                if every and count[0] % every == 0:
                    ti.sync()
            xpbd._substep = synced
            t = 0.0
            for _ in range(2):
                xpbd.step(scene.state, t, H)
                t += H
            ti.sync()
            times = []
            for _ in range(30):
                start = time.perf_counter()
                xpbd.step(scene.state, t, H)
                ti.sync()
                times.append(time.perf_counter() - start)
                t += H
            height = scene.state.to_numpy()[0][:, 1].mean()
            print(f"substeps {substeps:4d} sync every {sync_every:3d}: median {1e3 * statistics.median(times):7.2f} ms "
                  f"min {1e3 * min(times):7.2f} max {1e3 * max(times):7.2f}  mean height {height:.4f} m", flush=True)


if __name__ == "__main__":
    main()
