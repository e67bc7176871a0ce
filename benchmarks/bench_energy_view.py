"""What the live energy plot costs: stepping with and without keeping the energy samples, and
drawing a frame with and without the charts (and the strain legend).

    python benchmarks/bench_energy_view.py [--size 640x360] [--grid 32] [--frames 60]

One process, after a warm-up (kernel compilation excluded); the two sides alternate frame by
frame so that machine noise falls on both, and the figures are medians. The scene is a
grid x grid cloth, side by side with symplectic Euler and midpoint, stepped 1/30 s per frame at
h = 1 ms, rendered offscreen (Mesa's software Vulkan on a machine without a GPU).
"""
import argparse
import statistics
import time

import taichi_sim as ts
from taichi_sim.app.energy import EnergySample
from taichi_sim.app.energy_view import EnergyView, panel_centres
from taichi_sim.app.record import CHART_AREA, LEGEND
from taichi_sim.app.session import Session
from taichi_sim.render import Renderer, open_window, parse_size

FRAME = 1 / 30


def median_ms(samples):
    return 1e3 * statistics.median(samples)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--size", default="640x360")
    parser.add_argument("--grid", type=int, default=32)
    parser.add_argument("--frames", type=int, default=60)
    args = parser.parse_args()
    size = parse_size(args.size)
    ts.init(arch="cpu", precision="f32")
    params = {"nx": args.grid, "ny": args.grid}
    integrators = ["symplectic_euler", "midpoint"]
    sampled = Session("cloth", integrators, params=params, dt=1e-3)
    plain = Session("cloth", integrators, params=params, dt=1e-3, seed=1)  # a separate set of scenes
    for r in plain.runners:
        r._sample_energy = lambda: None  # as before the plot: the guard's check, nothing kept
    window = open_window("bench", size)
    try:
        renderer = Renderer(window, sampled.visuals(), size, bottom=CHART_AREA.y1 + 0.02)
        view = EnergyView(CHART_AREA, LEGEND)
        sampled.options.strain = True
        step_on, step_off, draw_on, draw_off, layout = [], [], [], [], []

        def step(session):
            t0 = time.perf_counter()
            session.advance(FRAME)
            return time.perf_counter() - t0

        def draw(charts):
            t0 = time.perf_counter()
            renderer.render([r.display for r in sampled.runners], sampled.options,
                            overlay=view.draw if charts else None)
            renderer.read_image()
            return time.perf_counter() - t0

        for k in range(args.frames + 5):
            first = k % 2 == 0  # which side goes first alternates: no side always follows the other
            on, off = (step(sampled), step(plain)) if first else reversed((step(plain), step(sampled)))
            t0 = time.perf_counter()
            view.update(sampled.runners, panel_centres(renderer), strain_scale=0.1)
            lay = time.perf_counter() - t0
            d_on, d_off = (draw(True), draw(False)) if first else reversed((draw(False), draw(True)))
            if k >= 5:
                step_on.append(on)
                step_off.append(off)
                layout.append(lay)
                draw_on.append(d_on)
                draw_off.append(d_off)
        trace = sampled.runners[0].energy_trace
        health = sampled.runners[0].guard.health
        adds = []
        for _ in range(2000):
            t0 = time.perf_counter()
            trace.add(EnergySample.from_health(1e9, health))
            adds.append(time.perf_counter() - t0)
    finally:
        window.destroy()
    checks = sampled.runners[0].guard.checks
    print(f"cloth {args.grid}x{args.grid}, {' vs '.join(integrators)}, {args.size}, {args.frames} frames "
          f"({checks} guard checks, each a sample, in the first run)")
    print(f"keep one sample              {1e6 * statistics.median(adds):7.2f} us")
    print(f"step a frame   with samples {median_ms(step_on):7.2f} ms   without {median_ms(step_off):7.2f} ms")
    print(f"lay out charts              {median_ms(layout):7.2f} ms")
    print(f"draw + read    with charts  {median_ms(draw_on):7.2f} ms   without {median_ms(draw_off):7.2f} ms")


if __name__ == "__main__":
    main()
