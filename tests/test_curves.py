"""Curves: the spline (interpolates, C¹, exact at knots, no overshoot, exact integral), the
JSON file (round trip, every kind of bad file refused), a curve-driven sprinkler emitting the
integral of its rate curve, the CLI's --curves, and the curve editor's mouse logic (no window)."""
import json

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.curves import MAX_POINTS, CurveDriver, Spline, check_curves, load_curves, parse_curves, save_curves
from taichi_sim.errors import ConfigError
from taichi_sim.scene import build_scene, scene_preset

POINTS = ((0.0, 50.0), (0.15, 600.0), (0.3, 900.0), (0.5, 400.0), (0.9, 400.0), (1.2, 0.0), (1.5, 650.0))


@pytest.fixture(scope="module")
def runtime():
    ts.init(arch="cpu", precision="f64")


# -- the spline -------------------------------------------------------------------------------

def test_spline_interpolates_its_points_exactly():
    s = Spline(POINTS)
    for t, v in POINTS:
        assert s(t) == v  # exactly, not approximately
    assert s(-1.0) == POINTS[0][1] and s(10.0) == POINTS[-1][1]  # held beyond the ends
    assert Spline(((2.0, 7.0),))(0.0) == 7.0


def test_spline_is_c1_and_never_overshoots():
    s = Spline(POINTS)
    for t, _ in POINTS:  # the derivative from the left meets the one from the right
        left, right = s.derivative(t - 1e-9), s.derivative(t + 1e-9)
        assert abs(left - right) < 1e-3 * max(1.0, abs(left)), (t, left, right)
    assert any(abs(s.derivative(t)) > 100 for t, _ in POINTS[1:-1])  # not flat at every knot
    ts_ = np.linspace(-0.5, 2.0, 5001)
    values = np.array([s(t) for t in ts_])
    # No jump: Fritsch–Carlson slopes are at most 3x the steepest secant.
    secant = max(abs(v1 - v0) / (t1 - t0) for (t0, v0), (t1, v1) in zip(POINTS, POINTS[1:]))
    assert np.all(np.abs(np.diff(values)) <= 3 * secant * (ts_[1] - ts_[0]) * 1.001)
    # Monotone (Fritsch–Carlson) tangents: each segment stays between its end values.
    for (t0, v0), (t1, v1) in zip(POINTS, POINTS[1:]):
        inside = values[(ts_ >= t0) & (ts_ <= t1)]
        assert inside.min() >= min(v0, v1) - 1e-9 and inside.max() <= max(v0, v1) + 1e-9
    # The analytic derivative matches finite differences.
    for t in (0.1, 0.41, 1.0, 1.33):
        fd = (s(t + 1e-6) - s(t - 1e-6)) / 2e-6
        assert abs(s.derivative(t) - fd) < 1e-4 * max(1.0, abs(fd))


def test_spline_integral_is_exact():
    s = Spline(POINTS)
    t = np.linspace(-0.3, 1.9, 200_001)
    numeric = np.trapezoid([s(x) for x in t], t)
    assert abs(s.integral(-0.3, 1.9) - numeric) < 1e-6 * abs(numeric)
    assert s.integral(0.2, 0.7) == pytest.approx(s.integral(0.2, 0.45) + s.integral(0.45, 0.7), rel=1e-13)


# -- files ------------------------------------------------------------------------------------

def test_save_load_round_trip_is_identical(tmp_path):
    curves = {"rate": Spline(POINTS), "spread": Spline(((0.0, 5.0), (1.0 / 3.0, 30.000000000000004)))}
    path = save_curves(tmp_path / "c.json", curves, "sprinkler")
    loaded = load_curves(path, scene_preset("sprinkler"))
    assert loaded == curves and loaded["spread"].points == curves["spread"].points
    assert save_curves(tmp_path / "d.json", loaded, "sprinkler").read_text() == path.read_text()


def _doc(**change):
    doc = {"format": "taichi-sim curves", "version": 1, "scene": "sprinkler",
           "curves": {"rate": [[0, 10], [1, 20]]}}
    doc.update(change)
    return json.dumps(doc)


