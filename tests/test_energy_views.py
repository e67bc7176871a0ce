"""The energy views: samples of a run's energy by component, their ring buffer, the chart
layout (pure numpy), the strain legend, and what they draw offscreen.

Drawing tests open and destroy their own window, as tests/test_render.py does (GGUI supports
one window per process); the rest need no window.
"""
import numpy as np
import pytest
import taichi as ti
from helpers import OffscreenWindows

import taichi_sim as ts
from taichi_sim.app.energy import EnergySample, EnergyTrace, curves_of, sample
from taichi_sim.app.energy_view import EnergyView, panel_centres
from taichi_sim.app.record import CHART_AREA, LEGEND, Clip, record
from taichi_sim.app.runner import Runner
from taichi_sim.app.session import Session
from taichi_sim.render import Renderer, vulkan
from taichi_sim.render.chart import (
    CURVE_COLOURS,
    PLOT_BACKGROUND,
    Rect,
    chart_rects,
    common_ranges,
    curve_points,
    energy_charts,
    legend_bar,
    segments,
    strain_colours,
)
from taichi_sim.scene import build_scene

SIZE = (320, 200)
WINDOWS = OffscreenWindows(SIZE)
runtime, window, _ = WINDOWS.fixtures()


def _rgb(colour):
    return np.round(np.asarray(colour) * 255).astype(int)


def _pixels_near(image, colour, tolerance=40):
    return np.all(np.abs(image.astype(int) - _rgb(colour)) <= tolerance, axis=-1)


def _px_box(rect: Rect, size):
    """(rows, cols) slices of ``rect`` (normalised, y up) in an image of ``size`` (w, h)."""
    w, h = size
    return (slice(int((1 - rect.y1) * h), int(np.ceil((1 - rect.y0) * h))),
            slice(int(rect.x0 * w), int(np.ceil(rect.x1 * w))))


# -- sampling ---------------------------------------------------------------------------------------

def test_components_sum_to_the_total_and_match_the_run_energy(runtime):
    scene = build_scene("pendulum", {"particle_count": 4})
    result = ts.run(scene, "symplectic_euler", dt=1e-3, steps=200)
    s = sample(scene, result.t)
    assert s.kinetic > 0 and s.gravity < 0 and s.spring > 0  # it swung, fell and stretched
    assert s.kinetic + s.gravity + s.spring == pytest.approx(s.total, rel=1e-12, abs=1e-12)
    # Against the other energy path (each term's own reduction) and the run's last sample.
    assert s.total == pytest.approx(scene.system.energy(scene.state), rel=1e-12, abs=1e-12)
    assert s.total == pytest.approx(result.energy[-1], rel=1e-12, abs=1e-12)
    assert s.kinetic == pytest.approx(scene.system.kinetic_energy(scene.state), rel=1e-12)
    assert s.gravity == pytest.approx(scene.system.term("gravity").energy(scene.state), rel=1e-12)
    assert s.spring == pytest.approx(scene.system.term("springs").energy(scene.state), rel=1e-12)


def test_the_ring_buffer_keeps_the_last_n_in_order():
    trace = EnergyTrace(4)
    for k in range(10):
        trace.add(EnergySample(t=0.1 * k, kinetic=k, gravity=-k, spring=2 * k, total=2 * k))
    assert len(trace) == 4
    np.testing.assert_allclose(trace.times(), [0.6, 0.7, 0.8, 0.9])
    np.testing.assert_allclose(trace.values("spring"), [12, 14, 16, 18])
    assert trace.last().kinetic == 9
    trace.add(EnergySample(t=0.0, kinetic=1, gravity=0, spring=0, total=1))  # a restart
    assert len(trace) == 1 and trace.times()[0] == 0.0
    with pytest.raises(ValueError, match="capacity"):
        EnergyTrace(1)
    with pytest.raises(ValueError, match="name"):
        trace.values("heat")


def test_a_runner_samples_at_its_guard_checks_only(runtime):
    runner = Runner(build_scene("spring"), "symplectic_euler", 0.01)
    checks = runner.guard.checks
    for _ in range(5):
        runner.advance(0.1)
    trace = runner.energy_trace
    assert len(trace) == 1 + runner.guard.checks - checks  # the start, then one per check
    assert trace.times()[-1] == pytest.approx(runner.t)
    assert trace.last().total == runner.energy
    runner.reset()
    assert len(trace) == 1 and trace.times()[0] == 0.0


