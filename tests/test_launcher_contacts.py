"""The launcher's contacts toggle (key x): the vertices vbd's solve holds in contact are the
ones its pair lists name (checked in numpy from the pair fields), the staged particles and
segments are theirs, stale pairs are not shown after a reset or a switch, a method without
contacts says so, and the window draws them. One small cloth-fold (12 x 12, no post-step
self-collision stage) for the whole module: compiling dominates."""
import types

import numpy as np
import pytest
import taichi as ti
from helpers import OffscreenWindows

import taichi_sim as ts
from taichi_sim.app.contacts_view import ContactsView, unavailable
from taichi_sim.app.input import KEYMAP, CameraControl, apply_key, help_lines
from taichi_sim.app.session import Session
from taichi_sim.geometry.distances import point_triangle_distance as _point_triangle_distance
from taichi_sim.geometry.distances import segment_distance as _segment_distance
from taichi_sim.geometry.distances import segment_point_distance as _segment_point
from taichi_sim.integrators import create_integrator
from taichi_sim.integrators.positional.vbd.contact import OBJECT_CONTACT, SELF_CONTACT
from taichi_sim.render import OrbitCamera
from taichi_sim.render.contacts import OBJECT, SELF

H = 1 / 60
SIZE = (320, 240)
PARAMS = {"nx": 12, "ny": 12, "self_collision": False, "jitter": 0.002}
WINDOWS = OffscreenWindows(SIZE)
runtime, window, own_windows = WINDOWS.fixtures()


@pytest.fixture(scope="module")
def session(runtime):
    """A launcher session of the fold with vbd and self-contact in the solve."""
    s = Session("cloth-fold", ["vbd"], params=PARAMS, dt=H, substeps=1,
                integrator_options={"vbd": {"self_contact": True}})
    s.set_integrator(0, "vbd")
    return s


def with_contacts(session, steps: int = 150):
    """Step the session (one step a frame) until vbd's last detection kept self-contact pairs
    and some vertex is on the ground; returns the runner."""
    runner = session.runners[0]
    contact = runner.integrator.contact
    for _ in range(steps):
        if contact.pair_total() and on_ground(runner).any():
            return runner
        session.frame()
        assert not runner.frozen, runner.message
    pytest.fail(f"no contacts after {steps} steps")


def on_ground(runner):
    """(n,) bool: vertices within vbd's contact radius of the ground plane, in numpy."""
    contact = runner.integrator.contact
    x = runner.scene.state.to_numpy()[0]
    plane = runner.scene.plane
    return (x - plane.point_np) @ plane.normal_np < contact.radius


def pairs_of(contact):
    """(ids (P, 4), kinds (P,)) of the pairs the last detection kept, read from its fields."""
    total = min(int(contact.pair_count[None]), contact.pair_capacity)
    return contact.pair_ids.to_numpy()[:total], contact.pair_kind.to_numpy()[:total]


def fake_renderer(runner, offset):
    """What ContactsView reads of a renderer: the panels' visuals and offsets (m)."""
    from taichi_sim.scene.visual import describe

    return types.SimpleNamespace(visuals=[describe(runner.scene)], offsets=[np.asarray(offset, float)])


def test_the_marked_vertices_are_those_in_the_solvers_pairs_and_on_the_ground(session):
    runner = with_contacts(session)
    contact = runner.integrator.contact
    ids, _ = pairs_of(contact)
    flags = ti.field(ti.i32, runner.scene.system.particle_count)
    count = contact.contact_vertices(runner.scene.state.x, runner.t, flags)
    marked = flags.to_numpy()
    in_pairs = np.zeros(len(marked), bool)
    in_pairs[np.unique(ids.ravel())] = True
    assert in_pairs.any()
    np.testing.assert_array_equal((marked & SELF_CONTACT) != 0, in_pairs)
    np.testing.assert_array_equal((marked & OBJECT_CONTACT) != 0, on_ground(runner))
    assert count == np.count_nonzero(marked) == np.count_nonzero(in_pairs | on_ground(runner))


