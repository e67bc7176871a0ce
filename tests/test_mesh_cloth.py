"""Triangle meshes as cloth (docs/meshes.md): import, welding, cleaning, bad input, pins, the
spring and mass model, the mesh and garment scenes."""
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.errors import ConfigError, InputWarning
from taichi_sim.scene import cloth as topo
from taichi_sim.scene.builder import SceneBuilder
from taichi_sim.scene.cloth_scenes import cloth_pins
from taichi_sim.scene.garment import skirt_mesh, skirt_panels
from taichi_sim.scene.mesh_cloth import add_mesh_cloth, mesh_size, mesh_springs, select_pins, vertex_masses
from taichi_sim.scene.mesh_import import ClothMesh, clean_mesh, load_mesh
from taichi_sim.scene.mesh_scenes import MESH
from taichi_sim.scene.params import resolve

SQUARE_X = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]]
SQUARE_T = [[0, 1, 2], [0, 2, 3]]


def write(tmp_path, name, text):
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def grid_obj(tmp_path, nx, ny, name="grid.obj"):
    """An OBJ of the cloth scene's grid: horizontal, 1 m square, at height 1 m."""
    x = topo.grid_positions(nx, ny, 1.0, 1.0, origin=(-0.5, 1.0, -0.5), u_axis=(1, 0, 0), v_axis=(0, 0, 1))
    trimesh.Trimesh(x, topo.grid_triangles(nx, ny), process=False).export(tmp_path / name)
    return tmp_path / name, x


# -- import -----------------------------------------------------------------------------------

@pytest.mark.parametrize("ext", ["obj", "ply", "stl", "off", "glb", "gltf"])
def test_every_format_reads_as_the_same_welded_square(tmp_path, ext):
    square = trimesh.Trimesh(SQUARE_X, SQUARE_T, process=False)
    exported = square.export(file_type=ext)
    if isinstance(exported, dict):  # glTF: the .gltf and its buffers
        for name, data in exported.items():
            (tmp_path / name).write_bytes(data)
        path = tmp_path / "model.gltf"
    else:
        path = write(tmp_path, f"square.{ext}", exported)
    mesh = load_mesh(path)
    assert mesh.vertex_count == 4 and len(mesh.triangles) == 2  # STL's six corners welded to four
    assert np.allclose(sorted(map(tuple, mesh.x)), sorted(map(tuple, SQUARE_X)))
    assert vertex_masses(mesh.x, mesh.triangles, 2.0).sum() == pytest.approx(2.0)


def test_welding_merges_seams_within_the_tolerance_only(tmp_path):
    # two triangles that share an edge, their shared vertices written twice (a UV seam)
    text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 0 0.0000004\nv 1 1.0000003 0\nv 0 1 0\nf 1 2 3\nf 4 5 6\n"
    welded = load_mesh(write(tmp_path, "seam.obj", text), weld=1e-6)
    assert welded.vertex_count == 4 and welded.welded == 2
    with pytest.warns(InputWarning, match="2 separate pieces"):
        split = load_mesh(write(tmp_path, "seam2.obj", text), weld=1e-7)
    assert split.vertex_count == 6


def test_degenerate_and_duplicate_triangles_are_removed_and_counted():
    x = np.array(SQUARE_X + [[2.0, 0.0, 0.0]])
    triangles = [[0, 1, 2], [0, 2, 3], [0, 0, 1], [0, 1, 4], [2, 1, 0]]  # repeated, flat, reversed copy
    with pytest.warns(InputWarning, match="removed 2 degenerate and 1 duplicate triangles"):
        mesh = clean_mesh(x, triangles, source="t")
    assert (mesh.removed_degenerate, mesh.removed_duplicate) == (2, 1)
    assert mesh.vertex_count == 4 and len(mesh.triangles) == 2  # vertex 4 is left unused: dropped


def test_non_manifold_edges_are_warned_of():
    x = SQUARE_X + [[0.5, 0.5, 1.0]]
    with pytest.warns(InputWarning, match="1 non-manifold edges"):
        mesh = clean_mesh(x, SQUARE_T + [[0, 2, 4]], source="fin")
    ends, kind = mesh_springs(mesh.triangles)
    assert len(ends) == 7 and not (kind == topo.FLEX).any()  # no bending across the shared edge


