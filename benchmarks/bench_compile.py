"""Benchmark: what compiling without Taichi's CFG pass saves where the toolkit does it, and what
it costs at run time (``runtime.without_cfg_optimisation``; docs/design.md, "Compile time").

Each case runs in a fresh process, in each of ``--kinds``, alternating for ``--repeats`` rounds:
"full" keeps the pass on everywhere, "lean" is the code as shipped, "off" turns it off
everywhere (``TI_CFG_OPTIMIZATION=0``). Reported: the first step (nearly all of it compiling)
and the median step after a warm-up, medians over the rounds; with two kinds, also the median,
lowest and highest of the rounds' step-time ratios (second kind over first, each round's pair
run back to back). Every process starts with an empty kernel cache, unless ``--warm``: then
each (case, kind) keeps its cache from round to round, so the first round's first step is the
compile and the later rounds cost little more than their steps.

``--cases methods`` is one case per registered method on a grid cloth (``method:NAME``), sized
by the method's own facts: an implicit one on 32 x 32 at 1/60 s, another that no step makes
blow up (the positional ones) on a stiff 64 x 64 cloth at 1/60 s, the rest on 64 x 64 at 1e-4 s.

    .venv/bin/python benchmarks/bench_compile.py [--repeats 2] [--cases self-contact,faces]
        [--kinds full,lean]
    .venv/bin/python benchmarks/bench_compile.py --cases rk4,implicit --kinds full,off
    .venv/bin/python benchmarks/bench_compile.py --cases methods --kinds lean,off --repeats 5 --warm
"""
import argparse
import contextlib
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time

CASES = ("self-contact", "faces", "rk4", "implicit")
KINDS = ("full", "lean", "off")


def method_cases() -> list[str]:
    from taichi_sim.integrators import INTEGRATORS

    return [f"method:{name}" for name in INTEGRATORS]


def build(case: str):
    import taichi_sim as ts
    from taichi_sim.integrators import integrator_class

    if case.startswith("method:"):  # 0 steps: as many as fill a timed batch
        method = case.split(":", 1)[1]
        facts = integrator_class(method)
        if facts.implicit:
            return ts.build_scene("cloth", {"nx": 32, "ny": 32}), method, 1 / 60, 5, 0
        if facts.stability_constant == math.inf:
            return ts.build_scene("cloth-stiff", {"nx": 64, "ny": 64}), method, 1 / 60, 5, 0
        return ts.build_scene("cloth", {"nx": 64, "ny": 64}), method, 1e-4, 50, 0
    if case == "self-contact":  # a folding cloth with the self-contact stage
        scene = ts.build_scene("cloth-fold", {"nx": 16, "ny": 16, "self_collision": True})
        return scene, "symplectic_euler", 1e-3, 400, 100
    if case == "rk4":  # the force loops, fused into one kernel per step
        return ts.build_scene("cloth", {"nx": 64, "ny": 64}), "rk4", 1e-4, 20, 20
    if case == "implicit":  # Newton and its linear solves
        return ts.build_scene("cloth", {"nx": 24, "ny": 24}), "implicit_euler", 5e-3, 20, 20
    # a cloth falling onto a box and a capsule: their face contact (and the corners' collide)
    from taichi_sim.scene import cloth as topo
    from taichi_sim.scene.builder import SceneBuilder
    from taichi_sim.scene.colliders import SpherePath

    n, size = 24, 0.5
    b = SceneBuilder()
    b.add_particles(topo.grid_positions(n, n, size, size, origin=(-size / 2, 0.2, -size / 2),
                                        u_axis=(1, 0, 0), v_axis=(0, 0, 1)), 0.01)
    ends, kind = topo.grid_springs(n, n)
    b.add_springs(ends, stiffness=5.0, damping=0.0, kind=kind)
    b.add_triangles(topo.grid_triangles(n, n))
    b.add_box(SpherePath((0.0, 0.0, 0.0)), (0.1, 0.1, 0.1))
    b.add_capsule(SpherePath((0.15, 0.05, 0.0)), 0.05, (0.1, 0.0, 0.0))
    scene = b.finalize(name="faces", params={}, default_dt=1e-3, default_integrator="symplectic_euler")
    return scene, "symplectic_euler", 1e-3, 300, 30


