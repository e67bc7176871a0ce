"""Taichi runtime set-up: architecture and floating-point precision.

``import taichi_sim`` never calls ``ti.init``; :func:`init` does, explicitly. Calling it again
re-initialises Taichi, which frees every field allocated before (scenes built earlier become
unusable).
"""
from __future__ import annotations

import contextlib
import io
import os
import sys

os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")  # keep stdout for our own output

import numpy as np  # noqa: E402
import taichi as ti  # noqa: E402
from taichi.lang import impl as _taichi_impl  # noqa: E402

from . import frontend_cache
from .errors import ConfigError

ARCHS = ("cpu", "gpu")
PRECISIONS = ("f32", "f64")
COMPILE_MODES = ("optimised", "quick")
COMPILE_MODE_VARIABLE = "TAICHI_SIM_COMPILE"
"""The environment variable that sets :func:`init`'s ``compile_mode`` when the call gives none
(the test suite sets it to ``quick``, tests/conftest.py; its subprocesses inherit it)."""

_current: dict = {"arch": None, "precision": None, "backend": None, "threads": 1, "compile_mode": None}

GPU_BACKENDS = (ti.cuda, ti.metal, ti.vulkan)
"""What ``arch="gpu"`` tries, in order, before the CPU. Taichi's own ``ti.gpu`` goes on to OpenGL
after Vulkan, and probing OpenGL kills the process with a segmentation fault on a machine that
has Mesa's EGL but no Vulkan driver (a common headless Linux set-up); the package is neither
tested nor documented on OpenGL, so it is not asked."""

SERIAL_WORK = 300_000
"""Items (particles plus springs) times spare threads below which a hot loop runs on one
thread (:func:`serial_loops`). On the 2-vCPU development machine a parallel loop costs about
30-80 us of thread hand-off and gains little (the two vCPUs share one core). Measured when it
was set, a cloth's symplectic Euler step, serial against parallel: 39 against 121 us at
32 x 32 (7k items), 365 against 424 us at 128 x 128 (113k) and 794 against 824 us at 192 x 192
(256k); at 256 x 256 (456k) parallel won, 1286 against 1410 us. Since the grid's springs are
summed in a serial, vectorised pass of their own (``GridSprings.serial_pass``) they no longer
count, and a grid cloth's items are its particles: serial against parallel, 46 against 133 us
at 32 x 32, 290 against 435 at 128 x 128, 1055 against 1308 at 256 x 256 (65k particles, now
serial), and 4570 against 4168 at 512 x 512 (262k, serial: a loss of 9 % in that run, a gain
of 21 % in another) (f32, ``benchmarks/bench_serial_loops.py``, alternated rounds, medians).
Machines with more threads were not measured: that the break-even shrinks as
1 / (threads - 1) is a guess."""


