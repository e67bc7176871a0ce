"""vbd with the cloth's triangles against the objects in its solve (option ``object_faces``, the
default) and without (vertices only), in one process, in turn: steps/s where the cloth lies on
the object, and what `taichi-sim check` says of every frame.

    python benchmarks/bench_vbd_faces.py --n 32 --t-end 3
    python benchmarks/bench_vbd_faces.py --n 32 --t-end 2.5 --set height=2.6
    python benchmarks/bench_vbd_faces.py --n 32 --t-end 2 --no-box --set height=1.4 --set capsule=1 \
        --set capsule_radius=0.01 --set capsule_y=0.3

The default scene is `cloth-fold` dropped from 1.4 m onto a box 0.6 x 0.3 x 0.6 m standing on
the ground (``--set height=1.4 --set box=1 --set box_y=0.15 --set box_half_x=0.3 --set box_half_y=0.15 --set
box_half_z=0.3``), at h = 1/60 s in f32 with the guard on. steps/s is the median over
``--repeats`` runs of each side of the steps from ``--from`` s on (the cloth on the box; the
first steps compile). The check is frame_check.check_run on every step's positions. Timings
depend on the machine's load.
"""
import argparse
import statistics
import time

import numpy as np
import taichi as ti

import taichi_sim as ts
from taichi_sim.frame_check import check_run

BOX = {"height": 1.4, "box": True, "box_y": 0.15, "box_half_x": 0.3, "box_half_y": 0.15, "box_half_z": 0.3}


def run(scene_name: str, params: dict, object_faces: bool, t_end: float, start: float) -> tuple[float, list[str]]:
    """(steps/s from ``start`` s on, check's report lines) of one run."""
    scene = ts.build_scene(scene_name, params)
    method = ts.create_integrator("vbd", scene.system, object_faces=object_faces)
    stepper = ts.Stepper(scene, method, 1 / 60)
    frames, times, walls = [scene.state.to_numpy()[0]], [0.0], []
    steps = round(t_end * 60)
    for k in range(steps):
        begin = time.perf_counter()
        stepper.step()
        ti.sync()  # a GPU step's kernels end here, not at the launch
        if k / 60 >= start:
            walls.append(time.perf_counter() - begin)
        frames.append(scene.state.to_numpy()[0])
        times.append((k + 1) / 60)
    arrays = {"scene": scene_name, "triangles": scene.mesh.triangles_np, "x": frames[-1],
              "x_history": np.asarray(frames), "t_history": np.asarray(times), **scene.arrays}
    history = {f"{key}_center_history": np.asarray([scene.object_centers(t)[f"{key}_center"] for t in times])
               for key in ("sphere", "capsule", "box") if f"{key}_center" in scene.arrays}
    arrays.update(history)
    lines, _ = check_run(arrays)
    return len(walls) / sum(walls), lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="cloth-fold")
    parser.add_argument("--n", type=int, default=32)
    parser.add_argument("--t-end", type=float, default=3.0)
    parser.add_argument("--from", dest="start", type=float, default=0.33, help="s: time the steps from here on")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--no-box", action="store_true", help="the scene as it is, without the box")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    parser.add_argument("--arch", choices=("cpu", "gpu"), default="cpu")
    args = parser.parse_args()
    params = {"nx": args.n, "ny": args.n, **({} if args.no_box else BOX)}
    for item in args.set:
        name, _, value = item.partition("=")
        params[name] = value  # text, parsed as `simulate --set` parses it
    ts.init(arch=args.arch, precision="f32")
    rates: dict[bool, list[float]] = {True: [], False: []}
    reports = {}
    for _ in range(args.repeats):
        for faces in (True, False):
            rate, reports[faces] = run(args.scene, params, faces, args.t_end, args.start)
            rates[faces].append(rate)
    print(f"{args.scene} {args.n} x {args.n}, {args.t_end} s, {params}, {ts.runtime.backend()}")
    for faces in (True, False):
        label = "object_faces=1 (default)" if faces else "object_faces=0 (vertices only)"
        print(f"  {label}: {statistics.median(rates[faces]):.2f} steps/s from {args.start} s "
              f"(runs: {', '.join(f'{r:.2f}' for r in rates[faces])})")
        for line in reports[faces]:
            print(f"    {line}")


if __name__ == "__main__":
    main()