def test_the_view_stages_the_marked_vertices_and_each_pairs_closest_points(session):
    runner = with_contacts(session)
    contact = runner.integrator.contact
    offset = np.array([0.5, -0.25, 0.125])
    view = ContactsView()
    view.update(session.runners, fake_renderer(runner, offset), on=True)
    assert len(view.shown) == 1
    drawer = view.shown[0]
    x = runner.scene.state.to_numpy()[0]
    ids, kinds = pairs_of(contact)
    in_pairs = np.zeros(len(x), bool)
    in_pairs[np.unique(ids.ravel())] = True
    ground = on_ground(runner)
    marked = in_pairs | ground
    # the particles: every marked vertex once, where it is, magenta when paired, else green
    points = drawer.points.to_numpy()[:drawer.point_count]
    colours = drawer.point_colours.to_numpy()[:drawer.point_count]
    assert drawer.point_count == marked.sum()
    assert drawer.self_count == in_pairs.sum() and drawer.object_count == ground.sum()
    which = np.argmin(np.linalg.norm(points[:, None, :] - (x + offset)[None], axis=2), axis=1)
    np.testing.assert_array_equal(np.sort(which), np.flatnonzero(marked))
    np.testing.assert_allclose(points, x[which] + offset, atol=1e-5)
    np.testing.assert_allclose(colours, np.where(in_pairs[which, None], SELF, OBJECT), atol=1e-6)
    # the segments: one per pair, between its closest points (their distance is the pair's)
    assert drawer.pair_count == len(ids) and drawer.segment_count == len(ids)
    ends = drawer.segments.to_numpy()[:2 * len(ids)].reshape(-1, 2, 3) - offset
    p = x[ids]
    expected = np.where(kinds == 0, _point_triangle_distance(p[:, 0], p[:, 1], p[:, 2], p[:, 3]),
                        _segment_distance(p[:, 0], p[:, 1], p[:, 2], p[:, 3]))
    np.testing.assert_allclose(np.linalg.norm(ends[:, 0] - ends[:, 1], axis=1), expected, atol=2e-5)
    # ... and on their primitives: the vertex and its triangle, or the two edges
    vt, ee = kinds == 0, kinds == 1
    assert vt.any() and ee.any()
    np.testing.assert_allclose(ends[vt, 0], p[vt, 0], atol=1e-5)
    assert _point_triangle_distance(ends[vt, 1], p[vt, 1], p[vt, 2], p[vt, 3]).max() < 2e-5
    assert _segment_point(ends[ee, 0], p[ee, 0], p[ee, 1]).max() < 2e-5
    assert _segment_point(ends[ee, 1], p[ee, 2], p[ee, 3]).max() < 2e-5
    line = view.notes[0][0]
    assert f"{drawer.self_count} vertices in self-contact" in line and f"{len(ids)} pairs" in line
    assert f"{drawer.object_count} touching objects" in line


def test_after_a_reset_or_a_switch_no_stale_pair_is_shown(session):
    """Pairs found at positions a reset or an integrator switch has left behind are forgotten:
    at the fold's start (in the air, no two layers near) nothing is marked."""
    runner = with_contacts(session)
    flags = ti.field(ti.i32, runner.scene.system.particle_count)
    session.set_integrator(0, "symplectic_euler")
    session.set_integrator(0, "vbd")
    assert runner.integrator.contact.pair_total() == 0  # the pairs were found elsewhere
    runner = with_contacts(session)
    session.reset()
    contact = runner.integrator.contact
    assert contact.pair_total() == 0
    assert contact.contact_vertices(runner.scene.state.x, runner.t, flags) == 0
    assert not flags.to_numpy().any()
    view = ContactsView()
    view.update(session.runners, fake_renderer(runner, (0, 0, 0)), on=True)
    drawer = view.shown[0]
    assert drawer.point_count == drawer.segment_count == 0
    assert view.notes[0][0].startswith("contacts: 0 vertices in self-contact (magenta, 0 pairs)")


def test_a_method_without_contacts_says_so_and_nothing_is_gathered_while_off(session):
    runner = session.runners[0]
    view = ContactsView()
    view.update(session.runners, fake_renderer(runner, (0, 0, 0)), on=False)
    assert not view.shown and not view.notes  # off: nothing gathered, nothing said
    session.set_integrator(0, "symplectic_euler")
    try:
        view.update(session.runners, fake_renderer(runner, (0, 0, 0)), on=True)
        assert not view.shown
        assert "symplectic_euler keeps no contacts (only vbd" in view.notes[0][0]
        assert view.panel_note().startswith("nothing to show: symplectic_euler keeps no contacts")
    finally:
        session.set_integrator(0, "vbd")
    # vbd on a scene with nothing to touch (no ground, no objects) and self_contact off
    cloth = ts.build_scene("cloth", {"nx": 4, "ny": 4})
    vbd = create_integrator("vbd", cloth.system)
    vbd.bind_contact(cloth.contact_inputs())
    assert vbd.contact is None
    assert "vbd has no contact in its solve here" in unavailable(vbd)
    assert "self_contact=1" in unavailable(vbd)


