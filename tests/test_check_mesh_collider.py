"""`taichi-sim check` judges collider meshes: vertices and face samples against the closed
mesh, frame by frame, from the collider's pose the npz keeps with its frames (docs/cli.md)."""
import numpy as np
import pytest
import trimesh

from taichi_sim.cli import main
from taichi_sim.frame_check import check_run
from taichi_sim.geometry.mesh_inside import mesh_depths
from taichi_sim.scene import cloth as topo


def convex_depths(points, mesh):
    """Depth inside a convex mesh, from its face planes alone: inside when below every plane,
    as deep as the nearest plane (0 outside)."""
    heights = np.einsum("pfk,fk->pf", points[:, None] - mesh.triangles[None, :, 0], mesh.face_normals)
    return np.where((heights < 0).all(axis=1), -heights.max(axis=1), 0.0)


@pytest.mark.parametrize("mesh", [trimesh.creation.icosphere(3, 0.3), trimesh.creation.box(extents=(0.6, 0.4, 0.6))],
                         ids=["icosphere", "box"])
def test_depths_inside_a_convex_mesh_are_its_nearest_planes(mesh):
    points = np.random.default_rng(0).uniform(-0.4, 0.4, (20000, 3))
    points[:4000] = np.round(points[:4000] * 10) / 10  # on the box's vertices' and edges' lines
    depth = mesh_depths(points, mesh.vertices, mesh.faces)
    expected = convex_depths(points, mesh)
    assert 3000 < (depth > 0).sum() < 17000
    np.testing.assert_allclose(depth, expected, rtol=0, atol=1e-12)


def test_the_inside_of_a_torus_is_its_tube():
    # not convex: a ray from the hole crosses the mesh four times or none
    mesh = trimesh.creation.torus(0.3, 0.1)
    points = np.random.default_rng(1).uniform(-0.45, 0.45, (20000, 3))
    tube = np.hypot(np.hypot(points[:, 0], points[:, 1]) - 0.3, points[:, 2])
    clear = np.abs(tube - 0.1) > 0.01  # the tessellation is within a centimetre of the tube
    inside = mesh_depths(points, mesh.vertices, mesh.faces) > 0
    assert inside.sum() > 1000 and np.array_equal(inside[clear], (tube < 0.1)[clear])


BOX = trimesh.creation.box(extents=(0.4, 0.4, 0.4))  # about its origin, placed by a centre


def cloth(n=5, size=0.5, height=0.45):
    x = topo.grid_positions(n, n, size, size, (-size / 2, height, -size / 2), (1, 0, 0), (0, 0, 1))
    return x, topo.grid_triangles(n, n)


def run_npz(path, frames, times, *, centers=None, vertices=None, mesh=BOX, center=(0.0, 0.2, 0.0), history=True):
    """A run's npz as `simulate --save-every` writes one: the cloth's ``frames`` (S, N, 3) (a
    square grid) and the collider mesh, at ``center`` or, with ``centers`` (S, 3), on a path,
    and with ``vertices`` (S, V, 3) as a sequence of frames."""
    n = int(round(np.sqrt(frames.shape[1])))
    arrays = dict(scene=np.str_("cloth"), triangles=topo.grid_triangles(n, n), x=frames[-1], t=np.float64(times[-1]),
                  pinned=np.zeros(n * n, bool), collider_mesh_triangles=np.asarray(mesh.faces),
                  collider_mesh_vertices=np.asarray(mesh.vertices if vertices is None else vertices[-1], float),
                  collider_mesh_center=np.asarray(center if centers is None else centers[-1], float))
    if history:
        arrays.update(x_history=frames, t_history=np.asarray(times, float),
                      collider_mesh_center_history=np.tile(center, (len(frames), 1)) if centers is None else centers)
        if vertices is not None:
            arrays["collider_mesh_vertices_history"] = vertices
    np.savez(path, **arrays)
    return path


def check(path, capsys):
    code = main(["check", str(path)])
    return code, capsys.readouterr().out.splitlines()


