"""The membrane's bending models measured (docs/materials.md, "Bending"): ``isometric``,
``dihedral`` and ``shape_operator`` side by side.

``--study strip``: the free cantilever strip (0.2 x 0.05 m, D = 0.1 N m, 0.2 kg/m^2, clamped by
two rows of vertices) under its own weight, its tip over Euler-Bernoulli's q L^4 / (8 D b) with
EI = D b: the small-deflection solve of the rest Hessian at each ``--spacings`` (the hinge
models; the isometric one's equals the dihedral's to 1e-8) and, at the first two spacings, a
simulation to rest (a ``mesh`` cloth, StVK with E t = 1e4 N/m, implicit Euler at 10 s steps).
``--study cylinder``: a flat 1 m^2 grid rolled onto a cylinder of radius 0.25 m, its axis at
0, 30 and 45 degrees to the grid's, each model's energy over the plate's (D/2) kappa^2 A.
``--study steps``: the ``cloth-membrane`` preset at ``--size`` per model and method, the
median of 20 steps of 1/60 s after a first (compiling, or loading Taichi's cache).

    .venv/bin/python benchmarks/bench_bending.py --study strip
    .venv/bin/python benchmarks/bench_bending.py --study cylinder
    .venv/bin/python benchmarks/bench_bending.py --study steps --size 32
"""
import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.sparse.linalg import spsolve

import taichi_sim as ts
from taichi_sim.forces.membrane import HingeBending, IsometricBending, lumped_masses, rest_frames
from taichi_sim.forces.membrane.hinge_term import hinge_elements
from taichi_sim.forces.membrane.hinges import normal_stiffness
from taichi_sim.scene import cloth as topo
from taichi_sim.scene.garment import write_obj
from taichi_sim.scene.mesh_import import ClothMesh
from taichi_sim.systems.particles import ParticleSystem

MODELS = ("isometric", "dihedral", "shape_operator")
LENGTH, WIDTH, STIFFNESS, DENSITY, G = 0.2, 0.05, 0.1, 0.2, 9.81


def strip(h: float):
    """The strip at spacing h: (positions (n, 3) m, triangles, clamped (n,)), as the tests'."""
    nx, ny = int(round(LENGTH / h)) + 2, int(round(WIDTH / h)) + 1
    x = topo.grid_positions(nx, ny, (nx - 1) * h, WIDTH, origin=(-h, 0.0, 0.0), u_axis=(1, 0, 0), v_axis=(0, 0, 1))
    return x, topo.grid_triangles(nx, ny), x[:, 0] < 1e-12


def beam(h: float) -> float:
    return DENSITY * G * (LENGTH + h / 2) ** 4 / (8 * STIFFNESS)


def linear_tip(model: str, h: float) -> float:
    x, triangles, clamped = strip(h)
    mass = lumped_masses(len(x), triangles, rest_frames(x, triangles)[1], DENSITY)
    matrix = normal_stiffness(x, hinge_elements(triangles, x, STIFFNESS, model))[~clamped][:, ~clamped]
    w = spsolve(matrix.tocsc(), (mass * G)[~clamped])
    full = np.zeros(len(x))
    full[~clamped] = w
    return float(full[np.isclose(x[:, 0], x[:, 0].max())].mean()) / beam(h)


def simulated_tip(model: str, h: float, folder: Path) -> tuple[float, float, float]:
    """(tip / beam, largest speed left (m/s), wall (s)) of the strip simulated to rest."""
    x, triangles, clamped = strip(h)
    path = folder / f"strip_{h}.obj"
    write_obj(ClothMesh(x + [0.0, 0.5, 0.0], triangles, {}, "strip"), path)
    scene = ts.build_scene("mesh", {"file": str(path), "pin": f"box:-1,0,-1,{h / 2},1,1", "material": "stvk",
                                    "stretch_modulus": 1e4, "bending_stiffness": STIFFNESS, "density": DENSITY,
                                    "membrane_damping": 0.0, "drag": 0.0, "bending_model": model})
    start = time.perf_counter()
    result = ts.run(scene, ts.create_integrator("implicit_euler", scene.system, linear_solver="direct"), dt=10.0,
                    steps=4, energy_every=0)
    wall = time.perf_counter() - start
    if result.status.value != "ok":
        raise SystemExit(f"{model} {h}: {result.status.value}")
    xs, v = scene.state.to_numpy()
    tip = 0.5 - xs[np.isclose(x[:, 0], x[:, 0].max()), 1].mean()
    return float(tip) / beam(h), float(np.abs(v).max()), wall


