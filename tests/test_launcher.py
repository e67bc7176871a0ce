"""The launcher's logic without a window: pacing to the wall clock, grab by default, scene
switching that reuses what it built, the display probe and what the launcher leaves on disk.

The real window (Xvfb, mouse and keys) is tested in tests/test_launcher_window.py.
"""
import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.app.pacing import FRAME_BUDGET, MAX_INTERVAL, Pacer, factor_text
from taichi_sim.app.session import Session


@pytest.fixture
def runtime():
    ts.init(arch="cpu", precision="f64")


# -- pacing (pure) ----------------------------------------------------------------------------

def _run_machine(pacer, cost, render, frames, dt=1e-3):
    """Frames on a model machine: simulating s seconds takes cost * s wall seconds, drawing
    ``render`` seconds. Returns the per-frame (interval, simulated, simulation wall time)."""
    out, interval = [], render
    for _ in range(frames):
        simulated = pacer.plan(interval, dt)
        wall = cost * simulated
        pacer.observe(interval, simulated, wall)
        out.append((interval, simulated, wall))
        interval = render + wall
    return out


def test_a_fast_machine_simulates_what_the_clock_says():
    pacer = Pacer()
    frames = _run_machine(pacer, cost=0.2, render=1 / 60, frames=200)
    intervals = np.array([f[0] for f in frames])
    simulated = np.array([f[1] for f in frames])
    assert simulated[10:] == pytest.approx(intervals[10:])  # each frame covers its own interval
    assert pacer.factor == pytest.approx(1.0)
    assert not pacer.limited and factor_text(pacer.factor) == ""


def test_a_slow_machine_keeps_frames_short_and_says_how_far_behind():
    pacer = Pacer()
    cost, render = 3.0, 0.02  # 3 wall seconds per simulated second: real time is out of reach
    frames = _run_machine(pacer, cost=cost, render=render, frames=300)
    walls = np.array([f[2] for f in frames])
    assert walls[5:].max() <= FRAME_BUDGET * 1.0001  # no spiral: every frame stays in budget
    expected = (FRAME_BUDGET / cost) / (render + FRAME_BUDGET)
    assert pacer.limited
    assert pacer.factor == pytest.approx(expected, rel=1e-6)
    assert factor_text(pacer.factor) == f"{expected:.2g}x real time"


def test_the_cost_estimate_follows_a_change_of_cost():
    pacer = Pacer()
    _run_machine(pacer, cost=3.0, render=0.02, frames=50)
    assert pacer.cost == pytest.approx(3.0)
    _run_machine(pacer, cost=0.1, render=0.02, frames=50)
    assert pacer.cost == pytest.approx(0.1, rel=1e-3) and not pacer.limited
    assert pacer.factor == pytest.approx(1.0)


def test_a_stall_is_skipped_and_a_slow_method_still_moves():
    pacer = Pacer()
    assert pacer.plan(5.0, 1e-3) == MAX_INTERVAL  # a 5 s hiccup is not simulated in one go
    pacer.observe(0.05, 1e-3, 30.0)  # the first frame compiles: not counted
    assert pacer.cost is None and pacer.plan(0.05, 1e-3) == 0.05
    pacer.observe(0.05, 1e-3, 10.0)  # one step took 10 s
    assert pacer.plan(0.05, 1e-3) == 1e-3  # still one step per frame
    assert pacer.plan(0.004, 0.01) == 0.004  # a step longer than the frame: the runner carries it
    assert pacer.factor is None  # less than a window of frames seen
    pacer.reset()
    assert pacer.cost is None and pacer.plan(0.05, 1e-3) == 0.05
    with pytest.raises(ValueError):
        Pacer(budget=0.0)


# -- the session's frame ----------------------------------------------------------------------

