"""One scene, three integrators, side by side at the same step.

    python demos/compare_integrators.py compare.mp4 [STEP]

The pendulum chain's stiff springs have omega_max of about 200 rad/s. At h = 8 ms
(h * omega_max = 1.6) explicit Euler is unstable for any step and blows up within a fraction of
a second (its panel freezes on the last finite state, labelled with the time it diverged);
symplectic Euler is stable below h * omega = 2 and RK4 below 2.83 (docs/integrators.md, Stability
on an oscillator).
"""
import sys

import taichi_sim as ts
from taichi_sim.app import Clip, record
from taichi_sim.render import RenderUnavailable


def main(out: str, step: float) -> None:
    ts.init(arch="cpu", precision="f64")
    clip = Clip(scene="pendulum", integrators=("euler", "rk4", "symplectic_euler"), dt=step,
                seconds=5.0, fps=24.0, size=(1280, 480))
    result = record(clip, out, progress=True)
    print(f"wrote {result.path}")
    for failure in result.failures:
        print(failure)


if __name__ == "__main__":
    if len(sys.argv) not in (2, 3):
        sys.exit("usage: python demos/compare_integrators.py OUT.mp4|OUT.gif|DIR/ [STEP_SECONDS]")
    try:
        main(sys.argv[1], float(sys.argv[2]) if len(sys.argv) == 3 else 8e-3)
    except (ts.ConfigError, RenderUnavailable, ValueError) as exc:
        sys.exit(f"error: {exc}")
