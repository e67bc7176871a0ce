"""Benchmark: what the cloth's self-contact stage costs, per phase, against the step it follows.

Each size's `cloth-fold` is run with symplectic Euler (dt = 1e-3 s) and the stage on up to
``--t`` seconds, so the cloth lies crumpled on the ground with many contacts; then, on that
state, each phase is timed alone ``--rounds`` times (after one warm-up call) and reported as a
median: building the triangle and edge hashes (broad phase), collecting candidate pairs, one
round of contact resolution, and the whole stage (what `after_step` pays, with its rounds); the
step it follows (symplectic Euler) is timed the same way.

Run from the repository root (outside pytest):

    .venv/bin/python benchmarks/bench_self_collision.py [--sizes 32,64] [--t 0.5] [--rounds 11]
"""
import argparse
import statistics
import time

import taichi as ti

import taichi_sim as ts
from taichi_sim.collide import SelfCollision


def median_ms(call, rounds: int) -> float:
    call()
    ti.sync()
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        call()
        ti.sync()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="32,64", help="grid sides, comma-separated")
    parser.add_argument("--t", type=float, default=0.5, help="seconds of folding before timing")
    parser.add_argument("--rounds", type=int, default=11)
    args = parser.parse_args()
    ts.init(arch="cpu", precision="f32")
    print("size  particles  pairs(v-t, e-e)  hashes  collect  round  stage(rounds)  step   stage/step")
    for n in (int(s) for s in args.sizes.split(",")):
        scene = ts.build_scene("cloth-fold", {"nx": n, "ny": n})
        (stage,) = [e for e in scene.post_step if isinstance(e, SelfCollision)]
        integrator = ts.create_integrator("symplectic_euler", scene.system)
        ts.run(scene, integrator, dt=1e-3, t_end=args.t)
        y = scene.state

        def hashes():
            stage._mark_intact()
            stage.triangle_grid.build(stage.x_start, y.x, scene.mesh.triangles, stage.triangle_alive)
            stage.edge_grid.build(stage.x_start, y.x, stage.edges, stage.edge_alive)

        hashes()
        build = median_ms(hashes, args.rounds)
        collect = median_ms(lambda: stage._collect(y), args.rounds)
        pairs = stage.pair_count.to_numpy()
        resolve = median_ms(lambda: stage._resolve(y), args.rounds)
        saved = y.to_numpy()

        def whole():
            y.from_numpy(*saved)
            stage.t_end = None  # the start estimated from x - h v: one more small kernel
            stage(y, args.t, 1e-3)

        whole_ms = median_ms(whole, args.rounds)
        step = median_ms(lambda: integrator.step(y, args.t, 1e-3), args.rounds)
        print(f"{n:4d}  {n * n:9d}  {pairs[0]:7d} {pairs[1]:7d}  {build:6.2f}  {collect:7.2f}  {resolve:5.2f}  "
              f"{whole_ms:8.2f} ({stage.iterations})  {step:5.2f}  {whole_ms / step:8.0f}x")


if __name__ == "__main__":
    main()