def study_strip(spacings) -> None:
    print("| model | spacing (m) | tip / beam, linear solve | tip / beam, simulated | speed left (m/s) | wall (s) |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for model in ("dihedral", "shape_operator", "isometric"):
            for k, h in enumerate(spacings):
                linear = f"{linear_tip(model, h):.4f}" if model != "isometric" else "(= dihedral)"
                simulated = speed = wall = ""
                if k < 2:
                    ratio, left, seconds = simulated_tip(model, h, Path(folder))
                    simulated, speed, wall = f"{ratio:.4f}", f"{left:.1e}", f"{seconds:.1f}"
                print(f"| {model} | {h} | {linear} | {simulated} | {speed} | {wall} |", flush=True)


def study_cylinder(sizes) -> None:
    radius, stiffness = 0.25, 1.0
    print("| model | n x n | axis 0 deg | 30 deg | 45 deg |")
    print("|---|---|---|---|---|")
    for n in sizes:
        x = topo.grid_positions(n, n, 1.0, 1.0, origin=(-0.5, 0.0, -0.5), u_axis=(1, 0, 0), v_axis=(0, 0, 1))
        triangles = topo.grid_triangles(n, n)
        plate = 0.5 * stiffness / radius ** 2
        for model in MODELS:
            term = IsometricBending(len(x), triangles, x, stiffness) if model == "isometric" \
                else HingeBending(len(x), triangles, x, stiffness, model)
            system = ParticleSystem(np.ones(len(x)), np.zeros(len(x), bool), [term])
            state = system.make_state()
            ratios = []
            for degrees in (0, 30, 45):
                a = np.radians(degrees)
                s = x[:, 0] * np.cos(a) + x[:, 2] * np.sin(a)
                t = -x[:, 0] * np.sin(a) + x[:, 2] * np.cos(a)
                rolled = np.stack([radius * np.sin(s / radius), radius * (1 - np.cos(s / radius)), t], axis=1)
                state.from_numpy(rolled, np.zeros_like(x))
                ratios.append(system.potential_energy(state) / plate)
            print(f"| {model} | {n} | " + " | ".join(f"{r:.4f}" for r in ratios) + " |", flush=True)


def study_steps(size: int) -> None:
    print("| model | method | first step (s) | median step (ms) |")
    print("|---|---|---|---|")
    for method in ("implicit_euler", "vbd"):
        for model in MODELS:
            scene = ts.build_scene("cloth-membrane", {"nx": size, "ny": size, "bending_model": model})
            stepper = ts.Stepper(scene, ts.create_integrator(method, scene.system), 1 / 60)
            start = time.perf_counter()
            stepper.step()
            first = time.perf_counter() - start
            walls = []
            for _ in range(20):
                start = time.perf_counter()
                stepper.step()
                walls.append(time.perf_counter() - start)
                if stepper.failure is not None:
                    raise SystemExit(f"{model} {method}: {stepper.failure.message}")
            print(f"| {model} | {method} | {first:.1f} | {1e3 * np.median(walls):.1f} |", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", choices=("strip", "cylinder", "steps"), default="strip")
    parser.add_argument("--spacings", type=float, nargs="+", default=[0.01, 0.005, 0.0025, 0.00125])
    parser.add_argument("--sizes", type=int, nargs="+", default=[16, 32, 64])
    parser.add_argument("--size", type=int, default=32)
    args = parser.parse_args(argv)
    ts.init(arch="cpu", precision="f64")
    {"strip": lambda: study_strip(args.spacings), "cylinder": lambda: study_cylinder(args.sizes),
     "steps": lambda: study_steps(args.size)}[args.study]()
    return 0


if __name__ == "__main__":
    sys.exit(main())
