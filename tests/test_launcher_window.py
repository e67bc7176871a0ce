"""The launcher in a real X window: Xvfb, keys and the mouse through xdotool.

It starts ``taichi-sim demo pendulum`` on a display of its own, switches to the cloth with a
key, drags the cloth with the mouse, closes the window with Escape, and checks that the cloth
moved away from where the same steps under gravity alone put it. The launcher reports what the
test needs (its scene, step count and a pixel on the cloth, and its positions at exit) through
the status file named by TAICHI_SIM_STATUS. Skipped, with the reason, only where Xvfb or xdotool
is not installed (``./test.sh`` installs them as root) or Vulkan is not usable.
"""
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.app.launcher import STATUS_ENV

ROOT = Path(__file__).resolve().parents[1]
SIZE = (1280, 720)
DEADLINE = 120.0  # s, a fail-safe: the test takes ~25 s on 2 shared cores with software Vulkan


@pytest.fixture
def xvfb():
    """A fresh Xvfb on a display number it picks itself; yields the DISPLAY string."""
    missing = [tool for tool in ("Xvfb", "xdotool") if shutil.which(tool) is None]
    if missing:
        pytest.skip(f"{' and '.join(missing)} not installed (Debian: apt-get install xvfb xdotool; "
                    "./test.sh does it when run as root)")
    read, write = os.pipe()
    server = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                              pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write)
    with os.fdopen(read) as pipe:
        number = pipe.readline().strip()
    if not number:
        server.kill()
        pytest.skip("Xvfb did not start")
    try:
        yield f":{number}"
    finally:
        server.terminate()
        server.wait(timeout=10)


def test_the_screen_size_is_read_from_the_display(xvfb, monkeypatch):
    from taichi_sim.app.display import screen_area

    monkeypatch.setenv("DISPLAY", xvfb)
    assert screen_area() == (0, 0, 1280, 800)
    monkeypatch.setenv("DISPLAY", ":9999")  # no server there: unknown, not an error
    assert screen_area() is None
    monkeypatch.delenv("DISPLAY")
    assert screen_area() is None


def _xdotool(display, *args) -> str:
    return subprocess.run(["xdotool", *args], env={**os.environ, "DISPLAY": display}, check=True,
                          capture_output=True, text=True, timeout=10).stdout.strip()


def _find_window(display) -> str:
    found = subprocess.run(["xdotool", "search", "--name", "taichi-sim"], env={**os.environ, "DISPLAY": display},
                           capture_output=True, text=True, timeout=10)
    return found.stdout.split()[0] if found.returncode == 0 and found.stdout.split() else ""


def _status(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _wait(what, until, launcher, start, poll=0.1):
    """Poll ``until()`` until it returns something truthy; fail past the deadline or when the
    launcher has exited."""
    while time.monotonic() - start < DEADLINE:
        value = until()
        if value:
            return value
        if launcher.poll() is not None:
            out, err = launcher.communicate()
            if "Vulkan" in err and launcher.returncode == 2:
                pytest.skip(f"Vulkan is not usable here: {err.strip()}")
            pytest.fail(f"the launcher exited ({launcher.returncode}) while waiting for {what}: {err[-2000:]}")
        time.sleep(poll)
    launcher.kill()
    pytest.fail(f"timed out waiting for {what}")


def test_switch_scene_drag_the_cloth_and_close(xvfb, tmp_path):
    start = time.monotonic()
    status_path = tmp_path / "status.json"
    env = {**os.environ, "DISPLAY": xvfb, STATUS_ENV: str(status_path),
           "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    env.pop("WAYLAND_DISPLAY", None)
    launcher = subprocess.Popen([sys.executable, "-m", "taichi_sim", "demo", "pendulum",
                                 "--size", f"{SIZE[0]}x{SIZE[1]}"], cwd=tmp_path, env=env,
                                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        status = _wait("the launcher's first status", lambda: _status(status_path), launcher, start)
        assert status["scene"] == "pendulum" and status["t"] >= 0
        window = _wait("the window", lambda: _find_window(xvfb), launcher, start)
        # on the 1280 x 800 screen, the whole window (the Status panel at its right edge too)
        geometry = dict(line.split("=") for line in _xdotool(xvfb, "getwindowgeometry", "--shell", window).split())
        x, y, w, h = (int(geometry[k]) for k in ("X", "Y", "WIDTH", "HEIGHT"))
        assert 0 <= x and x + w <= 1280 and 0 <= y and y + h <= 800, geometry

        # switch scene with the keyboard: Down steps through the scenes in the registry's order
        names = list(ts.SCENES)
        for _ in range((names.index("cloth") - names.index("pendulum")) % len(names)):
            before = _status(status_path)["scene"]
            _xdotool(xvfb, "key", "--window", window, "Down")
            _wait("a scene switch", lambda: (_status(status_path) or {}).get("scene") != before, launcher, start)
        status = _wait("the cloth running", lambda: (lambda s: s if s and s["scene"] == "cloth" and s["t"] > 0.5
                                                        and "probe" in s else None)(_status(status_path)),
                       launcher, start)
        assert status["grab_moves"] == 0  # grabbable, and not grabbed yet

        # drag the middle of the cloth up and sideways, hold it there a moment, let go
        x, y = (int(round(c)) for c in status["probe"]["px"])
        _xdotool(xvfb, "mousemove", "--window", window, str(x), str(y))
        time.sleep(0.3)
        _xdotool(xvfb, "mousedown", "1")
        for k in range(1, 11):
            _xdotool(xvfb, "mousemove", "--window", window, str(x + 15 * k), str(y - 20 * k))
            time.sleep(0.08)
        time.sleep(0.8)
        _xdotool(xvfb, "mouseup", "1")
        _wait("the grab to register", lambda: (_status(status_path) or {}).get("grab_moves", 0) >= 3,
              launcher, start)

        _xdotool(xvfb, "key", "--window", window, "Escape")
        out, err = launcher.communicate(timeout=max(5.0, DEADLINE - (time.monotonic() - start)))
    finally:
        if launcher.poll() is None:
            launcher.kill()
            launcher.communicate()
    assert launcher.returncode == 0, err[-2000:]
    final = _status(status_path)
    assert final["final"] and final["scene"] == "cloth" and final["grab_moves"] >= 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["status.json"]  # no imgui.ini left

    # the same steps without the mouse: gravity, springs and pins only
    ts.init(arch="cpu", precision=final["precision"])
    params = {**final["params"], "grab": False}
    scene = ts.build_scene("cloth", params, seed=final["seed"])
    result = ts.run(scene, final["integrators"][0], dt=final["dt"], steps=final["steps"])
    assert result.status.value == "ok"
    pulled = np.asarray(final["x"])
    alone = scene.state.x.to_numpy()
    moved = np.linalg.norm(pulled - alone, axis=1)
    pinned = ~scene.system.free.to_numpy().astype(bool)
    assert moved[pinned].max() == 0.0
    print(f"window test: {final['steps']} steps, t = {final['t']:.2f} s, cloth moved up to "
          f"{moved.max():.3f} m from the gravity-only run, {time.monotonic() - start:.1f} s")
    assert moved.max() > 0.05
