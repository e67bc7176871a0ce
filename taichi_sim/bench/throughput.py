"""Throughput: particle-steps per second against grid size, integrator, precision and features,
with the peers timed in the same run.

Every measurement runs in a subprocess (one per precision and grid size:
:mod:`.throughput_worker`; one per peer and grid size: :mod:`.peer_taichi`, :mod:`.peer_warp`),
so each precision gets its own ``ti.init``, memory is returned between sizes, and the Taichi
example's own ``ti.init`` at import stays out of ours. The machine may be shared, so nothing is
timed in one long stretch: the integrators (and feature variants) of one worker are timed in
rounds, one batch each per round; and for the head-to-head, our symplectic Euler and the peers
run as served processes (:mod:`.protocol`) whose batches the driver alternates. Ratios to the
peers come from that duel (kind ``duel``); the rk4 / symplectic Euler ratio from the sweep. Ours: the ``cloth`` scene (structural,
shear and flex springs: the 12-neighbour set, with dashpots, gravity and drag; two corners
pinned), ``integrator.step`` in a loop with the scene's post-step events, from the initial state
in each batch. Reported per configuration: the median over ``repeats`` batches of the time per
step (each batch about ``batch_seconds`` long, after a first step that compiles, reported
separately as ``first_step_s``), particle-steps per second (n^2 particles, pinned ones
included, as the peers count them) and spring evaluations per second (each spring counted once
per force evaluation, for us and the peers alike; our grid stencil and warp compute each spring
once, the Taichi example from both ends).

Besides, unless ``--quick``: the same symplectic Euler on the general spring-list path and
through :func:`taichi_sim.run` (what ``simulate`` calls) join the alternated batches (the
stencil's gain and the run loop's overhead); at one size (128 by default) Taichi's kernel
profiler gives each kernel loop's time for symplectic Euler and rk4, and the command line is
timed as a whole process with two step counts (the difference takes out start-up and
saving); and ``taichi-sim simulate cloth --steps 1`` is timed from process start, with an
empty and with a warm Taichi kernel cache.
"""
from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace

from .common import memory_bytes
from .throughput_worker import fixed_particles

BYTES_PER_PARTICLE = 4096  # generous: state, scratch of the largest method, 6 springs each, incidence


@dataclass(frozen=True)
class ThroughputConfig:
    sizes: tuple[int, ...]
    precisions: tuple[str, ...]
    integrators: tuple[str, ...]
    dt: float = 1e-4
    repeats: int = 7
    batch_seconds: float = 0.25
    max_step_seconds: float = 2.0
    features_size: int | None = 128
    peers: bool = True
    peer_precisions: tuple[str, ...] = ("f32", "f64")
    worker_timeout_s: float = 3600.0
    cli_size: int | None = 128  # grid side of the command-line measurement (None: skip it)
    cli_steps: int = 3000
    profile_size: int | None = 128  # grid side of the per-kernel profile (None: skip it)
    start_up: bool = True  # time `simulate cloth --steps 1` from process start
    variants: bool = True  # also duel the general spring-list path and run() (see VARIANTS)


def _run_streaming(module: str, args: list[str], *, timeout: float, on_record=None) -> tuple[list[dict], str | None]:
    """Run ``python -m module args``; collect its ``@@ {json}`` records (``tick`` records only
    call ``on_record``). Returns (records, error or None)."""
    from .protocol import MARK, child_env

    records: list[dict] = []
    with tempfile.TemporaryFile(mode="w+") as errors:
        proc = subprocess.Popen([sys.executable, "-m", module, *args], stdout=subprocess.PIPE,
                                stderr=errors, text=True, env=child_env())
        try:
            for line in proc.stdout:
                if line.startswith(MARK):
                    record = json.loads(line[len(MARK):])
                    if record.get("done"):
                        continue
                    if on_record is not None:
                        on_record(record)
                    if "tick" not in record:
                        records.append(record)
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            return records, f"timed out after {timeout:g} s"
        if proc.returncode != 0:
            errors.seek(0)
            tail = [line for line in errors.read().strip().splitlines() if line.strip()][-1:] or ["?"]
            return records, f"exit status {proc.returncode}: {tail[0][:300]}"
    return records, None


