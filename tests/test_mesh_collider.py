"""The triangle-mesh collider (taichi_sim.scene.colliders.mesh_collider): a cloth rests on a mesh
table with no vertex inside, friction holds it on a slope, a moving mesh pushes it, and the CLI
loads one from a file."""
import math

import numpy as np
import pytest
import trimesh

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.guard import injectable_energy, scene_facts
from taichi_sim.scene import cloth as topo
from taichi_sim.scene.builder import SceneBuilder
from taichi_sim.scene.colliders import SpherePath
from taichi_sim.scene.visual import describe

SKIN = 0.005


def cloth(n, size, height, *, gravity=9.81, stiffness=50.0, tilt=0.0):
    """A free n x n cloth of side ``size`` (m) at ``height``, turned by ``tilt`` (rad) about z."""
    x = topo.grid_positions(n, n, size, size, origin=(-size / 2, 0.0, -size / 2), u_axis=(1, 0, 0),
                            v_axis=(0, 0, 1))
    x = x @ rotation_z(tilt).T + [0.0, height, 0.0]
    b = SceneBuilder()
    b.add_particles(x, 0.01)
    ends, kind = topo.grid_springs(n, n)
    b.add_springs(ends, stiffness=stiffness, damping=0.01, kind=kind)
    b.add_triangles(topo.grid_triangles(n, n))
    b.set_gravity(gravity)
    return b


