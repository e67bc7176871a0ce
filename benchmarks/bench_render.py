"""Offscreen rendering speed: frames per second at 1280x720 for a 64x64 cloth, and the wall time
of recording a 5 s, 30 fps clip of it.

    python benchmarks/bench_render.py [--size 1280x720] [--grid 64] [--frames 60]

Everything runs in one process after a warm-up (kernel compilation excluded); per-frame times
are medians. Rendering uses Vulkan (on a machine without a GPU, Mesa's software rasteriser);
the simulation runs on the CPU in f32.
"""
import argparse
import statistics
import tempfile
import time
from pathlib import Path

import taichi_sim as ts
from taichi_sim.app import Clip, Runner, record
from taichi_sim.render import DrawOptions, Renderer, open_window, parse_size
from taichi_sim.scene.cloth import fixed_particle_cloth
from taichi_sim.scene.visual import describe


def median_ms(samples: list[float]) -> float:
    return 1e3 * statistics.median(samples)


def render_fps(size: tuple[int, int], grid: int, frames: int) -> dict:
    """Median cost of one offscreen frame of a moving cloth: drawing (staging copy, normals,
    GGUI) and reading the pixels back, with the simulation stepped outside the timings."""
    scene = ts.build_scene("cloth", {"nx": grid, "ny": grid, **fixed_particle_cloth(grid, grid)})
    runner = Runner(scene, "symplectic_euler", 1e-3)
    window = open_window("bench", size)
    try:
        renderer = Renderer(window, [describe(scene)], size)
        options = DrawOptions()
        draw, read = [], []
        for k in range(frames + 5):
            runner.advance(1 / 30)
            t0 = time.perf_counter()
            renderer.render([runner.display], options)
            t1 = time.perf_counter()
            renderer.read_image()
            t2 = time.perf_counter()
            if k >= 5:  # warm-up: kernel compilation, first uploads
                draw.append(t1 - t0)
                read.append(t2 - t1)
    finally:
        window.destroy()
    total = [d + r for d, r in zip(draw, read)]
    return {"draw_ms": median_ms(draw), "read_ms": median_ms(read), "frame_ms": median_ms(total),
            "fps": 1.0 / statistics.median(total)}


def record_time(size: tuple[int, int], grid: int, seconds: float, fps: float) -> dict:
    """Wall time of recording an .mp4 (simulation, rendering, encoding), after a short warm-up
    recording that compiles every kernel."""
    clip = Clip(scene="cloth", integrators=("symplectic_euler",), params={"nx": grid, "ny": grid},
                dt=1e-3, seconds=seconds, fps=fps, size=size)
    with tempfile.TemporaryDirectory() as tmp:
        record(Clip(**{**clip.__dict__, "seconds": 2 / fps}), Path(tmp) / "warm.mp4", progress=False)
        start = time.perf_counter()
        result = record(clip, Path(tmp) / "clip.mp4", progress=False)
        wall = time.perf_counter() - start
        size_mb = result.path.stat().st_size / 1e6
    sim = Runner(ts.build_scene("cloth", {"nx": grid, "ny": grid, **fixed_particle_cloth(grid, grid)}), "symplectic_euler", 1e-3)
    sim.advance(1 / fps)  # compile
    t0 = time.perf_counter()
    for _ in range(result.frames - 1):
        sim.advance(1 / fps)
    sim_wall = time.perf_counter() - t0
    return {"frames": result.frames, "wall_s": wall, "sim_s": sim_wall, "mb": size_mb}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--grid", type=int, default=64)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--fps", type=float, default=30.0)
    args = parser.parse_args()
    size = parse_size(args.size)
    ts.init(arch="cpu", precision="f32")
    r = render_fps(size, args.grid, args.frames)
    print(f"offscreen render, {args.grid}x{args.grid} cloth at {size[0]}x{size[1]}: "
          f"{r['fps']:.1f} fps (frame {r['frame_ms']:.1f} ms = draw {r['draw_ms']:.1f} ms "
          f"+ readback {r['read_ms']:.1f} ms; medians of {args.frames})")
    c = record_time(size, args.grid, args.seconds, args.fps)
    print(f"record {args.seconds:g} s at {args.fps:g} fps ({c['frames']} frames, {size[0]}x{size[1]}, "
          f"dt = 1 ms): {c['wall_s']:.1f} s wall, of which simulation alone {c['sim_s']:.1f} s; "
          f"{c['mb']:.1f} MB mp4")


if __name__ == "__main__":
    main()
