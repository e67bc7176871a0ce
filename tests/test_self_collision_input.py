"""Degenerate input to the self-contact stage and to the intersection check: a clear error
naming the parameter, or handled, never a crash or NaN."""
import math

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.collide.mesh_check import check_contact_mesh
from taichi_sim.errors import ConfigError
from taichi_sim.geometry import self_intersections
from taichi_sim.scene import cloth as topo
from taichi_sim.scene.builder import SceneBuilder


def flat_grid(n: int, size: float = 1.0):
    x = topo.grid_positions(n, n, size, size, (0.0, 0.0, 0.0), (1, 0, 0), (0, 0, 1))
    return x, topo.grid_triangles(n, n)


@pytest.mark.parametrize("thickness", [0.0, -0.01, math.nan, math.inf, True, "0.01"])
def test_a_thickness_that_is_not_a_positive_number_is_named(thickness):
    x, tris = flat_grid(4)
    with pytest.raises(ValueError, match="thickness"):
        check_contact_mesh(x, tris, thickness)


def test_the_limit_is_the_grids_closest_non_adjacent_distance():
    # In a flat grid of spacing s, a vertex is s / sqrt(2) from the diagonal of the next cell's
    # triangle that it is not a corner of: nothing non-adjacent is closer.
    x, tris = flat_grid(8)
    limit = (1.0 / 7) / math.sqrt(2)
    assert check_contact_mesh(x, tris, 0.99 * limit) == pytest.approx(limit, rel=1e-12)
    assert check_contact_mesh(x, tris, 0.5 * limit) > 0.5 * limit
    for thickness in (limit, 1.01 * limit, 1.0):
        with pytest.raises(ConfigError, match=r"thickness .* must be below 0\.101015 m"):
            check_contact_mesh(x, tris, thickness)


def test_a_repeated_vertex_and_a_zero_area_triangle_are_named():
    x, tris = flat_grid(4)
    bad = tris.copy()
    bad[3] = [bad[3, 0], bad[3, 0], bad[3, 2]]
    with pytest.raises(ConfigError, match=r"triangles: triangle 3 .* repeats a vertex"):
        check_contact_mesh(x, bad, 0.01)
    collinear = x.copy()
    a, b, c = tris[5]
    collinear[c] = 0.5 * (x[a] + x[b])  # c on the segment ab: no area, no normal
    with pytest.raises(ConfigError, match=r"triangles: triangle \d+ .* zero area"):
        check_contact_mesh(collinear, tris, 0.01)
    coincident = x.copy()
    coincident[b] = x[a]  # two corners of a triangle at one point
    with pytest.raises(ConfigError, match="zero area"):
        check_contact_mesh(coincident, tris, 0.01)


def test_coincident_non_adjacent_particles_and_non_finite_positions_are_named():
    # two separate triangles, a corner of one exactly on a corner of the other
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [0, 0, 0], [-1, 0, 0], [0, 1, 0]], float)
    tris = np.array([[0, 1, 2], [3, 4, 5]])
    with pytest.raises(ConfigError, match="x: non-adjacent parts of the cloth touch"):
        check_contact_mesh(x, tris, 0.01)
    x[3] = [0.0, 0.5, 0.0]
    assert check_contact_mesh(x, tris, 0.01) > 0.01
    x[4, 1] = np.nan
    with pytest.raises(ConfigError, match=r"x: 1 particle\(s\) have non-finite"):
        check_contact_mesh(x, tris, 0.01)


def test_a_torn_triangle_is_left_out_and_an_empty_mesh_passes():
    x, tris = flat_grid(3)
    tris = tris.copy()
    tris[0] = -1
    assert check_contact_mesh(x, tris, 0.1) == pytest.approx(0.5 / math.sqrt(2))
    assert check_contact_mesh(x, np.zeros((0, 3), int), 0.1) == math.inf


