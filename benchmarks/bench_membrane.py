"""The cloth as a material, measured (docs/materials.md): a 1 m^2 sheet hangs from one edge and
comes to rest under its own weight, as a membrane and as the spring net, at several resolutions;
prints how far its lowest point hangs below the pinned edge and how long each run took.

    .venv/bin/python benchmarks/bench_membrane.py [--sizes 16 32 64] [--materials stvk neohookean springs]
"""
import argparse
import time

import numpy as np

import taichi_sim as ts

SHEET = {"pin": "edge", "density": 1.0, "area_drag": 2.0, "stretch_modulus": 100.0, "poisson_ratio": 0.3,
         "bending_stiffness": 1e-4, "membrane_damping": 0.02}


def hang(material: str, n: int) -> tuple[float, float, float]:
    """(sag (m), largest speed left (m/s), wall time (s)) of the sheet after 4 s of implicit
    Euler at 0.05 s."""
    scene = ts.build_scene("cloth", {"nx": n, "ny": n, "material": material, **SHEET})
    start = time.perf_counter()
    result = ts.run(scene, "implicit_euler", dt=0.05, t_end=4.0, energy_every=0)
    wall = time.perf_counter() - start
    if result.status.value != "ok":
        raise SystemExit(f"{material} {n}: {result.status.value}")
    x, v = scene.state.to_numpy()
    return 1.0 - float(x[:, 1].min()), float(np.abs(v).max()), wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[16, 32, 64])
    parser.add_argument("--materials", nargs="+", default=["stvk", "neohookean", "springs"])
    args = parser.parse_args()
    ts.init(arch="cpu", precision="f64")
    print("| material | n x n | sag (m) | stretch: sag - 1 m (mm) | largest speed left (m/s) | wall (s) |")
    print("|---|---|---|---|---|---|")
    for material in args.materials:
        for n in args.sizes:
            sag, speed, wall = hang(material, n)
            print(f"| {material} | {n} | {sag:.5f} | {1000 * (sag - 1):.2f} | {speed:.3f} | {wall:.1f} |", flush=True)


if __name__ == "__main__":
    main()