def duel(contenders: list[tuple[str, list[str], dict]], repeats: int) -> list[dict]:
    """Time served contenders ((module, args, base record) each) batch by batch in turn, for
    ``repeats`` rounds: one record each, with the median of its batches."""
    from .protocol import Served

    served, records = [], []
    for module, args, base in contenders:
        child = Served(module, args)
        try:
            ready = child.start()
        except RuntimeError as exc:
            records.append({**base, "status": "unavailable", "note": str(exc)})
            child.close()
            continue
        ready.pop("ready", None)
        ready["kind"] = base["kind"]
        if ready.get("status") != "ok":
            records.append({**base, **ready})
            child.close()
            continue
        served.append((child, ready, []))
    try:
        for _ in range(repeats):
            for child, ready, samples in served:
                if ready.get("status") == "ok":
                    try:
                        samples.append(child.batch()["step_s"])
                    except RuntimeError as exc:
                        ready.update(status="error", note=str(exc))
    finally:
        for child, _, _ in served:
            child.close()
    for _, ready, samples in served:
        if samples and ready.get("status") == "ok":
            step_s = statistics.median(samples)
            records.append({**ready, "step_s": step_s, "step_min_s": min(samples), "step_max_s": max(samples),
                            "particle_steps_per_s": ready["particles"] / step_s,
                            "spring_evals_per_s": ready["springs"] * ready.get("f_evals_per_step", 1.0) / step_s,
                            "repeats": len(samples)})
        else:
            records.append(ready)
    return records


def _simulate_seconds(args: list[str], env: dict | None = None, timeout: float = 600.0) -> float:
    """Wall seconds of one ``taichi-sim simulate`` process, start to exit; RuntimeError if it fails."""
    from .protocol import child_env

    with tempfile.TemporaryDirectory() as folder:
        command = [sys.executable, "-m", "taichi_sim", "simulate", *args, "--out", f"{folder}/run.npz", "--quiet"]
        start = time.perf_counter()
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, env=env or child_env())
        wall = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError((done.stderr.strip().splitlines() or ["?"])[-1][:300])
    return wall


def measure_cli(precision: str, n: int, dt: float, steps: int, repeats: int) -> dict:
    """Seconds per step through the command line: ``simulate`` with ``steps`` and with 10 steps,
    alternated ``repeats`` times; the difference of the medians over the difference of the step
    counts takes out start-up and saving."""
    fixed = fixed_particles(n)  # the cloth the worker times
    base = ["cloth", "--set", f"nx={n}", "--set", f"ny={n}", "--set", f"density={fixed['density']!r}",
            "--set", f"area_drag={fixed['area_drag']!r}", "--integrator", "symplectic_euler",
            "--dt", repr(dt), "--precision", precision]
    short, long = [], []
    try:
        _simulate_seconds(base + ["--steps", "10"])  # fills the kernel cache
        for _ in range(repeats):
            short.append(_simulate_seconds(base + ["--steps", "10"]))
            long.append(_simulate_seconds(base + ["--steps", str(10 + steps)]))
    except (RuntimeError, subprocess.TimeoutExpired) as exc:
        return {"kind": "cli", "name": "taichi-sim simulate", "precision": precision, "n": n, "status": "error",
                "note": str(exc)}
    step_s = (statistics.median(long) - statistics.median(short)) / steps
    return {"kind": "cli", "name": "taichi-sim simulate", "precision": precision, "n": n, "status": "ok",
            "step_s": step_s, "particle_steps_per_s": n * n / step_s, "steps": steps, "repeats": repeats,
            "short_s": statistics.median(short), "long_s": statistics.median(long)}


def measure_start(precision: str, repeats: int = 3) -> dict:
    """Process start to exit of ``taichi-sim simulate cloth --steps 1`` (the default cloth and
    integrator), the median of ``repeats`` runs each way, alternated: with an empty Taichi
    kernel cache (a new folder each time: every kernel compiled) and with a warm one (filled by
    the run before; the process writes it at exit)."""
    from .protocol import child_env

    args = ["cloth", "--steps", "1", "--precision", precision]
    record = {"kind": "start", "name": "simulate cloth --steps 1", "precision": precision}
    cold, warm = [], []
    with tempfile.TemporaryDirectory() as folder:
        warm_env = {**child_env(), "TI_OFFLINE_CACHE_FILE_PATH": f"{folder}/warm"}
        try:
            _simulate_seconds(args, warm_env)
            for k in range(repeats):
                warm.append(_simulate_seconds(args, warm_env))
                cold.append(_simulate_seconds(args, {**child_env(), "TI_OFFLINE_CACHE_FILE_PATH": f"{folder}/cold{k}"}))
        except (RuntimeError, subprocess.TimeoutExpired) as exc:
            return {**record, "status": "error", "note": str(exc)}
    return {**record, "status": "ok", "cold_s": statistics.median(cold), "warm_s": statistics.median(warm)}


def fits_in_memory(n: int) -> bool:
    available = memory_bytes("MemAvailable")
    return available is None or n * n * BYTES_PER_PARTICLE < 0.5 * available


