"""Do the warnings mean "off"? A matrix of stiff cases x fast methods, each run as a user runs it
(defaults, the default tolerance of 1 mm, work raised where the method may), checked against
the truth at every sampled step: the distance of the step's positions from its equation's
converged solution from the same start (Newton to 1e-8 m, f64 numpy).

A miss: some sampled step is truly farther than the tolerance, and the run did not warn.
A false alarm: the run warned, and no sampled step was truly farther than the tolerance.
The estimate is held to a factor of 3 of the truth, so the table also counts the clear cases:
a clear miss is truly farther than three times the tolerance, unwarned; a clear false alarm
warned with every sampled step truly within a third of it. A run whose steps' truth could not
be computed (the reference Newton did not converge) is "unknown"; one that stopped with a
status (diverged) said so and is right.

    .venv/bin/python benchmarks/bench_warning_matrix.py [--sizes 16 32] [--steps 30]
    .venv/bin/python benchmarks/bench_warning_matrix.py --sizes 32 --stiffnesses 1e6 1e8 --methods xpbd vbd --no-pendulum

(``--stiffnesses``, ``--methods`` and ``--no-pendulum`` pick a part of the matrix: at 32 x 32 the
truth of a sample can take thousands of Newton steps, ``--truth-iterations`` of them at most.)
"""
import argparse
import time

import numpy as np

import taichi_sim as ts
from taichi_sim.bench.stiffcloth import cloth_params
from taichi_sim.stepper import Stepper

METHODS = ("projective_dynamics", "xpbd", "vbd", "implicit_euler_linearised")
H = 1 / 60


class Truth:
    """After each sampled step, the true distance of that step from its converged solution."""

    def __init__(self, max_iterations: int = 3000):
        self.truths = []
        self.seen = 0
        self.max_iterations = max_iterations

    def after_step(self, stepper, report):
        monitor = stepper.monitor
        if len(monitor.distances) == self.seen and not (monitor.times and monitor.times[-1] == stepper.t):
            return
        self.seen = len(monitor.distances)
        integrator = stepper.integrator
        h = integrator.solved_h if getattr(integrator, "tracks_solved_start", False) else report.h
        x0, v0 = (a.astype(float) for a in monitor._start.to_numpy())
        x1 = stepper.scene.state.to_numpy()[0].astype(float)
        try:
            x_star, _ = monitor.distance_model.solve_step(x0, v0, h, guess=x1, tolerance=1e-8,
                                                               max_iterations=self.max_iterations)
        except RuntimeError:
            return
        self.truths.append(float(np.max(np.linalg.norm(x1 - x_star, axis=1))))


def run_case(scene_name, params, method, steps, truth_iterations=3000):
    ts.init(arch="cpu", precision="f32")
    scene = ts.build_scene(scene_name, params)
    truth = Truth(truth_iterations)
    stepper = Stepper(scene, ts.create_integrator(method, scene.system), H, observers=[truth])
    for s in range(steps):
        stepper.step(check=s == steps - 1)
        if stepper.failure is not None:
            return stepper.failure.status.value, truth, stepper
    return "ok", truth, stepper


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[16, 32])
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--stiffnesses", type=float, nargs="+", default=[1e4, 1e6, 1e8])
    parser.add_argument("--methods", nargs="+", default=list(METHODS))
    parser.add_argument("--no-pendulum", action="store_true")
    parser.add_argument("--truth-iterations", type=int, default=3000)
    args = parser.parse_args()
    cases = [("cloth", cloth_params(size, k), f"{size}x{size} cloth, k={k:g}")
             for size in args.sizes for k in args.stiffnesses]
    if not args.no_pendulum:
        cases.append(("pendulum", {"particle_count": 10, "stiffness": 1e8}, "10-particle pendulum, k=1e8"))
    print("| case | method | status | warned | worst estimate (m) | worst true (m) | verdict | s |")
    print("|---|---|---|---|---|---|---|---|")
    misses = alarms = clear = 0
    for scene_name, params, label in cases:
        for method in args.methods:
            start = time.perf_counter()
            status, truth, stepper = run_case(scene_name, params, method, args.steps, args.truth_iterations)
            tol = stepper.monitor.tolerance
            warned = bool(stepper.warnings)
            worst_true = max(truth.truths, default=float("nan"))
            off = worst_true > tol
            if status != "ok":
                verdict = "right"  # stopped with its status (diverged): not a silent answer
            elif not truth.truths:
                verdict = "unknown"
            elif off and not warned and status == "ok":
                verdict = "clear miss" if worst_true > 3 * tol else "miss"
            elif warned and not off:
                verdict = "clear false alarm" if worst_true < tol / 3 else "false alarm"
            else:
                verdict = "right"
            misses += verdict.endswith("miss")
            alarms += verdict.endswith("false alarm")
            clear += verdict.startswith("clear")
            print(f"| {label} | {method} | {status} | {'yes' if warned else 'no'} | "
                  f"{stepper.monitor.worst_distance:.3g} | {worst_true:.3g} | {verdict} | "
                  f"{time.perf_counter() - start:.0f} |", flush=True)
    print(f"\n{misses} misses, {alarms} false alarms ({clear} of them clear)")


if __name__ == "__main__":
    main()
