"""Frames out: OBJ and PLY sequences and USD stages read back equal the run, and bad input is
refused in one line with nothing written."""
import os

import numpy as np
import pytest
import trimesh
from pxr import Usd, UsdGeom

from taichi_sim.cli import main
from taichi_sim.export import FORMATS, Frames, export, time_codes


def grid_frames(n=5, frames=4, dt=1 / 30, rng=None):
    """A small n x n sheet moving and deforming over ``frames`` frames, with its triangles."""
    rng = rng or np.random.default_rng(7)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    ids = i * n + j
    a, b, c, d = ids[:-1, :-1].ravel(), ids[1:, :-1].ravel(), ids[1:, 1:].ravel(), ids[:-1, 1:].ravel()
    triangles = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    base = np.stack([i.ravel() / n, np.ones(n * n), j.ravel() / n], 1)
    positions = np.stack([base + rng.normal(scale=0.1, size=base.shape) * k for k in range(frames)])
    return Frames(positions, np.arange(frames) * dt, triangles, "cloth-sphere")


def save_run(path, frames, **drop):
    arrays = {"x_history": frames.positions, "t_history": frames.times, "scene": np.str_(frames.name)}
    if frames.triangles is not None:
        arrays["triangles"] = frames.triangles
    np.savez(path, **{k: v for k, v in arrays.items() if k not in drop})
    return path


@pytest.mark.parametrize("fmt", ["obj", "ply"])
def test_sequence_frames_read_back_equal_the_run(tmp_path, fmt):
    frames = grid_frames()
    out = export(frames, FORMATS[fmt], tmp_path / "frames", progress=False)
    names = sorted(p.name for p in out.iterdir())
    assert names == [f"frame_{k:04d}.{fmt}" for k in range(4)]
    for k, name in enumerate(names):
        mesh = trimesh.load(out / name, process=False)
        if fmt == "obj":  # 9 significant digits
            np.testing.assert_allclose(mesh.vertices, frames.positions[k], rtol=1e-8, atol=1e-12)
        else:  # binary floats
            np.testing.assert_array_equal(mesh.vertices, frames.positions[k].astype(np.float32))
        np.testing.assert_array_equal(mesh.faces, frames.triangles)
    assert "t = 0.1 s" in (out / names[3]).read_bytes().decode("latin-1")


@pytest.mark.parametrize("suffix", [".usda", ".usdc", ".usd"])
def test_usd_stage_has_a_sample_per_frame_at_the_frame_times(tmp_path, suffix):
    frames = grid_frames(frames=5, dt=0.02)
    path = export(frames, FORMATS["usd"], tmp_path / f"run{suffix}", progress=False)
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == 50 and stage.GetFramesPerSecond() == 50
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 4)
    assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == 1
    assert stage.GetDefaultPrim().GetPath() == "/World"
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/cloth_sphere"))
    assert mesh and mesh.GetSubdivisionSchemeAttr().Get() == "none"
    points, extent = mesh.GetPointsAttr(), mesh.GetExtentAttr()
    assert points.GetTimeSamples() == [0, 1, 2, 3, 4]
    for code, x in enumerate(frames.positions):
        # a frame at t seconds sits at time code t * timeCodesPerSecond
        assert frames.times[code] * stage.GetTimeCodesPerSecond() == pytest.approx(code)
        np.testing.assert_array_equal(np.array(points.Get(code)), x.astype(np.float32))
        np.testing.assert_array_equal(np.array(extent.Get(code)),
                                      [x.astype(np.float32).min(0), x.astype(np.float32).max(0)])
    np.testing.assert_array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()), frames.triangles.ravel())
    assert set(mesh.GetFaceVertexCountsAttr().Get()) == {3}
    assert len(mesh.GetFaceVertexCountsAttr().Get()) == len(frames.triangles)
    assert (path.read_bytes()[:8] == b"#usda 1.") == (suffix == ".usda")  # .usd: binary crate


