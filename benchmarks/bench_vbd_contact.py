"""Contact in the VBD solve against symplectic Euler with the post-step Bridson stage
on `cloth-fold` (or ``--scene cloth-twist``), in one process: steps/s, the cost of each phase,
intersecting frames, energy.

    python benchmarks/bench_vbd_contact.py --n 64 --t-end 5 --base-t-end 0.3
    python benchmarks/bench_vbd_contact.py --scene cloth-twist --n 32 --t-end 4 --base-t-end 1

`vbd` runs with self-contact in its solve (which replaces the preset's post-step self-collision
stage) at h = 1/60 s in f32 with the guard on, its substeps cut into pieces as its
``contact_pieces`` (16 unless ``--option contact_pieces=N``) allows; every step's positions are
checked with the exact intersection test (taichi_sim.geometry.self_intersections, the `check`
command's). Beside it, symplectic Euler
with the Bridson stage at 1 ms (0.9 of its stable step where that is less) for
``--base-t-end`` seconds. Per-phase times are wall times around each phase with ti.sync(),
medians over the steps after the first two (compiling). Timings depend on the machine's load.
"""
import argparse
import statistics
import sys
import time

import taichi as ti

import taichi_sim as ts
from taichi_sim.forces.springs.spectrum import explicit_default_step
from taichi_sim.geometry import self_intersections
from taichi_sim.integrators import parse_options

PACE_TIME = 0.5  # s: by then a free fold has collapsed (32 x 32, symplectic Euler at 1 ms: 0.04 m from 0.6)
HEIGHT_TIMES = (0.25, 0.5, 0.75, 1.0, 2.0)  # s: when the mean height is kept (the fold's pace)


def timed(fn, bucket: list):
    def wrapper(*args, **kwargs):
        ti.sync()
        start = time.perf_counter()
        out = fn(*args, **kwargs)
        ti.sync()
        bucket.append(time.perf_counter() - start)
        return out
    return wrapper


