"""One case in one fresh process: ``python -m taichi_sim.bench.sweep.worker ARRAYS.npz`` reads
the case (:meth:`Case.payload`) on stdin, calls its function and prints ``@@ {"rows": [...]}``
(:mod:`taichi_sim.bench.protocol`); arrays the function returns go to ARRAYS.npz.

A fresh process per case is what keeps a long study alive: Taichi frees fields only at
``ti.init``/``ti.reset``, and a study that built hundreds of scenes in one runtime crashed.
:func:`execute` is the driver side, the same on this machine and on a Dask worker.
"""
from __future__ import annotations

import importlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from pathlib import Path

from ..protocol import MARK, child_env, emit

_live: set[subprocess.Popen] = set()
_live_lock = threading.Lock()


def call(payload: dict):
    module, _, name = payload["function"].partition(":")
    function = getattr(importlib.import_module(module), name)
    result = function(**payload["params"], **payload.get("inputs", {}))
    rows, arrays = result if isinstance(result, tuple) else (result, {})
    return rows, arrays


def main(argv: list[str]) -> int:
    payload = json.loads(sys.stdin.read())
    try:
        rows, arrays = call(payload)
    except Exception as exc:  # the driver records it as the case's error
        traceback.print_exc()
        emit({"error": f"{type(exc).__name__}: {exc}".splitlines()[0][:300]})
        return 0
    if arrays:
        import numpy as np

        np.savez(argv[0], **arrays)
    emit({"rows": rows, "arrays": bool(arrays)})
    return 0


def execute(payload: str, timeout_s: float | None) -> dict:
    """Run one case (its :meth:`Case.payload`) in a fresh child process and wait for it.

    Returns ``{"status": "done" | "timeout" | "error", "rows": [...], "arrays": {...},
    "note": str, "wall_s": float}``; a child past ``timeout_s`` is killed (its whole process
    group), one that dies or raises becomes an ``error`` with its last words as the note.
    """
    with tempfile.TemporaryDirectory(prefix="taichi-sim-case-") as tmp:
        arrays_path = Path(tmp) / "arrays.npz"
        out_path, err_path = Path(tmp) / "stdout", Path(tmp) / "stderr"
        start = time.perf_counter()
        with open(out_path, "w") as out, open(err_path, "w") as err:
            proc = subprocess.Popen([sys.executable, "-m", __name__, str(arrays_path)], stdin=subprocess.PIPE,
                                    stdout=out, stderr=err, text=True, env=child_env(), start_new_session=True)
            with _live_lock:
                _live.add(proc)
            try:
                proc.stdin.write(payload)
                proc.stdin.close()
                proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                _kill(proc)
                return {"status": "timeout", "rows": [], "arrays": {}, "wall_s": time.perf_counter() - start,
                        "note": f"the case ran past its {timeout_s:g} s timeout and was stopped"}
            finally:
                _kill(proc)
                with _live_lock:
                    _live.discard(proc)
        wall = time.perf_counter() - start
        record = None
        for line in out_path.read_text(errors="replace").splitlines():
            if line.startswith(MARK):
                record = json.loads(line[len(MARK):])
        if record is None or "error" in record:
            lines = [ln for ln in err_path.read_text(errors="replace").splitlines() if ln.strip()]
            note = record["error"] if record else \
                f"the worker process exited with code {proc.returncode}: {(lines or ['no message'])[-1][:300]}"
            return {"status": "error", "rows": [], "arrays": {}, "wall_s": wall, "note": note}
        arrays = {}
        if record.get("arrays"):
            import numpy as np

            with np.load(arrays_path) as data:
                arrays = {k: data[k] for k in data.files}
        return {"status": "done", "rows": record["rows"], "arrays": arrays, "wall_s": wall, "note": ""}


def _kill(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            proc.kill()
        proc.wait()


def kill_all() -> None:
    """Stop every case process this process started (after Ctrl-C)."""
    with _live_lock:
        live = list(_live)
    for proc in live:
        _kill(proc)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
