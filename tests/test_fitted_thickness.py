"""A mesh cloth whose user gives no thickness takes one that fits its rest shape (half its
smallest distance between non-adjacent parts, at most the default, at least THICKNESS_FLOOR)
and says so once; a thickness the user gives is checked as before (docs/meshes.md)."""
import warnings

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.collide.mesh_check import THICKNESS_FLOOR, contact_thickness
from taichi_sim.errors import ConfigError, InputNote
from taichi_sim.geometry import self_intersections


def two_panels(gap: float, length: float = 0.2, width: float = 0.1, spacing: float = 0.04):
    """Two flat panels, one over the other as a garment's front and back before sewing: a lower
    one at y = 0 and an upper one at y = ``gap`` (m), each ``length`` along x from x = 0 by
    ``width`` along z, a grid of ``spacing`` (m; 1/sqrt 2 of it above the gap). The nearest
    non-adjacent parts are the two panels, exactly ``gap`` apart (a vertex of one under a corner
    of a triangle of the other, parallel edges). Returns (x (N, 3) m, triangles (T, 3))."""
    u = np.linspace(0.0, length, int(round(length / spacing)) + 1)
    w = np.linspace(0.0, width, int(round(width / spacing)) + 1)
    ids = np.arange(len(u) * len(w)).reshape(len(u), len(w))
    a, b, c, d = ids[:-1, :-1], ids[:-1, 1:], ids[1:, :-1], ids[1:, 1:]
    panel = np.concatenate([np.stack([a, c, d], -1).reshape(-1, 3), np.stack([a, d, b], -1).reshape(-1, 3)])
    x = np.array([(pu, py, pw) for py in (0.0, gap) for pu in u for pw in w])
    return x, np.concatenate([panel, panel + ids.size])


def write_obj(path, x, triangles):
    lines = [f"v {a:.9f} {b:.9f} {c:.9f}" for a, b, c in x] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in triangles]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("gap, ceiling, taken", [
    (0.006, 0.01, 0.003),       # the default does not fit: half the gap
    (0.015, 0.01, 0.0075),      # the default fits, but leaves less margin than half the gap
    (0.03, 0.01, 0.01),         # the default, half the gap being larger
    (0.0008, 0.01, THICKNESS_FLOOR),  # half the gap is below the floor, the floor still fits
])
def test_the_fitted_thickness_is_half_the_gap_within_its_bounds(gap, ceiling, taken):
    x, tris = two_panels(gap)
    thickness, smallest = contact_thickness(x, tris, ceiling, fit=True)
    if gap < 2 * ceiling:  # measured exactly as far as it decides the thickness
        assert smallest == pytest.approx(gap, rel=1e-9)
    assert thickness == pytest.approx(taken, rel=1e-9)
    if ceiling < gap:  # without fit, the default is taken as given when it fits
        assert contact_thickness(x, tris, ceiling)[0] == ceiling


def test_a_mesh_closer_than_the_floor_and_a_given_thickness_too_large_are_refused():
    x, tris = two_panels(0.0004)
    with pytest.raises(ConfigError, match=r"^thickness: non-adjacent parts .* within 0\.0004 m .* below 0\.0004 m"):
        contact_thickness(x, tris, 0.01, fit=True)
    x, tris = two_panels(0.006)
    with pytest.raises(ConfigError, match=r"thickness 0\.01 m must be below 0\.006 m"):
        contact_thickness(x, tris, 0.01)


def test_the_grid_cloth_keeps_its_default(f32):
    with warnings.catch_warnings():
        warnings.simplefilter("error", InputNote)
        scene = ts.build_scene("cloth-fold", {"nx": 8, "ny": 8})
    assert scene.part("self_collision") is not None and scene.params["thickness"] == 0.01


