"""Probe: Newton iterations of exact backward Euler on a stiff cloth, per step, with the default
inexact linear solves (forcing terms) against exact ones, and with other forcing ceilings.

    .venv/bin/python benchmarks/probe_newton_iterations.py [--size 24] [--steps 12] [--stiffness 1e8]
        [--ceilings 0.1,0.01,0.001]

Scene: ``cloth``, nx = ny = ``--size``, ``stiffness`` (structural), f64, dt = 1/60 s, from rest.
First, per step: Newton iterations, line-search evaluations, solved pieces, CG iterations and
the iterations Newton went on only for the energy test (the residual test was met, the
iterate's energy above the step's start energy),
with the default options and with ``cg_tolerance = 1e-10`` (every solve exact); then, per
forcing ceiling (``common.FORCING_CEILING``), the means per step and the wall time.
"""
import argparse
import time

import taichi_sim as ts
from taichi_sim.integrators.implicit import common
from taichi_sim.scene.cloth import fixed_particle_cloth

DT = 1 / 60


def run(scene, steps: int, per_step: bool, label: str, **options):
    scene.reset()
    integrator = ts.create_integrator("implicit_euler", scene.system, **options)
    s = integrator.stats
    stage = integrator._stage
    energy_ok = type(stage).energy_ok
    held = [0]

    def counted(self) -> bool:  # called only once the residual test has passed
        ok = energy_ok(self)
        held[0] += not ok
        return ok

    stage.energy_ok = counted.__get__(stage)
    t, start = 0.0, time.perf_counter()
    last = (0, 0, 0, 0)
    for index in range(steps):
        report = integrator.step(scene.state, t, DT)
        t += DT
        if report.status is not ts.Status.OK:
            raise RuntimeError(f"{label}: {report.status.value} at step {index}: {report.message}")
        now = (s.newton_iterations, s.line_search_evaluations, s.substeps, s.iterations)
        if per_step:
            print(f"  {label} step {index}: Newton {now[0] - last[0]}, line search {now[1] - last[1]}, "
                  f"pieces {now[2] - last[2]}, CG {now[3] - last[3]}, held by the energy test {held[0]}")
        held[0] = 0
        last = now
    del stage.energy_ok
    return last, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--size", type=int, default=24)
    parser.add_argument("--steps", type=int, default=12)
    parser.add_argument("--stiffness", type=float, default=1e8)
    parser.add_argument("--ceilings", default="0.1,0.01,0.001")
    args = parser.parse_args()
    ts.init(arch="cpu", precision="f64")
    scene = ts.build_scene("cloth", {"nx": args.size, "ny": args.size, "stiffness": args.stiffness,
                                      **fixed_particle_cloth(args.size, args.size)})
    for label, options in (("forcing", {}), ("exact", {"cg_tolerance": 1e-10, "cg_max_iterations": 20000})):
        _, wall = run(scene, args.steps, True, label, **options)
        print(f"  {label}: {wall:.1f} s")
    default = common.FORCING_CEILING
    for ceiling in (float(c) for c in args.ceilings.split(",")):
        common.FORCING_CEILING = ceiling
        (newton, search, pieces, cg), wall = run(scene, args.steps, False, f"ceiling {ceiling:g}")
        n = args.steps
        print(f"ceiling {ceiling:g}: Newton {newton / n:.1f}/step, pieces {pieces / n:.2f}, CG {cg / n:.0f}/step, "
              f"line search {search / n:.1f}, wall {wall:.1f} s")
    common.FORCING_CEILING = default


if __name__ == "__main__":
    main()