def test_an_interactive_session_follows_the_clock(runtime):
    s = Session("spring", ["symplectic_euler"], dt=0.01, substeps=5, interactive=True)
    # A budget no frame can exceed: on a loaded machine one slow frame (a worker descheduled, a
    # late first launch) otherwise makes the pacer cut the next frames, correctly, and the clock
    # falls behind (docs/first-contact.md, "Supported Pythons"). Cutting has tests of its own.
    s.pacer.budget = 60.0
    r = s.runners[0]
    for _ in range(60):
        s.frame(0.025)
    assert r.t == pytest.approx(1.5, abs=0.01)  # 60 frames of 25 ms of wall time
    assert s.pacer.factor == pytest.approx(1.0, abs=0.02)
    assert any("(real time)" in line for line in s.hud_lines(30.0))
    s.set_real_time(False)
    s.frame(0.025)
    assert r.steps == 150 + 5  # fixed: substeps per frame whatever the clock says
    s.toggle_pause()
    s.frame(0.025)
    assert r.steps == 155


# -- grab by default --------------------------------------------------------------------------

def _is_cloth_or_chain(scene) -> bool:
    return scene.springs is not None and scene.particle_count > 2


def test_every_cloth_and_chain_is_grabbable_in_the_launcher_only(runtime):
    checked = []
    for name, preset in ts.SCENES.items():
        headless = ts.build_scene(name)
        if not _is_cloth_or_chain(headless):
            continue
        assert headless.grabber is None and headless.system.term("grab") is None  # no cost headless
        launcher = Session(name, [preset.default_integrator], interactive=True).scenes[0]
        assert launcher.grabber is not None and launcher.system.term("grab") is not None, name
        checked.append(name)
    assert {"pendulum", "cloth", "cloth-sphere", "cloth-tear", "cloth-wind"} <= set(checked)
    explicit = Session("cloth", ["symplectic_euler"], params={"grab": False}, interactive=True)
    assert explicit.scenes[0].grabber is None  # a --set grab=0 is respected


def test_the_grabbed_particle_follows_the_mouse_on_a_plane_facing_the_camera(runtime):
    from taichi_sim.app.input import CameraControl, GrabberHook
    from taichi_sim.render import OrbitCamera

    s = Session("pendulum", ["symplectic_euler"], interactive=True)
    scene = s.scenes[0]
    cam = OrbitCamera(1.6, target=scene.x0.mean(axis=0), distance=3.0, yaw=0.4, pitch=0.3)
    control = CameraControl(cam, lambda: None, [GrabberHook(scene.grabber, np.zeros(3), reach=0.1)])
    end = scene.x0[-1]
    (u, v), = cam.project(end)[0]
    control.update(u, v, left=True, right=False, middle=False)
    assert scene.grabber.particle == scene.particle_count - 1
    control.update(u + 0.1, v - 0.05, left=True, right=False, middle=False)
    target = scene.system.term("grab").target[None].to_numpy()
    assert np.dot(target - end, cam.forward) == pytest.approx(0.0, abs=1e-9)  # on the plane
    (tu, tv), = cam.project(target)[0]
    assert (tu, tv) == pytest.approx((u + 0.1, v - 0.05), abs=1e-9)  # under the cursor
    s.frame()
    assert s.runners[0].t > 0 and not s.runners[0].frozen  # the pull does not trip the guard
    control.update(u + 0.1, v - 0.05, left=False, right=False, middle=False)
    assert scene.grabber.particle is None and scene.system.term("grab").particle[None] == -1


# -- switching scenes -------------------------------------------------------------------------

def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) / 1024 for line in f if line.startswith("VmRSS"))


def test_switching_scenes_reuses_them_and_memory_stays_flat(runtime):
    s = Session("cloth", ["symplectic_euler"], interactive=True)
    cloth = s.scenes[0]
    default_k = cloth.springs.stiffness.to_numpy().copy()
    s.set_param("stiffness", 900.0)  # live, on this visit only
    names = ["pendulum", "cloth"]
    for k in range(4):  # every scene built and every kernel compiled once
        s.select_scene(names[k % 2])
        s.frame(0.02)
    before = _rss_mb()
    for k in range(50):
        s.select_scene(names[k % 2])
        assert s.runners[0].t == 0.0
        np.testing.assert_array_equal(s.scenes[0].state.x.to_numpy(), s.scenes[0].x0)
        s.frame(0.02)
    grown = _rss_mb() - before
    print(f"RSS {before:.1f} MB before 50 scene switches, grown by {grown:.2f} MB after")
    assert grown < 5.0
    assert s.scenes[0] is cloth  # the same scene object, back at t = 0
    np.testing.assert_array_equal(cloth.springs.stiffness.to_numpy(), default_k)  # live change undone
    s.set_param("nx", 8)
    s.reset()  # new setup parameters: a new scene (kept for later visits too)
    assert s.scenes[0] is not cloth and s.scenes[0].particle_count == 8 * 32