def test_time_codes_of_an_uneven_last_frame_and_an_adaptive_run():
    # --t-end shortens the last step: whole codes, then a fraction
    per_second, codes = time_codes(np.array([0.0, 0.1, 0.2, 0.25]))
    assert per_second == 10 and codes.tolist() == [0, 1, 2, 2.5]
    per_second, codes = time_codes(np.array([0.0, 1 / 60, 2 / 60]))
    assert per_second == 60 and codes.tolist() == [0, 1, 2]
    assert time_codes(np.array([0.0]))[1].tolist() == [0]
    # times summed step by step carry rounding (0.30000000000000004): the codes are still whole
    per_second, codes = time_codes(np.concatenate([[0.0], np.cumsum([0.1] * 7)]))
    assert per_second == 10 and codes.tolist() == list(range(8))


def test_a_run_without_a_surface_exports_points(tmp_path):
    frames = grid_frames()
    points = Frames(frames.positions, frames.times, None, "pendulum")
    out = export(points, FORMATS["obj"], tmp_path / "pts", progress=False)
    text = (out / "frame_0002.obj").read_text()
    assert text.count("\nv ") == 25 and "\nf " not in text
    mesh = trimesh.load(export(points, FORMATS["ply"], tmp_path / "ply", progress=False) / "frame_0002.ply",
                        process=False)
    np.testing.assert_array_equal(np.asarray(mesh.vertices), frames.positions[2].astype(np.float32))
    stage = Usd.Stage.Open(str(export(points, FORMATS["usd"], tmp_path / "p.usda", progress=False)))
    prim = UsdGeom.Points(stage.GetPrimAtPath("/World/pendulum"))
    np.testing.assert_array_equal(np.array(prim.GetPointsAttr().Get(3)), frames.positions[3].astype(np.float32))


@pytest.mark.parametrize("fmt, out", [("usd", "run.usdc"), ("obj", "frames")])
def test_export_command_writes_what_the_npz_holds(tmp_path, capsys, fmt, out):
    frames = grid_frames()
    npz = save_run(tmp_path / "run.npz", frames)
    assert main(["export", str(npz), "--format", fmt, "--out", str(tmp_path / out)]) == 0
    assert f"cloth-sphere: 4 frames of 25 vertices (32 triangles), t = 0 to 0.1 s, as {fmt}" in capsys.readouterr().out
    assert (tmp_path / out).exists()


def bad(tmp_path, capsys, args, problem):
    """One line on stderr naming the problem, exit 2, nothing new in tmp_path."""
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("taichi-sim: error: ") and len(err.splitlines()) == 1, err
    assert problem in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("drop, fmt, out, problem", [
    ("x_history", "usd", "o.usda", "no frames (no `x_history`): run `simulate` with --save-every"),
    ("t_history", "obj", "o", "no frame times (`t_history`)"),
    (None, "ply2", "o", "unknown export format 'ply2': did you mean 'ply'?"),
    (None, "USD", "o.usda", "did you mean 'usd'?"),
    (None, "usd", "o.abc", "must end in .usda, .usdc, .usd"),
    (None, "obj", "missing/o", "directory"),
    (None, "usd", "missing/o.usda", "does not exist"),
])
def test_bad_export_input_is_one_line_and_writes_nothing(tmp_path, capsys, drop, fmt, out, problem):
    npz = save_run(tmp_path / "run.npz", grid_frames(), **({drop: True} if drop else {}))
    bad(tmp_path, capsys, ["export", str(npz), "--format", fmt, "--out", str(tmp_path / out)], problem)