def child(case: str, kind: str) -> dict:
    """One measurement in this (fresh) process."""
    import taichi as ti

    import taichi_sim as ts
    from taichi_sim import runtime

    if kind == "full":
        runtime.without_cfg_optimisation = contextlib.nullcontext
    ts.init(arch="cpu", precision="f64")
    scene, integrator, dt, warmup, steps = build(case)
    stepper = ts.Stepper(scene, integrator, dt)
    start = time.perf_counter()
    stepper.step()
    ti.sync()
    first = time.perf_counter() - start
    start = time.perf_counter()
    for _ in range(warmup):
        stepper.step()
    ti.sync()
    sized = not steps
    if sized:  # as many steps as fill about 0.3 s
        steps = max(1, round(0.3 / max((time.perf_counter() - start) / warmup, 1e-6)))
    times = []
    for _ in range(5 if sized else 3):
        start = time.perf_counter()
        for _ in range(steps):
            stepper.step()
        ti.sync()
        times.append((time.perf_counter() - start) / steps)
    if stepper.failure is not None:
        raise SystemExit(f"{case}: {stepper.failure.summary}")
    return {"first_s": first, "step_ms": 1e3 * statistics.median(times)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--cases", default="self-contact,faces")
    parser.add_argument("--kinds", default="full,lean")
    parser.add_argument("--warm", action="store_true", help="keep each (case, kind)'s kernel cache across rounds")
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(*args.child)))
        return
    cases = [c for c in args.cases.split(",") if c]
    if "methods" in cases:
        at = cases.index("methods")
        cases[at:at + 1] = method_cases()
    kinds = [k for k in args.kinds.split(",") if k]
    known = CASES + tuple(method_cases())
    if not cases or any(c not in known for c in cases):
        parser.error(f"--cases: from {', '.join(CASES)}, methods, method:NAME")
    if not kinds or any(k not in KINDS for k in kinds):
        parser.error(f"--kinds: from {', '.join(KINDS)}")
    if args.repeats < 1:
        parser.error("--repeats: at least 1")
    ratio_head = f"  {kinds[1]}/{kinds[0]} step: median (lowest-highest)" if len(kinds) == 2 else ""
    print(f"{'case':34s} {'kind':5s} {'first step (s)':>15s} {'step (ms)':>10s}{ratio_head}")
    for case in cases:
        results = {kind: [] for kind in kinds}
        with contextlib.ExitStack() as kept:  # --warm: one cache per kind for all the rounds
            caches = {kind: kept.enter_context(tempfile.TemporaryDirectory()) for kind in kinds if args.warm}
            for _ in range(args.repeats):
                for kind in kinds:
                    if args.warm:
                        results[kind].append(run_child(case, kind, caches[kind]))
                        continue
                    with tempfile.TemporaryDirectory() as fresh:
                        results[kind].append(run_child(case, kind, fresh))
        for kind in kinds:
            first = results[kind][0]["first_s"] if args.warm else statistics.median(r["first_s"] for r in results[kind])
            step = statistics.median(r["step_ms"] for r in results[kind])
            ratio = ""
            if len(kinds) == 2 and kind == kinds[1]:
                ratios = [b["step_ms"] / a["step_ms"] for a, b in zip(results[kinds[0]], results[kinds[1]])]
                ratio = f"  {statistics.median(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f})"
            print(f"{case:34s} {kind:5s} {first:15.2f} {step:10.3f}{ratio}", flush=True)


def run_child(case: str, kind: str, cache: str) -> dict:
    env = {**os.environ, "TI_OFFLINE_CACHE_FILE_PATH": cache}
    if kind == "off":
        env["TI_CFG_OPTIMIZATION"] = "0"
    out = subprocess.run([sys.executable, __file__, "--child", case, kind], env=env,
                         capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"{case} ({kind}) failed: {out.stderr.strip()[-500:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


if __name__ == "__main__":
    main()