def test_a_static_mesh_clear_of_the_cloth_passes(tmp_path, capsys):
    x, _ = cloth()
    code, lines = check(run_npz(tmp_path / "a.npz", np.stack([x, x]), [0.0, 0.1]), capsys)
    assert code == 0
    assert lines == ["cloth: 2 frame(s), no triangles intersect",
                     "cloth: no vertex inside the collider mesh in any frame",
                     "cloth: no face reaches into the collider mesh in any frame (25 points a triangle, deeper "
                     "than 1e-06 m)"]


def test_a_vertex_inside_a_static_mesh_fails(tmp_path, capsys):
    x, _ = cloth()
    pushed = x.copy()
    pushed[12, 1] = 0.3  # the middle vertex 0.1 m into the box (its top at y = 0.4)
    code, lines = check(run_npz(tmp_path / "a.npz", np.stack([x, pushed, x]), [0.0, 0.1, 0.2]), capsys)
    assert code == 1
    assert ("cloth: 1 of 3 frame(s) have vertices inside an object; first at t = 0.1 s, most (1 inside the "
            "collider mesh) at t = 0.1 s") in lines
    # its four triangles' samples follow it in
    assert any(line.startswith("cloth: 1 of 3 frame(s) have a face reaching into the collider mesh") and
               "deepest" in line for line in lines)


def test_a_mesh_reaching_between_the_vertices_fails_on_the_faces(tmp_path, capsys):
    # a post 0.2 m thick through the middle of a cell of a cloth 0.5 m apart: no vertex inside (and
    # the 25 points of a triangle, 8 cm apart, would miss a post much thinner)
    post = trimesh.creation.box(extents=(0.2, 0.6, 0.2))
    x, _ = cloth(n=3, size=1.0, height=0.1)
    code, lines = check(run_npz(tmp_path / "a.npz", np.stack([x, x]), [0.0, 0.1], mesh=post,
                                center=(0.25, 0.0, 0.2)), capsys)
    assert code == 1
    assert "cloth: no vertex inside the collider mesh in any frame" in lines
    assert lines[-1].startswith("cloth: 2 of 2 frame(s) have a face reaching into the collider mesh (25 points a "
                                "triangle, deeper than 1e-06 m); first at t = 0 s, deepest ")


def rising(offsets):
    """The box's vertices (S, V, 3) raised by ``offsets`` (m), one frame each."""
    return np.stack([BOX.vertices + [0.0, dy, 0.0] for dy in offsets])


def test_an_animated_mesh_is_judged_in_each_frames_pose(tmp_path, capsys):
    x, _ = cloth()
    frames, times = np.stack([x, x, x]), [0.0, 0.1, 0.2]
    # the box rises to just below the cloth and back: clear in every frame
    code, lines = check(run_npz(tmp_path / "a.npz", frames, times, vertices=rising([0.0, 0.04, 0.0])), capsys)
    assert code == 0 and "cloth: no vertex inside the collider mesh in any frame" in lines
    # through the cloth in the middle frame only, clear at the end (the file's final pose)
    code, lines = check(run_npz(tmp_path / "b.npz", frames, times, vertices=rising([0.0, 0.1, 0.0])), capsys)
    assert code == 1
    assert ("cloth: 1 of 3 frame(s) have vertices inside an object; first at t = 0.1 s, most (9 inside the "
            "collider mesh) at t = 0.1 s") in lines
    # the same motion as a rigid path
    centers = np.array([[0.0, 0.2, 0.0], [0.0, 0.3, 0.0], [0.0, 0.2, 0.0]])
    code, lines = check(run_npz(tmp_path / "c.npz", frames, times, centers=centers), capsys)
    assert code == 1 and any("1 of 3 frame(s) have vertices inside an object; first at t = 0.1 s" in line
                             for line in lines)


