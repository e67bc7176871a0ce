"""The cloth as a material, measured (docs/materials.md): a 1 m^2 sheet hangs from one edge and
comes to rest under its own weight, as a membrane and as the spring net, at several resolutions;
prints how far its lowest point hangs below the pinned edge and how long each run took. With
``--study sheet``: the same sheet as a ``mesh`` cloth, its triangles along its sides (the grid's)
and turned 45 degrees to them (:func:`~taichi_sim.scene.mesh_cloth.square_sheet`), both meshes
with the same spring rules (a stretch spring per edge, a flex spring across each interior edge)
or the same membrane: the stretch of each, their difference (the anisotropy) and the median
implicit Euler step. With
``--study cylinder``: the energy stored by rolling the 1 m^2 grid onto a cylinder (radius
0.25 m) about a grid axis, by the membrane's bending (D = 1 N m) and by the spring net's
default springs, against the plate's (D/2) kappa^2 A (numpy, no simulation).

    .venv/bin/python benchmarks/bench_membrane.py [--sizes 16 32 64] [--materials stvk neohookean springs]
    .venv/bin/python benchmarks/bench_membrane.py --study cylinder
    .venv/bin/python benchmarks/bench_membrane.py --study sheet --sizes 16 32 64 128
    .venv/bin/python benchmarks/bench_membrane.py --study steps --sizes 32

``--study steps``: the ``cloth-membrane`` preset per material and method, its first step
(compiling, or loading from Taichi's cache) and the median of the next 20 (implicit, 1/60 s)
or 200 (explicit, at the scene's explicit step) steps.
"""
import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

import taichi_sim as ts
from taichi_sim.forces.membrane import bending_stencils
from taichi_sim.scene import cloth as topo
from taichi_sim.scene.garment import write_obj
from taichi_sim.scene.mesh_cloth import square_sheet

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


def hang_sheet(material: str, n: int, turned: bool, folder: Path) -> tuple[float, float, float, int]:
    """The sheet of :func:`hang` as a ``mesh`` cloth of n x n vertices' spacing, aligned or
    ``turned``, to rest (implicit Euler, 0.05 s for 4 s): (sag (m), largest speed left (m/s),
    median step (s), vertices). The springs: 500 N/m along every edge, 20 N/m across each
    interior edge (the mesh scene's defaults); the drag per vertex is the grid's 2 N s/m per
    m^2 shared out."""
    mesh = square_sheet(n, turned=turned)
    path = folder / f"sheet_{n}_{int(turned)}.obj"
    write_obj(mesh, path)
    params = {key: SHEET[key] for key in ("density", "stretch_modulus", "poisson_ratio", "bending_stiffness",
                                           "membrane_damping")}
    scene = ts.build_scene("mesh", {"file": str(path), "pin": "top:1e-3", "material": material,
                                    "drag": SHEET["area_drag"] / mesh.vertex_count, **params})
    stepper = ts.Stepper(scene, ts.create_integrator("implicit_euler", scene.system), 0.05)
    walls = []
    for _ in range(80):
        start = time.perf_counter()
        stepper.step()
        walls.append(time.perf_counter() - start)
        if stepper.failure is not None:
            raise SystemExit(f"{material} {n} turned={turned}: {stepper.failure.message}")
    x, v = scene.state.to_numpy()
    return 1.0 - float(x[:, 1].min()), float(np.abs(v).max()), float(np.median(walls[1:])), mesh.vertex_count


