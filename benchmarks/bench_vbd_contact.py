"""Contact in the VBD solve against symplectic Euler with the post-step Bridson stage
on `cloth-fold` (or ``--scene cloth-twist``), in one process: steps/s, the cost of each phase,
intersecting frames, energy.

    python benchmarks/bench_vbd_contact.py --n 64 --t-end 5 --base-t-end 0.3
    python benchmarks/bench_vbd_contact.py --scene cloth-twist --n 32 --t-end 4 --base-t-end 1
    python benchmarks/bench_vbd_contact.py --n 64 --t-end 2.5 --base-t-end 0 --precision f64 --against skip_move=0

`vbd` runs with self-contact in its solve (which replaces the preset's post-step self-collision
stage) at h = 1/60 s in f32 with the guard on, its substeps cut into pieces as its
``contact_pieces`` (16 unless ``--option contact_pieces=N``) allows; every step's positions are
checked with the exact intersection test (taichi_sim.geometry.self_intersections, the `check`
command's). Beside it, symplectic Euler
with the Bridson stage at 1 ms (0.9 of its stable step where that is less) for
``--base-t-end`` seconds. Per-phase times are wall times around each phase with ti.sync(),
medians over the steps after the first two (compiling). Timings depend on the machine's load.
``--against NAME=VALUE`` runs a second `vbd` with that option beside the first, a step of each
in turn, and prints both (before and after a change, on the same load): their mean wall and
CPU time a step over the fall (steps 3-30), the landing (31-90), the pile (91 on) and steps 31
on (what the difference of a 150- and a 30-step run of the command line measures).
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
PHASES = ((2, 30), (30, 90), (90, 10 ** 9), (30, 10 ** 9))  # steps: the fall, the landing, the pile; 31 on


def timed(fn, bucket: list):
    def wrapper(*args, **kwargs):
        ti.sync()
        start = time.perf_counter()
        out = fn(*args, **kwargs)
        ti.sync()
        bucket.append(time.perf_counter() - start)
        return out
    return wrapper


class Run:
    """One run of ``scene_name`` at n x n for t_end s, stepped by :meth:`step` (so that two runs
    can take turns in one process) and summed up by :meth:`result`; dt in s, or "explicit" for
    symplectic Euler's step on these scenes before they defaulted to vbd: 1 ms, or 0.9 of its
    stable step where that is less (fine grids). ``sweeps``: "serial" or "parallel" overrides
    vbd's choice of one serial task or parallel colour loops (``VBD.serial``)."""

    def __init__(self, scene_name: str, n: int, t_end: float, integrator: str, dt: float | str, options: dict,
                 params: dict, sweeps: str = "auto", label: str | None = None):
        self.scene = scene = ts.build_scene(scene_name, {"nx": n, "ny": n, **params})
        self.name = label or integrator
        if dt == "explicit":
            dt = explicit_default_step(scene.arrays, scene.x0, 1e-3, 0.9)
        self.dt = dt
        self.method = method = ts.create_integrator(integrator, scene.system, **options)
        if sweeps != "auto" and hasattr(method, "serial"):
            method.serial = sweeps == "serial"
        self.steps, self.events, self.refresh, self.cpu = [], [], [], []
        method.step = timed(method.step, self.steps)
        scene.after_step = timed(scene.after_step, self.events)
        self.stepper = ts.Stepper(scene, method, dt)
        if getattr(method, "contact", None) is not None and method.contact.self_contact:
            method.contact.refresh = timed(method.contact.refresh, self.refresh)
        self.tris = scene.mesh.triangles_np
        self.energy0 = self.top = scene.energy()
        self.bad_frames, self.first_bad, self.failure = 0, None, None
        self.count = int(round(t_end / dt))
        self.done = 0
        self.wall = self.check_time = 0.0
        self.height = None  # the cloth's mean height at PACE_TIME: how fast the fold collapses
        self.heights, self.marks = {}, list(HEIGHT_TIMES)
        self.refresh_per_step = []  # each step's detections together (substeps, the pins' pieces)
        self.pieces_per_step = []

    def step(self) -> bool:
        """One step and its checks; False once the run is over (its steps done, or failed)."""
        if self.done >= self.count or self.failure is not None:
            return False
        before, pieces = len(self.refresh), getattr(self.method, "pieces", 0)
        start, cpu = time.perf_counter(), time.process_time()
        self.stepper.step()
        self.cpu.append(time.process_time() - cpu)
        self.wall += time.perf_counter() - start
        self.refresh_per_step.append(sum(self.refresh[before:]))
        self.pieces_per_step.append(getattr(self.method, "pieces", 0) - pieces)
        self.done += 1
        k, dt, scene = self.done, self.dt, self.scene
        if self.stepper.failure is not None:
            self.failure = self.stepper.failure.message
            return False
        if k % 60 == 0:  # a run cut short still says how far it got
            print(f"  {self.name}: {k} of {self.count} steps, {self.wall:.1f} s, {self.bad_frames} intersecting",
                  file=sys.stderr, flush=True)
        start = time.perf_counter()
        self.top = max(self.top, scene.energy())
        x = scene.state.to_numpy()[0]
        if self.height is None and self.stepper.t >= PACE_TIME - 0.5 * dt:
            self.height = float(x[:, 1].mean())
        if self.marks and self.stepper.t >= self.marks[0] - 0.5 * dt:
            self.heights[self.marks.pop(0)] = round(float(x[:, 1].mean()), 3)
        if len(self_intersections(x, self.tris).pairs):
            self.bad_frames += 1
            self.first_bad = self.first_bad if self.first_bad is not None else k * dt
        self.check_time += time.perf_counter() - start
        return True

    def result(self) -> dict:
        if self.failure is not None:
            return {"name": self.name, "failure": self.failure, "steps": self.done}
        warm = slice(2, None)
        step_med = statistics.median(self.steps[warm])
        event_med = statistics.median(self.events[warm])
        refresh_med = statistics.median(self.refresh_per_step[warm]) if self.refresh else 0.0
        method = self.method
        pieces = getattr(method, "pieces", None) if getattr(method, "contact", None) is not None else None
        return {"name": self.name, "dt": self.dt, "steps": self.count, "steps_per_s": 1.0 / (step_med + event_med),
                "wall": self.wall, "step_ms": 1e3 * step_med, "refresh_ms": 1e3 * refresh_med,
                "solve_ms": 1e3 * (step_med - refresh_med), "events_ms": 1e3 * event_med,
                "bad_frames": self.bad_frames, "first_bad": self.first_bad, "energy0": self.energy0,
                "energy_max": self.top, "pairs": getattr(getattr(method, "contact", None), "pairs_total", 0),
                "height": self.height, "pieces_per_step": None if pieces is None else pieces / self.count,
                "heights": self.heights}

    def phases(self) -> list[tuple]:
        """(steps a .. b, mean wall ms a step, mean CPU ms a step, pieces a step) over the fall
        (steps 3-30), the landing (31-90) and the pile (91 on), and over steps 31 on, the span
        that the difference of a 150- and a 30-step run of the command line measures."""
        rows = []
        for a, b in PHASES:
            b = min(b, self.done)
            if b > a:
                rows.append((a, b, 1e3 * statistics.fmean(self.steps[a:b]), 1e3 * statistics.fmean(self.cpu[a:b]),
                             statistics.fmean(self.pieces_per_step[a:b])))
        return rows


