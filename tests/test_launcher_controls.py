"""The launcher's controls without a window: the camera and screen <-> world mapping, the
mouse hooks (orbit, zoom, grab), the session's pause / step / reset, live and pending
parameters, the pickers, the keys, and freezing on divergence. Drawing and recording are tested
in tests/test_render.py."""
import math

import numpy as np
import pytest
import taichi as ti

import taichi_sim as ts
from taichi_sim.app.input import KEYMAP, CameraControl, GrabberHook, apply_key, help_lines
from taichi_sim.app.runner import Runner
from taichi_sim.app.session import Session, compatible_integrators
from taichi_sim.errors import ConfigError
from taichi_sim.integrators import Status
from taichi_sim.render import OrbitCamera


@pytest.fixture(scope="module")
def runtime():
    """One Taichi runtime for this module (CPU, f64)."""
    ts.init(arch="cpu", precision="f64")


# -- the camera and screen <-> world mapping (no window) ------------------------------------------

def test_camera_view_matches_ggui_and_rays_invert_projection(runtime):
    cam = OrbitCamera(1.6, target=(0.2, 0.5, -0.1), distance=3.0, yaw=0.7, pitch=0.4)
    ggui = ti.ui.Camera()
    cam.apply(ggui)
    # GGUI's matrix acts on row vectors: it is our column-vector matrix transposed.
    np.testing.assert_allclose(np.array(ggui.get_view_matrix()).T, cam.view_matrix(), atol=1e-5)
    proj = np.array(ggui.get_projection_matrix(1.6)).T
    points = np.array([[0.2, 0.5, -0.1], [0.6, 0.9, 0.3], [-0.4, 0.1, -0.5]])
    clip = (proj @ cam.view_matrix() @ np.c_[points, np.ones(3)].T).T
    uv_ggui = 0.5 * (clip[:, :2] / clip[:, 3:] + 1.0)
    uv, depth = cam.project(points)
    np.testing.assert_allclose(uv, uv_ggui, atol=1e-5)
    assert np.all(depth > 0)
    np.testing.assert_allclose(uv[0], [0.5, 0.5], atol=1e-12)  # the target is in the middle
    for p, (u, v) in zip(points, uv):
        origin, direction = cam.screen_ray(u, v)
        assert np.isclose(np.linalg.norm(direction), 1.0)
        miss = (p - origin) - np.dot(p - origin, direction) * direction
        assert np.linalg.norm(miss) < 1e-9


def test_camera_inset_centres_the_target_in_the_uncovered_part():
    cam = OrbitCamera(2.0, target=(1.0, 2.0, 3.0), yaw=-0.3, pitch=0.2, inset=0.3)
    uv, _ = cam.project([cam.target])
    np.testing.assert_allclose(uv[0], [0.3 + 0.7 / 2, 0.5], atol=1e-12)
    cam.frame((-1.0, -0.5, -0.2), (1.0, 0.5, 0.2))
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-0.5, 0.5) for z in (-0.2, 0.2)])
    uv, depth = cam.project(corners)
    assert np.all(depth > 0)
    assert uv[:, 0].min() >= 0.3 - 1e-9 and uv[:, 0].max() <= 1.0 and 0 <= uv[:, 1].min() <= uv[:, 1].max() <= 1
    # the box fills the view: some corner is near an edge of the uncovered region
    edge = np.min([uv[:, 0].min() - 0.3, 1 - uv[:, 0].max(), uv[:, 1].min(), 1 - uv[:, 1].max()])
    assert edge < 0.1


