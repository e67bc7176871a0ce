"""Measure the garment scene: steps per second after warm-up, and over a run of T seconds the
frames whose triangles intersect (the check of `taichi-sim check`) and the deepest vertex inside
the body's capsules. One line per configuration; docs/meshes.md quotes the figures.

    python examples/garments/measure_garment.py --t-end 3 xpbd:0.0166667 vbd:0.0166667 ...

A configuration is METHOD:DT[:sc] (sc: self-collision on).
"""
import argparse
import time

import numpy as np

import taichi_sim as ts
from taichi_sim.geometry import self_intersections
from taichi_sim.scene.garment import BODY


def capsule_depth(frames: np.ndarray) -> float:
    """Deepest vertex inside any body capsule over the frames (m; <= 0: none inside)."""
    deepest = -np.inf
    for centre, half_axis, radius in BODY:
        c, h = np.asarray(centre), np.asarray(half_axis)
        d = frames - (c - h)
        s = np.clip((d @ (2 * h)) / (4 * h @ h), 0.0, 1.0)
        gap = np.linalg.norm(d - s[..., None] * (2 * h), axis=-1)
        deepest = max(deepest, float((radius - gap).max()))
    return deepest


def measure(spec: str, t_end: float, frame: float, params: dict) -> str:
    method, dt, *flags = spec.split(":")
    dt = float(dt)
    values = dict(params, self_collision="sc" in flags)
    scene = ts.build_scene("garment", values)
    integrator = ts.create_integrator(method, scene.system)
    ts.run(scene, integrator, dt=dt, steps=3)  # warm-up: compiles every kernel
    scene.reset()
    stepper = ts.Stepper(scene, integrator, dt=dt)
    times = []
    for _ in range(min(30, max(5, int(0.2 / dt)))):
        start = time.perf_counter()
        stepper.step()
        times.append(time.perf_counter() - start)
    rate = 1.0 / float(np.median(times))
    scene.reset()
    save = max(1, round(frame / dt))
    start = time.perf_counter()
    result = ts.run(scene, integrator, dt=dt, t_end=t_end, save_every=save)
    wall = time.perf_counter() - start
    frames = result.x_history
    hits = sum(self_intersections(x, scene.mesh.triangles_np).count > 0 for x in frames)
    return (f"{spec:<28} {scene.particle_count} vertices  {rate:8.1f} steps/s (median of {len(times)})  "
            f"{result.t / wall:6.3f} sim-s per wall-s  status {result.status.value}  "
            f"{hits} of {len(frames)} frames intersect  deepest in body {1e3 * capsule_depth(frames):.2f} mm  "
            f"hem y {frames[-1][:, 1].min():.3f} m")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("configs", nargs="+")
    parser.add_argument("--t-end", type=float, default=3.0)
    parser.add_argument("--frame", type=float, default=1 / 30, help="seconds between checked frames")
    parser.add_argument("--precision", default="f32")
    parser.add_argument("--set", action="append", default=[], help="NAME=VALUE garment parameters")
    args = parser.parse_args()
    ts.init(arch="cpu", precision=args.precision)
    params = dict(a.split("=", 1) for a in args.set)
    for spec in args.configs:
        print(measure(spec, args.t_end, args.frame, params), flush=True)


if __name__ == "__main__":
    main()