def test_the_final_frame_alone_and_an_older_file(tmp_path, capsys):
    x, _ = cloth()
    pushed = x.copy()
    pushed[12, 1] = 0.3
    code, lines = check(run_npz(tmp_path / "a.npz", pushed[None], [0.5], history=False), capsys)
    assert code == 1 and "most (1 inside the collider mesh)" in " ".join(lines)
    path = run_npz(tmp_path / "b.npz", np.stack([x, pushed]), [0.0, 0.1])
    with np.load(path) as data:  # saved before the poses were kept: the mesh is not judged
        arrays = {k: data[k] for k in data.files if k != "collider_mesh_center_history"}
    lines, passed = check_run(arrays)
    assert passed and lines[-1] == ("cloth: the collider mesh not checked: the file keeps no centres with its "
                                    "frames (saved by an older version)")


def test_poses_that_do_not_match_the_frames_are_refused(tmp_path, capsys):
    x, _ = cloth()
    path = run_npz(tmp_path / "a.npz", np.stack([x, x, x]), [0.0, 0.1, 0.2], vertices=rising([0.0, 0.1]))
    code = main(["check", str(path)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err == ("taichi-sim: error: collider_mesh_vertices_history holds 2 pose(s) for 3 saved "
                                 "frame(s): not a run's npz")


def platform(path, top):
    """A 1.2 x 0.1 x 1.2 m slab whose top is at y = ``top`` (m), written as a mesh file."""
    slab = trimesh.creation.box(extents=(1.2, 0.1, 1.2))
    slab.apply_translation((0.0, top - 0.05, 0.0))
    slab.export(path)
    return path


def test_a_cloth_landing_on_a_mesh_passes_check(tmp_path, capsys, f32):
    out = tmp_path / "run.npz"
    mesh = platform(tmp_path / "slab.obj", 0.15)
    assert main(["simulate", "cloth", "--set", "pin=none", "--set", "nx=12", "--set", "ny=12", "--set", "size=0.6",
                 "--set", "height=0.3", "--set", f"collider_mesh={mesh}", "--t-end", "0.4", "--save-every", "40",
                 "--out", str(out), "--quiet"]) == 0
    with np.load(out) as data:
        assert data["collider_mesh_center_history"].shape == (11, 3)
        assert data["x_history"][-1][:, 1].min() == pytest.approx(0.155, abs=1e-3)  # resting on it, at the skin
    code, lines = check(out, capsys)
    assert code == 0 and lines[1:] == ["cloth: no vertex inside the collider mesh in any frame",
                                       "cloth: no face reaches into the collider mesh in any frame (25 points a "
                                       "triangle, deeper than 1e-06 m)"]


def test_a_cloth_on_a_rising_mesh_keeps_its_poses_and_passes_check(tmp_path, capsys, f32):
    folder = tmp_path / "slab"
    folder.mkdir()
    for k, top in enumerate((0.15, 0.2, 0.25)):
        platform(folder / f"slab_{k}.obj", top)
    out = tmp_path / "run.npz"
    assert main(["simulate", "cloth", "--set", "pin=none", "--set", "nx=12", "--set", "ny=12", "--set", "size=0.6",
                 "--set", "height=0.3", "--set", f"collider_mesh={folder / 'slab_*.obj'}",
                 "--set", "collider_mesh_fps=5", "--t-end", "0.6", "--save-every", "60", "--out", str(out),
                 "--quiet"]) == 0
    with np.load(out) as data:
        poses, times = data["collider_mesh_vertices_history"], data["t_history"]
        frames, tops = data["x_history"], poses[:, :, 1].max(axis=1)
    # the slab's top where its frames put it at each saved time (0.25 m/s from 0.15 m, then held)
    np.testing.assert_allclose(tops, np.minimum(0.15 + 0.25 * times, 0.25), atol=1e-9)
    assert frames[-1][:, 1].min() == pytest.approx(0.255, abs=2e-3)  # carried up on it
    code, lines = check(out, capsys)
    assert code == 0 and "cloth: no vertex inside the collider mesh in any frame" in lines