def run(scene_name: str, n: int, t_end: float, integrator: str, dt: float | str, options: dict,
        params: dict, sweeps: str = "auto") -> dict:
    """One :class:`Run` to its end: its :meth:`Run.result`."""
    one = Run(scene_name, n, t_end, integrator, dt, options, params, sweeps)
    while one.step():
        pass
    return one.result()


def paired(args, options: dict, against: dict, params: dict) -> list[dict]:
    """vbd with ``options`` and with ``against`` over them, in one process, a step of each in
    turn (so that a machine's changing load falls on both alike); prints each phase's mean
    wall and CPU time a step (:meth:`Run.phases`) and returns the two results."""
    label = "vbd(" + ", ".join(f"{k}={v}" for k, v in against.items()) + ")"
    runs = [Run(args.scene, args.n, args.t_end, "vbd", 1 / 60, options, params, args.sweeps),
            Run(args.scene, args.n, args.t_end, "vbd", 1 / 60, {**options, **against}, params, args.sweeps, label)]
    while any([one.step() for one in runs]):
        pass
    print("| run | steps | wall (ms a step) | CPU (ms a step) | pieces a step | steps/s (wall) |")
    print("|---|---|---|---|---|---|")
    for one in runs:
        for a, b, wall, cpu, pieces in one.phases():
            print(f"| {one.name} | {a + 1}-{b} | {wall:.1f} | {cpu:.1f} | {pieces:.2f} | {1e3 / wall:.1f} |")
    print()
    return [one.result() for one in runs]


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
    parser.add_argument("--against", action="append", default=[], metavar="NAME=VALUE",
                        help="a second vbd in the same process with this option over the first's (repeatable), "
                             "the two stepped in turn; both rows and their phases are printed")
    parser.add_argument("--precision", choices=("f32", "f64"), default="f32",
                        help="f64: the command line's default")
    args = parser.parse_args()
    ts.init(arch=args.arch, precision=args.precision)
    params = {} if args.contact_radius is None else {"thickness": args.contact_radius}
    if args.jitter is not None:
        params["jitter"] = args.jitter
    options = parse_options("vbd", dict(text.split("=", 1) for text in args.option))
    params.update(text.split("=", 1) for text in args.set)  # build_scene parses and checks them
    options = {"iterations": args.iterations, "substeps": args.substeps, **options}
    if args.against:
        rows = paired(args, options, parse_options("vbd", dict(text.split("=", 1) for text in args.against)), params)
    else:
        rows = [run(args.scene, args.n, args.t_end, "vbd", 1 / 60, options, params, args.sweeps)]
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
