"""Record a chain pendulum: five particles on stiff springs, released horizontally.

    python demos/pendulum_video.py pendulum.gif

Stiff springs (1000 N/m on 0.1 kg) make the chain nearly inextensible; symplectic Euler keeps
its energy bounded at a 1 ms step. Try `integrators=("euler",)` to watch explicit Euler gain
energy until the recording freezes on the last finite state and says so.
"""
import sys

import taichi_sim as ts
from taichi_sim.app import Clip, record
from taichi_sim.render import RenderUnavailable


def main(out: str) -> None:
    ts.init(arch="cpu", precision="f64")
    clip = Clip(scene="pendulum", integrators=("symplectic_euler",),
                params={"particle_count": 5, "stiffness": 1000.0, "angle": 90.0},
                dt=1e-3, seconds=6.0, fps=20.0, size=(640, 480))
    result = record(clip, out, progress=True)
    print(f"wrote {result.path}: {result.frames} frames in {result.wall:.1f} s")
    for failure in result.failures:  # a run that diverged says where and why
        print(failure)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python demos/pendulum_video.py OUT.mp4|OUT.gif|DIR/")
    try:
        main(sys.argv[1])
    except (ts.ConfigError, RenderUnavailable) as exc:
        sys.exit(f"error: {exc}")