def cylinder(n: int, radius: float = 0.25, stiffness: float = 1.0) -> tuple[float, float]:
    """(bending energy / (D/2) kappa^2 A, the default spring net's energy (J)) of the 1 m^2 n x n
    grid rolled isometrically onto a cylinder of ``radius`` (m) about the grid's z axis."""
    x = topo.grid_positions(n, n, 1.0, 1.0, origin=(-0.5, 0.0, -0.5), u_axis=(1, 0, 0), v_axis=(0, 0, 1))
    rolled = np.stack([radius * np.sin(x[:, 0] / radius), radius * (1 - np.cos(x[:, 0] / radius)), x[:, 2]], axis=1)
    vertices, weights = bending_stencils(x, topo.grid_triangles(n, n))
    bending = 0.5 * stiffness * (np.einsum("bk,bkj->bj", weights, rolled[vertices]) ** 2).sum()
    ends, kind = topo.grid_springs(n, n)
    k = topo.kind_stiffness(kind, (500.0, 250.0, 100.0))
    rest = np.linalg.norm(x[ends[:, 0]] - x[ends[:, 1]], axis=1)
    length = np.linalg.norm(rolled[ends[:, 0]] - rolled[ends[:, 1]], axis=1)
    springs = 0.5 * (k * (length - rest) ** 2).sum()
    return bending / (0.5 * stiffness / radius ** 2), springs


def steps(material: str, method: str, n: int) -> tuple[float, float, float]:
    """(step (s), first step's wall time (s), median step's (s)) of ``cloth-membrane``."""
    scene = ts.build_scene("cloth-membrane", {"nx": n, "ny": n, "material": material})
    dt = 1 / 60 if method.startswith("implicit") else scene.explicit_dt
    stepper = ts.Stepper(scene, ts.create_integrator(method, scene.system), dt)
    start = time.perf_counter()
    stepper.step()
    first = time.perf_counter() - start
    walls = []
    for _ in range(20 if method.startswith("implicit") else 200):
        start = time.perf_counter()
        stepper.step()
        walls.append(time.perf_counter() - start)
        if stepper.failure is not None:
            raise SystemExit(f"{material} {method}: {stepper.failure.message}")
    return dt, first, float(np.median(walls))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[16, 32, 64])
    parser.add_argument("--materials", nargs="+", default=["stvk", "neohookean", "springs"])
    parser.add_argument("--study", choices=("hang", "sheet", "cylinder", "steps"), default="hang")
    args = parser.parse_args()
    if args.study == "cylinder":
        print("| n x n | bending / plate's (D/2) kappa^2 A | spring net's energy (J) |")
        print("|---|---|---|")
        for n in args.sizes:
            ratio, springs = cylinder(n)
            print(f"| {n} | {ratio:.4f} | {springs:.3g} |")
        return
    ts.init(arch="cpu", precision="f64")
    if args.study == "sheet":
        print("| material | n x n | vertices (aligned, turned) | stretch aligned (mm) | stretch turned (mm) | "
              "turned / aligned - 1 | largest speed left (m/s) | median step aligned, turned (ms) |")
        print("|---|---|---|---|---|---|---|---|")
        with tempfile.TemporaryDirectory() as folder:
            for material in args.materials:
                for n in args.sizes:
                    a = hang_sheet(material, n, False, Path(folder))
                    t = hang_sheet(material, n, True, Path(folder))
                    print(f"| {material} | {n} | {a[3]}, {t[3]} | {1000 * (a[0] - 1):.2f} | {1000 * (t[0] - 1):.2f} | "
                          f"{(t[0] - 1) / (a[0] - 1) - 1:+.2%} | {max(a[1], t[1]):.3f} | "
                          f"{1000 * a[2]:.1f}, {1000 * t[2]:.1f} |", flush=True)
        return
    if args.study == "steps":
        print("| material | n x n | method | step (s) | first step (s) | median step (ms) |")
        print("|---|---|---|---|---|---|")
        for material in [m for m in args.materials if m != "springs"]:
            for n in args.sizes:
                for method in ("symplectic_euler", "implicit_euler", "implicit_midpoint"):
                    dt, first, median = steps(material, method, n)
                    print(f"| {material} | {n} | {method} | {dt:.2g} | {first:.1f} | {1000 * median:.2f} |", flush=True)
        return
    print("| material | n x n | sag (m) | stretch: sag - 1 m (mm) | largest speed left (m/s) | wall (s) |")
    print("|---|---|---|---|---|---|")
    for material in args.materials:
        for n in args.sizes:
            sag, speed, wall = hang(material, n)
            print(f"| {material} | {n} | {sag:.5f} | {1000 * (sag - 1):.2f} | {speed:.3f} | {wall:.1f} |", flush=True)


if __name__ == "__main__":
    main()