def init(arch: str = "cpu", precision: str = "f64", *, debug: bool = False,
         offline_cache: bool = True, cpu_max_num_threads: int | None = None,
         kernel_profiler: bool = False, compile_mode: str | None = None) -> None:
    """Initialise Taichi for taichi_sim.

    Args:
        arch: ``"cpu"`` (LLVM x64/arm64) or ``"gpu"`` (the first of :data:`GPU_BACKENDS` that
            Taichi finds: CUDA, Metal, Vulkan; the CPU when there is none).
        precision: ``"f32"`` or ``"f64"``; the dtype of every state, parameter and scratch field.
        debug: Taichi debug mode (bounds checks; slow).
        offline_cache: keep compiled kernels on disk so the next process starts fast.
        cpu_max_num_threads: limit the CPU thread pool (default: all cores).
        kernel_profiler: record each kernel launch's time (``ti.profiler``; it adds a little
            to every launch, so leave it off except to find where time goes).
        compile_mode: ``"optimised"`` (Taichi's defaults) or ``"quick"``: Taichi's IR optimiser
            leaves out its whole-kernel common-subexpression elimination and its control-flow
            pass (Taichi's ``opt_level=0``; LLVM still optimises the code it is given). A kernel
            compiles in about two thirds of the time or less (a cloth's ``rk4`` stage: half),
            while some steps run slower and the results may differ in the last bits (the
            floating-point operations LLVM is handed differ), so runs use ``"optimised"``; the
            test suite compiles ``"quick"``, and tests/test_compile_levels.py holds the two to
            the same answers (docs/first-contact.md, "The suite's time"). None: the
            :data:`COMPILE_MODE_VARIABLE` environment variable, else ``"optimised"``. Compiled
            kernels are cached per mode.
    """
    if arch not in ARCHS:
        raise ConfigError(f"arch must be one of {', '.join(ARCHS)}, got {arch!r}")
    if precision not in PRECISIONS:
        raise ConfigError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if compile_mode is None:
        compile_mode = os.environ.get(COMPILE_MODE_VARIABLE) or "optimised"
        if compile_mode not in COMPILE_MODES:
            raise ConfigError(f"{COMPILE_MODE_VARIABLE} must be one of {', '.join(COMPILE_MODES)}, "
                              f"got {compile_mode!r}")
    elif compile_mode not in COMPILE_MODES:
        raise ConfigError(f"compile_mode must be one of {', '.join(COMPILE_MODES)}, got {compile_mode!r}")
    kwargs = dict(arch=ti.cpu if arch == "cpu" else list(GPU_BACKENDS),
                  default_fp=ti.f64 if precision == "f64" else ti.f32,
                  default_ip=ti.i32, debug=debug, offline_cache=offline_cache,
                  log_level=ti.WARN, kernel_profiler=kernel_profiler)
    if compile_mode == "quick":
        kwargs["opt_level"] = 0
    if cpu_max_num_threads is not None:
        kwargs["cpu_max_num_threads"] = int(cpu_max_num_threads)
    frontend_cache.install()
    log = ""
    _quiet_cache_locks()  # ti.init first resets the program before, which writes the cache
    with contextlib.redirect_stdout(io.StringIO()):  # ti.init prints "Starting on arch=..."
        if arch == "gpu":
            # Taichi's own log says why CUDA was skipped and which Vulkan device was found, in raw
            # "[W ...] [cuda_driver.cpp:...]" lines; read them and say it in one line instead.
            kwargs["log_level"] = ti.TRACE
            with _capture_fd2() as captured:
                try:
                    ti.init(**kwargs)
                finally:
                    ti.set_logging_level(ti.WARN)
            log = captured.text
        else:
            ti.init(**kwargs)
    chosen = str(ti.lang.impl.current_cfg().arch).split(".")[-1]
    if offline_cache:
        _write_kernel_cache_at_exit()
    if arch == "gpu":
        print(f"taichi_sim: --arch gpu: {describe_gpu_choice(chosen, log)}", file=sys.stderr)
    threads = int(cpu_max_num_threads) if cpu_max_num_threads is not None else usable_cpus()
    _current.update(arch=arch, precision=precision, backend=chosen, threads=max(1, threads),
                    compile_mode=compile_mode)


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one, e.g. a container
    limited to 2 of a host's 64; else the machine's count): what a parallel loop can gain."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def cpu_backend() -> bool:
    """Whether Taichi runs kernels on the CPU (LLVM x64 or arm64)."""
    return _current["backend"] in ("x64", "arm64")


def serial_loops(items: int, break_even: int | None = None) -> bool:
    """Whether a loop over ``items`` (with work about the same per item) should run on one
    thread: only on a CPU backend, and only when ``items`` times the spare threads is below
    ``break_even`` (default :data:`SERIAL_WORK`). On a GPU a serial loop is one GPU thread:
    never."""
    if not cpu_backend():
        return False
    limit = SERIAL_WORK if break_even is None else break_even
    return _current["threads"] <= 1 or items * (_current["threads"] - 1) < limit


class _WithoutCfgOptimisation:
    """The context manager :func:`without_cfg_optimisation` returns (one, nestable)."""

    def __init__(self):
        self.depth = 0
        self.config = None
        self.was = True

    def __enter__(self):
        if self.depth == 0:
            program = _taichi_impl.get_runtime().prog
            if program is not None:
                self.config = program.config()
                self.was = self.config.cfg_optimization
                self.config.cfg_optimization = False
        self.depth += 1
        return self

    def __exit__(self, *exc):
        self.depth -= 1
        if self.depth == 0 and self.config is not None:
            self.config.cfg_optimization = self.was
            self.config = None
        return False


_WITHOUT_CFG = _WithoutCfgOptimisation()


def without_cfg_optimisation() -> _WithoutCfgOptimisation:
    """A block in which kernels launched for the first time compile without Taichi's
    control-flow-graph optimisation (store-to-load forwarding and dead-store elimination over
    the whole kernel).

    That pass grows faster than the kernel: in the large, branchy kernels of the self-contact
    stage and of the objects' face contact it is half of the compile, and LLVM's optimisation,
    which runs after it in any case, leaves their code as fast without it. Elsewhere it stays on:
    some methods step faster with it (``vbd`` in every round of the benchmark of every method;
    docs/design.md, "Compile time"). A kernel already compiled keeps its code; the setting
    is part of Taichi's cache key, so a cached kernel is never taken for the other kind. Entering
    and leaving costs a few microseconds, so it wraps a whole stage, not each launch."""
    return _WITHOUT_CFG