# -- no display, or a bad one -----------------------------------------------------------------

def free_display_number(start: int = 170) -> int:
    """A display number no X server here uses (no socket, no lock file)."""
    import os

    for n in range(start, start + 200):
        if not os.path.exists(f"/tmp/.X11-unix/X{n}") and not os.path.exists(f"/tmp/.X{n}-lock"):
            return n
    raise RuntimeError("no free X display number")


def test_a_bad_display_is_found_before_glfw_would_end_the_process(monkeypatch, capsys):
    from taichi_sim.app.display import display_problem
    from taichi_sim.cli import main

    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.delenv("DISPLAY", raising=False)
    assert display_problem() == "no display (DISPLAY / WAYLAND_DISPLAY unset)"
    bad = f":{free_display_number()}"
    monkeypatch.setenv("DISPLAY", bad)
    assert display_problem() == f"cannot open the X display {bad!r}"
    assert main(["demo", "pendulum"]) == 2  # one line, exit 2, instead of GLFW's exit 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"cannot open the X display {bad!r}" in err


def test_the_default_command_falls_back_to_the_showcase_on_a_bad_display(monkeypatch, capsys, tmp_path):
    import taichi_sim.app.launcher as launcher_module
    import taichi_sim.app.showcase as showcase_module
    from taichi_sim.app.record import Recording
    from taichi_sim.cli import main

    recorded = []

    def record(clip, out, *, still, still_at, progress):  # what the short showcase asks for
        recorded.append((clip, out))
        return Recording(path=out, frames=clip.frame_count, wall=1.0, still=still, failures=())

    monkeypatch.setattr(showcase_module, "record", record)
    monkeypatch.setattr(launcher_module, "Launcher", lambda *a, **k: pytest.fail("no window here"))
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    bad = f":{free_display_number()}"
    monkeypatch.setenv("DISPLAY", bad)
    monkeypatch.chdir(tmp_path)
    assert main([]) == 0
    # a short showcase into the untracked out/showcase/, never into the README's media/
    assert {out.parent.as_posix() for _, out in recorded} == {"out/showcase"}
    assert 3 <= len(recorded) <= 4 and all(clip.seconds <= 2 and clip.supersample == 1 for clip, _ in recorded)
    assert sum(c.frame_count * c.size[0] * c.size[1] * len(c.integrators) for c, _ in recorded) < 4e7
    captured = capsys.readouterr()
    assert captured.err.strip() == (f"taichi-sim: cannot open the X display {bad!r}: recording a short "
                                    "showcase into out/showcase/ instead")
    # a line per clip as it is done, though stdout is no terminal here
    lines = captured.out.splitlines()
    assert lines[0].startswith(f"Recording {len(recorded)} short clips into out/showcase/")
    assert [line.split("]")[0] for line in lines[1:]] == [f"  [{k}/{len(recorded)}" for k in range(1, len(recorded) + 1)]
    assert all("out/showcase/" in line for line in lines[1:])
    assert not (tmp_path / "media").exists()


def test_record_showcase_without_a_folder_writes_the_gallery_in_media(monkeypatch, tmp_path):
    import taichi_sim.app.showcase as showcase_module
    from taichi_sim.cli import main

    folders = []
    monkeypatch.setattr(showcase_module, "record_showcase", lambda folder, **kw: folders.append(folder) or [])
    monkeypatch.chdir(tmp_path)
    assert main(["record", "--showcase", "--quiet"]) == 0
    assert main(["record", "--showcase", "mine", "--quiet"]) == 0
    assert folders == ["media", "mine"]