def test_orbit_zoom_and_grab_hooks_follow_the_mouse():
    cam = OrbitCamera(1.5, distance=4.0)
    events = []

    class Hook:
        def __init__(self, name, distance):
            self.name, self.distance = name, distance

        def pick(self, origin, direction):
            events.append((self.name, "pick", direction.copy()))
            return self.distance

        def hold(self):
            events.append((self.name, "hold"))

        def drag(self, origin, direction, normal):
            assert normal == pytest.approx(cam.forward)  # the plane faces the camera
            events.append((self.name, "drag", direction.copy()))

        def release(self):
            events.append((self.name, "release"))

    homed = []
    control = CameraControl(cam, lambda: homed.append(True), [Hook("far", 0.3), Hook("near", 0.1),
                                                               Hook("none", None)])
    control.update(0.5, 0.5, left=False, right=False, middle=False)
    yaw, pitch = cam.yaw, cam.pitch
    control.update(0.6, 0.45, left=False, right=True, middle=False)  # right-drag orbits
    assert cam.yaw == pytest.approx(yaw - math.pi * 0.1) and cam.pitch == pytest.approx(pitch + math.pi * 0.05)
    assert control.user_moved
    distance = cam.distance
    control.update(0.6, 0.55, left=False, right=False, middle=True)  # middle-drag up: closer
    assert cam.distance < distance
    control.update(0.6, 0.55, left=True, right=False, middle=False, over_panel=True)
    assert not events  # a press over the control panel is the panel's
    control.update(0.6, 0.55, left=False, right=False, middle=False)
    control.update(0.5, 0.5, left=True, right=False, middle=False)
    assert [e[:2] for e in events] == [("far", "pick"), ("near", "pick"), ("none", "pick"), ("near", "hold")]
    np.testing.assert_allclose(events[0][2], -control.camera.basis()[2], atol=1e-12)  # centre ray
    control.update(0.55, 0.5, left=True, right=False, middle=False)
    assert events[-1][:2] == ("near", "drag")
    control.update(0.55, 0.5, left=False, right=False, middle=False)
    assert events[-1] == ("near", "release") and control.held is None
    control.home()
    assert homed and not control.user_moved


def test_grabber_hook_picks_the_particle_under_the_cursor(runtime):
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6, "grab": True})
    offset = np.array([2.0, 0.0, 0.0])
    cam = OrbitCamera(1.6, target=scene.x0.mean(axis=0) + offset, distance=3.0, yaw=0.4, pitch=0.6)
    hook = GrabberHook(scene.grabber, offset, reach=0.05)
    target = 14
    uv, _ = cam.project([scene.x0[target] + offset])
    origin, direction = cam.screen_ray(*uv[0])
    assert hook.pick(origin, direction) == pytest.approx(0.0, abs=1e-9)
    assert hook.candidate == target
    hook.hold()
    hook.drag(*cam.screen_ray(uv[0][0] + 0.05, uv[0][1]))
    term = scene.system.term("grab")
    assert term.particle[None] == target
    assert not np.allclose(term.target[None].to_numpy(), scene.x0[target])
    hook.release()
    assert term.particle[None] == -1
    assert hook.pick(*cam.screen_ray(0.0, 0.0)) is None  # nothing near the corner ray


# -- the launcher's logic (no window) -------------------------------------------------------------

def test_pause_single_step_and_reset(runtime):
    s = Session("spring", ["symplectic_euler"], dt=0.01, substeps=5)
    r = s.runners[0]
    s.frame()
    assert r.steps == 5 and r.t == pytest.approx(0.05)
    s.toggle_pause()
    s.frame()
    assert r.steps == 5
    s.step()
    assert r.steps == 6 and s.paused
    s.reset()
    assert r.t == 0.0 and r.steps == 0
    np.testing.assert_array_equal(r.scene.state.x.to_numpy(), r.scene.x0)
    status = s.status()
    assert status == "paused"
    s.toggle_pause()
    assert s.status() == "running"


