"""The exact self-intersection check (taichi_sim.geometry) and the run's saved history."""
import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.geometry import intersections, predicates, self_intersections

TRI = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def pair(t1, t2):
    """Two separate triangles as one mesh (no shared vertex)."""
    return np.concatenate([t1, t2]), np.array([[0, 1, 2], [3, 4, 5]])


@pytest.mark.parametrize("t2, meets", [
    # pierces the interior
    (np.array([[0.2, 0.2, -1.0], [0.3, 0.2, 1.0], [0.2, 0.4, 1.0]]), True),
    # the same, lifted just off: above z = 0 by the smallest float step at 1
    (np.array([[0.2, 0.2, 1e-300], [0.3, 0.2, 1.0], [0.2, 0.4, 1.0]]), False),
    # a vertex touching the face: closed triangles meet
    (np.array([[0.2, 0.2, 0.0], [0.3, 0.2, 1.0], [0.2, 0.4, 1.0]]), True),
    # edge through edge (neither vertex inside the other)
    (np.array([[0.5, -0.5, -0.5], [0.5, 0.5, 0.5], [0.5, -0.5, 0.5]]), True),
    # coplanar, overlapping
    (np.array([[0.1, 0.1, 0.0], [2.0, 0.1, 0.0], [0.1, 2.0, 0.0]]), True),
    # coplanar, one inside the other
    (np.array([[0.1, 0.1, 0.0], [0.2, 0.1, 0.0], [0.1, 0.2, 0.0]]), True),
    # coplanar, apart across the hypotenuse by one ulp
    (np.array([[0.5, np.nextafter(0.5, 1.0), 0.0], [1.0, 1.0, 0.0], [0.6, 1.0, 0.0]]), False),
    # coplanar, touching the hypotenuse at its midpoint
    (np.array([[0.5, 0.5, 0.0], [1.0, 1.0, 0.0], [0.6, 1.0, 0.0]]), True),
    # parallel planes
    (TRI + [0.0, 0.0, 1e-12], False),
])
def test_pairs_of_triangles(t2, meets):
    x, tris = pair(TRI, t2)
    report = self_intersections(x, tris)
    assert report.count == int(meets)
    swapped = self_intersections(*pair(t2, TRI))
    assert swapped.count == int(meets)


def test_neighbours_sharing_a_vertex_are_not_checked():
    x = np.concatenate([TRI, [[0.2, 0.2, -1.0], [0.3, 0.2, 1.0]]])
    tris = np.array([[0, 1, 2], [0, 3, 4]])  # crossing, but sharing vertex 0
    assert self_intersections(x, tris).candidates == 0


def test_the_float_filter_agrees_with_exact_arithmetic(monkeypatch):
    rng = np.random.default_rng(3)
    # nearly coplanar and nearly touching: where rounding could flip a sign
    a, b, c = rng.normal(size=(3, 4000, 3))
    d = a + rng.uniform(-1, 1, (4000, 1)) * (b - a) + rng.uniform(-1, 1, (4000, 1)) * (c - a)
    d += rng.normal(size=d.shape) * np.where(rng.random((4000, 1)) < 0.5, 1e-15, 0.0)
    filtered = predicates.orient3d(a, b, c, d)
    exact = np.array([predicates._orient3d_exact(*p) for p in zip(a, b, c, d)])
    assert np.array_equal(filtered, exact)
    naive = np.sign(np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a)))
    assert (naive != exact).sum() > 100  # cases where plain floating point gets the sign wrong


def grid_triangles(n):
    """The triangles of an n x n grid of vertices, two a square."""
    v = np.arange(n * n).reshape(n, n)
    a, b, c, d = v[:-1, :-1].ravel(), v[1:, :-1].ravel(), v[:-1, 1:].ravel(), v[1:, 1:].ravel()
    return np.concatenate([np.stack([a, b, d], axis=1), np.stack([a, d, c], axis=1)])


