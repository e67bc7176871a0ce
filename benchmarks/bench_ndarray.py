"""Fields against ndarrays: what a kernel's compile costs across scene sizes, and what each
step costs, for the same mass-spring cloth step written both ways.

The package keeps every scene in Taichi fields, and its kernels take them as templates: a
field's shape and its place in Taichi's memory tree are compiled into each kernel that touches
it, so every new scene size (and every new scene in one program) compiles its kernels again,
and the offline cache's key changes with the order in which fields were made. Kernels that take
Taichi ndarrays are compiled once per element type and dimension and serve every size. This
benchmark measures both sides of that trade on one small, complete step (spring forces with
atomics, gravity, pinned particles, symplectic Euler), so the choice rests on numbers:

* ``sizes``: in one fresh process per side, with an empty kernel cache of its own, scenes of
  growing size built one after the other in one Taichi program, each stepped ``--steps``
  times; the seconds of each scene's first step (compile or cache load, and the step) and of
  the rest. Run twice: the second run finds the first's kernels in the cache.
* ``speed``: the step's time at the larger sizes, both sides with parallel and with serial
  loops (the package runs a grid cloth's loops on one thread below a break-even), in one
  process, alternated rounds, medians after a warm-up.

    .venv/bin/python benchmarks/bench_ndarray.py            # both parts
    .venv/bin/python benchmarks/bench_ndarray.py --part speed --sizes 64,128,256
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

SIZE_SWEEP = (6, 8, 12, 16, 24, 32, 48, 64)
SPEED_SIZES = (64, 128, 256)
KINDS = ("field", "ndarray")
LOOPS = ("parallel", "serial")


def cloth_arrays(n: int, dtype) -> dict[str, np.ndarray]:
    """An n x n grid cloth, 1 m a side, hanging from two corners: positions (n*n, 3) in m, the
    structural, shear and bending springs' ends (m, 2) and rest lengths (m,) in m, and the
    inverse masses (n*n,) in 1/kg (0 where pinned)."""
    h = 1.0 / (n - 1)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    x = np.stack([i.ravel() * h, np.zeros(n * n), j.ravel() * h], axis=1)
    index = (i * n + j)
    pairs = [(index[:-1, :], index[1:, :]), (index[:, :-1], index[:, 1:]),
             (index[:-1, :-1], index[1:, 1:]), (index[1:, :-1], index[:-1, 1:]),
             (index[:-2, :], index[2:, :]), (index[:, :-2], index[:, 2:])]
    ends = np.concatenate([np.stack([a.ravel(), b.ravel()], axis=1) for a, b in pairs]).astype(np.int32)
    rest = np.linalg.norm(x[ends[:, 0]] - x[ends[:, 1]], axis=1)
    inv_mass = np.full(n * n, float(n * n))  # 1 kg in all
    inv_mass[[0, (n - 1) * n]] = 0.0
    return {"x": x.astype(dtype), "ends": ends, "rest": rest.astype(dtype), "inv_mass": inv_mass.astype(dtype)}


def step_sides(ti, real, vec, serial: bool) -> dict:
    """The two sides' cloth classes (``field``, ``ndarray``), their loops on one thread when
    ``serial`` (as the package runs a grid cloth's loops below its break-even,
    ``runtime.serial_loops``). Each class takes :func:`cloth_arrays` and has ``step(h)`` and
    ``positions()``."""
    stiffness, damping, gravity = 2000.0, 0.02, -9.8

    # -- the step over ndarrays: compiled once per element type and dimension ------------------
    @ti.kernel
    def forces_nd(x: ti.types.ndarray(dtype=vec, ndim=1), v: ti.types.ndarray(dtype=vec, ndim=1),
                  f: ti.types.ndarray(dtype=vec, ndim=1), ends: ti.types.ndarray(dtype=ti.i32, ndim=2),
                  rest: ti.types.ndarray(dtype=real, ndim=1)):
        ti.loop_config(serialize=serial)
        for p in f:
            f[p] = vec(0.0, 0.0, 0.0)
        ti.loop_config(serialize=serial)
        for s in rest:
            a, b = ends[s, 0], ends[s, 1]
            d = x[b] - x[a]
            length = d.norm() + 1e-12
            u = d / length
            push = stiffness * (length - rest[s]) + damping * stiffness * (v[b] - v[a]).dot(u) * 1e-3
            f[a] += push * u
            f[b] -= push * u

    @ti.kernel
    def advance_nd(x: ti.types.ndarray(dtype=vec, ndim=1), v: ti.types.ndarray(dtype=vec, ndim=1),
                   f: ti.types.ndarray(dtype=vec, ndim=1), inv_mass: ti.types.ndarray(dtype=real, ndim=1),
                   h: real):
        ti.loop_config(serialize=serial)
        for p in x:
            w = inv_mass[p]
            if w > 0:
                v[p] += h * (w * f[p] + vec(0.0, gravity, 0.0))
                x[p] += h * v[p]

    # -- the same step over fields, as the package's data-oriented parts do it -----------------
    @ti.data_oriented
    class FieldCloth:
        def __init__(self, arrays):
            n, m = len(arrays["x"]), len(arrays["rest"])
            self.x, self.v, self.f = (ti.Vector.field(3, real, n) for _ in range(3))
            self.inv_mass, self.rest = ti.field(real, n), ti.field(real, m)
            self.ends = ti.Vector.field(2, ti.i32, m)
            self.x.from_numpy(arrays["x"])
            self.inv_mass.from_numpy(arrays["inv_mass"])
            self.rest.from_numpy(arrays["rest"])
            self.ends.from_numpy(arrays["ends"])

        @ti.kernel
        def forces(self):
            ti.loop_config(serialize=serial)
            for p in self.f:
                self.f[p] = vec(0.0, 0.0, 0.0)
            ti.loop_config(serialize=serial)
            for s in self.rest:
                a, b = self.ends[s][0], self.ends[s][1]
                d = self.x[b] - self.x[a]
                length = d.norm() + 1e-12
                u = d / length
                push = (stiffness * (length - self.rest[s])
                        + damping * stiffness * (self.v[b] - self.v[a]).dot(u) * 1e-3)
                self.f[a] += push * u
                self.f[b] -= push * u

        @ti.kernel
        def advance(self, h: real):
            ti.loop_config(serialize=serial)
            for p in self.x:
                w = self.inv_mass[p]
                if w > 0:
                    self.v[p] += h * (w * self.f[p] + vec(0.0, gravity, 0.0))
                    self.x[p] += h * self.v[p]

        def step(self, h):
            self.forces()
            self.advance(h)

        def positions(self):
            return self.x.to_numpy()

    class NdarrayCloth:
        def __init__(self, arrays):
            n, m = len(arrays["x"]), len(arrays["rest"])
            self.x, self.v, self.f = (ti.Vector.ndarray(3, real, n) for _ in range(3))
            self.inv_mass, self.rest = ti.ndarray(real, n), ti.ndarray(real, m)
            self.ends = ti.ndarray(ti.i32, (m, 2))
            self.x.from_numpy(arrays["x"])
            self.v.fill(0.0)
            self.inv_mass.from_numpy(arrays["inv_mass"])
            self.rest.from_numpy(arrays["rest"])
            self.ends.from_numpy(arrays["ends"])

        def step(self, h):
            forces_nd(self.x, self.v, self.f, self.ends, self.rest)
            advance_nd(self.x, self.v, self.f, self.inv_mass, h)

        def positions(self):
            return self.x.to_numpy()

    return {"field": FieldCloth, "ndarray": NdarrayCloth}


def child(kind: str, sizes: list[int], steps: int, precision: str, rounds: int) -> dict:
    """Run in a process of its own: time ``steps`` steps of each size on the ``kind`` side
    with parallel loops (the sizes part), or ``rounds`` rounds of both sides, with parallel
    and with serial loops, at each size (``kind`` "both": the speed part)."""
    import taichi as ti

    import taichi_sim as ts

    ts.init(precision=precision)
    real = ti.f64 if precision == "f64" else ti.f32
    dtype = np.float64 if precision == "f64" else np.float32
    vec = ti.types.vector(3, real)
    h = 1e-4
    out: dict = {"sizes": [], "speed": {}}
    if kind in KINDS:
        make = step_sides(ti, real, vec, serial=False)[kind]
        for n in sizes:
            t0 = time.perf_counter()
            cloth = make(cloth_arrays(n, dtype))
            t1 = time.perf_counter()
            cloth.step(h)
            y = cloth.positions()
            t2 = time.perf_counter()
            for _ in range(steps - 1):
                cloth.step(h)
            y = cloth.positions()
            t3 = time.perf_counter()
            out["sizes"].append({"n": n, "build": t1 - t0, "first": t2 - t1, "rest": t3 - t2,
                                 "y_min": float(y[:, 1].min())})
    if kind == "both":
        classes = {loops: step_sides(ti, real, vec, serial=loops == "serial") for loops in LOOPS}
        variants = [(k, loops) for k in KINDS for loops in LOOPS]
        cloths = {v: {n: classes[v[1]][v[0]](cloth_arrays(n, dtype)) for n in sizes} for v in variants}
        batch = 50
        times: dict = {v: {n: [] for n in sizes} for v in variants}
        for r in range(rounds + 1):  # round 0 warms up
            for n in sizes:
                for v in (variants if r % 2 else variants[::-1]):
                    cloth = cloths[v][n]
                    cloth.step(h)
                    ti.sync()
                    t = time.perf_counter()
                    for _ in range(batch):
                        cloth.step(h)
                    ti.sync()
                    if r:
                        times[v][n].append((time.perf_counter() - t) / batch)
        out["speed"] = {"/".join(v): {str(n): statistics.median(t) for n, t in per.items()}
                        for v, per in times.items()}
    return out


def run_child(kind, sizes, steps, precision, rounds, cache_dir):
    env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=cache_dir,
               TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES=str(1 << 30))
    args = [sys.executable, __file__, "--child", kind, "--sizes", ",".join(map(str, sizes)),
            "--steps", str(steps), "--precision", precision, "--rounds", str(rounds)]
    done = subprocess.run(args, env=env, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"bench_ndarray: the {kind} run failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def cache_entries(folder: str) -> int:
    return sum(name.endswith(".tic") for _, _, names in os.walk(folder) for name in names)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--part", choices=("sizes", "speed", "both"), default="both")
    p.add_argument("--sizes", default=None, help="comma-separated grid sizes (points a side)")
    p.add_argument("--steps", type=int, default=20, help="steps per scene in the sizes part")
    p.add_argument("--rounds", type=int, default=7, help="timed rounds in the speed part")
    p.add_argument("--precision", choices=("f32", "f64"), default="f32")
    p.add_argument("--child", choices=KINDS + ("both",), help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    try:
        custom = [int(v) for v in a.sizes.split(",")] if a.sizes else []
    except ValueError:
        p.error(f"--sizes must be comma-separated integers, got {a.sizes!r}")
    if any(n < 3 for n in custom):
        p.error("--sizes: each cloth needs at least 3 points a side")
    if a.steps < 1 or a.rounds < 1:
        p.error("--steps and --rounds must be at least 1")
    if a.child:
        print(json.dumps(child(a.child, custom, a.steps, a.precision, a.rounds)))
        return 0
    if a.part in ("sizes", "both"):
        sizes = custom or list(SIZE_SWEEP)
        print(f"## One program, scenes of {len(sizes)} sizes one after the other ({a.precision}, "
              f"{a.steps} steps each): seconds")
        print()
        print("| side | kernel cache | build (all) | first steps (all) | other steps (all) | "
              "cache entries | total |")
        print("|---|---|---|---|---|---|---|")
        lowest = {}
        for kind in KINDS:
            with tempfile.TemporaryDirectory(prefix=f"bench_ndarray_{kind}_") as cache:
                for label in ("empty", "warm"):
                    rows = run_child(kind, sizes, a.steps, a.precision, a.rounds, cache)["sizes"]
                    lowest[kind] = np.array([r["y_min"] for r in rows])
                    build = sum(r["build"] for r in rows)
                    first = sum(r["first"] for r in rows)
                    rest = sum(r["rest"] for r in rows)
                    print(f"| {kind} | {label} | {build:.2f} | {first:.2f} | {rest:.3f} | "
                          f"{cache_entries(cache)} | {build + first + rest:.2f} |", flush=True)
        gap = float(np.abs(lowest["field"] - lowest["ndarray"]).max())
        print()
        print(f"The two sides' lowest points after the steps differ by at most {gap:.1e} m "
              "(the spring forces are summed with atomics, in no fixed order).")
        print()
    if a.part in ("speed", "both"):
        sizes = custom or list(SPEED_SIZES)
        with tempfile.TemporaryDirectory(prefix="bench_ndarray_speed_") as cache:
            speed = run_child("both", sizes, a.steps, a.precision, a.rounds, cache)["speed"]
        print(f"## Step time, both sides and both loop schedules in one process ({a.precision}, "
              f"{a.rounds} alternated rounds of 50 steps, medians after a warm-up round): microseconds")
        print()
        print("| points a side | fields, parallel | fields, serial | ndarrays, parallel | "
              "ndarrays, serial | each side's faster: ndarrays / fields |")
        print("|---|---|---|---|---|---|")
        for n in sizes:
            us = {v: speed[v][str(n)] * 1e6 for v in speed}
            best = {k: min(us[f"{k}/{loops}"] for loops in LOOPS) for k in KINDS}
            print(f"| {n} | {us['field/parallel']:.0f} | {us['field/serial']:.0f} | "
                  f"{us['ndarray/parallel']:.0f} | {us['ndarray/serial']:.0f} | "
                  f"{best['ndarray'] / best['field']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