def test_parameter_changes_apply_live_or_on_reset(runtime):
    s = Session("cloth", ["symplectic_euler", "rk4"], params={"nx": 5, "ny": 4})
    generation = s.generation
    controls = {c.param.name: c for c in s.param_controls()}
    assert controls["stiffness"].live and controls["gravity"].live and not controls["nx"].live
    assert controls["stiffness"].low == 0.0 and controls["stiffness"].high == 2000.0
    assert s.set_param("stiffness", 800.0) is True
    for scene in s.scenes:  # every panel, without a rebuild
        kinds = scene.springs.kind_np
        np.testing.assert_allclose(scene.springs.stiffness.to_numpy()[kinds == 0], 800.0)
        np.testing.assert_allclose(scene.springs.stiffness.to_numpy()[kinds == 1], 250.0)
    assert s.set_param("gravity", 5.0) is True
    np.testing.assert_allclose(s.scenes[1].system.term("gravity").get(), [0.0, -5.0, 0.0])
    assert s.generation == generation
    assert s.set_param("nx", 6) is False
    assert s.pending == {"nx": 6} and s.value("nx") == 6 and s.params["nx"] == 5
    with pytest.raises(ConfigError):
        s.set_param("nx", 1)
    s.reset()
    assert s.generation == generation + 1 and not s.pending
    assert all(scene.particle_count == 24 for scene in s.scenes)
    assert s.params["stiffness"] == 800.0  # live changes survive the rebuild
    np.testing.assert_allclose(s.scenes[0].springs.stiffness.to_numpy()[s.scenes[0].springs.kind_np == 0], 800.0)


def test_integrator_and_scene_pickers(runtime):
    s = Session("simple", ["euler"], dt=0.1)
    assert "symplectic_euler" not in compatible_integrators(s.scenes[0])
    seen = {s.cycle_integrator(0) for _ in range(len(compatible_integrators(s.scenes[0])))}
    assert seen == set(compatible_integrators(s.scenes[0]))
    with pytest.raises(ConfigError):
        s.set_integrator(0, "symplectic_euler")
    s.select_scene("pendulum")
    assert s.scene_name == "pendulum" and s.dt == ts.SCENES["pendulum"].default_dt
    s.select_scene("simple")  # symplectic_euler cannot step it: the preset's default takes over
    assert s.integrators[0] in compatible_integrators(s.scenes[0])
    with pytest.raises(ConfigError):
        s.set_dt(-1.0)
    with pytest.raises(ConfigError):
        s.set_substeps(0)
    with pytest.raises(ConfigError):
        Session("spring", ["euler", "rk4", "midpoint", "trapezoid"])


def test_keys_toggle_what_they_say_and_help_lists_them(runtime):
    s = Session("pendulum", ["symplectic_euler"])
    cam = OrbitCamera(1.5, distance=2.0)
    control = CameraControl(cam, lambda: None)
    assert apply_key(" ", s, control) == "pause" and s.paused
    assert apply_key("n", s, control) == "step" and s.runners[0].steps == 1
    springs = s.options.springs
    apply_key("k", s, control)
    assert s.options.springs is not springs
    apply_key("h", s, control)
    assert s.show_help
    apply_key("i", s, control)
    assert cam.distance == pytest.approx(2.0 / 1.15)
    assert apply_key("Escape", s, control) == "quit"
    assert apply_key("?", s, control) is None
    text = "\n".join(help_lines())
    for key, (_, meaning) in KEYMAP.items():
        assert meaning in text
    assert "right-drag" in text


def test_divergence_freezes_on_the_last_finite_state(runtime):
    runner = Runner(ts.build_scene("pendulum"), "euler", 8e-3)
    for _ in range(100):
        runner.advance(0.05)
        if runner.frozen:
            break
    assert runner.status is Status.DIVERGED
    assert runner.message.startswith("diverged at step ")
    assert runner.failure.startswith("diverged at t = ")
    assert runner.message.endswith(": lower the step or pick a more stable integrator")
    assert isinstance(runner.display, np.ndarray) and np.all(np.isfinite(runner.display))
    t, frozen_view = runner.t, runner.display.copy()
    runner.advance(0.05)
    assert runner.t == t
    np.testing.assert_array_equal(runner.display, frozen_view)
    runner.reset()
    assert not runner.frozen and runner.display is runner.scene.state.x


def test_non_finite_state_freezes_the_run(runtime):
    runner = Runner(ts.build_scene("simple"), "rk4", 0.01)
    runner.advance(0.1)
    good = runner.last_good.copy()
    runner.scene.state.x.from_numpy(np.array([[np.nan, 0.0, 0.0]]))
    runner.advance(0.1)
    assert runner.frozen and "diverged" in runner.message
    np.testing.assert_array_equal(runner.display, good)