# Our served contenders besides the plain one: the same symplectic Euler on the general
# spring-list path (what the grid stencil saves), and through run() as `simulate` calls it
# (what the run loop's energy samples, checks and bookkeeping cost).
VARIANTS = (
    ("symplectic_euler", {}),
    ("symplectic_euler, general path", {"path": "general"}),
    ("symplectic_euler via run()", {"loop": "run", "batch_factor": 4}),
)


def _contenders(config: ThroughputConfig, precision: str, n: int) -> list[tuple[str, list[str], dict]]:
    """Ours (symplectic Euler, served, in its variants) and the peers that apply to this precision."""
    timing = ["--n", str(n), "--batch-seconds", str(config.batch_seconds), "--serve"]
    out = []
    for label, extra in VARIANTS if config.variants else VARIANTS[:1]:
        # run() sets up its guard at each call (about 10 ms at 128 x 128): its batches are longer,
        # as a real run is, so that what is compared is the cost per step
        extra = dict(extra)
        factor = extra.pop("batch_factor", 1)
        spec = {"mode": "serve", "precision": precision, "size": n, "integrator": "symplectic_euler",
                "label": label, "dt": config.dt, "batch_seconds": factor * config.batch_seconds,
                "max_step_seconds": config.max_step_seconds, **extra}
        out.append(("taichi_sim.bench.throughput_worker", [json.dumps(spec)],
                    {"kind": "duel", "name": label, "precision": precision, "n": n}))
    if precision in config.peer_precisions:
        out.append(("taichi_sim.bench.peer_taichi", timing + ["--precision", precision],
                    {"kind": "peer", "name": "taichi example", "precision": precision, "n": n}))
    if precision == "f32":
        out.append(("taichi_sim.bench.peer_warp", timing,
                    {"kind": "peer", "name": "warp benchmark_cloth", "precision": precision, "n": n}))
    return out


def task_count(config: ThroughputConfig) -> int:
    from .throughput_worker import FEATURE_VARIANTS

    total = 0
    for precision in config.precisions:
        for n in config.sizes:
            total += len(config.integrators)
            if n == config.features_size:
                total += len(FEATURE_VARIANTS)
            if config.peers:
                total += len(_contenders(config, precision, n))
            total += (n == config.cli_size) + (n == config.profile_size)
    return total + bool(config.start_up)