def test_scenes_without_springs_have_no_spring_curve(runtime):
    sprinkler = build_scene("sprinkler")
    assert curves_of(sprinkler) == ("kinetic", "gravity", "total")
    assert curves_of(build_scene("simple")) == ()  # no energy: no plot
    assert curves_of(build_scene("spring")) == ("kinetic", "gravity", "spring", "total")
    runner = Runner(sprinkler, "symplectic_euler", 0.01)
    runner.advance(0.2)
    view = EnergyView(CHART_AREA, LEGEND)
    view.update([runner], [0.5])
    lines, colours, _, _ = view.arrays()
    assert len(lines)
    spring = np.all(np.isclose(colours, CURVE_COLOURS["spring"]), axis=1)
    kinetic = np.all(np.isclose(colours, CURVE_COLOURS["kinetic"]), axis=1)
    assert kinetic.any() and not spring.any()


# -- layout (numpy) ---------------------------------------------------------------------------------

def test_samples_map_into_the_chart_rectangle():
    rect = Rect(0.2, 0.1, 0.6, 0.3)
    t = np.linspace(0.0, 2.0, 21)
    panels = [(t, {"kinetic": np.sin(t), "total": np.ones_like(t)}),
              (t[:11], {"kinetic": 3 * t[:11], "total": np.ones(11)})]
    t_range, v_range = common_ranges(panels)
    assert t_range == (0.0, 2.0)
    assert v_range[0] < np.sin(t).min() and v_range[1] > 3.0  # both panels, with margins
    p = curve_points(t, np.sin(t), rect, t_range, v_range)
    assert p[0, 0] == pytest.approx(rect.x0) and p[-1, 0] == pytest.approx(rect.x1)
    assert np.all((p[:, 1] > rect.y0) & (p[:, 1] < rect.y1))
    # The largest value of all panels sits 5 % of the span below the top.
    top = curve_points(t[:11], 3 * t[:11], rect, t_range, v_range)[-1, 1]
    assert (rect.y1 - top) / rect.height == pytest.approx(0.05 / 1.1)
    np.testing.assert_allclose(curve_points([5.0], [np.inf], rect, t_range, v_range), [[0.6, 0.3]])
    seg = segments(p)
    assert seg.shape == (40, 2) and np.array_equal(seg[1], seg[2])
    g = energy_charts(panels, [rect, Rect(0.7, 0.1, 0.9, 0.3)])
    x = g.lines[:, 0]
    inside = ((x >= 0.2) & (x <= 0.6)) | ((x >= 0.7) & (x <= 0.9))
    assert inside.all() and np.all((g.lines[:, 1] >= 0.1) & (g.lines[:, 1] <= 0.3))


def test_charts_sit_under_their_panels_inside_the_area():
    area = Rect(0.05, 0.05, 0.95, 0.3)
    rects = chart_rects([0.7, 0.3], area)
    assert rects[0].x0 > rects[1].x1  # the order of the centres
    for rect, c in zip(rects, [0.7, 0.3]):
        assert rect.x0 >= area.x0 and rect.x1 <= area.x1
        assert 0.5 * (rect.x0 + rect.x1) == pytest.approx(c)
    edge = chart_rects([0.01, 0.99], area)
    assert edge[0].x0 == area.x0 and edge[1].x1 == pytest.approx(area.x1)
    with pytest.raises(ValueError, match="x0 < x1"):
        Rect(0.5, 0.0, 0.5, 1.0)


def test_the_legend_colours_match_the_strain_colour_map_at_its_ends(runtime):
    from taichi_sim.render.drawer import _colormap

    ends = ti.Vector.field(3, ti.f64, 2)

    @ti.kernel
    def kernel_colours():
        ends[0] = _colormap(0.0)
        ends[1] = _colormap(1.0)

    kernel_colours()
    np.testing.assert_allclose(strain_colours(np.array([0.0, 1.0])), ends.to_numpy(), atol=1e-6)
    verts, colours = legend_bar(LEGEND, bands=64)
    bottom, top = colours[np.argmin(verts[:, 1])], colours[np.argmax(verts[:, 1])]
    np.testing.assert_allclose(bottom, ends.to_numpy()[0], atol=0.05)  # half a band in
    np.testing.assert_allclose(top, ends.to_numpy()[1], atol=0.05)


# -- drawing ----------------------------------------------------------------------------------------

