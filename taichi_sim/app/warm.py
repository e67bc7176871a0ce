"""Compile ahead, into Taichi's offline kernel cache, what the launcher's first visit to a scene
compiles: ``python -m taichi_sim.app.warm [SCENE ...]`` (default: every scene the launcher lists).

Taichi keys a cached kernel by the fields it touches, their shapes and their place in the
program's memory tree, which counts every field made before them (the scene the launcher opened
on, its renderer's fields). So each scene is warmed the way the launcher reaches it: a launcher
on the scene ``taichi-sim`` opens with, drawing offscreen, whose first step is taken, then a
switch to the scene and its first step, each scene in a process of its own (a fresh program,
as a launcher started afresh). A launcher started after that loads those kernels from the
cache instead of compiling them; one already running does not see them (a Taichi program reads
the cache's index once, when it compiles or loads its first kernel). ``./run.sh`` runs this in
the background on its first use (docs/first-contact.md, "The first scene switch").

Exit status 0 when every scene was warmed, 1 when one failed (its error on stderr).
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

# The warm-up opens the launcher where ``taichi-sim`` opens it (launcher.first_session): the scene
# and method it starts from decide the keys of everything compiled after them (the window's size
# does not: a launcher on a screen that cut it to fit compiled 2 kernels of 96 the warm-up had not).
LAUNCHER_SIZE = (1280, 800)
MAX_FRAMES = 40  # frames to wait for a first step (a switch takes three: notice, build, step)


def warm_switch(scene: str, size: tuple[int, int] = LAUNCHER_SIZE) -> None:
    """In this process: open the launcher offscreen where ``taichi-sim`` opens it
    (:func:`~taichi_sim.app.launcher.first_session`), take its first step,
    switch to ``scene`` and take that scene's first step, compiling (or loading) every kernel a
    launcher does on the way. Needs Vulkan (offscreen); raises RenderUnavailable without it."""
    from .. import runtime
    from ..render import open_window
    from .launcher import Launcher, first_session

    runtime.init(arch="cpu", precision="f64")
    window = open_window("taichi-sim warm", size)
    try:
        launcher = Launcher(first_session(), size, window=window)
        start = launcher.session.scene_name
        _frames_until(launcher, start)
        if scene != start:
            launcher.request_scene(scene)
            _frames_until(launcher, scene)
    finally:
        window.destroy()


def _frames_until(launcher, scene: str) -> None:
    """Draw frames until the session shows ``scene`` and has stepped it."""
    for _ in range(MAX_FRAMES):
        launcher.draw_frame(1 / 60)
        session = launcher.session
        if session.scene_name == scene and session.runners[0].steps > 0:
            return
    raise RuntimeError(f"warming {scene}: no step after {MAX_FRAMES} frames ({launcher.error or 'no error shown'})")


def main(argv: list[str] | None = None) -> int:
    from ..scene import SCENES, scene_preset

    args = list(sys.argv[1:] if argv is None else argv)
    if args[:1] == ["--one"]:  # a child: one scene, in this process
        warm_switch(args[1])
        return 0
    try:
        scenes = [scene_preset(name).name for name in args] or list(SCENES)
    except Exception as exc:  # noqa: BLE001 - a ConfigError naming the scene
        print(f"taichi_sim.app.warm: error: {exc}", file=sys.stderr)
        return 2
    # the children run in a folder of their own: this package must stay importable from there
    root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))}
    failed = 0
    for name in scenes:
        with tempfile.TemporaryDirectory() as folder:  # where ImGui leaves its imgui.ini
            done = subprocess.run([sys.executable, "-m", "taichi_sim.app.warm", "--one", name], cwd=folder, env=env,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        if done.returncode != 0:
            failed += 1
            print(f"taichi_sim.app.warm: {name}: {done.stderr.strip().splitlines()[-1:] or done.returncode}",
                  file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