def run_throughput(config: ThroughputConfig, progress=None) -> tuple[list[dict], dict]:
    """All measurements of ``config`` (module docstring). Returns (rows, details)."""
    from .throughput_worker import FEATURE_VARIANTS

    rows: list[dict] = []

    def tick(_record=None):
        if progress is not None:
            progress.update(1)

    for precision in config.precisions:
        for n in config.sizes:
            features = n == config.features_size
            if not fits_in_memory(n):
                for name in config.integrators:
                    rows.append({"kind": "ours", "name": name, "precision": precision, "n": n,
                                 "status": "skipped", "note": "not enough memory"})
                for _ in range(task_count(replace(config, precisions=(precision,), sizes=(n,)))):
                    tick()
                continue
            spec = {"mode": "sweep", "precision": precision, "size": n, "integrators": list(config.integrators),
                    "dt": config.dt, "repeats": config.repeats, "batch_seconds": config.batch_seconds,
                    "max_step_seconds": config.max_step_seconds, "features": features}
            ticks = []
            records, error = _run_streaming("taichi_sim.bench.throughput_worker", [json.dumps(spec)],
                                            timeout=config.worker_timeout_s,
                                            on_record=lambda r: (ticks.append(1), tick()) if "tick" in r else None)
            rows.extend(records)
            if error is not None:
                done = {r["name"] for r in records if r.get("kind") == "ours"}
                for name in config.integrators:
                    if name not in done:
                        rows.append({"kind": "ours", "name": name, "precision": precision, "n": n,
                                     "status": "error", "note": error})
                for _ in range(len(config.integrators) + (len(FEATURE_VARIANTS) if features else 0) - len(ticks)):
                    tick()
            if config.peers:
                contenders = _contenders(config, precision, n)
                rows.extend(duel(contenders, config.repeats))
                for _ in contenders:
                    tick()
            if n == config.profile_size:
                spec = {"mode": "profile", "precision": precision, "size": n, "dt": config.dt,
                        "integrators": [name for name in ("symplectic_euler", "rk4") if name in config.integrators],
                        "steps": 300, "batch_seconds": config.batch_seconds, "max_step_seconds": config.max_step_seconds}
                records, error = _run_streaming("taichi_sim.bench.throughput_worker", [json.dumps(spec)],
                                                timeout=config.worker_timeout_s)
                rows.extend(records)
                if error is not None:
                    rows.append({"kind": "kernel", "precision": precision, "n": n, "status": "error", "note": error})
                tick()
            if n == config.cli_size:
                rows.append(measure_cli(precision, n, config.dt, config.cli_steps, max(3, config.repeats // 2)))
                tick()
    if config.start_up:
        rows.append(measure_start(config.precisions[0]))
        tick()
    summary = summarize(rows)
    return rows, {"summary": summary, "targets": check_targets(summary)}


def summarize(rows: list[dict]) -> list[dict]:
    """Per (precision, n): our symplectic Euler against each peer, and rk4's cost per step
    relative to symplectic Euler's."""
    def ok(r):
        return r.get("status") == "ok" and r.get("step_s")

    out = []
    keys = sorted({(r["precision"], r["n"]) for r in rows if "n" in r}, key=lambda k: (k[0], k[1]))
    for precision, n in keys:
        same = [r for r in rows if r.get("precision") == precision and r.get("n") == n]
        ours = {r["name"]: r for r in same if r.get("kind") == "ours" and ok(r)}
        duels = {r["name"]: r for r in same if r.get("kind") == "duel" and ok(r)}
        dueled = duels.get("symplectic_euler")
        peers = {r["name"]: r for r in same if r.get("kind") == "peer"}
        entry = {"precision": precision, "n": n}
        symplectic = ours.get("symplectic_euler")
        if symplectic:
            entry["symplectic_particle_steps_per_s"] = symplectic["particle_steps_per_s"]
            entry["symplectic_spring_evals_per_s"] = symplectic["spring_evals_per_s"]
            if "rk4" in ours:
                entry["rk4_over_symplectic"] = ours["rk4"]["step_s"] / symplectic["step_s"]
        against = dueled or symplectic  # batches alternated with the peers', when they ran
        if dueled:
            entry["duel_particle_steps_per_s"] = dueled["particle_steps_per_s"]
            general = duels.get("symplectic_euler, general path")
            if general:
                entry["stencil_speedup"] = general["step_s"] / dueled["step_s"]
            through_run = duels.get("symplectic_euler via run()")
            if through_run:
                entry["run_overhead"] = through_run["step_s"] / dueled["step_s"] - 1.0
        cli = next((r for r in same if r.get("kind") == "cli" and ok(r)), None)
        if cli and (dueled or symplectic):
            entry["cli_overhead"] = cli["step_s"] / (dueled or symplectic)["step_s"] - 1.0
        for name, peer in peers.items():
            key = "taichi" if name.startswith("taichi") else "warp"
            if ok(peer):
                entry[f"{key}_particle_steps_per_s"] = peer["particle_steps_per_s"]
                if against:
                    entry[f"ratio_vs_{key}"] = against["particle_steps_per_s"] / peer["particle_steps_per_s"]
            else:
                entry[f"{key}_unavailable"] = peer.get("note", peer.get("status"))
        out.append(entry)
    return out


TARGET_PRECISION = "f32"
TARGET_SIZES = (64, 128, 256)  # where symplectic Euler should do twice the Taichi example's work
RUN_OVERHEAD = 0.05
RK4_RATIO = 4.5


def check_targets(summary: list[dict]) -> list[dict]:
    """The throughput targets, at f32: against the Taichi example (twice its particle-steps/s
    at 64, 128 and 256, 1.5 times everywhere), the run loop's overhead and rk4's cost per step
    at every size."""
    f32 = [s for s in summary if s["precision"] == TARGET_PRECISION]
    out = []
    for entry in f32:
        if "ratio_vs_taichi" in entry:
            value = entry["ratio_vs_taichi"]
            goal = 2.0 if entry["n"] in TARGET_SIZES else 1.5
            out.append({"target": f"symplectic Euler >= {goal:g} x the Taichi example's particle-steps/s "
                                  f"(f32, {entry['n']} x {entry['n']})", "value": value, "met": value >= goal})
    for entry in f32:
        if "run_overhead" in entry:
            value = entry["run_overhead"]
            out.append({"target": f"run() (the simulate path) adds <= 5 % to the bare loop (f32, {entry['n']} x "
                                  f"{entry['n']})", "value": value, "met": value <= RUN_OVERHEAD})
    for entry in f32:
        if "rk4_over_symplectic" in entry:
            value = entry["rk4_over_symplectic"]
            out.append({"target": f"rk4 time per step <= {RK4_RATIO:g} x symplectic Euler's (f32, {entry['n']} x "
                                  f"{entry['n']})", "value": value, "met": value <= RK4_RATIO})
    return out
