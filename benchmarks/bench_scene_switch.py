"""Benchmark: the launcher's first scene switch on a virtual display (docs/first-contact.md,
"The first scene switch").

Starts ``taichi-sim`` with no arguments (the launcher on its first scene) on the display in
``$DISPLAY`` (``Xvfb :99 &`` and ``DISPLAY=:99``), waits until that scene steps, presses Down
(the next scene) with xdotool and prints the seconds until the next scene has stepped, read
from the launcher's status file. ``--warm`` first runs ``python -m taichi_sim.app.warm`` for
that scene into the same cache. Each run uses a fresh kernel cache folder (removed after).

    Xvfb :99 -screen 0 1280x800x24 -nolisten tcp &
    DISPLAY=:99 .venv/bin/python benchmarks/bench_scene_switch.py          # empty cache
    DISPLAY=:99 .venv/bin/python benchmarks/bench_scene_switch.py --warm   # after the warm-up
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

from taichi_sim.app.launcher import FIRST, STATUS_ENV
from taichi_sim.scene import SCENES

START_SCENE = FIRST[0]  # where `taichi-sim` opens the launcher


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--warm", action="store_true", help="warm the switch's kernels first")
    args = parser.parse_args()
    names = list(SCENES)
    target = names[(names.index(START_SCENE) + 1) % len(names)]  # where Down goes
    folder = tempfile.mkdtemp(prefix="scene-switch-")
    env = {**os.environ, STATUS_ENV: os.path.join(folder, "status.json"),
           "TI_OFFLINE_CACHE_FILE_PATH": os.path.join(folder, "cache")}
    try:
        if args.warm:
            subprocess.run([sys.executable, "-m", "taichi_sim.app.warm", target], env=env, check=True)
        start = time.monotonic()
        launcher = subprocess.Popen([sys.executable, "-m", "taichi_sim"], cwd=folder, env=env,
                                    stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                    text=True)
        try:
            _wait(launcher, env[STATUS_ENV], lambda s: s["scene"] == START_SCENE and s["steps"] > 0)
            opened = time.monotonic() - start
            window = ""
            while not window:
                window = subprocess.run(["xdotool", "search", "--name", "taichi-sim"], capture_output=True,
                                        text=True).stdout.split()
                time.sleep(0.1)
            time.sleep(1.0)
            pressed = time.monotonic()
            subprocess.run(["xdotool", "key", "--window", window[0], "Down"], check=True)
            _wait(launcher, env[STATUS_ENV], lambda s: s["scene"] == target and s["steps"] > 0)
            print(f"{START_SCENE} stepping {opened:.1f} s after the start; Down -> {target} stepped after "
                  f"{time.monotonic() - pressed:.2f} s ({'warmed' if args.warm else 'empty'} cache)")
        finally:
            launcher.terminate()
            launcher.wait(60)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return 0


def _wait(launcher, path, done, limit=900.0):
    """Poll the launcher's status file until ``done(status)``; exit on a launcher that ended."""
    start = time.monotonic()
    while time.monotonic() - start < limit:
        try:
            with open(path) as f:
                status = json.load(f)
        except (OSError, ValueError):
            status = None
        if status and done(status):
            return status
        if launcher.poll() is not None:
            sys.exit(f"the launcher exited ({launcher.returncode}): {launcher.stderr.read()[-1500:]}")
        time.sleep(0.05)
    sys.exit("timed out")


if __name__ == "__main__":
    sys.exit(main())
