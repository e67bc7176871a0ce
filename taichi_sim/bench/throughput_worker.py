"""One throughput worker: ``python -m taichi_sim.bench.throughput_worker SPEC_JSON``.

Runs in its own process so that each precision gets its own ``ti.init`` and each grid size
its own memory. SPEC_JSON keys: precision ("f32" | "f64"), size (grid side n: an n x n cloth),
dt (s), batch_seconds (target length of a timed batch), max_step_seconds (above this a batch
is one step), arch ("cpu" | "gpu"), and:

* ``mode: "sweep"`` (default): ``integrators`` (names), ``repeats``, ``features`` (bool).
  Every integrator on the ``cloth`` scene (and, with features, symplectic Euler on the cloth
  with each extra switched on or off) is compiled and warmed up, then timed in ``repeats``
  rounds, one batch of each configuration per round, so that load changes on the machine hit
  all of them alike. One ``@@ {json}`` line per configuration (and ``@@ {"tick": ...}`` lines
  while warming up, for the progress bar).
* ``mode: "serve"``: ``integrator``: one configuration, served batch by batch
  (:mod:`taichi_sim.bench.protocol`) so the driver can alternate it with the peers. Options:
  ``path: "general"`` builds the cloth on the general spring-list path instead of the grid
  stencil; ``loop: "run"`` times each batch through :func:`taichi_sim.run` as ``simulate``
  calls it (default energy sampling, guard, no progress bar on a pipe) instead of the bare loop.
* ``mode: "profile"``: ``integrators``, ``steps``: Taichi's kernel profiler over ``steps``
  steps of each (after a warm-up), one ``@@`` record per kernel: name, launches, total and
  mean time. The profiler adds to every launch, so these runs are not the timed ones.
"""
import json
import statistics
import sys
import time

from taichi_sim.bench.protocol import emit, serve

from ..scene.cloth import fixed_particle_cloth

# name, extra parameters (or a function of the grid side n that gives them): the same cloth
# with one feature switched on (or off)
FEATURE_VARIANTS = (
    ("cloth", {}),
    ("cloth, no dashpots", {"damping": 0.0}),
    ("cloth + wind", {"wind": True}),
    ("cloth + sphere", {"sphere": True}),
    ("cloth + tearing", {"tear": True}),
    ("cloth + wind + sphere + tearing", {"wind": True, "sphere": True, "tear": True}),
    # thickness half the grid spacing: the stage refuses one at or above spacing / sqrt(2)
    ("cloth + self-collision", lambda n: {"self_collision": True, "thickness": 0.5 / max(n - 1, 1)}),
)