def run(scene_name: str, n: int, t_end: float, integrator: str, dt: float | str, options: dict,
        params: dict, sweeps: str = "auto") -> dict:
    """One run of ``scene_name`` at n x n for t_end s; dt in s, or "explicit" for symplectic
    Euler's step on these scenes before they defaulted to vbd: 1 ms, or 0.9 of its stable step
    where that is less (fine grids). ``sweeps``: "serial" or "parallel" overrides vbd's choice
    of one serial task or parallel colour loops (``VBD.serial``)."""
    scene = ts.build_scene(scene_name, {"nx": n, "ny": n, **params})
    name = integrator
    if dt == "explicit":
        dt = explicit_default_step(scene.arrays, scene.x0, 1e-3, 0.9)
    method = ts.create_integrator(name, scene.system, **options)
    if sweeps != "auto" and hasattr(method, "serial"):
        method.serial = sweeps == "serial"
    steps, events, refresh = [], [], []
    method.step = timed(method.step, steps)
    scene.after_step = timed(scene.after_step, events)
    stepper = ts.Stepper(scene, method, dt)
    if getattr(method, "contact", None) is not None and method.contact.self_contact:
        method.contact.refresh = timed(method.contact.refresh, refresh)
    tris = scene.mesh.triangles_np
    energy0 = scene.energy()
    top, bad_frames, first_bad = energy0, 0, None
    count = int(round(t_end / dt))
    wall = time.perf_counter()
    check_time = 0.0
    height = None  # the cloth's mean height at PACE_TIME: how fast the fold collapses
    heights, marks = {}, list(HEIGHT_TIMES)
    refresh_per_step = []  # each step's detections together (substeps, the pins' pieces)
    for k in range(count):
        before = len(refresh)
        stepper.step()
        refresh_per_step.append(sum(refresh[before:]))
        if stepper.failure is not None:
            return {"name": name, "failure": stepper.failure.message, "steps": k}
        if (k + 1) % 60 == 0:  # a run cut short still says how far it got
            print(f"  {name}: {k + 1} of {count} steps, {time.perf_counter() - wall:.1f} s (checks "
                  f"{check_time:.1f} s), {bad_frames} intersecting", file=sys.stderr, flush=True)
        top = max(top, scene.energy())
        start = time.perf_counter()
        x = scene.state.to_numpy()[0]
        if height is None and stepper.t >= PACE_TIME - 0.5 * dt:
            height = float(x[:, 1].mean())
        if marks and stepper.t >= marks[0] - 0.5 * dt:
            heights[marks.pop(0)] = round(float(x[:, 1].mean()), 3)
        if len(self_intersections(x, tris).pairs):
            bad_frames += 1
            first_bad = first_bad if first_bad is not None else (k + 1) * dt
        check_time += time.perf_counter() - start
    wall = time.perf_counter() - wall - check_time
    warm = slice(2, None)
    step_med = statistics.median(steps[warm])
    event_med = statistics.median(events[warm])
    refresh_med = statistics.median(refresh_per_step[warm]) if refresh else 0.0
    pieces = getattr(method, "pieces", None) if getattr(method, "contact", None) is not None else None
    return {"name": name, "dt": dt, "steps": count, "steps_per_s": 1.0 / (step_med + event_med),
            "wall": wall, "step_ms": 1e3 * step_med, "refresh_ms": 1e3 * refresh_med,
            "solve_ms": 1e3 * (step_med - refresh_med), "events_ms": 1e3 * event_med,
            "bad_frames": bad_frames, "first_bad": first_bad, "energy0": energy0, "energy_max": top,
            "pairs": getattr(getattr(method, "contact", None), "pairs_total", 0), "height": height,
            "pieces_per_step": None if pieces is None else pieces / count, "heights": heights}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=("cloth-fold", "cloth-twist"), default="cloth-fold")
    parser.add_argument("--n", type=int, default=64)
    parser.add_argument("--t-end", type=float, default=5.0)
    parser.add_argument("--base-t-end", type=float, default=0.3, help="seconds of symplectic Euler with the stage (0: skip)")
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--substeps", type=int, default=1)
    parser.add_argument("--contact-radius", type=float, default=None, help="the scene's thickness (m)")
    parser.add_argument("--jitter", type=float, default=None,
                        help="the scene's jitter (m); 128 x 128 needs 0.001: at 0.002 it starts tangled")
    parser.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                        help="a vbd option, e.g. bound_fraction=0.49 or self_contact=0 (repeatable)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="a scene parameter, e.g. self_collision=0 (repeatable)")
    parser.add_argument("--arch", choices=("cpu", "gpu"), default="cpu")
    parser.add_argument("--sweeps", choices=("auto", "serial", "parallel"), default="auto",
                        help="vbd's sweeps as one serial task or parallel colour loops (default: its own rule)")
    args = parser.parse_args()
    ts.init(arch=args.arch, precision="f32")
    params = {} if args.contact_radius is None else {"thickness": args.contact_radius}
    if args.jitter is not None:
        params["jitter"] = args.jitter
    options = parse_options("vbd", dict(text.split("=", 1) for text in args.option))
    params.update(text.split("=", 1) for text in args.set)  # build_scene parses and checks them
    rows = [run(args.scene, args.n, args.t_end, "vbd", 1 / 60,
                {"iterations": args.iterations, "substeps": args.substeps, **options}, params, args.sweeps)]
    if args.base_t_end > 0:
        rows.append(run(args.scene, args.n, args.base_t_end, "symplectic_euler", "explicit", {}, params))
    for row in rows:
        print(row)
    print()
    print("| method | h (s) | steps | steps/s | step (ms) | refresh (ms) | solve (ms) | events (ms) "
          "| frames intersecting | energy max / start (J) | mean height at 0.5 s (m) | pieces a step |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "failure" in r:
            print(f"| {r['name']} | failed after {r['steps']} steps: {r['failure']} |")
            continue
        print(f"| {r['name']} | {r['dt']:.4g} | {r['steps']} | {r['steps_per_s']:.3g} | {r['step_ms']:.3g} "
              f"| {r['refresh_ms']:.3g} | {r['solve_ms']:.3g} | {r['events_ms']:.3g} | {r['bad_frames']} of {r['steps']} "
              f"| {r['energy_max']:.4g} / {r['energy0']:.4g} "
              f"| {'-' if r['height'] is None else format(r['height'], '.3f')} "
              f"| {'-' if r['pieces_per_step'] is None else format(r['pieces_per_step'], '.2f')} |")
    print("load average:", open("/proc/loadavg").read().split()[:3], "backend:", ts.runtime.backend())


if __name__ == "__main__":
    main()