def test_a_drawn_frame_has_the_plot_in_its_rectangle_and_the_legend_in_its_colours(window):
    session = Session("pendulum", ["euler", "symplectic_euler"], params={"particle_count": 3})
    session.options.strain = True
    for _ in range(4):
        session.advance(0.05)
    renderer = Renderer(window, session.visuals(), SIZE, bottom=CHART_AREA.y1 + 0.02)
    view = EnergyView(CHART_AREA, LEGEND)
    view.update(session.runners, panel_centres(renderer), strain_scale=0.1)
    renderer.render([r.display for r in session.runners], session.options, overlay=view.draw)
    image = renderer.read_image()
    assert len(view.geometry.rects) == 2
    for rect in view.geometry.rects:
        box = image[_px_box(rect, SIZE)]
        assert _pixels_near(box, PLOT_BACKGROUND, 6).mean() > 0.5  # the chart is there
        for name in ("kinetic", "gravity"):  # the stiff links' energy hides under the total
            assert _pixels_near(box, CURVE_COLOURS[name]).any(), name
    outside = image.copy()
    for rect in view.geometry.rects:
        outside[_px_box(rect, SIZE)] = 0
    assert not _pixels_near(outside, CURVE_COLOURS["kinetic"], 20).any()
    bar = image[_px_box(LEGEND, SIZE)]
    ends = strain_colours(np.array([0.0, 1.0]))
    assert _pixels_near(bar[-3], ends[0], 25).mean() > 0.5  # coolest at the bottom
    assert _pixels_near(bar[2], ends[1], 25).mean() > 0.5  # hottest at the top


def test_record_with_energy_and_strain_writes_charts_and_legend(runtime, tmp_path):
    WINDOWS.release()
    if vulkan.vulkan_problem():
        pytest.skip("no usable Vulkan")
    size = (240, 160)
    clip = Clip(scene="cloth", integrators=("symplectic_euler",), params={"nx": 8, "ny": 8},
                seconds=0.3, fps=10, size=size, energy=True, strain=True)
    result = record(clip, f"{tmp_path}/frames/", progress=False)
    from PIL import Image
    last = np.asarray(Image.open(sorted(result.path.glob("*.png"))[-1]).convert("RGB"))
    chart = Rect(0.25, CHART_AREA.y0, 0.75, CHART_AREA.y1)  # one panel: the middle half
    box = last[_px_box(chart, size)]
    assert _pixels_near(box, CURVE_COLOURS["kinetic"]).any()
    bar = last[_px_box(LEGEND, size)]
    assert _pixels_near(bar[2], strain_colours(np.array([1.0]))[0], 25).any()


def test_the_launcher_draws_the_plot_and_labels_it_in_the_hud(window):
    from taichi_sim.app.input import apply_key
    from taichi_sim.app.launcher import Launcher

    session = Session("spring", ["euler", "symplectic_euler"], dt=0.01)
    launcher = Launcher(session, SIZE, window=window)
    for _ in range(3):
        launcher.draw_frame()
        image = launcher.renderer.read_image()
    view = launcher.energy_view
    assert view.geometry is not None and len(view.geometry.rects) == 2
    assert launcher.renderer.camera.bottom > view.area.y1  # the scenes are framed above the charts
    box = image[_px_box(view.geometry.rects[0], SIZE)]
    assert _pixels_near(box, PLOT_BACKGROUND, 6).mean() > 0.5
    hud = [text for text, _ in view.hud_lines()]
    assert hud[0].startswith("energy plot:") and any(t.startswith("  spring:") for t in hud)
    apply_key("e", session, launcher.control)  # off: no charts, full framing
    launcher.draw_frame()
    launcher.renderer.read_image()
    assert view.geometry is None and launcher.renderer.camera.bottom == 0.0


def test_record_side_by_side_plots_energy_unless_told_not_to(runtime, tmp_path):
    from PIL import Image

    from taichi_sim.cli import main

    WINDOWS.release()
    if vulkan.vulkan_problem():
        pytest.skip("no usable Vulkan")
    base = ["record", "spring", "--side-by-side", "euler,symplectic_euler", "--seconds", "0.4", "--fps", "5",
            "--size", "320x200", "--quiet", "--out"]
    plot_area = []
    for flag, folder in (([], "on"), (["--no-energy"], "off")):
        assert main(base + [f"{tmp_path}/{folder}/"] + flag) == 0
        last = np.asarray(Image.open(sorted((tmp_path / folder).glob("*.png"))[-1]).convert("RGB"))
        box = last[_px_box(Rect(0.0, CHART_AREA.y0 + 0.03, 1.0, CHART_AREA.y1 - 0.08), (320, 200))]
        plot_area.append(_pixels_near(box, PLOT_BACKGROUND, 4).mean())
    assert plot_area[0] > 0.15 and plot_area[1] < 0.01