def test_export_refuses_a_file_that_is_not_an_npz_and_a_full_folder(tmp_path, capsys):
    (tmp_path / "notes.npz").write_text("not a zip")
    bad(tmp_path, capsys, ["export", str(tmp_path / "notes.npz"), "--format", "obj", "--out",
                           str(tmp_path / "o")], "is not a run's npz (not a zip archive)")
    bad(tmp_path, capsys, ["export", str(tmp_path / "none.npz"), "--format", "obj", "--out",
                           str(tmp_path / "o")], "no such file")
    npz = save_run(tmp_path / "run.npz", grid_frames())
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("mine")
    bad(tmp_path, capsys, ["export", str(npz), "--format", "obj", "--out", str(tmp_path / "full")], "is not empty")
    assert os.listdir(tmp_path / "full") == ["keep.txt"]
    (tmp_path / "empty").mkdir()  # an empty folder is filled
    assert main(["export", str(npz), "--format", "ply", "--out", str(tmp_path / "empty"), "--quiet"]) == 0
    assert len(os.listdir(tmp_path / "empty")) == 4


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc")
def test_an_export_folder_that_refuses_files_is_refused(tmp_path, capsys):
    npz = save_run(tmp_path / "run.npz", grid_frames())
    bad(tmp_path, capsys, ["export", str(npz), "--format", "usd", "--out", "/proc/run.usda"],
        "cannot write '/proc/run.usda'")


def test_a_failed_write_leaves_nothing(tmp_path, monkeypatch):
    """A writer that fails halfway leaves neither the target nor a temporary behind."""
    from taichi_sim.export import obj

    calls = []

    def failing(triangles, name):
        write = obj.frame_writer(triangles, name)

        def once(f, x, t):
            calls.append(t)
            if len(calls) == 3:
                raise OSError("disk full")
            write(f, x, t)
        return once

    monkeypatch.setitem(FORMATS, "obj", FORMATS["obj"].__class__("obj", True, (".obj",), frame_writer=failing))
    with pytest.raises(OSError):
        export(grid_frames(), FORMATS["obj"], tmp_path / "frames", progress=False)
    assert list(tmp_path.iterdir()) == []


def test_simulate_exports_the_frames_it_saved(tmp_path, capsys):
    out, usd = tmp_path / "run.npz", tmp_path / "run.usda"
    code = main(["simulate", "cloth", "--set", "nx=4", "--set", "ny=3", "--steps", "7", "--save-every", "3",
                 "--out", str(out), "--export", str(usd), "--export-format", "usd"])
    assert code == 0 and f"cloth: 4 frames as usd -> {usd}" in capsys.readouterr().out
    data = np.load(out)
    stage = Usd.Stage.Open(str(usd))
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/World/cloth")).GetPointsAttr()
    codes = points.GetTimeSamples()
    assert len(codes) == len(data["t_history"]) == 4  # t = 0, after 3 and 6 steps, and at the end
    for code, t, x in zip(codes, data["t_history"], data["x_history"]):
        assert code == pytest.approx(t * stage.GetTimeCodesPerSecond())
        np.testing.assert_array_equal(np.array(points.Get(code)), x.astype(np.float32))
    assert codes[-1] == pytest.approx(7 / 3)  # the last frame, one step after the one before


@pytest.mark.parametrize("args, problem", [
    (["--export", "x.usda", "--export-format", "usd"], "give --save-every"),
    (["--save-every", "2", "--export", "frames"], "go together"),
    (["--save-every", "2", "--export", "x.usda", "--export-format", "abc"], "unknown export format 'abc'"),
    (["--save-every", "2", "--export", "nowhere/x.usda", "--export-format", "usd"], "does not exist"),
])
def test_simulate_checks_its_export_before_running(tmp_path, capsys, monkeypatch, args, problem):
    monkeypatch.chdir(tmp_path)
    bad(tmp_path, capsys, ["simulate", "spring", "--steps", "3", "--out", "run.npz", *args], problem)


@pytest.mark.parametrize("with_surface", [True, False])
def test_usd_validators_find_nothing_wrong(tmp_path, with_surface):
    """USD's own validators (default prim, metersPerUnit, upAxis, schema types, ...)."""
    from pxr import UsdValidation

    frames = grid_frames()
    if not with_surface:
        frames = Frames(frames.positions, frames.times, None, "sprinkler")
    stage = Usd.Stage.Open(str(export(frames, FORMATS["usd"], tmp_path / "run.usdc", progress=False)))
    context = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    assert [error.GetMessage() for error in context.Validate(stage)] == []
