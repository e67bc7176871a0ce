"""Time to build cloth scenes (topology in numpy + field allocation), median of 5 after warm-up.

    .venv/bin/python benchmarks/bench_build.py
"""
import statistics
import time

import taichi_sim as ts
from taichi_sim.scene.cloth import per_particle


def main():
    ts.init(arch="cpu", precision="f32")
    for n in (64, 128, 256):
        ts.build_scene("cloth", {"nx": n, "ny": n, **per_particle(n, n, mass=0.01, drag=0.005)})  # warm-up
        times = []
        for _ in range(5):
            start = time.perf_counter()
            scene = ts.build_scene("cloth", {"nx": n, "ny": n, **per_particle(n, n, mass=0.01, drag=0.005)})
            times.append(time.perf_counter() - start)
        print(f"cloth {n}x{n}: {scene.features['springs']} springs, build {statistics.median(times) * 1e3:.0f} ms (median of 5)")


if __name__ == "__main__":
    main()