def test_scenes_refuse_a_thickness_their_rest_shape_cannot_keep(f32):
    # 8 x 8 on 1 m: the limit is 0.101 m (see above)
    with pytest.raises(ConfigError, match=r"thickness 0\.2 m must be below 0\.101015 m"):
        ts.build_scene("cloth-fold", {"nx": 8, "ny": 8, "thickness": 0.2})
    b = SceneBuilder()
    b.add_particles(np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [0, 0, 0]], float), 0.01)
    b.add_triangles(np.array([[0, 1, 2], [3, 3, 1]]))
    b.enable_self_collision(0.01)
    with pytest.raises(ValueError, match="repeats a vertex"):
        b.finalize(name="t", params={}, default_dt=1e-3, default_integrator="symplectic_euler")


@pytest.mark.long
def test_a_jittered_start_closer_than_the_thickness_is_accepted_and_stays_finite(f32):
    # The limit is measured on the rest shape (the grid before its seeded jitter): a start that
    # the jitter brought closer than the thickness is a disturbance the contacts smooth out.
    scene = ts.build_scene("cloth-fold", {"nx": 8, "ny": 8, "thickness": 0.09, "jitter": 0.03})
    x0, tris = scene.x0, scene.mesh.triangles_np
    from taichi_sim.collide.mesh_check import _vertex_triangle

    assert _vertex_triangle(x0, tris, 0.09) < 0.09  # the start does violate the thickness
    result = ts.run(scene, "symplectic_euler", dt=1e-3, steps=200)
    x, v = scene.state.to_numpy()
    assert result.status.value == "ok" and np.isfinite(x).all() and np.isfinite(v).all()


