"""Time to build cloth scenes (topology in numpy + field allocation), median of 5 after warm-up.

    .venv/bin/python benchmarks/bench_build.py
"""
import statistics
import time

import taichi_sim as ts
from taichi_sim.scene.cloth import fixed_particle_cloth


def main():
    ts.init(arch="cpu", precision="f32")
    for n in (64, 128, 256):
        ts.build_scene("cloth", {"nx": n, "ny": n, **fixed_particle_cloth(n, n)})  # warm-up
        times = []
        for _ in range(5):
            start = time.perf_counter()
            scene = ts.build_scene("cloth", {"nx": n, "ny": n, **fixed_particle_cloth(n, n)})
            times.append(time.perf_counter() - start)
        print(f"cloth {n}x{n}: {scene.features['springs']} springs, build {statistics.median(times) * 1e3:.0f} ms (median of 5)")


if __name__ == "__main__":
    main()