@pytest.mark.parametrize("seed", range(6))
def test_the_broad_phase_passes_every_pair_of_overlapping_boxes_once(seed):
    rng = np.random.default_rng(seed)
    n = 16
    u, v = (g.ravel() for g in np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij"))
    # crumpled, some vertices far more than others: boxes spanning one cell to several
    x = np.stack([u, v, 0 * u], axis=1) + rng.normal(0, 0.1, (n * n, 3)) * rng.random((n * n, 1)) ** 2
    if seed % 2:
        x = np.round(x * 32) / 32  # on a lattice: boxes touching face to face or edge to edge
    if seed % 3 == 0:
        x[rng.integers(0, n * n, 3)] *= 4  # stretched triangles, wider than the grid allows
    tris = grid_triangles(n)
    corners = x[tris]
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    i, j = np.triu_indices(len(tris), 1)
    boxes = np.all((lo[i] <= hi[j]) & (lo[j] <= hi[i]), axis=1)
    shared = (tris[i][:, :, None] == tris[j][:, None, :]).any(axis=(1, 2))
    expected = np.stack([i, j], axis=1)[boxes & ~shared]
    found = intersections._broad_phase(corners, tris)
    assert np.array_equal(found[np.lexsort(found.T[::-1])], expected)  # all of them, each once


def test_a_flat_cloth_is_clean_and_a_folded_one_is_not(f64):
    scene = ts.build_scene("cloth", {"nx": 16, "ny": 16})
    tris = scene.mesh.triangles_np
    assert self_intersections(scene.x0, tris).count == 0
    x = scene.x0.copy()
    mid = np.median(x[:, 0])
    right = x[:, 0] > mid
    x[right, 0] = mid - 0.5 * (x[right, 0] - mid)  # folded back onto the left half...
    x[right, 1] += 0.02 * np.sin(9 * x[right, 2])  # ...through it, along waves
    report = self_intersections(x, tris)
    assert report.count > 10
    i, j = report.pairs.T
    assert np.all(i < j) and not np.any((tris[i][:, :, None] == tris[j][:, None, :]).any(axis=(1, 2)))


def test_degenerate_and_bad_input():
    x = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 0.0]])
    report = self_intersections(x, np.array([[0, 1, 2], [3, 4, 5], [-1, 2, 3]]))
    assert report.degenerate.tolist() == [0] and report.count == 0  # collinear, torn: left out
    with pytest.raises(ValueError, match="x holds non-finite"):
        self_intersections(np.full((3, 3), np.nan), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="triangles refers to vertex 7"):
        self_intersections(x, np.array([[0, 1, 7]]))
    with pytest.raises(ValueError, match="x must be"):
        self_intersections(np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="triangles must be"):
        self_intersections(x, np.array([[0.0, 1, 2]]))


def test_save_every_keeps_the_run_frame_by_frame(f64, tmp_path):
    out = tmp_path / "run.npz"
    assert main(["simulate", "cloth", "--set", "nx=6", "--set", "ny=6", "--steps", "25",
                 "--save-every", "10", "--out", str(out), "--quiet"]) == 0
    data = np.load(out)
    assert data["t_history"].tolist() == pytest.approx([0.0, 0.01, 0.02, 0.025])
    assert data["x_history"].shape == (4, 36, 3)
    assert np.array_equal(data["x_history"][0], data["x0"]) and np.array_equal(data["x_history"][-1], data["x"])
    assert data["triangles"].shape == (50, 3)
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6})
    result = ts.run(scene, "symplectic_euler", dt=1e-3, steps=20, save_every=10)
    assert np.allclose(result.x_history[1], data["x_history"][1])  # the API keeps the same frames
    assert ts.run(scene, "symplectic_euler", dt=1e-3, steps=2).x_history is None
    with pytest.raises(ValueError, match="save_every"):
        ts.run(scene, "symplectic_euler", dt=1e-3, steps=2, save_every=-1)
    assert main(["simulate", "cloth", "--steps", "3", "--save-every", "0", "--out", str(out)]) == 2


def test_a_diverged_run_keeps_frames_up_to_the_state_it_returns(f64):
    scene = ts.build_scene("pendulum", {})
    result = ts.run(scene, "euler", dt=0.008, steps=2000, save_every=5)
    assert result.status.value == "diverged"
    assert result.t_history[-1] == result.t and np.all(np.diff(result.t_history) > 0)
    assert np.array_equal(result.x_history[-1], scene.state.x.to_numpy())


def test_check_command_reports_frames_with_intersections(f64, tmp_path, capsys):
    out = tmp_path / "run.npz"
    assert main(["simulate", "cloth", "--set", "nx=8", "--set", "ny=8", "--steps", "20",
                 "--save-every", "10", "--out", str(out), "--quiet"]) == 0
    assert main(["check", str(out)]) == 0
    assert "3 frame(s), no triangles intersect" in capsys.readouterr().out
    data = dict(np.load(out))
    x = data["x_history"][1].copy()
    x[x[:, 0] > 0.5, 1] += 5.0  # lift the right half...
    x[x[:, 0] > 0.5, 0] -= 0.5  # ...onto the left one, then drop its middle row through it
    x[x[:, 0] > 0.3, 1] -= 5.0 * (np.abs(x[x[:, 0] > 0.3, 2] - x[:, 2].mean()) < 0.2)
    data["x_history"][1] = x
    np.savez(tmp_path / "edited.npz", **data)
    expected = self_intersections(x, data["triangles"]).count
    assert expected > 0
    assert main(["check", str(tmp_path / "edited.npz")]) == 1
    assert f"1 of 3 frame(s) have intersecting triangles; first at t = 0.01 s, most ({expected} pairs)" \
        in capsys.readouterr().out
    spring = tmp_path / "spring.npz"
    assert main(["simulate", "spring", "--steps", "2", "--out", str(spring), "--quiet"]) == 0
    assert main(["check", str(spring)]) == 2
    assert "no cloth surface" in capsys.readouterr().err
    assert main(["check", str(tmp_path / "missing.npz")]) == 2
    capsys.readouterr()
    (tmp_path / "notes.md").write_text("# not a run\n")
    assert main(["check", str(tmp_path / "notes.md")]) == 2
    err = capsys.readouterr().err
    assert err == (f"taichi-sim: error: {tmp_path / 'notes.md'} is not a run's npz (not a zip archive): "
                   "give a file written by `taichi-sim simulate --out RUN.npz`\n")