def test_the_cli_refuses_in_one_line_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "run.npz"
    code = main(["simulate", "cloth-fold", "--set", "nx=8", "--set", "ny=8", "--set", "thickness=0.5",
                 "--steps", "2", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "thickness" in err and "0.101015" in err
    assert list(tmp_path.iterdir()) == []


def test_the_check_leaves_zero_area_triangles_out_and_says_so(tmp_path, capsys):
    x, tris = flat_grid(4)
    x = x.copy()
    a, b, c = tris[2]
    x[c] = x[a]  # triangle 2 collapses to a segment (as would its neighbours sharing c)
    report = self_intersections(x, tris)
    assert 2 in report.degenerate and report.count == 0
    np.savez(tmp_path / "run.npz", x=x, triangles=tris, scene="t")
    assert main(["check", str(tmp_path / "run.npz")]) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith("t: 1 frame(s), no triangles intersect") and "zero-area triangle(s)" in line
    x[0] = np.nan
    np.savez(tmp_path / "bad.npz", x=x, triangles=tris)
    assert main(["check", str(tmp_path / "bad.npz")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "non-finite" in err


def test_a_start_that_already_passes_through_itself_is_refused_before_the_run():
    """A seeded jitter large against the spacing can leave triangles crossing at t = 0; the
    stage would keep those crossings for the whole run, so the build refuses, naming them."""
    params = {"nx": 16, "ny": 16, "jitter": 0.03, "self_collision": True, "thickness": 0.01}
    ts.init(arch="cpu", precision="f64")
    loose = ts.build_scene("cloth-fold", {**params, "self_collision": False})
    assert self_intersections(loose.x0, loose.mesh.triangles_np).count > 0
    with pytest.raises(ConfigError, match="starts passing through itself"):
        ts.build_scene("cloth-fold", params)


def test_points_inside_each_kind_of_object_are_found_and_points_on_a_surface_are_not():
    from taichi_sim.scene.colliders.shape import inside_objects

    arrays = {"sphere_center": [[0.0, 1.0, 0.0]], "sphere_radius": [0.5],
              "capsule_center": [[0.0, 0.0, 0.0]], "capsule_radius": [0.1], "capsule_half_axis": [[0.3, 0.0, 0.0]],
              "box_center": [[2.0, 0.0, 0.0]], "box_half_extents": [[0.2, 0.2, 0.2]],
              "plane_point": [0.0, -0.5, 0.0], "plane_normal": [0.0, 2.0, 0.0]}
    points = np.array([[0.0, 1.4, 0.0],    # sphere: inside
                       [0.0, 1.5, 0.0],    # sphere: on its surface
                       [0.35, 0.0, 0.0],   # capsule: in its end cap (0.05 from the end-cap centre)
                       [0.45, 0.0, 0.0],   # capsule: 0.15 past the end-cap centre, outside
                       [-0.25, 0.05, 0.0],  # capsule: beside the axis, inside
                       [2.19, 0.1, -0.1],  # box: inside
                       [2.2, 0.0, 0.0],    # box: on a face
                       [5.0, -0.6, 0.0]])  # below the plane
    found = inside_objects(points, arrays)
    assert {k: np.flatnonzero(v).tolist() for k, v in found.items()} == {
        "sphere": [0], "capsule": [2, 4], "box": [5], "plane": [7]}
    assert inside_objects(points, {}) == {}


def test_a_box_is_as_thin_as_its_least_half_extent():
    # A slab 1 m square and 4 cm thick (not a cube): a face whose edge lies 2 mm inside its top
    # has gone a tenth of the slab's thinnest size in, far past FACE_SHARE; measured against
    # the slab's largest half extent (0.5 m) it would be 0.4 %, and pass.
    from taichi_sim.geometry.inside import FACE_SHARE
    from taichi_sim.scene.colliders.shape import face_depths, faces_inside, object_depths

    arrays = {"box_center": [[0.0, 0.0, 0.0]], "box_half_extents": [[0.5, 0.02, 0.5]]}
    depth, thinnest = object_depths(np.array([[0.0, 0.0, 0.0], [0.3, 0.015, -0.4]]), arrays)["box"]
    assert thinnest.tolist() == [0.02]
    assert depth[:, 0] == pytest.approx([0.02, 0.005])  # to the nearest side: the top
    x = np.array([[-0.1, 0.018, 0.0], [0.1, 0.018, 0.0], [0.0, 0.2, 0.0]])
    shares, depths = face_depths(x, [[0, 1, 2]], arrays)["box"]
    assert depths == pytest.approx([0.002]) and shares == pytest.approx([0.1])
    assert 0.002 / 0.5 < FACE_SHARE and faces_inside(x, [[0, 1, 2]], arrays)["box"].tolist() == [True]


def test_a_cloth_that_starts_inside_an_object_is_reported_before_the_run(f64, tmp_path, capsys):
    across = {"nx": 8, "ny": 8, "capsule": True, "capsule_y": 0.12, "capsule_radius": 0.1}
    warning = ts.build_scene("cloth-fold", across).start_warning()
    assert "starts inside an object (6 inside the capsule, of 64 vertices; " in warning
    assert ts.build_scene("cloth-fold", dict(across, capsule_z=0.3)).start_warning() == ""  # beside it
    assert "inside the ground plane" in ts.build_scene("cloth", {"nx": 4, "ny": 4, "plane": True,
                                                                 "plane_height": 2.0}).start_warning()
    plain = ts.build_scene("cloth", {"nx": 4, "ny": 4})
    corner = plain.x0[np.flatnonzero(plain.arrays["pinned"])[0]]  # a pinned corner: no collider moves it
    held = {"nx": 4, "ny": 4, "sphere": True, "sphere_radius": 0.1, "sphere_x": corner[0], "sphere_y": corner[1],
            "sphere_z": corner[2]}
    assert ts.build_scene("cloth", held).start_warning() == ""
    # an object between the vertices, through a triangle: only the faces tell
    tri = plain.mesh.triangles_np[5]
    centroid = plain.x0[tri].mean(axis=0)
    through = {"nx": 4, "ny": 4, "sphere": True, "sphere_radius": 0.05, "sphere_x": centroid[0],
               "sphere_y": centroid[1], "sphere_z": centroid[2]}
    assert "starts inside an object (1 of 18 triangles reaching into the sphere)" in \
        ts.build_scene("cloth", through).start_warning()
    args = ["simulate", "cloth-fold", *[a for k, v in across.items() for a in ("--set", f"{k}={v}")],
            "--integrator", "symplectic_euler", "--steps", "1", "--quiet", "--out", str(tmp_path / "fold.npz")]
    assert main(args) == 0
    assert "warning: the cloth starts inside an object (6 inside the capsule" in capsys.readouterr().err
