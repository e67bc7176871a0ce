"""The two ways to run many cases: N worker processes on this machine, or a Dask cluster.
Both call :func:`.worker.execute` for each case and yield ``(case, outcome, concurrency)`` as
cases end; ``concurrency`` is how many cases were running at once while this one ran (on a
cluster: the cluster's worker threads, an upper bound, since the driver cannot watch them)."""
from __future__ import annotations

import threading
import uuid
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from typing import Iterator

from ...errors import ConfigError
from .cases import Case
from .worker import execute, kill_all


class _Overlap:
    """The most cases seen running at once during each case's life."""

    def __init__(self):
        self.lock = threading.Lock()
        self.running: dict[str, int] = {}

    def start(self, key: str) -> None:
        with self.lock:
            self.running[key] = 0
            n = len(self.running)
            for k in self.running:
                self.running[k] = max(self.running[k], n)

    def end(self, key: str) -> int:
        with self.lock:
            return self.running.pop(key)


class LocalPool:
    """``jobs`` cases at once, each in its own child process on this machine."""

    def __init__(self, jobs: int):
        if jobs < 1:
            raise ConfigError(f"--jobs must be >= 1, got {jobs}")
        self.jobs = jobs
        self.where = f"{jobs} local process{'es' if jobs > 1 else ''}"

    def run(self, cases: list[Case], timeout_s: float | None) -> Iterator[tuple[Case, dict, int]]:
        overlap = _Overlap()

        def one(case: Case):
            overlap.start(case.key)
            try:
                return execute(case.payload(), timeout_s)
            finally:
                case_overlap[case.key] = overlap.end(case.key)

        case_overlap: dict[str, int] = {}
        executor = ThreadPoolExecutor(max_workers=self.jobs, thread_name_prefix="case")
        try:
            futures = {executor.submit(one, case): case for case in cases}
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
                for future in finished:
                    case = futures[future]
                    yield case, future.result(), case_overlap[case.key]
        finally:  # Ctrl-C or an error in the driver: stop every child, start no more
            executor.shutdown(wait=False, cancel_futures=True)
            kill_all()

    def close(self) -> None:
        pass


class DaskPool:
    """Cases sent to the Dask scheduler at ``address`` (``tcp://host:8786``); each Dask worker
    runs a case in a child process of its own, like :class:`LocalPool` does."""

    def __init__(self, address: str, connect_timeout_s: float = 5.0):
        try:
            from distributed import Client
        except ImportError:
            raise ConfigError("--scheduler needs dask.distributed: pip install 'dask[distributed]' "
                              "(the bench extra has it)") from None
        _check_reachable(address, connect_timeout_s)
        try:
            self.client = Client(address, timeout=connect_timeout_s, set_as_default=False)
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            raise ConfigError(f"--scheduler {address}: cannot reach a Dask scheduler there "
                              f"({str(exc).splitlines()[0][:200] or type(exc).__name__})") from None
        threads = sum(self.client.nthreads().values())
        if threads == 0:
            self.client.close()
            raise ConfigError(f"--scheduler {address}: the scheduler has no workers")
        self.threads = threads
        self.where = f"the Dask scheduler at {address} ({threads} worker threads)"

    def run(self, cases: list[Case], timeout_s: float | None) -> Iterator[tuple[Case, dict, int]]:
        from distributed import as_completed

        run = uuid.uuid4().hex[:8]  # two studies on one cluster never share a task
        futures = {self.client.submit(execute, case.payload(), timeout_s, pure=False,
                                      key=f"taichi-sim-{run}-{case.key}"): case for case in cases}
        try:
            with self.client.as_current():
                finished = as_completed(list(futures))
            for future in finished:
                try:
                    outcome = future.result()
                except Exception as exc:  # the Dask worker died, or lost the task
                    outcome = {"status": "error", "rows": [], "arrays": {}, "wall_s": float("nan"),
                               "note": f"on the cluster: {type(exc).__name__}: {exc}".splitlines()[0][:300]}
                yield futures[future], outcome, min(self.threads, len(cases))
        finally:
            self.client.cancel(list(futures))

    def close(self) -> None:
        self.client.close()


def _check_reachable(address: str, timeout_s: float) -> None:
    """ConfigError unless ``address`` parses and, for TCP, something listens there: checked
    with a plain socket first, since a Dask client that fails half-way complains again at exit."""
    import socket

    from distributed.comm import parse_address, parse_host_port

    try:
        scheme, location = parse_address(address)
        if scheme in ("inproc", "ucx"):
            return
        if scheme not in ("tcp", "tls", "ws", "wss"):
            raise ValueError(f"Dask speaks tcp, tls, ws, wss, ucx or inproc, not {scheme}")
        host, port = parse_host_port(location)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"--scheduler {address}: not a scheduler address like tcp://host:8786 ({exc})") from None
    try:
        socket.create_connection((host, port), timeout=timeout_s).close()
    except OSError as exc:
        raise ConfigError(f"--scheduler {address}: cannot reach a Dask scheduler there "
                          f"({exc.strerror or type(exc).__name__})") from None