class Timed:
    """One (scene, integrator) configuration: compiled and warmed up at construction; each
    :meth:`batch` times ``steps`` steps (plus the scene's post-step events) from the initial
    state."""

    def __init__(self, scene, integrator, *, dt: float, batch_seconds: float, max_step_seconds: float,
                 through_run: bool = False):
        import taichi as ti

        self.ti, self.scene, self.integrator, self.dt = ti, scene, integrator, dt
        from taichi_sim.stepper import Stepper

        self.through_run = through_run
        self.f_evals = self.linear = self.steps_done = 0
        self.worst = "ok"
        scene.reset()
        # The steps every run takes: post-step events, the blow-up guard (a check every 100 units
        # of work) and their costs are part of a step's cost.
        self.stepper = Stepper(scene, integrator, dt, raise_work=False)  # the method at its settings
        start = time.perf_counter()
        self._advance(1)  # compiles
        self.first = time.perf_counter() - start
        if through_run:  # and the run loop's own kernels (its guard's check, the snapshot)
            import taichi_sim as ts

            ts.run(scene, integrator, dt=dt, steps=2, progress=False, raise_work=False)
            scene.reset()
        start = time.perf_counter()
        self._advance(1)
        one = time.perf_counter() - start
        self.steps = 1 if one > max_step_seconds else max(1, min(2000, int(batch_seconds / max(one, 1e-7))))
        self.warm = (self.f_evals / 2, self.linear / 2)  # per step, until batches say more
        self.f_evals = self.linear = self.steps_done = 0
        self.samples: list[float] = []

    def _advance(self, steps: int) -> None:
        stepper, left = self.stepper, steps
        while left > 0:
            f_evals, linear = stepper.f_evals, stepper.linear_iterations
            left -= stepper.run_until(max_calls=left)
            self.f_evals += stepper.f_evals - f_evals
            self.linear += stepper.linear_iterations - linear
            if stepper.failure is not None:
                # noted in the record's status; the batch goes on from the start so that it
                # still times as many steps as it says
                self.worst = stepper.status.value
                self.scene.reset()
                stepper.restart()
        self.ti.sync()
        self.steps_done += steps

    def batch(self) -> dict:
        self.scene.reset()
        self.stepper.restart()
        # checks every check_work units, as in a long run (a restart starts the 1, 2, 4, ...
        # schedule again, which would weigh on short batches); run() batches keep theirs
        self.stepper.guard.interval = self.stepper.guard.limits.check_work
        start = time.perf_counter()
        if self.through_run:
            import taichi_sim as ts

            result = ts.run(self.scene, self.integrator, dt=self.dt, steps=self.steps, progress=False,
                            raise_work=False)
            self.ti.sync()
            self.steps_done += self.steps
            self.f_evals += result.f_evals
            if result.status is not ts.Status.OK:
                self.worst = result.status.value
        else:
            self._advance(self.steps)
        step_s = (time.perf_counter() - start) / self.steps
        self.samples.append(step_s)
        return {"step_s": step_s}

    def info(self) -> dict:
        n = self.scene.particle_count
        springs = int(self.scene.features.get("springs", 0))
        if self.steps_done:
            per_step, linear = self.f_evals / self.steps_done, self.linear / self.steps_done
        else:
            per_step, linear = self.warm
        return {"particles": n, "springs": springs, "f_evals_per_step": per_step,
                "linear_iterations_per_step": linear,
                "first_step_s": self.first, "batch_steps": self.steps}

    def record(self) -> dict:
        info = self.info()
        step_s = statistics.median(self.samples)
        return {**info, "step_s": step_s, "step_min_s": min(self.samples), "step_max_s": max(self.samples),
                "particle_steps_per_s": info["particles"] / step_s,
                "spring_evals_per_s": info["springs"] * info["f_evals_per_step"] / step_s,
                "repeats": len(self.samples), "status": self.worst}


def fixed_particles(n: int) -> dict:
    """The n x n cloth this study times: 0.01 kg and 0.005 N s/m a particle at every n (as every
    grid cloth had before its mass became per area), so a step it takes is stable at any n."""
    return {"nx": n, "ny": n, **fixed_particle_cloth(n, n)}


def _error(exc: Exception) -> str:
    return f"{type(exc).__name__}: {exc}".strip().splitlines()[0][:300]


def profile(scene, names: list[str], *, dt: float, steps: int) -> list[dict]:
    """Per-kernel times of ``steps`` steps of each integrator (the runtime was initialised with
    the kernel profiler), taken by a bare :class:`~taichi_sim.stepper.Stepper`: the method's own
    kernels and the scene's events, without the guard's or the convergence samples'."""
    import taichi as ti

    import taichi_sim as ts
    from taichi_sim.stepper import Stepper

    records = []
    for name in names:
        scene.reset()
        stepper = Stepper(scene, ts.create_integrator(name, scene.system), dt, bare=True)
        stepper.run_until(max_calls=3)  # compiles
        ti.sync()
        ti.profiler.clear_kernel_profiler_info()
        start = time.perf_counter()
        calls = stepper.run_until(max_calls=steps)  # fewer when a step failed (its status says)
        ti.sync()
        wall = (time.perf_counter() - start) / max(calls, 1)
        for r in _kernel_totals():
            records.append({"kind": "kernel", "integrator": name, "wall_step_s": wall, "steps": calls,
                            "status": stepper.status.value, **r})
    return records