_AT_EXIT = {"registered": False}


def _write_kernel_cache_at_exit() -> None:
    """Make Taichi write its offline kernel cache when the process ends.

    Taichi 1.7 writes the cache when a program is reset (another ``ti.init``, ``ti.reset``),
    not when the interpreter exits, so a process that initialises once (``simulate``,
    ``record``, the launcher) compiled every kernel afresh every time: about a second of its
    start-up. Resetting at exit writes what this process compiled; the next start loads it."""
    if _AT_EXIT["registered"]:
        return
    import atexit

    def reset():
        _quiet_cache_locks()
        try:
            ti.reset()
        except Exception:  # noqa: BLE001 - a failure to cache must not fail the exit
            pass

    atexit.register(reset)
    _AT_EXIT["registered"] = True


def _quiet_cache_locks() -> None:
    """Keep Taichi's warnings about its cache's lock off stderr while a program is reset.

    Resetting a program writes the kernels it compiled into the offline cache and trims the
    cache, each under a lock file that Taichi tries for 0.2 s; where another process holds it
    (a test worker exiting at the same moment, another command on a loaded machine) Taichi
    gives up and prints "[W ...] Lock .../ticache.lock failed. ... try again." once for each.
    Nothing is lost but this process's new entries (they compile again next time), and the line
    came after the command's own last line or after pytest's summary. Only errors are printed
    until the next :func:`init` sets the level again."""
    ti.set_logging_level(ti.ERROR)


class _Captured:
    text = ""


@contextlib.contextmanager
def _capture_fd2():
    """Collect what is written to file descriptor 2 (Taichi's C++ logger writes there) into
    ``.text``; on an exception the collected text is written back, so no error is lost."""
    import tempfile

    captured = _Captured()
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as sink:
        os.dup2(sink.fileno(), 2)
        failed = False
        try:
            yield captured
        except BaseException:
            failed = True
            raise
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            captured.text = sink.read().decode(errors="replace")
            if failed:
                sys.stderr.write(captured.text)


_SOFTWARE_VULKAN = ("llvmpipe", "lavapipe", "swiftshader", "software")


def describe_gpu_choice(backend: str, log: str) -> str:
    """One line saying which backend ``--arch gpu`` got and why, from Taichi's init ``log``
    (its trace of CUDA loading and of the Vulkan devices found)."""
    reasons = []
    if "libcuda.so" in log and "not found" in log:
        reasons.append("no CUDA driver (libcuda.so not found)")
    device = None
    for line in log.splitlines():
        if "Found Vulkan Device" in line and "(" in line:
            device = line.split("Found Vulkan Device", 1)[1].split("(", 1)[1].rsplit(")", 1)[0].strip()
            break
    why = f"{'; '.join(reasons)}; " if reasons and backend != "cuda" else ""
    if backend == "cuda":
        return "running on CUDA"
    if backend == "vulkan":
        if device and any(name in device.lower() for name in _SOFTWARE_VULKAN):
            return (f"{why}running on Vulkan with a software device, {device}: it computes on the CPU, "
                    "usually slower than --arch cpu")
        return f"{why}running on Vulkan" + (f" ({device})" if device else "")
    if backend in ("x64", "arm64"):
        return f"{why}no GPU backend available, running on the CPU ({backend})"
    return f"{why}running on {backend}"


def is_initialized() -> bool:
    return _current["precision"] is not None


def precision() -> str:
    """The precision passed to the last :func:`init` (``"f32"`` or ``"f64"``)."""
    _require_init()
    return _current["precision"]


def arch() -> str:
    """The arch asked for (``"cpu"`` or ``"gpu"``)."""
    _require_init()
    return _current["arch"]


def backend() -> str:
    """The Taichi backend actually running (``"x64"``, ``"cuda"``, ``"vulkan"``, ...)."""
    _require_init()
    return _current["backend"]


def real():
    """The Taichi float dtype of the current precision."""
    return ti.f64 if precision() == "f64" else ti.f32


def np_real():
    """The numpy float dtype of the current precision."""
    return np.float64 if precision() == "f64" else np.float32


def epsilon() -> float:
    """The current precision's machine epsilon (the spacing of its floats just above 1)."""
    return float(np.finfo(np_real()).eps)


def machine_epsilon() -> float:
    """Unit round-off scale of the current precision: numpy's eps of its float dtype."""
    return float(np.finfo(np_real()).eps)


def _require_init() -> None:
    if _current["precision"] is None:
        raise RuntimeError("call taichi_sim.init(arch=..., precision=...) before building scenes")
