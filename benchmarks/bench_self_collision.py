"""Benchmark: what the cloth's self-contact stage costs, per phase, against the step it follows.

Each size's `cloth-fold` is run for ``--steps`` steps of ``--dt`` with ``--integrator`` and the
stage, after ``--warmup`` steps (compiling, the first fall). Every call of a phase is timed (with
a device sync on each side, so phases are not blurred into each other) and reported as its total
per step over the measured steps:

- broad: the triangle and edge hashes and the candidate pair lists (including the rebuilds the
  fail-safe asks for when its zones have moved vertices beyond the boxes' margin);
- rounds: the contact rounds (proximity and continuous detection, push apart, friction);
- fail-safe: continuous detection of touches left after the rounds, and the rigid impact zones
  (without its rebuilds, counted in broad);
- step: the integrator's step alone, timed the same way.

Run from the repository root (outside pytest):

    .venv/bin/python benchmarks/bench_self_collision.py [--sizes 32,64] [--integrator implicit_euler]
        [--dt 0.016666666666666666] [--warmup 30] [--steps 60] [--collision-iterations K]
        [--set thickness=0.005] [--passes K]
"""
import argparse
import collections
import statistics
import time

import taichi as ti

import taichi_sim as ts
from taichi_sim.collide import SelfCollision


class PhaseTimer:
    """Wraps methods so that each call's wall time (synced) adds to a named phase."""

    def __init__(self):
        self.seconds = collections.defaultdict(float)
        self.calls = collections.Counter()
        self.inside = []

    def wrap(self, obj, method: str, phase: str) -> None:
        call = getattr(obj, method)

        def timed(*args, **kwargs):
            ti.sync()
            start = time.perf_counter()
            self.inside.append(phase)
            try:
                return call(*args, **kwargs)
            finally:
                self.inside.pop()
                ti.sync()
                elapsed = time.perf_counter() - start
                self.seconds[phase] += elapsed
                self.calls[phase] += 1
                if self.inside:  # a phase called inside another: not counted twice
                    self.seconds[self.inside[-1]] -= elapsed

        setattr(obj, method, timed)

    def reset(self) -> None:
        self.seconds.clear()
        self.calls.clear()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="32,64", help="grid sides, comma-separated")
    parser.add_argument("--integrator", default="implicit_euler")
    parser.add_argument("--dt", type=float, default=1 / 60)
    parser.add_argument("--warmup", type=int, default=30, help="steps before timing")
    parser.add_argument("--steps", type=int, default=60, help="steps timed")
    parser.add_argument("--profile", action="store_true", help="also print Taichi's per-kernel times")
    parser.add_argument("--collision-iterations", type=int, default=None,
                        help="contact rounds per step (default: the scene's)")
    parser.add_argument("--passes", type=int, default=0, metavar="K",
                        help="then time K passes over the candidate pairs of the last step (a contact round, "
                             "a continuous detection), each from the state its stage started from; medians")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a scene parameter, as simulate's --set (repeatable): e.g. thickness=0.005")
    args = parser.parse_args()
    ts.init(arch="cpu", precision="f32", kernel_profiler=args.profile)
    print(f"cloth-fold, {args.integrator}, dt = {args.dt:.4g} s, f32; ms per step over {args.steps} steps "
          f"after {args.warmup}")
    print("size  pairs(v-t, e-e)  broad  rounds  fail-safe  stage   step  zone steps (rounds)  stage/step")
    for n in (int(s) for s in args.sizes.split(",")):
        params = {"nx": n, "ny": n}
        if args.collision_iterations is not None:
            params["collision_iterations"] = args.collision_iterations
        for item in args.set:
            key, _, value = item.partition("=")
            params[key] = value  # checked and converted by the scene, as simulate's --set
        scene = ts.build_scene("cloth-fold", params)
        (stage,) = [e for e in scene.post_step if isinstance(e, SelfCollision)]
        integrator = ts.create_integrator(args.integrator, scene.system)
        timer = PhaseTimer()
        timer.wrap(stage, "_broad_phase", "broad")
        timer.wrap(stage, "_resolve", "rounds")
        timer.wrap(stage, "_fail_safe", "fail-safe")
        timer.wrap(integrator, "step", "step")
        step, taken, zones_before = integrator.step, [0], [(0, 0)]

        def counted(*a, **k):  # the timing starts at the first step after the warm-up
            if taken[0] == args.warmup:
                timer.reset()
                if args.profile:
                    ti.profiler.clear_kernel_profiler_info()
                zones_before[0] = (stage.zone_steps, stage.zone_rounds)
            taken[0] += 1
            return step(*a, **k)

        integrator.step = counted
        before_collection = {}
        if args.passes:  # the state each step's stage collects its pairs from; the last is timed
            collect = stage._broad_phase

            def kept(state, only_changed=False, append=False):
                # the step's first collection only: the fail-safe's last resort collects again
                if not only_changed and before_collection.get("step") != taken[0]:
                    before_collection.update(x=state.x.to_numpy(), v=state.v.to_numpy(),
                                             x_start=stage.x_start.to_numpy(), step=taken[0])
                return collect(state, only_changed, append)

            stage._broad_phase = kept
        ts.run(scene, integrator, dt=args.dt, steps=args.warmup + args.steps)
        ms = {k: 1e3 * v / args.steps for k, v in timer.seconds.items()}
        stage_ms = ms.get("broad", 0) + ms.get("rounds", 0) + ms.get("fail-safe", 0)
        vt, ee = stage.pair_count.to_numpy()
        print(f"{n:4d}  {vt:7d} {ee:7d}  {ms.get('broad', 0):5.1f}  {ms.get('rounds', 0):6.1f}  "
              f"{ms.get('fail-safe', 0):9.1f}  {stage_ms:5.1f}  {ms['step']:5.1f}  "
              f"{stage.zone_steps - zones_before[0][0]:4d}/{args.steps:<4d} ({stage.zone_rounds - zones_before[0][1]:4d})"
              f"  {stage_ms / ms['step']:8.1f}x")
        if args.profile:
            ti.profiler.print_kernel_profiler_info()
        if args.passes:
            time_passes(scene.state, stage, before_collection, args.passes)


def time_passes(state, stage, snapshot: dict, passes: int) -> None:
    """Median times of one contact round (every pair looked at) and one continuous detection
    over the candidate pairs of the last step's stage, each pass from the state that stage
    started from (positions at the step's start and end, before any contact)."""
    x, v, x_start = snapshot["x"], snapshot["v"], snapshot["x_start"]
    rounds, detections = [], []
    for k in range(passes + 2):  # two to warm up
        state.x.from_numpy(x)
        state.v.from_numpy(v)
        stage.x_start.from_numpy(x_start)
        stage._broad_phase(state)
        ti.sync()
        start = time.perf_counter()
        stage._resolve(state, 1, stage.vt_pairs, stage.ee_pairs)
        ti.sync()
        middle = time.perf_counter()
        stage._detect(state, stage.vt_pairs, stage.ee_pairs, stage.collided)
        ti.sync()
        if k >= 2:
            rounds.append(middle - start)
            detections.append(time.perf_counter() - middle)
    vt, ee = stage.pair_count.to_numpy()
    print(f"      passes over the last step's {vt} v-t and {ee} e-e pairs: contact round "
          f"{1e3 * statistics.median(rounds):.1f} ms, continuous detection {1e3 * statistics.median(detections):.1f} ms "
          f"(medians of {passes})")


if __name__ == "__main__":
    main()