def test_check_command_finds_vertices_inside_the_objects_where_they_were_at_each_frame(f64, tmp_path, capsys):
    out = tmp_path / "drop.npz"
    assert main(["simulate", "cloth", "--set", "nx=6", "--set", "ny=6", "--set", "sphere=1", "--set", "sphere_motion=drop",
                 "--set", "plane=1", "--steps", "200", "--save-every", "100", "--out", str(out), "--quiet"]) == 0
    assert main(["check", str(out)]) == 0
    assert capsys.readouterr().out.splitlines() == [
        "cloth: 3 frame(s), no triangles intersect",
        "cloth: no vertex inside the ground plane or spheres in any frame",
        "cloth: no face reaches into the spheres in any frame (25 points a triangle, deeper than 1 % of the "
        "object's thinnest size)"]
    data = dict(np.load(out))
    centres, radius = data["sphere_center_history"][:, 0], float(data["sphere_radius"][0])
    assert centres.shape == (3, 3) and centres[2, 1] == pytest.approx(centres[0, 1] - 0.1)  # 0.5 m/s for 0.2 s
    below = centres[2] - [0.0, radius - 0.02, 0.0]  # inside the sphere at 0.2 s, outside where it started
    free = int(np.flatnonzero(~data["pinned"])[0])

    def check_edited(frame, point):
        edited = {k: v.copy() for k, v in data.items()}
        edited["x_history"][frame, free] = point
        np.savez(tmp_path / "edited.npz", **edited)
        code = main(["check", str(tmp_path / "edited.npz")])
        return code, capsys.readouterr().out

    code, text = check_edited(0, below)
    # (the vertex is clear of the sphere there, but the faces it drags down reach into it)
    assert "cloth: no vertex inside the ground plane or spheres in any frame" in text
    assert code == 1 and "cloth: 1 of 3 frame(s) have a face reaching into an object" in text
    code, text = check_edited(2, below)
    assert code == 1 and ("cloth: 1 of 3 frame(s) have vertices inside an object; first at t = 0.2 s, most "
                          "(1 inside the spheres) at t = 0.2 s") in text
    code, text = check_edited(1, [0.0, -0.01, 0.0])
    assert code == 1 and "first at t = 0.1 s, most (1 inside the ground plane)" in text


@pytest.mark.parametrize("kind", ["box", "sphere", "capsule"])
def test_check_command_finds_an_object_reaching_into_a_face_between_its_vertices(tmp_path, capsys, kind):
    """A 1 m triangle over an object 10 cm across: in the second frame the object reaches 20 mm
    above the triangle's plane under its middle, no corner anywhere near it."""
    x = np.array([[-0.5, 0.0, -0.3], [0.5, 0.0, -0.3], [0.0, 0.0, 0.6]])
    sizes = {"box": {"box_half_extents": np.array([[0.05, 0.05, 0.05]])},
             "sphere": {"sphere_radius": np.array([0.05])},
             "capsule": {"capsule_radius": np.array([0.05]), "capsule_half_axis": np.array([[0.05, 0.0, 0.0]])}}[kind]
    centres = np.array([[[0.0, -0.2, 0.0]], [[0.0, -0.03, 0.0]]])  # clear, then 20 mm through
    np.savez(tmp_path / "run.npz", scene="one", triangles=np.array([[0, 1, 2]]), x=x, t=0.1,
             x_history=np.stack([x, x]), t_history=np.array([0.0, 0.1]), pinned=np.zeros(3, bool),
             **sizes, **{f"{kind}_center": centres[-1], f"{kind}_center_history": centres})
    assert main(["check", str(tmp_path / "run.npz")]) == 1
    name = {"box": "boxes", "sphere": "spheres", "capsule": "capsules"}[kind]
    lines = capsys.readouterr().out.splitlines()
    assert lines[1] == f"one: no vertex inside the {name} in any frame"
    # the sampled points lie on a grid: the deepest found is within a grid step's rise of 20 mm
    prefix = ("one: 1 of 2 frame(s) have a face reaching into an object (25 points a triangle, deeper than "
              "1 % of the object's thinnest size); first at t = 0.1 s, deepest ")
    assert lines[2].startswith(prefix) and lines[2].endswith(f" mm inside the {name} at t = 0.1 s")
    depth = float(lines[2][len(prefix):].split()[0])
    assert 5.0 < depth <= 20.0
    np.savez(tmp_path / "clear.npz", scene="one", triangles=np.array([[0, 1, 2]]), x=x, t=0.1,
             x_history=np.stack([x, x]), t_history=np.array([0.0, 0.1]), pinned=np.zeros(3, bool),
             **sizes, **{f"{kind}_center": centres[0], f"{kind}_center_history": centres[[0, 0]]})
    assert main(["check", str(tmp_path / "clear.npz")]) == 0