def test_scale_and_z_up(tmp_path):
    path = write(tmp_path, "zup.obj", "v 0 0 0\nv 100 0 0\nv 0 0 100\nv 0 100 0\nf 1 2 3\nf 1 4 2\n")
    mesh = load_mesh(path, scale=0.01, up="z")
    assert np.allclose(mesh.x, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, -1]])  # +z up becomes +y, +y goes to -z


@pytest.mark.parametrize("name, content, problem", [
    ("empty.obj", b"", "is empty"),
    ("garbage.obj", bytes(range(256)) * 4, "is binary data, not a text OBJ file"),
    ("words.obj", "this is not a mesh\n" * 20, "has no triangles"),
    ("garbage.ply", b"\x00\x01\xfe" * 100, "not a readable PLY mesh"),
    ("garbage.glb", b"glTF" + b"\xff" * 64, "not a readable GLB mesh"),
    ("points.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n", "has no triangles"),
    ("nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
    ("inf.off", "OFF\n3 1 0\n0 0 0\ninf 0 0\n0 1 0\n3 0 1 2\n", "NaN or infinite"),
    ("flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "no triangles of nonzero area"),
    ("mesh.txt", "v 0 0 0\n", "unknown format"),
])
def test_what_cannot_be_cloth_is_one_line_naming_the_file(tmp_path, name, content, problem):
    with pytest.raises(ConfigError, match=problem) as error:
        load_mesh(write(tmp_path, name, content))
    assert name in str(error.value) and "\n" not in str(error.value)


def test_a_missing_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="nowhere.obj: cannot be read"):
        load_mesh(tmp_path / "nowhere.obj")


# -- pins -------------------------------------------------------------------------------------

def test_pin_specs_select_the_vertices_they_say(tmp_path):
    text = "o top\nv 0 1 0\nv 1 1 0\nv 0 0.99 0.5\nf 1 2 3\no low\nv 1 0 0\nv 0 0 1\nf 2 4 5\n"
    mesh = load_mesh(write(tmp_path, "pins.obj", text))
    y = mesh.x[:, 1]
    assert set(np.flatnonzero(select_pins("top:0.02", mesh))) == set(np.flatnonzero(y >= 0.98))
    assert set(np.flatnonzero(select_pins("bottom:0", mesh))) == set(np.flatnonzero(y == 0))
    assert np.flatnonzero(select_pins("ids:0, 4", mesh)).tolist() == [0, 4]
    box = select_pins("box:-0.1,0.9,-0.1,0.1,1.1,0.6", mesh)
    assert set(map(tuple, mesh.x[box])) == {(0.0, 1.0, 0.0), (0.0, 0.99, 0.5)}
    low = select_pins("group:low", mesh)
    assert set(map(tuple, mesh.x[low])) == {(1.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)}
    assert not select_pins("none", mesh).any()


def test_a_welded_vertex_stays_in_its_group(tmp_path):
    # Two panels sewn along y = 1: the hem's copies of the seam's vertices come later in the
    # file, a rounding off the body's (so each is found as itself), and weld into the body's;
    # pinning the hem must still pin the seam.
    text = ("o body\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n"
            "o hem\nv 0 1.0000004 0\nv 1 1.0000003 0\nv 1 2 0\nv 0 2 0\nf 5 6 7\nf 5 7 8\n")
    mesh = load_mesh(write(tmp_path, "sewn.obj", text), weld=1e-6)
    assert mesh.vertex_count == 6 and mesh.welded == 2
    hem = select_pins("group:hem", mesh)
    assert set(map(tuple, mesh.x[hem])) == {(0.0, 1.0, 0.0), (1.0, 1.0, 0.0), (1.0, 2.0, 0.0), (0.0, 2.0, 0.0)}
    body = select_pins("group:body", mesh)
    assert set(map(tuple, mesh.x[body & hem])) == {(0.0, 1.0, 0.0), (1.0, 1.0, 0.0)}  # the seam, in both


def test_gltf_nodes_are_groups_placed_by_their_transforms(tmp_path):
    scene = trimesh.Scene()
    triangle = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    scene.add_geometry(trimesh.Trimesh(triangle, [[0, 1, 2]], process=False), node_name="sleeve")
    scene.add_geometry(trimesh.Trimesh(triangle, [[0, 1, 2]], process=False), node_name="body",
                       transform=trimesh.transformations.translation_matrix([0.0, 0.0, 2.0]))
    with pytest.warns(InputWarning, match="2 separate pieces"):
        mesh = load_mesh(write(tmp_path, "two.glb", scene.export(file_type="glb")))
    assert np.allclose(mesh.x[select_pins("group:body", mesh)][:, 2], 2.0)
    assert np.allclose(mesh.x[select_pins("group:sleeve", mesh)][:, 2], 0.0)


@pytest.mark.parametrize("spec, problem", [
    ("top:-1", "cannot read"), ("ids:", "cannot read"), ("box:0,0,0", "cannot read"), ("corners", "cannot read"),
    ("ids:9", "vertex id 9 is not in 0..3"), ("group:sleeve", "no group 'sleeve'"),
    ("box:5,5,5,6,6,6", "selects no vertex"), ("top:10", "selects every vertex"),
])
def test_a_pin_that_selects_nothing_or_everything_is_refused(spec, problem):
    mesh = ClothMesh(np.asarray(SQUARE_X, float), np.asarray(SQUARE_T), {}, "square")
    with pytest.raises(ConfigError, match=problem):
        select_pins(spec, mesh)


# -- the cloth model --------------------------------------------------------------------------

def test_a_grid_mesh_has_the_grids_structural_springs_and_one_diagonal(tmp_path):
    nx, ny = 6, 5
    mesh = load_mesh(grid_obj(tmp_path, nx, ny)[0])
    ends, kind = mesh_springs(mesh.triangles)
    grid_ends, grid_kind = topo.grid_springs(nx, ny)
    as_set = lambda e: set(map(tuple, np.sort(e, axis=1).tolist()))  # noqa: E731
    idx = topo.grid_index(nx, ny)
    diagonal = np.stack([idx[:-1, :-1].ravel(), idx[1:, 1:].ravel()], 1)  # the triangles' diagonals
    assert as_set(ends[kind == topo.STRUCTURAL]) == as_set(grid_ends[grid_kind == topo.STRUCTURAL]) | as_set(diagonal)
    interior_edges = len(ends[kind == 0]) - 2 * (nx - 1 + ny - 1)
    assert (kind == topo.FLEX).sum() == interior_edges  # one bending spring across each interior edge
    assert mesh_size(mesh, True).springs == len(ends)


def test_vertex_masses_are_a_third_of_each_incident_triangle_times_density(rng):
    x = rng.normal(size=(30, 3))
    triangles = rng.integers(0, 30, size=(50, 3))
    triangles = triangles[(triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2])
                          & (triangles[:, 0] != triangles[:, 2])]
    a, b, c = (x[triangles[:, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    mass = vertex_masses(x, triangles, 0.3)
    assert mass.sum() == pytest.approx(0.3 * area.sum())
    assert mass[triangles[0, 0]] == pytest.approx(0.1 * area[(triangles == triangles[0, 0]).any(axis=1)].sum())


def test_a_grid_mesh_sags_like_the_grid_cloth(f64, tmp_path):
    """One diagonal at k carries any uniform strain as both diagonals at k/2 do (the grid's shear
    springs at the default ratio), so with equal masses the two cloths sag alike."""
    nx = ny = 7
    path, _ = grid_obj(tmp_path, nx, ny)
    common = {"damping": 0.0, "gravity": 9.8}
    grid = ts.build_scene("cloth", dict(common, nx=nx, ny=ny, pin="corners", flex=False, stiffness=50.0,
                                        shear_stiffness=25.0, **topo.per_particle(nx, ny, mass=0.01, drag=0.3)))
    p = resolve(MESH.params, "mesh", dict(common, drag=0.3, file=str(path), bending=False, stiffness=50.0,
                                          pin="none"))
    b = SceneBuilder()
    add_mesh_cloth(b, p, 0, load_mesh(path), mass=np.full(nx * ny, 0.01), pinned=cloth_pins(nx, ny, "corners"))
    mesh = MESH.finish(b, p, 0)
    assert mesh.springs.spring_count == grid.springs.spring_count - (nx - 1) * (ny - 1)
    sags = []
    for scene in (grid, mesh):
        result = ts.run(scene, "symplectic_euler", dt=2e-3, steps=1500)
        assert result.status.value == "ok"
        x, _ = scene.state.to_numpy()
        sags.append(1.0 - x[:, 1].min())
    # 0.864 m and 0.876 m; without the diagonals (grid shear=False) it sags 0.946 m
    assert sags[0] > 0.5
    assert sags[1] == pytest.approx(sags[0], rel=0.025)


def test_every_cloth_extra_builds_on_a_mesh(f64, tmp_path):
    path, _ = grid_obj(tmp_path, 5, 5)
    scene = ts.build_scene("mesh", {"file": str(path), "pin": "ids:0", "wind": True, "sphere": True,
                                    "capsule": True, "box": True, "plane": True, "tear": True,
                                    "self_collision": True, "grab": True, "sphere_y": 0.4, "box_y": -1.0})
    f = scene.features
    assert f["wind"] and f["spheres"] == f["capsules"] == f["boxes"] == 1 and f["plane"]
    assert f["tearing"] and f["self_collision"] and f["grab"] and f["pinned"] == 1


# -- the scenes and the command line ----------------------------------------------------------

def test_the_mesh_scene_runs_from_the_command_line_and_saves_its_triangles(tmp_path, capsys):
    path = write(tmp_path, "two.obj", "v 0 1 0\nv 1 1 0\nv 1 0 0\nv 0 0 0\nf 1 2 3\nf 1 3 4\nv 5 5 5\nv 6 5 5\n"
                 "v 5 6 5\nf 5 6 7\n")
    out = tmp_path / "run.npz"
    code = main(["simulate", "mesh", "--set", f"file={path}", "--set", "pin=top:0", "--steps", "10",
                 "--quiet", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0
    assert err.startswith("taichi-sim: warning: mesh two.obj: 2 separate pieces") and err.count("\n") == 1
    data = np.load(out)
    assert data["triangles"].shape == (3, 3) and len(data["x"]) == 7
    assert data["mass"].sum() == pytest.approx(0.2 * 1.5)  # density x area


@pytest.mark.parametrize("sets, problem", [
    (["file=__garbage__"], "garbage.obj: is binary data"),
    (["file=__square__", "pin=bottom:-1"], "parameter pin: cannot read"),
    (["file=__square__", "pin=box:5,5,5,6,6,6"], "selects no vertex"),
    (["file=__square__", "pin=bottom:5"], "selects every vertex"),
    (["file=nowhere.obj"], "nowhere.obj: cannot be read"),
])
def test_bad_mesh_input_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, sets, problem):
    write(tmp_path, "garbage.obj", b"\x89PNG\r\n\x1a\n" + bytes(range(200)))
    write(tmp_path, "square.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n")
    sets = [s.replace("__garbage__", str(tmp_path / "garbage.obj")).replace("__square__", str(tmp_path / "square.obj"))
            for s in sets]
    out = tmp_path / "run.npz"
    code = main(["simulate", "mesh", *[a for s in sets for a in ("--set", s)], "--steps", "3", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and not out.exists()
    assert err.startswith("taichi-sim: error: ") and problem in err and "\n" not in err


def test_the_skirts_rest_lengths_are_those_of_its_flat_panels():
    mesh = skirt_mesh()
    assert mesh.vertex_count == 5000 and len(mesh.groups["waist"]) == 100
    uv, _ = skirt_panels(10, 10, 50, 0.15, 0.32, 0.55)
    flat = uv[:, :-1].reshape(-1, 2)  # gore 0 without its right seam
    ids = np.arange(5000).reshape(50, 100)[:, :10].ravel()
    ends, _ = mesh_springs(mesh.triangles, bending=False)
    inside = np.isin(ends, ids).all(axis=1)
    where = {v: k for k, v in enumerate(ids)}
    e = ends[inside]
    rest_3d = np.linalg.norm(mesh.x[e[:, 0]] - mesh.x[e[:, 1]], axis=1)
    rest_flat = np.linalg.norm(flat[[where[v] for v in e[:, 0]]] - flat[[where[v] for v in e[:, 1]]], axis=1)
    assert len(e) > 100 and np.allclose(rest_3d, rest_flat, rtol=0, atol=1e-12)
    assert mesh_size(mesh, True).springs == 14800 + 14600


def test_the_skirt_obj_in_the_repository_is_the_generators():
    path = Path(__file__).resolve().parent.parent / "examples" / "garments" / "skirt.obj"
    assert path.stat().st_size < 1_000_000
    with warnings.catch_warnings():
        warnings.simplefilter("error", InputWarning)  # one piece, manifold, nothing removed
        mesh = load_mesh(path)
    generated = skirt_mesh()
    assert np.allclose(mesh.x, generated.x, atol=1e-6)
    as_set = lambda t: set(map(tuple, np.sort(t, axis=1).tolist()))  # noqa: E731 (grouped by panel in the file)
    assert as_set(mesh.triangles) == as_set(generated.triangles)
    assert set(mesh.groups) == {f"gore{k}" for k in range(10)}
    assert select_pins("top:0.001", mesh).sum() == 100


def test_the_garment_scene_counts_what_it_allocates(f32):
    scene = ts.build_scene("garment", {"rows": 6, "gores": 4, "gore_columns": 3})
    size = ts.SCENES["garment"].size(resolve(ts.SCENES["garment"].params, "garment",
                                             {"rows": 6, "gores": 4, "gore_columns": 3}))
    assert (size.particles, size.springs, size.triangles) == (
        scene.particle_count, scene.springs.spring_count, scene.mesh.triangle_count)
    assert scene.features["capsules"] == 4 and scene.features["pinned"] == 12


def test_a_mesh_too_large_for_the_memory_is_refused_before_building(tmp_path, capsys, monkeypatch):
    import taichi_sim.memory

    monkeypatch.setattr(taichi_sim.memory, "available_bytes", lambda: 100_000)
    out = tmp_path / "run.npz"
    code = main(["simulate", "mesh", "--set", f"file={grid_obj(tmp_path, 12, 12, 'big.obj')[0]}", "--steps", "3",
                 "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and not out.exists() and "\n" not in err
    assert f"parameters file = {tmp_path / 'big.obj'}: the scene needs about" in err and "144 particles" in err


def test_a_live_change_of_stiffness_keeps_each_kind_its_own(f64, tmp_path):
    from taichi_sim.scene.live import LIVE_SETTERS

    path, _ = grid_obj(tmp_path, 4, 4)
    scene = ts.build_scene("mesh", {"file": str(path), "pin": "ids:0"})
    values = dict(scene.params, stiffness=300.0, flex_stiffness=3.0)
    assert LIVE_SETTERS["flex_stiffness"](scene, values)
    k, kind = scene.springs.stiffness.to_numpy(), scene.springs.kind_np
    assert set(k[kind == topo.STRUCTURAL]) == {300.0} and set(k[kind == topo.FLEX]) == {3.0}


@pytest.mark.parametrize("motion, moved", [
    ("lift", lambda t: np.array([0.0, 0.3 * min(t, 0.2), 0.0])),
    ("sweep", lambda t: np.array([0.3 * min(t, 0.2), 0.0, 0.0])),
    ("oscillate", lambda t: np.array([0.0, 0.1 * np.sin(2 * np.pi * t), 0.0])),
])
def test_pinned_vertices_follow_their_motion_and_pull_the_cloth(f64, tmp_path, motion, moved):
    """A mesh cloth's pins ride the kinematic pins: at every step they are where the motion puts
    them (lift and sweep for pin_duration, then still), and the free vertices follow."""
    path, x0 = grid_obj(tmp_path, 5, 5)
    params = {"file": str(path), "pin": "box:-0.6,0.9,-0.6,0.6,1.1,-0.4", "pin_motion": motion,
              "pin_duration": 0.2, "pin_speed": 0.3, "pin_amplitude": 0.1, "pin_frequency": 1.0}
    scene = ts.build_scene("mesh", params)
    pinned = ~scene.system.free.to_numpy().astype(bool)
    assert pinned.sum() == 5 and scene.features["kinematic"] == 5
    result = ts.run(scene, "xpbd", dt=0.01, steps=30)
    assert result.status.value == "ok"
    x, _ = scene.state.to_numpy()
    np.testing.assert_allclose(x[pinned], x0[pinned] + moved(result.t), atol=1e-9)
    still = ts.build_scene("mesh", {**params, "pin_motion": "static"})
    ts.run(still, "xpbd", dt=0.01, steps=30)
    assert np.abs(x[~pinned] - still.state.to_numpy()[0][~pinned]).max() > 1e-3