def _kernel_totals() -> list[dict]:
    """Taichi's profiler records by offloaded loop: kernel name (Taichi's per-compilation suffix
    dropped) and loop index, launches, total s, mean s per launch. Taichi 1.7 has no public
    accessor for the per-kernel statistics it prints, so this reads its profiler object."""
    import re

    from taichi.profiler import kernel_profiler

    profiler = kernel_profiler.get_default_kernel_profiler()
    profiler._update_records()  # noqa: SLF001
    profiler._count_statistics()  # noqa: SLF001
    totals: dict[str, list] = {}  # a kernel compiled for several arguments: one entry
    for name, result in profiler._statistical_results.items():  # noqa: SLF001
        match = re.match(r"^(.*?)_c\d+_\d+_kernel_(\d+)_(\w+)$", name)
        label = f"{match.group(1)} loop {match.group(2)}" if match else name
        entry = totals.setdefault(label, [0, 0.0])
        entry[0] += result.counter
        entry[1] += result.total_time / 1e3  # ms -> s
    return [{"kernel": k, "launches": c, "total_s": t, "mean_s": t / max(c, 1)}
            for k, (c, t) in sorted(totals.items(), key=lambda item: -item[1][1])]


def main(argv=None) -> int:
    spec = json.loads((argv or sys.argv[1:])[0])
    import taichi_sim as ts
    from taichi_sim.scene.builder import general_paths

    mode = spec.get("mode", "sweep")
    ts.init(arch=spec.get("arch", "cpu"), precision=spec["precision"], kernel_profiler=mode == "profile")
    n = int(spec["size"])
    base = {"precision": spec["precision"], "n": n, "dt": spec["dt"], "backend": ts.runtime.backend()}
    timing = {k: spec[k] for k in ("dt", "batch_seconds", "max_step_seconds")}
    start = time.perf_counter()
    if spec.get("path") == "general":
        with general_paths():
            scene = ts.build_scene("cloth", fixed_particles(n))
    else:
        scene = ts.build_scene("cloth", fixed_particles(n))
    build = time.perf_counter() - start

    if mode == "profile":
        for record in profile(scene, spec["integrators"], dt=spec["dt"], steps=int(spec["steps"])):
            emit({**base, **record})
        emit({"done": True})
        return 0
    if mode == "serve":
        name = spec["integrator"]
        label = spec.get("label", name)
        try:
            timed = Timed(scene, ts.create_integrator(name, scene.system), **timing,
                          through_run=spec.get("loop") == "run")
        except Exception as exc:
            emit({**base, "kind": "ours", "name": label, "status": "error", "note": _error(exc)})
            return 0
        serve({**base, "kind": "ours", "name": label, "build_s": build, **timed.info(), "status": "ok"}, timed.batch)
        return 0

    configs = []  # (record, Timed or None)
    for name in spec["integrators"]:
        record = {**base, "kind": "ours", "name": name, "build_s": build}
        try:
            configs.append((record, Timed(scene, ts.create_integrator(name, scene.system), **timing)))
        except Exception as exc:  # keep measuring the others
            configs.append(({**record, "status": "error", "note": _error(exc)}, None))
        emit({"tick": name})
    if spec.get("features"):
        for label, extra in FEATURE_VARIANTS:
            record = {**base, "kind": "feature", "name": label, "integrator": "symplectic_euler"}
            try:
                start = time.perf_counter()
                if callable(extra):  # parameters that depend on the grid side
                    extra = extra(n)
                variant = ts.build_scene("cloth", {**fixed_particles(n), **extra})
                record["build_s"] = time.perf_counter() - start
                record["features"] = {k: v for k, v in variant.features.items() if v}
                configs.append((record, Timed(variant, ts.create_integrator("symplectic_euler", variant.system),
                                              **timing)))
            except Exception as exc:
                configs.append(({**record, "status": "error", "note": _error(exc)}, None))
            emit({"tick": label})
    for _ in range(int(spec["repeats"])):  # interleaved: one batch of each per round
        for record, timed in configs:
            if timed is not None and "note" not in record:
                try:
                    timed.batch()
                except Exception as exc:
                    record.update(status="error", note=_error(exc))
    for record, timed in configs:
        if timed is not None and "note" not in record:
            record.update(timed.record())
        emit(record)
    emit({"done": True})
    return 0


if __name__ == "__main__":
    sys.exit(main())
