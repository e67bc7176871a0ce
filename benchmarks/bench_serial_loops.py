"""Benchmark: a system's hot loops on one thread against Taichi's parallel loops, the data behind
``taichi_sim.runtime.SERIAL_WORK`` (and XPBD's ``SERIAL_SPRINGS``).

Run from the repository root (outside pytest):

    .venv/bin/python benchmarks/bench_serial_loops.py [--sizes 32,64,128,256] [--precision f32]
        [--integrators symplectic_euler,xpbd] [--rounds 7] [--threads N] [--pass]

For every size and integrator, two cloths are built, one whose loops are forced serial and one
forced parallel (the break-even is patched for each build, nothing else differs; a grid's
spring pass is as the default puts it in both, see ``GridSprings.serial_pass``; with
``--pass`` the grid's spring pass is forced serial or parallel instead), warmed up,
then timed in alternating rounds of raw ``integrator.step`` calls (``ti.sync`` around each
round): the medians over rounds, per step, and serial / parallel. Symplectic Euler steps at
1e-5 s, XPBD at 1/60 s with its default 20 substeps. The 1-minute load average is printed
first: other processes on the machine slow every figure.
"""
import argparse
import os
import statistics
import time

import taichi as ti

import taichi_sim as ts
from taichi_sim import runtime
from taichi_sim.forces.springs import grid
from taichi_sim.integrators.positional import xpbd
from taichi_sim.scene.cloth import fixed_particle_cloth

STEP = {"symplectic_euler": 1e-5, "xpbd": 1 / 60}


def build(n: int, name: str, serial: bool, grid_pass: bool = False):
    """A cloth and its integrator with every hot loop serial or every one parallel; with
    ``grid_pass``, the grid's spring pass serial or parallel instead (the system's loops as
    the default break-even puts them)."""
    saved = runtime.SERIAL_WORK, xpbd.SERIAL_SPRINGS, grid.SERIAL_PASS_F32_POINTS, grid.SERIAL_PASS_F64_POINTS
    if grid_pass:
        grid.SERIAL_PASS_F32_POINTS = grid.SERIAL_PASS_F64_POINTS = 10 ** 12 if serial else 0
    else:
        runtime.SERIAL_WORK = xpbd.SERIAL_SPRINGS = 10 ** 12 if serial else 0
    try:
        scene = ts.build_scene("cloth", {"nx": n, "ny": n, **fixed_particle_cloth(n, n)})
        integrator = ts.create_integrator(name, scene.system)
    finally:
        runtime.SERIAL_WORK, xpbd.SERIAL_SPRINGS, grid.SERIAL_PASS_F32_POINTS, grid.SERIAL_PASS_F64_POINTS = saved
    return scene, integrator


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="32,64,128,256")
    parser.add_argument("--precision", default="f32", choices=("f32", "f64"))
    parser.add_argument("--integrators", default="symplectic_euler,xpbd")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--pass", dest="grid_pass", action="store_true",
                        help="compare the grid's spring pass serial and parallel instead")
    args = parser.parse_args()
    ts.init(arch="cpu", precision=args.precision, cpu_max_num_threads=args.threads)
    print(f"load average (1 min): {os.getloadavg()[0]:.2f}; {args.precision}; "
          f"{runtime._current['threads']} threads")
    print(f"{'size':>5} {'integrator':<18} {'items':>8} {'serial us/step':>15} {'parallel us/step':>17} "
          f"{'serial/parallel':>16} {'chosen':>8}", flush=True)
    for n in (int(s) for s in args.sizes.split(",")):
        for name in args.integrators.split(","):
            h = STEP[name]
            pair = {serial: build(n, name, serial, args.grid_pass) for serial in (True, False)}
            for scene, integrator in pair.values():
                for _ in range(3):
                    integrator.step(scene.state, 0.0, h)
            ti.sync()
            # about 0.2 s of stepping per round
            start = time.perf_counter()
            pair[False][1].step(pair[False][0].state, 0.0, h)
            ti.sync()
            reps = max(3, int(0.2 / max(time.perf_counter() - start, 1e-6)))
            times = {True: [], False: []}
            for _ in range(args.rounds):
                for serial, (scene, integrator) in pair.items():
                    ti.sync()
                    start = time.perf_counter()
                    for _ in range(reps):
                        integrator.step(scene.state, 0.0, h)
                    ti.sync()
                    times[serial].append((time.perf_counter() - start) / reps * 1e6)
            system = pair[True][0].system
            # the items the choice counts: a grid's springs, summed serially anyway, do not
            items = system.particle_count + sum(getattr(t, "spring_count", 0) for t in system.terms
                                                if not getattr(t, "serial_pass", False))
            serial_t, parallel_t = statistics.median(times[True]), statistics.median(times[False])
            # what the default break-even picks for this cloth
            picks_serial = (runtime.serial_loops(items) if name != "xpbd" else
                            runtime.serial_loops(items, xpbd.SERIAL_SPRINGS))
            if args.grid_pass:  # what GridSprings picks for this grid
                limit = grid.SERIAL_PASS_F32_POINTS if args.precision == "f32" else grid.SERIAL_PASS_F64_POINTS
                picks_serial = n * n < limit
            chosen = "serial" if picks_serial else "parallel"
            print(f"{n:>5} {name:<18} {items:>8} {serial_t:>15.0f} {parallel_t:>17.0f} "
                  f"{serial_t / parallel_t:>16.2f} {chosen:>8}", flush=True)


if __name__ == "__main__":
    main()