@pytest.mark.parametrize("text, words", [
    ("{not json", "not JSON"),
    ("[1, 2]", "JSON object"),
    (_doc(version=2), "version 2"),
    (_doc(format="other"), "not a curves file"),
    (_doc(scene="cloth"), "made for scene 'cloth'"),
    (_doc(curves={"wibble": [[0, 1]]}), "no parameter 'wibble'"),
    (_doc(curves={"capacity": [[0, 100]]}), "cannot change while"),
    (_doc(curves={"rate": [[0, 1], [2, 3], [1, 4]]}), "increase strictly"),
    (_doc(curves={"rate": [[0, 1], [0, 3]]}), "increase strictly"),
    (_doc(curves={"rate": []}), "non-empty"),
    (_doc(curves={"rate": [[0, -5]]}), "must be >= 0"),
    (_doc(curves={"rate": [[-1, 5]]}), "time must be >= 0"),
    (_doc(curves={"rate": [[0, "5"]]}), "must be a number"),
    (_doc(curves={"rate": [[0, 1, 2]]}), "[t, value] pair"),
    (_doc(curves={"rate": [[k, 1] for k in range(MAX_POINTS + 1)]}), f"at most {MAX_POINTS}"),
    ('{"format": "taichi-sim curves", "version": 1, "curves": {"rate": [[0, NaN]]}}', "NaN"),
    ('{"format": "taichi-sim curves", "version": 1, "curves": {"rate": [[0, 1e999]]}}', "finite"),
    ('{"format": "taichi-sim curves", "version": 1, "version": 1, "curves": {}}', "twice"),
])
def test_bad_curves_are_refused_naming_the_culprit(text, words):
    with pytest.raises(ConfigError, match=None) as info:
        parse_curves(text, scene_preset("sprinkler"))
    assert words in str(info.value)


