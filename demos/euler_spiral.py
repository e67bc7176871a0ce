"""Explicit Euler on the circle ODE dx/dt = (-y, x): the orbit spirals outward.

    python demos/euler_spiral.py spiral.gif

The exact solution is a circle (drawn faintly). Every Euler step multiplies the radius by
sqrt(1 + h^2), so after n steps it has grown by (1 + h^2)^(n/2): with h = 0.1, 1.01^(n/2).
The trail shows the path; `speed` runs 4 simulated seconds per video second.
"""
import sys

import taichi_sim as ts
from taichi_sim.app import Clip, record
from taichi_sim.render import RenderUnavailable


def main(out: str) -> None:
    ts.init(arch="cpu", precision="f64")
    h, seconds, speed = 0.1, 6.0, 4.0
    clip = Clip(scene="simple", integrators=("euler",), dt=h, seconds=seconds, fps=15.0,
                size=(480, 480), speed=speed)
    result = record(clip, out, progress=True)
    steps = round(seconds * speed / h)
    print(f"wrote {result.path}; expected radius after {steps} steps: {(1 + h * h) ** (steps / 2):.3f}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python demos/euler_spiral.py OUT.mp4|OUT.gif|DIR/")
    try:
        main(sys.argv[1])
    except (ts.ConfigError, RenderUnavailable) as exc:
        sys.exit(f"error: {exc}")