def test_a_mesh_file_without_a_thickness_takes_the_fitted_one_and_runs(tmp_path, capsys, f32):
    obj = write_obj(tmp_path / "fold.obj", *two_panels(0.006))
    out = tmp_path / "run.npz"
    # both panels held along x = 0: the upper one sags onto the lower one, which the ground holds
    args = ["simulate", "mesh", "--set", f"file={obj}", "--set", "pin=box:-0.001,-1,-1,0.001,1,1",
            "--set", "self_collision=1", "--set", "plane=1", "--set", "plane_height=-0.01",
            "--steps", "12", "--save-every", "4", "--out", str(out), "--quiet"]
    assert main(args) == 0
    err = capsys.readouterr().err
    note = [line for line in err.splitlines() if "self_collision takes thickness" in line]
    assert len(note) == 1, err
    assert note[0] == ("taichi-sim: mesh: self_collision takes thickness 0.003 m from the mesh (half the 0.006 m "
                       "between its closest non-adjacent parts at rest), not the default 0.01 m; give thickness "
                       "to choose")
    with np.load(out) as data:
        assert float(data["param_thickness"]) == pytest.approx(0.003, rel=1e-9)
        frames, triangles = data["x_history"], data["triangles"]
    moved = np.abs(frames[-1] - frames[0]).max()
    assert moved > 0.005  # the panels did sag
    assert all(self_intersections(x, triangles).count == 0 for x in frames)


def test_vbd_follows_the_fitted_thickness(tmp_path, capsys, f32):
    obj = write_obj(tmp_path / "fold.obj", *two_panels(0.006))
    out = tmp_path / "run.npz"
    assert main(["simulate", "mesh", "--set", f"file={obj}", "--set", "pin=box:-0.001,-1,-1,0.001,1,1",
                 "--set", "self_collision=1", "--integrator", "vbd", "--steps", "3", "--out", str(out),
                 "--quiet"]) == 0
    assert capsys.readouterr().err.count("self_collision takes thickness 0.003 m") == 1


def test_a_given_thickness_is_used_or_refused_as_before(tmp_path, capsys, f32):
    obj = write_obj(tmp_path / "fold.obj", *two_panels(0.006))
    out = tmp_path / "run.npz"
    base = ["simulate", "mesh", "--set", f"file={obj}", "--set", "pin=box:-0.001,-1,-1,0.001,1,1",
            "--set", "self_collision=1", "--steps", "2", "--out", str(out), "--quiet"]
    assert main(base + ["--set", "thickness=0.008"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]  # (and the two pieces' warning)
    assert len(errors) == 1 and "thickness 0.008 m must be below 0.006 m" in errors[0] and not out.exists()
    assert main(base + ["--set", "thickness=0.004"]) == 0
    assert "takes thickness" not in capsys.readouterr().err
    with np.load(out) as data:
        assert float(data["param_thickness"]) == 0.004


@pytest.mark.parametrize("quantized", [False, True])
def test_the_measurements_box_pairs_are_every_overlapping_pair_once(quantized):
    # the broad phase the measurement (and check_contact_mesh) runs on: against brute force,
    # boxes on the cells' boundaries included
    from taichi_sim.collide.mesh_check import _box_pairs

    rng = np.random.default_rng(7)
    for _ in range(10):
        if quantized:
            lo_a, lo_b = rng.integers(0, 20, (200, 3)) * 0.05, rng.integers(0, 20, (150, 3)) * 0.05
            hi_a, hi_b = lo_a + rng.integers(0, 3, (200, 3)) * 0.05, lo_b + rng.integers(0, 3, (150, 3)) * 0.05
        else:
            lo_a, lo_b = rng.uniform(0, 1, (200, 3)), rng.uniform(0, 1, (150, 3))
            hi_a, hi_b = lo_a + rng.uniform(0, 0.1, (200, 3)), lo_b + rng.uniform(0, 0.1, (150, 3))
        cell = float(max((hi_a - lo_a).max(), (hi_b - lo_b).max()))
        pairs = _box_pairs(lo_a, hi_a, lo_b, hi_b, cell)
        overlap = np.all((lo_a[:, None] <= hi_b[None]) & (lo_b[None] <= hi_a[:, None]), axis=2)
        assert len(pairs) == overlap.sum() and overlap[pairs[:, 0], pairs[:, 1]].all()