def test_a_failed_showcase_leaves_no_empty_folder(monkeypatch, tmp_path):
    import taichi_sim.app.showcase as showcase_module
    from taichi_sim.render import RenderUnavailable

    def no_vulkan(*args, **kwargs):
        raise RenderUnavailable("rendering needs Vulkan")

    monkeypatch.setattr(showcase_module, "record", no_vulkan)
    with pytest.raises(RenderUnavailable):
        showcase_module.record_showcase(tmp_path / "media")
    assert not (tmp_path / "media").exists()
    (tmp_path / "mine").mkdir()
    with pytest.raises(RenderUnavailable):
        showcase_module.record_showcase(tmp_path / "mine")
    assert (tmp_path / "mine").is_dir()  # a folder that was there stays


@pytest.mark.parametrize("name, params", [("cloth-tear", {"nx": 12, "ny": 12}),
                                          ("sprinkler", {"capacity": 64, "rate": 300.0})])
def test_reset_restores_torn_and_emitting_scenes_in_place(runtime, name, params):
    from taichi_sim.app.runner import Runner

    fresh = Runner(ts.build_scene(name, params), "symplectic_euler", 2e-3)
    fresh.advance(2.0)
    runner = Runner(ts.build_scene(name, params), "symplectic_euler", 2e-3)
    scene = runner.scene
    runner.advance(2.0)
    changed = scene.springs.alive_count() < scene.springs.spring_count if name == "cloth-tear" \
        else scene.emitter.live_count[None] > 0
    assert changed  # the model itself changed during the run
    runner.reset()
    assert runner.scene is scene and runner.t == 0.0  # the same fields, nothing rebuilt
    runner.advance(2.0)
    assert runner.steps == fresh.steps
    np.testing.assert_array_equal(scene.state.x.to_numpy(), fresh.scene.state.x.to_numpy())
    for key, value in fresh.scene.arrays.items():
        np.testing.assert_array_equal(scene.arrays[key], value, err_msg=key)


def test_the_imgui_ini_file_is_taken_back(tmp_path):
    from taichi_sim.render import vulkan

    new, old = tmp_path / "new" / "imgui.ini", tmp_path / "old" / "imgui.ini"
    old.parent.mkdir()
    new.parent.mkdir()
    old.write_text("[Window][Mine]\n")
    vulkan.watch_imgui_ini(new)
    vulkan.watch_imgui_ini(old)
    new.write_text("[Window][Controls]\n")  # what ImGui writes when its window goes
    old.write_text("[Window][Controls]\n")
    vulkan.watch_imgui_ini(old)  # a second launcher in the process keeps the first "before"
    vulkan.take_back_imgui_ini(new)
    vulkan.take_back_imgui_ini(old)
    assert not new.exists() and old.read_text() == "[Window][Mine]\n"


@pytest.mark.parametrize("size", [(1280, 800), (1024, 640), (800, 600)])
def test_the_help_overlay_holds_all_its_lines(size):
    """GGUI clips text at a panel's edges: every help line fits the panel's width and height."""
    from taichi_sim.app.input import help_lines
    from taichi_sim.app.launcher import HUD_CHAR_PX, LINE_PX, help_window

    (x, y, width, height), lines = help_window(size)
    assert max(len(line) for line in lines) * HUD_CHAR_PX <= width * size[0] - 2 * HUD_CHAR_PX
    assert (len(lines) + 1.5) * LINE_PX <= height * size[1]  # the lines under a title bar
    assert 0 <= y and y + height <= 1 and 0 <= x and x + width <= 1
    assert " ".join(lines).split() == " ".join(help_lines()).split()  # wrapped, nothing lost


def test_the_hud_states_the_estimated_error_and_whether_it_is_within_the_tolerance(runtime):
    s = Session("cloth", ["xpbd"], dt=1 / 60, substeps=1, interactive=False,
                params={"nx": 6, "ny": 6, "stiffness": 1e4})
    r = s.runners[0]
    s.frame(1 / 60)
    assert r.error_estimate is not None and r.error_estimate < 1e-3
    assert any("error ~" in line and "tolerance" not in line for line in s.hud_lines())
    r.stepper.monitor.tolerance = r.error_estimate / 2  # the same sample, judged tighter
    assert any("error ~" in line and "> tolerance" in line for line in s.hud_lines())
