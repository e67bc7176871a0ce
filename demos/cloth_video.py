"""Record a cloth falling from two pinned corners, as a video.

    python demos/cloth_video.py cloth.mp4        # or cloth.gif, or frames/ for PNG frames

The recorder advances the scene by 1/fps of simulated time per video frame, in steps of dt, and
draws every frame offscreen (Vulkan; Mesa's software driver is enough) with the same renderer as
the interactive launcher. Nothing is left on disk if it fails.
"""
import sys

import taichi_sim as ts
from taichi_sim.app import Clip, record
from taichi_sim.render import RenderUnavailable


def main(out: str) -> None:
    ts.init(arch="cpu", precision="f32")  # the simulation runs on the CPU; drawing uses Vulkan
    clip = Clip(
        scene="cloth",
        integrators=("symplectic_euler",),  # one force evaluation per step, stable at 1 ms here
        params={"nx": 32, "ny": 32, "pin": "corners"},  # see `taichi-sim list`
        dt=1e-3,  # s per step: 1000 steps per simulated second
        seconds=5.0,  # of video
        fps=30.0,
        size=(1280, 720),  # pixels (even sides for an .mp4)
    )
    result = record(clip, out, progress=True)
    print(f"wrote {result.path}: {result.frames} frames in {result.wall:.1f} s")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python demos/cloth_video.py OUT.mp4|OUT.gif|DIR/")
    try:
        main(sys.argv[1])
    except (ts.ConfigError, RenderUnavailable) as exc:
        sys.exit(f"error: {exc}")