def rotation_z(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def box_distance(x, center, half):
    """Signed distance (m) of points x to the box: negative inside (independent of the code)."""
    q = np.abs(x - center) - half
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


def test_a_cloth_falls_onto_a_mesh_table_and_drapes_over_it_with_no_vertex_inside(f64):
    half = np.array([0.3, 0.2, 0.3])  # the top at y = 0.2, edges sharper than the cloth's spacing
    table = trimesh.creation.box(extents=2 * half)
    b = cloth(20, 0.9, 0.35)
    b.add_mesh_collider(table.vertices, table.faces, friction=0.3, skin=SKIN)
    scene = b.finalize(name="table", params={}, default_dt=2e-3, default_integrator="symplectic_euler")
    assert scene.features["collider_mesh"] == 12 and [p.name for p in scene.parts] == ["collider_mesh"]
    lowest = []
    for _ in range(8):
        result = ts.run(scene, "symplectic_euler", dt=2e-3, steps=50)
        assert result.status.value == "ok"
        x = scene.state.to_numpy()[0]
        lowest.append(box_distance(x, 0.0, half).min())
    assert min(lowest) >= SKIN * (1 - 1e-6)  # never inside, nor within the skin
    on_top = np.abs(x[:, [0, 2]]).max(axis=1) < 0.25
    assert np.allclose(x[on_top, 1], 0.2 + SKIN, atol=1e-3)  # resting on the top
    assert x[:, 1].min() < 0.1  # the rim hangs down over the edges
    (solid,) = describe(scene).solids
    assert len(solid.vertices) == 36 and np.allclose(solid.place(), 0.0)


def slide_on_slope(friction, steps=250):
    """A cloth starting at rest on a plane tilted 20 degrees (tan = 0.364): how far its centre
    moved (m) along the slope after ``steps`` of 4 ms."""
    tilt = math.radians(20.0)
    plane = 3.0 * np.array([[-1.0, 0.0, -1.0], [1.0, 0.0, -1.0], [1.0, 0.0, 1.0], [-1.0, 0.0, 1.0]]) @ rotation_z(tilt).T
    b = cloth(10, 0.3, 0.0, tilt=tilt)
    b.displace(np.tile(SKIN * rotation_z(tilt)[:, 1], (100, 1)))  # just on the skin
    b.add_mesh_collider(plane, [[0, 2, 1], [0, 3, 2]], friction=friction, skin=SKIN)
    scene = b.finalize(name="slope", params={}, default_dt=4e-3, default_integrator="symplectic_euler")
    start = scene.state.to_numpy()[0].mean(axis=0)
    assert ts.run(scene, "symplectic_euler", dt=4e-3, steps=steps).status.value == "ok"
    x = scene.state.to_numpy()[0]
    height = (x - [0.0, 0.0, 0.0]) @ rotation_z(tilt)[:, 1]
    assert height.min() >= SKIN * (1 - 1e-6)  # on the slope's upper side throughout
    return float(np.linalg.norm(x.mean(axis=0) - start))


def test_friction_holds_a_cloth_on_a_tilted_mesh_that_slides_without_it(f64):
    held, slid = slide_on_slope(0.6), slide_on_slope(0.0)
    g_along, h, t = 9.81 * math.sin(math.radians(20.0)), 4e-3, 1.0
    # without friction, symplectic Euler's slide g sin(20) t (t + h) / 2 (1.68 m); with mu above
    # tan(20) friction stops the velocity every step, and the position keeps only the step's own
    # slide g sin(20) h^2 (as every collider does: docs/collisions.md), g sin(20) h t in all
    assert slid == pytest.approx(0.5 * g_along * t * (t + h), rel=0.01)
    assert held <= 1.001 * g_along * h * t


def test_a_fast_moving_mesh_pushes_the_cloth_without_passing_through_it(f64):
    # a plate 2 cm thick rising at 5 m/s: 5 cm a step, more than its thickness and the skin
    plate = trimesh.creation.box(extents=(1.0, 0.02, 1.0))
    b = cloth(12, 0.5, 0.1, gravity=0.0)
    path = SpherePath((0.0, 0.0, 0.0), velocity=(0.0, 5.0, 0.0))
    b.add_mesh_collider(plate.vertices, plate.faces, path=path, skin=SKIN)
    scene = b.finalize(name="lift", params={}, default_dt=1e-2, default_integrator="symplectic_euler")
    assert ts.run(scene, "symplectic_euler", dt=1e-2, steps=10).status.value == "ok"
    x = scene.state.to_numpy()[0]
    top = 0.5 + 0.01  # the plate's centre after 0.1 s, plus its half thickness
    assert np.allclose(x[:, 1], top + SKIN, atol=1e-6)  # carried on its top
    assert np.allclose(scene.state.to_numpy()[1][:, 1], 5.0)
    energy, speed = injectable_energy(scene, scene_facts(scene), 1.0)["moving collider mesh"]
    assert speed == 10.0 and energy > 0
    assert np.allclose(scene.arrays["collider_mesh_center"], [0.0, 0.5, 0.0])
    scene.reset()
    assert np.allclose(scene.arrays["collider_mesh_center"], 0.0)


def test_the_cli_loads_a_collider_mesh_from_a_file_and_refuses_a_missing_one(tmp_path, capsys):
    path = tmp_path / "table.obj"
    trimesh.creation.box(extents=(0.6, 0.4, 0.6)).export(path)
    out = tmp_path / "run.npz"
    assert main(["simulate", "cloth", "--set", f"collider_mesh={path}", "--set", "nx=8", "--set", "ny=8",
                 "--set", "pin=none", "--set", "height=0.3", "--steps", "300",
                 "--out", str(out)]) == 0
    saved = np.load(out)
    assert saved["collider_mesh_triangles"].shape == (12, 3)
    assert box_distance(saved["x"], 0.0, np.array([0.3, 0.2, 0.3])).min() >= 0.005 * (1 - 1e-6)
    assert "collider mesh:" in capsys.readouterr().out
    missing = tmp_path / "missing.npz"
    assert main(["simulate", "cloth", "--set", "collider_mesh=nowhere.obj", "--steps", "1",
                 "--out", str(missing)]) == 2
    assert "collider_mesh" in capsys.readouterr().err and not missing.exists()


@pytest.mark.parametrize("triangles", [[[0, 1, 1]], [[0, 1, 5]]])
def test_degenerate_collider_meshes_are_refused(triangles):
    with pytest.raises(ValueError, match="collider_mesh"):
        SceneBuilder().add_mesh_collider(np.eye(3), triangles)


def test_the_self_contact_stage_keeps_the_cloth_out_of_the_mesh_too(f64, tmp_path):
    path = tmp_path / "table.stl"
    trimesh.creation.box(extents=(0.6, 0.4, 0.6)).export(path)
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6, "collider_mesh": str(path), "self_collision": True})
    mesh, stage = scene.part("collider_mesh"), scene.part("self_collision")
    assert stage.obstacles == (mesh,) and [p.name for p in scene.parts] == ["collider_mesh", "self_collision"]


def test_a_mesh_cloth_on_a_collider_mesh_defaults_to_the_method_that_meets_it_in_its_solve(tmp_path):
    # xpbd meets a collider mesh after the step, vertex by vertex: a moving body passes through
    # the garment while the run says ok (docs/meshes.md, "On a moving body"); vbd meets it inside
    ts.init(arch="cpu", precision="f32")
    body = tmp_path / "body.obj"
    trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(body)
    sheet = {"file": str(tmp_path / "sheet.obj"), "pin": "none"}
    u, w = np.meshgrid(np.linspace(-0.3, 0.3, 4), np.linspace(-0.3, 0.3, 4), indexing="ij")
    x = np.stack([u.ravel(), np.full(16, 0.5), w.ravel()], axis=1)
    trimesh.Trimesh(x, topo.grid_triangles(4, 4), process=False).export(sheet["file"])
    assert ts.build_scene("mesh", sheet).default_integrator == "xpbd"
    assert ts.build_scene("mesh", dict(sheet, collider_mesh=str(body))).default_integrator == "vbd"