def test_cli_refuses_a_bad_curves_file_with_exit_2_and_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(_doc(curves={"rate": [[0, 1], [0.5, float("nan")]]}).replace("NaN", "NaN"))
    out = tmp_path / "out.npz"
    for argv in (["simulate", "sprinkler", "--steps", "3", "--out", str(out)],
                 ["record", "sprinkler", "--seconds", "0.1", "--out", str(tmp_path / "a.gif")]):
        assert main([*argv, "--curves", str(bad)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "--curves" in err and "NaN" in err
    assert main(["simulate", "sprinkler", "--steps", "3", "--out", str(out),
                 "--curves", str(tmp_path / "missing.json")]) == 2
    assert list(tmp_path.iterdir()) == [bad]


# -- driving a scene --------------------------------------------------------------------------

def test_sprinkler_emits_the_integral_of_its_rate_curve(runtime, tmp_path):
    curve = Spline(((0.0, 0.0), (0.1, 700.0), (0.25, 150.0), (0.4, 500.0)))
    path = save_curves(tmp_path / "rate.json", {"rate": curve}, "sprinkler")
    out = tmp_path / "s.npz"
    dt, t_end = 3e-3, 0.5
    assert main(["simulate", "sprinkler", "--t-end", str(t_end), "--dt", str(dt), "--set", "capacity=400",
                 "--set", "lifetime=5", "--curves", str(path), "--out", str(out), "--quiet"]) == 0
    data = np.load(out)
    expected = curve.integral(0.0, t_end)  # about 200 particles
    assert expected - 1 < int(data["emitted"]) <= expected
    assert int(data["alive"].sum()) == int(data["emitted"])  # none died, none recycled
    recorded = json.loads(str(data["curves"]))
    assert parse_curves(json.dumps(recorded), scene_preset("sprinkler")) == {"rate": curve}
    # Without curves the npz still counts what was emitted: rate * t, to within one.
    plain = tmp_path / "p.npz"
    assert main(["simulate", "sprinkler", "--t-end", str(t_end), "--dt", str(dt), "--set", "capacity=400",
                 "--set", "rate=300", "--out", str(plain), "--quiet"]) == 0
    p = np.load(plain)
    assert 149 <= int(p["emitted"]) <= 150 and "curves" not in p.files


def test_driver_applies_values_and_refuses_what_the_scene_lacks(runtime):
    scene = build_scene("sprinkler", {"capacity": 20})
    driver = CurveDriver(scene, {"speed": Spline(((0.0, 1.0), (1.0, 3.0))),
                                 "spread": Spline(((0.0, 4.0),))})
    driver.apply(0.5)
    assert scene.emitter.spec.speed == pytest.approx(2.0) and scene.emitter.spec.spread == 4.0
    scene.restore()
    assert scene.emitter.spec.speed == 3.5  # as built
    cloth = build_scene("cloth", {"nx": 4, "ny": 4})
    with pytest.raises(ConfigError, match="wind_speed"):
        CurveDriver(cloth, check_curves({"wind_speed": Spline(((0.0, 1.0),))}, scene_preset("cloth")))


def test_sphere_speed_curve_moves_the_sphere_without_a_jump(runtime):
    scene = build_scene("cloth-tear", {"nx": 4, "ny": 4})
    driver = CurveDriver(scene, {"sphere_speed": Spline(((0.0, 0.6), (0.2, 0.0)))})
    y = []
    for k in range(40):
        driver.apply(k * 0.01)
        scene.spheres.move_to((k + 1) * 0.01)
        y.append(scene.spheres.centers()[0, 1])
    drops = -np.diff(y)
    assert np.all(drops >= -1e-12) and drops[-1] == pytest.approx(0.0, abs=1e-12)  # slows to a stop
    assert abs(y[0] - 1.5 + 0.006) < 1e-9 and np.all(np.abs(np.diff(drops)) < 1e-3)


# -- the curve editor (no window) -------------------------------------------------------------

def test_curve_editor_adds_drags_and_deletes_points_with_the_mouse(runtime, tmp_path):
    from taichi_sim.app.curve_editor import CurveEditor
    from taichi_sim.app.session import Session

    session = Session("sprinkler", ["symplectic_euler"], params={"capacity": 200}, dt=0.01, substeps=5)
    editor = CurveEditor(session, (1000, 500))
    assert editor.param == "rate" and {"rate", "speed", "spread"} <= set(editor.choices())
    view = editor.view()
    for t, value in ((0.0, 0.0), (3.7, 123.0), (10.0, 1600.0)):
        u, v = view.to_window(t, value)
        assert view.to_curve(u, v) == pytest.approx((t, value))

    def click(t, value, button="left"):
        u, v = editor.view().to_window(t, value)
        assert editor.update(u, v, left=button == "left", right=button == "right")
        editor.update(u, v, left=False, right=False)

    click(1.0, 200.0)
    click(4.0, 800.0)
    click(2.0, 600.0)
    assert [t for t, _ in editor.points()] == pytest.approx([1.0, 2.0, 4.0])
    assert "rate" in session.curves and session.curves["rate"](2.0) == pytest.approx(600.0)
    # Drag the middle point past its right neighbour: its time stops just short of it.
    u, v = editor.view().to_window(2.0, 600.0)
    editor.update(u, v, left=True, right=False)
    u2, v2 = editor.view().to_window(9.0, 300.0)
    editor.update(u2, v2, left=True, right=False)
    editor.update(u2, v2, left=False, right=False)
    (t1, v1) = editor.points()[1]
    assert 3.9 < t1 < 4.0 and v1 == pytest.approx(300.0, rel=1e-6)
    # Dragged below the parameter's minimum (rate >= 0): held at 0.
    u, v = editor.view().to_window(1.0, 200.0)
    editor.update(u, v, left=True, right=False)
    editor.update(u, editor.rect[1], left=True, right=False)
    editor.update(u, editor.rect[1], left=False, right=False)
    assert editor.points()[0][1] >= 0.0
    click(*editor.points()[2], button="right")  # delete the last point
    assert len(editor.points()) == 2
    # Outside the strip the mouse is not the editor's.
    assert not editor.update(0.1, 0.9, left=True, right=False)
    # The session runs along the curve: the emitter launches its integral.
    spline = session.curves["rate"]
    for _ in range(20):
        session.frame()
    t = session.runners[0].t
    assert spline.integral(0.0, t) - 1 < session.runners[0].scene.emitter.emitted <= spline.integral(0.0, t)
    # Save, clear, load: the same curve again.
    editor.save(tmp_path / "c.json")
    editor.clear()
    assert session.curves == {} and editor.points() == []
    editor.load(tmp_path / "c.json")
    assert session.curves == {"rate": spline}
    editor.select("spread")
    for k in range(MAX_POINTS):
        assert editor.add(0.1 * k, 5.0) is not None
    assert editor.add(99.0, 5.0) is None and str(MAX_POINTS) in editor.message


def test_wind_curve_drives_a_cloth_run(runtime, tmp_path):
    curves = {"wind_speed": Spline(((0.0, 0.0), (0.05, 6.0))), "wind_heading": Spline(((0.0, 0.0), (0.05, 90.0)))}
    path = save_curves(tmp_path / "w.json", curves, "cloth-wind")
    out = tmp_path / "w.npz"
    assert main(["simulate", "cloth-wind", "--steps", "40", "--set", "nx=5", "--set", "ny=5",
                 "--curves", str(path), "--out", str(out), "--quiet"]) == 0
    data = np.load(out)
    assert str(data["status"]) == "ok" and "wind_speed" in str(data["curves"])
    scene = build_scene("cloth-wind", {"nx": 4, "ny": 4})
    driver = CurveDriver(scene, curves)
    assert driver.apply(0.05)
    wind = scene.system.term("wind")
    assert wind.speed[None] == pytest.approx(6.0)
    assert np.allclose(wind.direction[None].to_numpy(), [0.0, 0.0, 1.0], atol=1e-12)


def _draw_curve_strip(out: str) -> None:
    """In a child process: the launcher with the curve strip on, one frame, saved to ``out``
    (.npz: the image, the point markers, the time marker, the runner's time)."""
    from taichi_sim.app.launcher import Launcher
    from taichi_sim.app.session import Session
    from taichi_sim.render.vulkan import open_window

    ts.init(arch="cpu", precision="f64")
    size = (480, 320)
    session = Session("sprinkler", ["symplectic_euler"], params={"capacity": 50}, dt=0.05, substeps=10)
    window = open_window("curves test", size)
    try:
        launcher = Launcher(session, size, window=window)
        launcher.show_curves = True
        editor = launcher.editor
        editor.add(1.0, 300.0)
        editor.add(6.0, 1200.0)
        launcher.draw_frame()  # says the first step compiles, and steps nothing
        launcher.draw_frame()
        np.savez(out, image=launcher.renderer.read_image(), markers=np.asarray(editor.markers()),
                 now=editor.time_marker(), t=session.runners[0].t)
    finally:
        window.destroy()


def test_launcher_draws_the_curve_strip_offscreen(tmp_path):
    """The strip is drawn where the editor says: its points in the curve's colour, the time
    marker in its own (GGUI's canvas has v up, as the editor). Drawn in a child process, so its
    window never shares a test worker with the render tests' shared window (GGUI 1.7 supports
    one window at a time: closing one can break the others, see test_render.own_windows)."""
    import subprocess
    import sys
    from pathlib import Path

    from taichi_sim.app.curve_panel import CURVE_LINE, CURVE_NOW
    from taichi_sim.render import vulkan

    problem = vulkan.vulkan_problem()
    if problem:
        pytest.skip(f"no usable Vulkan: {problem}")
    out = tmp_path / "strip.npz"
    code = (f"import runpy; runpy.run_path({str(Path(__file__))!r})['_draw_curve_strip']({str(out)!r})")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 0, done.stderr[-2000:]
    drawn = np.load(out)
    image = drawn["image"].astype(int)
    size = (image.shape[1], image.shape[0])

    def near(uv, colour):
        r, c = int((1.0 - uv[1]) * size[1]), int(uv[0] * size[0])
        patch = image[max(r - 3, 0):r + 4, max(c - 3, 0):c + 4]
        return (np.abs(patch - np.round(np.asarray(colour) * 255)).max(axis=2) <= 40).any()

    for uv in drawn["markers"]:
        assert near(uv, CURVE_LINE)
    assert float(drawn["t"]) == pytest.approx(0.5) and near((float(drawn["now"]), 0.2), CURVE_NOW)