def test_the_key_toggles_the_contacts_and_the_help_lists_it(session):
    assert KEYMAP["x"][0] == "contacts"
    assert any(line.strip().startswith("x") and "contacts" in line for line in help_lines())
    control = CameraControl(OrbitCamera(1.5, distance=2.0), lambda: None)
    before = session.options.contacts
    assert apply_key("x", session, control) == "contacts"
    assert session.options.contacts is not before
    apply_key("x", session, control)
    assert session.options.contacts is before


def magenta(image):
    """(H, W) bool: pixels of the self-contact colour's hue (lit or shaded)."""
    rgb = image.astype(int)
    return (rgb[..., 0] > 110) & (rgb[..., 2] > 90) & (rgb[..., 1] < 0.6 * rgb[..., 0])


def test_the_launcher_draws_the_contacts_when_toggled(session, window):
    from taichi_sim.app.launcher import Launcher

    with_contacts(session)
    session.paused = True  # the same state in both frames
    launcher = Launcher(session, SIZE, window=window)
    session.options.contacts = False
    launcher.draw_frame()
    without = launcher.renderer.read_image()
    session.options.contacts = True
    launcher.draw_frame()
    image = launcher.renderer.read_image()
    drawer = launcher.contacts_view.shown[0]
    assert drawer.self_count > 0
    assert any(line.startswith("contacts: ") for line, _ in launcher.contacts_view.notes)
    added = magenta(image) & ~magenta(without)
    assert added.sum() >= 3, "no magenta particle drawn"
    # where they were drawn: at the paired vertices' pixels
    points = drawer.points.to_numpy()[:drawer.point_count][drawer.point_colours.to_numpy()[:drawer.point_count, 1] < 0.5]
    uv, depth = launcher.renderer.camera.project(points.astype(float))
    rows = ((1.0 - uv[:, 1]) * SIZE[1]).astype(int)
    cols = (uv[:, 0] * SIZE[0]).astype(int)
    inside = (depth > 0) & (rows >= 0) & (rows < SIZE[1]) & (cols >= 0) & (cols < SIZE[0])
    near = [added[max(r - 2, 0):r + 3, max(c - 2, 0):c + 3].any() for r, c in zip(rows[inside], cols[inside])]
    assert np.mean(near) > 0.5, np.mean(near)


def test_the_command_line_guide_lists_every_key():
    """docs/cli.md's key table holds every key of the launcher's map."""
    import pathlib

    text = (pathlib.Path(__file__).parent.parent / "docs" / "cli.md").read_text()
    # the indented table under "Mouse and keys" (the npz's table, not indented, names keys too)
    firsts = [line.split("|")[1] for line in text.splitlines() if line.startswith("  | `")]
    listed = {key.strip("` ") for cell in firsts for key in cell.split("/")}
    assert {"space" if key == " " else key for key in KEYMAP} <= listed


def test_record_draws_the_contacts_when_asked(own_windows, tmp_path, capsys):
    """``record --contacts``: the same clip's last frame gains magenta pixels (the contacts) over
    the one recorded without; a flag the showcase cannot take is refused."""
    import imageio.v2 as imageio

    from taichi_sim.cli import main

    last = {}
    for flag in ([], ["--contacts"]):
        out = tmp_path / ("with" if flag else "without")
        assert main(["record", "cloth-fold", "--integrator", "vbd", "--dt", str(H), *sum(
            (["--set", f"{k}={v}"] for k, v in PARAMS.items() if k != "self_collision"), []),
            "--seconds", "1.5", "--fps", "4", "--size", "240x180", *flag, "--out", f"{out}/", "--quiet"]) == 0
        last[bool(flag)] = imageio.imread(sorted(out.iterdir())[-1])[..., :3]
    assert (magenta(last[True]) & ~magenta(last[False])).sum() >= 3
    assert main(["record", "--showcase", str(tmp_path / "s"), "--contacts"]) == 2
    assert "drop --contacts" in capsys.readouterr().err
