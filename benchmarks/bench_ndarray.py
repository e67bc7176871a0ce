"""Fields against ndarrays: what a kernel's compile costs across scene sizes, and what each
step costs, for the same mass-spring cloth step written both ways.

The package keeps every scene in Taichi fields, and its kernels take them as templates: a
field's shape and its place in Taichi's memory tree (the fields made so far, numbered in order)
are compiled into each kernel that touches it, so every new scene size (and every new scene in
one program) compiles its kernels again, and the offline cache's key changes with the order in
which fields were made. Kernels that take Taichi ndarrays as arguments are compiled once per
element type and dimension and serve every size. This benchmark measures both sides of that
trade on one small, complete step (spring forces summed with atomics over a spring list,
gravity, pinned particles, symplectic Euler), so the choice rests on numbers:

* ``sizes``: in one fresh process per run and side, scenes of growing size built one after the
  other in one Taichi program, each stepped ``--steps`` times; the seconds of the builds (with
  their upload kernels), of each scene's first step and read of its positions (compile or
  cache load of the step and read kernels, and the step) and of the other steps. Three runs
  per side share a kernel cache of their own: empty, then warm, then warm with the sizes in
  reverse order (a cache key that depends on what was made before misses there).
* ``speed``: the step's time at the larger sizes, both sides with parallel and with serial
  loops (the package runs a grid cloth's loops on one thread below a break-even), in one
  process, alternated rounds, medians after a warm-up; every cloth is checked finite after.

The step is ``1e-3 / n`` s for n points a side, a third of the stable limit or less at every
size. Both parts compare the two sides' positions.

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
    stiffness, damping, gravity = 2000.0, 2e-5, -9.8  # N/m, s (damping time), m/s^2

    @ti.func
    def spring_pull(d, dv, rest):
        """The force (N) on a spring's first end: its extension and its ends' relative speed
        along it, for ``d`` and ``dv`` the second end's position and velocity less the first's
        (one function, so that both sides do the same arithmetic)."""
        length = d.norm() + 1e-12
        u = d / length
        return (stiffness * (length - rest) + damping * stiffness * dv.dot(u)) * u

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
            pull = spring_pull(x[b] - x[a], v[b] - v[a], rest[s])
            f[a] += pull
            f[b] -= pull

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
                pull = spring_pull(self.x[b] - self.x[a], self.v[b] - self.v[a], self.rest[s])
                self.f[a] += pull
                self.f[b] -= pull

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
            self.x.from_numpy(arrays["x"])  # v and f: Taichi makes ndarrays zero-filled
            self.inv_mass.from_numpy(arrays["inv_mass"])
            self.rest.from_numpy(arrays["rest"])
            self.ends.from_numpy(arrays["ends"])

        def step(self, h):
            forces_nd(self.x, self.v, self.f, self.ends, self.rest)
            advance_nd(self.x, self.v, self.f, self.inv_mass, h)

        def positions(self):
            return self.x.to_numpy()

    return {"field": FieldCloth, "ndarray": NdarrayCloth}


def step_size(n: int) -> float:
    """The step (s) for an n x n cloth: its stiffest mode's frequency grows as n (the mass per
    point falls as 1 / n^2), so the step shrinks as 1 / n to stay well inside the stable limit."""
    return 1e-3 / n


def child(kind: str, sizes: list[int], steps: int, precision: str, rounds: int, out_dir: str) -> dict:
    """Run in a process of its own: time ``steps`` steps of each size on the ``kind`` side
    with parallel loops (the sizes part; positions saved as ``x_<n>.npy`` in ``out_dir``), or
    ``rounds`` rounds of both sides, with parallel and with serial loops, at each size
    (``kind`` "both": the speed part)."""
    import taichi as ti

    import taichi_sim as ts

    ts.init(precision=precision)
    real = ti.f64 if precision == "f64" else ti.f32
    dtype = np.float64 if precision == "f64" else np.float32
    vec = ti.types.vector(3, real)
    out: dict = {"sizes": [], "speed": {}}
    if kind in KINDS:
        make = step_sides(ti, real, vec, serial=False)[kind]
        for n in sizes:
            h = step_size(n)
            t0 = time.perf_counter()
            cloth = make(cloth_arrays(n, dtype))
            t1 = time.perf_counter()
            cloth.step(h)
            x = cloth.positions()
            t2 = time.perf_counter()
            for _ in range(steps - 1):
                cloth.step(h)
            x = cloth.positions()
            t3 = time.perf_counter()
            np.save(os.path.join(out_dir, f"x_{n}.npy"), x)
            out["sizes"].append({"n": n, "build": t1 - t0, "first": t2 - t1, "rest": t3 - t2})
    if kind == "both":
        classes = {loops: step_sides(ti, real, vec, serial=loops == "serial") for loops in LOOPS}
        variants = [(k, loops) for k in KINDS for loops in LOOPS]
        cloths = {v: {n: classes[v[1]][v[0]](cloth_arrays(n, dtype)) for n in sizes} for v in variants}
        batch = 50
        times: dict = {v: {n: [] for n in sizes} for v in variants}
        for r in range(rounds + 1):  # round 0 warms up
            for n in sizes:
                h = step_size(n)
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
        # every variant took the same steps from the same start: they should agree
        final = {v: {n: cloths[v][n].positions() for n in sizes} for v in variants}
        out["finite"] = all(bool(np.isfinite(x).all()) for per in final.values() for x in per.values())
        out["gap"] = max(float(np.abs(final[v][n] - final[variants[0]][n]).max())
                         for v in variants for n in sizes)
    return out


def run_child(kind, sizes, steps, precision, rounds, cache_dir, out_dir) -> dict:
    """``child`` in a fresh process whose Taichi kernel cache is ``cache_dir``; its answer comes
    back through a file in ``out_dir`` (Taichi may print to stdout as the process ends)."""
    env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=cache_dir,
               TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES=str(1 << 30))
    args = [sys.executable, __file__, "--child", kind, "--sizes", ",".join(map(str, sizes)),
            "--steps", str(steps), "--precision", precision, "--rounds", str(rounds),
            "--out-dir", out_dir]
    done = subprocess.run(args, env=env, capture_output=True, text=True)
    answer = os.path.join(out_dir, "answer.json")
    if done.returncode or not os.path.exists(answer):
        raise SystemExit(f"bench_ndarray: the {kind} run failed (exit {done.returncode}):\n"
                         f"{done.stdout[-1000:]}{done.stderr[-2000:]}")
    with open(answer) as f:
        result = json.load(f)
    os.remove(answer)
    return result


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
    p.add_argument("--out-dir", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    try:
        custom = [int(v) for v in a.sizes.split(",")] if a.sizes else []
    except ValueError:
        p.error(f"--sizes must be comma-separated integers, got {a.sizes!r}")
    if any(n < 3 for n in custom):
        p.error("--sizes: each cloth needs at least 3 points a side")
    if len(set(custom)) != len(custom):
        p.error("--sizes: each size once")
    if a.steps < 1 or a.rounds < 1:
        p.error("--steps and --rounds must be at least 1")
    if a.child:
        result = child(a.child, custom, a.steps, a.precision, a.rounds, a.out_dir)
        with open(os.path.join(a.out_dir, "answer.json"), "w") as f:
            json.dump(result, f)
        return 0
    if a.part in ("sizes", "both"):
        sizes = custom or list(SIZE_SWEEP)
        print(f"## One program, scenes of {len(sizes)} sizes one after the other ({a.precision}, "
              f"{a.steps} steps each): seconds")
        print()
        print("| side | kernel cache | build (all) | first steps (all) | other steps (all) | "
              "cache entries after | total |")
        print("|---|---|---|---|---|---|---|")
        with tempfile.TemporaryDirectory(prefix="bench_ndarray_") as work:
            runs = (("empty", sizes), ("warm", sizes), ("warm, sizes reversed", sizes[::-1]))
            for kind in KINDS:
                cache = os.path.join(work, f"cache_{kind}")
                for i, (label, order) in enumerate(runs):
                    out_dir = os.path.join(work, f"{kind}_{i}")
                    os.makedirs(out_dir)
                    rows = run_child(kind, order, a.steps, a.precision, a.rounds, cache, out_dir)["sizes"]
                    build = sum(r["build"] for r in rows)
                    first = sum(r["first"] for r in rows)
                    rest = sum(r["rest"] for r in rows)
                    print(f"| {kind} | {label} | {build:.2f} | {first:.2f} | {rest:.3f} | "
                          f"{cache_entries(cache)} | {build + first + rest:.2f} |", flush=True)
            gap = max(float(np.abs(np.load(os.path.join(work, f"field_{i}", f"x_{n}.npy"))
                                   - np.load(os.path.join(work, f"ndarray_{i}", f"x_{n}.npy"))).max())
                      for i in range(len(runs)) for n in sizes)
        print()
        print(f"The two sides' positions after the steps differ by at most {gap:.1e} m (each "
              "run, each size).")
        print()
    if a.part in ("speed", "both"):
        sizes = custom or list(SPEED_SIZES)
        with tempfile.TemporaryDirectory(prefix="bench_ndarray_speed_") as work:
            result = run_child("both", sizes, a.steps, a.precision, a.rounds, work, work)
        if not result["finite"]:
            raise SystemExit("bench_ndarray: a cloth of the speed part diverged (non-finite "
                             "positions); its times would not be a step's")
        speed = result["speed"]
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
        print()
        print(f"Every cloth stayed finite; the four variants' positions differ by at most "
              f"{result['gap']:.1e} m.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
