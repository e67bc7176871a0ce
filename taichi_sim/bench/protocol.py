"""A line protocol between the throughput driver and the processes it times.

A child prints ``@@ {json}`` lines on stdout (other lines, e.g. Taichi's banner, are ignored).
A *served* child warms up, prints ``@@ {"ready": true, ...}``, then runs one timed batch for
every ``batch`` line it reads on stdin and answers ``@@ {"step_s": ...}``; ``quit`` ends it.
The driver alternates batches between several served children (ours and the peers), so a
machine whose load changes during the run slows every contender alike.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

MARK = "@@ "


def emit(record: dict) -> None:
    print(MARK + json.dumps(record), flush=True)


def serve(ready: dict, batch) -> None:
    """Child side: announce ``ready``, then answer ``batch`` commands with ``batch()``'s record."""
    emit({"ready": True, **ready})
    for line in sys.stdin:
        command = line.strip()
        if command == "batch":
            emit(batch())
        elif command == "quit":
            break


def child_env() -> dict:
    env = dict(os.environ)
    env.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


class Served:
    """Driver side: one served child process (``python -m module args``)."""

    def __init__(self, module: str, args: list[str]):
        self.errors = tempfile.TemporaryFile(mode="w+")
        self.proc = subprocess.Popen([sys.executable, "-m", module, *args], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=self.errors, text=True, env=child_env())
        self.ready: dict | None = None

    def read(self) -> dict:
        """The next ``@@`` record; RuntimeError (with the child's last stderr line) if it died."""
        for line in self.proc.stdout:
            if line.startswith(MARK):
                return json.loads(line[len(MARK):])
        self.proc.wait()
        self.errors.seek(0)
        tail = [line for line in self.errors.read().strip().splitlines() if line.strip()][-1:] or ["?"]
        raise RuntimeError(f"exit status {self.proc.returncode}: {tail[0][:300]}")

    def start(self) -> dict:
        self.ready = self.read()
        return self.ready

    def batch(self) -> dict:
        self.proc.stdin.write("batch\n")
        self.proc.stdin.flush()
        return self.read()

    def close(self) -> None:
        try:
            if self.proc.poll() is None:
                self.proc.stdin.write("quit\n")
                self.proc.stdin.flush()
                self.proc.wait(timeout=60)
        except (OSError, subprocess.TimeoutExpired, ValueError):
            self.proc.kill()
            self.proc.wait()
        finally:
            self.errors.close()
