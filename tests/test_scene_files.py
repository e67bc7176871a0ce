"""Scene files: every preset round-trips through `list --scene-file`, problems are `FILE:LINE:
problem` with nothing written, paths are relative to the file, the command line wins."""
import dataclasses
import importlib
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd

from taichi_sim.app.session import Session
from taichi_sim.cli import main
from taichi_sim.cli.parser import build_parser
from taichi_sim.cli.views import _session_args
from taichi_sim.errors import ConfigError
from taichi_sim.export import FORMATS
from taichi_sim.scene import SCENES, Param, scene_preset
from taichi_sim.scene_file import apply_scene_file, key_line, load_scene_file, scene_file_text

EXAMPLES = sorted((Path(__file__).resolve().parent.parent / "examples" / "scenes").glob("*.toml"))

TEXT = """# a comment with nx = 1 in it
scene = "cloth"

[parameters]
nxx = 3
nx = 4
"quoted" = 1

[run]
dt = 0.5
[integrator]
name = "xpbd"
  substeps=2
output.npz = "a.npz"
"""


@pytest.mark.parametrize("table, key, line", [
    ((), "scene", 2), (("parameters",), "nx", 6), (("parameters",), "nxx", 5), (("parameters",), "quoted", 7),
    (("run",), "dt", 10), (("integrator",), "substeps", 13), (("integrator", "output"), "npz", 14),
    (("parameters",), None, 4), (("integrator",), None, 11), (("parameters",), "absent", 1), ((), "run", 9),
])
def test_key_line_finds_the_key_in_its_table(table, key, line):
    assert key_line(TEXT, table, key) == line


def test_key_line_of_a_dotted_table_and_a_table_without_header():
    text = 'scene = "x"\nrun.dt = 1\nrun.seed = 2\n[parameters]\n[ output ]\nnpz = "a"\n'
    assert key_line(text, ("run",), "seed") == 3 and key_line(text, ("run",), None) == 2
    assert key_line(text, ("output",), "npz") == 6 and key_line(text, ("output",), None) == 5


@pytest.mark.parametrize("name", list(SCENES))
def test_every_preset_round_trips_through_list_scene_file(tmp_path, capsys, name):
    assert main(["list", "--scene-file", name]) == 0
    path = tmp_path / f"{name}.toml"
    path.write_text(capsys.readouterr().out)
    preset = SCENES[name]
    loaded = load_scene_file(path)
    assert loaded.scene == name and loaded.integrator == preset.default_integrator
    assert list(loaded.params) == [p.name for p in preset.params]
    for p in preset.params:  # every default, of its own type
        assert loaded.params[p.name] == p.default and type(loaded.params[p.name]) is type(p.default), p.name
    assert loaded.run["dt"] == preset.default_dt and loaded.output["npz"] == str(tmp_path / f"{name}.npz")
    text = path.read_text()
    for p in preset.params:  # units and meanings as comments
        assert p.meaning in text and (not p.unit or f"[{p.unit}]" in text)


def test_a_printed_scene_file_runs_unchanged(tmp_path, capsys, monkeypatch):
    main(["list", "--scene-file", "spring"])
    (tmp_path / "spring.toml").write_text(capsys.readouterr().out)
    monkeypatch.chdir("/")  # the npz goes beside the file, wherever the command runs
    assert main(["simulate", str(tmp_path / "spring.toml"), "--quiet"]) == 0
    data = np.load(tmp_path / "spring.npz")
    assert str(data["integrator"]) == "symplectic_euler" and float(data["t"]) == pytest.approx(1.0)
    assert float(data["param_stiffness"]) == 10.0 and int(data["steps"]) == 100


def test_list_scene_file_of_an_unknown_scene(capsys):
    assert main(["list", "--scene-file", "clth"]) == 2
    assert "did you mean 'cloth'" in capsys.readouterr().err


GOOD = 'scene = "cloth"\n\n[parameters]\nnx = 4\nny = 3\n\n[run]\nsteps = 2\n\n[output]\nnpz = "run.npz"\n'


@pytest.mark.parametrize("edit, line, problem", [
    (("nx = 4", "nx = 1"), 4, "parameter nx: must be >= 2, got 1"),
    (("nx = 4", 'nx = "4"'), 4, "parameter nx: expected int, got '4'"),
    (("nx = 4", "stifness = 4.0"), 4, "scene 'cloth' has no parameter 'stifness': did you mean 'stiffness'"),
    (("[parameters]", "[paramters]"), 3, "unknown table 'paramters': did you mean 'parameters'?"),
    (("[run]", "[run.extra]\nx = 1\n[run]"), 7, "[run]: 'extra'"),
    (("steps = 2", "stepz = 2"), 8, "unknown key in [run]: 'stepz': did you mean 'steps'?"),
    (("steps = 2", "steps = 2\nduration = 1.0"), 8, "give [run] steps or duration, not both"),
    (("steps = 2", "steps = 0"), 8, "parameter steps: must be >= 1"),
    (("steps = 2", 'precision = "f16"'), 8, "must be one of f32, f64"),
    (("steps = 2", 'curves = "nowhere.json"'), 8, "curves: no such file 'nowhere.json'"),
    (('npz = "run.npz"', 'npz = "run.npz"\nexport_format = "objj"'), 12, "did you mean 'obj'"),
    (('npz = "run.npz"', 'npz = ""'), 11, "npz: an empty path"),
    (('scene = "cloth"', 'scene = "clth"'), 1, "did you mean 'cloth'"),
    (("nx = 4", "nx = 4\nnx = 5"), 5, "not valid TOML"),
    (("[run]", '[integrator]\nname = "pkg.mod:Stepper"\n[run]'), 8, "registered integrators only"),
    (("[run]", '[integrator]\nname = "eulr"\n[run]'), 8, "did you mean 'euler'"),
    (("[run]", '[integrator]\nname = "xpbd"\nsubsteps = 2.5\n[run]'), 9, "option substeps: expects int"),
    (("[run]", '[integrator]\nname = "xpbd"\nrtol = 1e-3\n[run]'), 9, "takes no option 'rtol'"),
    (("[run]", '[integrator]\nsubsteps = 2\n[run]'), 7, "[integrator] needs name"),
])
def test_a_bad_scene_file_is_one_line_with_its_line_and_writes_nothing(tmp_path, capsys, edit, line, problem):
    path = tmp_path / "scene.toml"
    path.write_text(GOOD.replace(*edit))
    assert main(["simulate", str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and err.startswith(f"taichi-sim: error: {path}:{line}: "), err
    assert problem in err, err
    assert [p.name for p in tmp_path.iterdir()] == ["scene.toml"]


def test_a_scene_file_naming_an_importable_class_is_refused_before_importing_it(tmp_path, capsys, monkeypatch):
    # The module exists and leaves a mark when imported: refused, the mark must not be there.
    # (A module that does not exist could not tell "refused" from "failed to import".)
    mark = tmp_path / "imported"
    (tmp_path / "marking_plugin.py").write_text(
        f"from pathlib import Path\nPath({str(mark)!r}).touch()\n\n\nclass Stepper:\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    monkeypatch.delitem(sys.modules, "marking_plugin", raising=False)
    path = tmp_path / "scene.toml"
    path.write_text(GOOD.replace("[run]", '[integrator]\nname = "marking_plugin:Stepper"\n[run]'))
    assert main(["simulate", str(path)]) == 2
    assert "registered integrators only" in capsys.readouterr().err
    assert not mark.exists() and "marking_plugin" not in sys.modules
    assert not (tmp_path / "run.npz").exists()
    importlib.import_module("marking_plugin")  # the control: importing it does leave the mark
    assert mark.exists()


def test_a_missing_scene_file_and_a_missing_length(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "none.toml")]) == 2
    assert "scene file" in capsys.readouterr().err
    (tmp_path / "s.toml").write_text('scene = "spring"\n')
    assert main(["simulate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "a.npz")]) == 2
    assert "simulate needs --steps N or --t-end T" in capsys.readouterr().err
    assert main(["simulate", str(tmp_path / "s.toml"), "--steps", "2"]) == 2
    assert "simulate needs --out" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]


@pytest.fixture
def mesh_preset(monkeypatch):
    """A preset with a file parameter (unit "path"), as a mesh scene has."""
    preset = dataclasses.replace(SCENES["spring"], name="with-file", params=(
        *SCENES["spring"].params, Param("file", "", "path", "a mesh file")))
    monkeypatch.setitem(SCENES, preset.name, preset)
    return preset


def test_paths_are_relative_to_the_scene_file(tmp_path, mesh_preset, monkeypatch):
    (tmp_path / "sub" / "meshes").mkdir(parents=True)
    (tmp_path / "sub" / "meshes" / "flag.obj").write_text("v 0 0 0\n")
    (tmp_path / "sub" / "pulse.json").write_text("{}")
    path = tmp_path / "sub" / "scene.toml"
    path.write_text('scene = "with-file"\n[parameters]\nfile = "meshes/flag.obj"\n[run]\ncurves = "pulse.json"\n'
                    '[output]\nnpz = "../runs/a.npz"\nexport = "frames"\n')
    monkeypatch.chdir("/")
    loaded = load_scene_file(path)
    assert loaded.params["file"] == str(tmp_path / "sub" / "meshes" / "flag.obj")
    assert loaded.run["curves"] == str(tmp_path / "sub" / "pulse.json")
    assert loaded.output == {"npz": str(tmp_path / "runs" / "a.npz"), "export": str(tmp_path / "sub" / "frames")}


def test_a_missing_mesh_file_is_named_with_its_line(tmp_path, capsys, mesh_preset):
    path = tmp_path / "scene.toml"
    path.write_text('scene = "with-file"\n\n[parameters]\nstiffness = 5.0\nfile = "flag.obj"\n')
    assert main(["simulate", str(path), "--steps", "1", "--out", str(tmp_path / "a.npz")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"taichi-sim: error: {path}:5: file: no such file 'flag.obj' (looked for "
                          f"'{tmp_path / 'flag.obj'}'")
    assert [p.name for p in tmp_path.iterdir()] == ["scene.toml"]


def parsed(tmp_path, text, *argv, command="simulate"):
    path = tmp_path / "scene.toml"
    path.write_text(text)
    args = build_parser().parse_args([command, str(path), *argv])
    apply_scene_file(args, command)
    return args


FULL = """scene = "cloth"
[parameters]
nx = 4
stiffness = 100.0
[integrator]
name = "xpbd"
substeps = 3
iterations = 2
[run]
dt = 0.002
steps = 5
seed = 7
precision = "f32"
save_every = 2
[output]
npz = "a.npz"
export = "a.usda"
export_format = "usd"
"""


def test_the_command_line_overrides_the_file(tmp_path):
    args = parsed(tmp_path, FULL)  # the file alone
    assert (args.scene, args.integrator, args.dt, args.steps, args.t_end, args.seed, args.precision, args.arch) == \
        ("cloth", "xpbd", 0.002, 5, None, 7, "f32", "cpu")
    assert dict(args.assignments) == {"nx": "4", "stiffness": "100.0"}
    assert dict(args.integrator_options) == {"substeps": "3", "iterations": "2"}
    assert (args.out, args.export, args.export_format, args.save_every) == \
        (str(tmp_path / "a.npz"), str(tmp_path / "a.usda"), "usd", 2)
    args = parsed(tmp_path, FULL, "--set", "stiffness=50", "--dt", "0.001", "--t-end", "0.01", "--seed", "1",
                  "--precision", "f64", "--substeps", "4", "--option", "iterations=1", "--out", "b.npz")
    assert dict(args.assignments) == {"nx": "4", "stiffness": "50"}  # per parameter
    assert (args.dt, args.steps, args.t_end, args.seed, args.precision, args.out) == \
        (0.001, None, 0.01, 1, "f64", "b.npz")  # --t-end replaces the file's steps
    assert args.flag_options == {"substeps": 4} and dict(args.integrator_options) == {"iterations": "1"}  # per option
    args = parsed(tmp_path, FULL, "--integrator", "symplectic_euler")
    assert args.integrator == "symplectic_euler" and args.integrator_options == []  # xpbd's options stay behind


def test_a_usd_export_needs_no_format(tmp_path, capsys):
    path = tmp_path / "scene.toml"
    path.write_text(FULL.replace('export_format = "usd"\n', "").replace("nx = 4", "nx = 3\nny = 2"))
    assert main(["simulate", str(path), "--steps", "2", "--integrator", "symplectic_euler", "--quiet"]) == 0
    assert (tmp_path / "a.usda").is_file()
    assert main(["simulate", str(path), "--steps", "2", "--export", str(tmp_path / "frames")]) == 2
    assert "go together" in capsys.readouterr().err and not (tmp_path / "frames").exists()


def test_a_scene_file_run_applies_the_overrides(tmp_path, capsys):
    path = tmp_path / "scene.toml"
    path.write_text(FULL.replace('export = "a.usda"\nexport_format = "usd"\n', ""))
    assert main(["simulate", str(path), "--set", "stiffness=50", "--steps", "3", "--quiet"]) == 0
    data = np.load(tmp_path / "a.npz")
    assert int(data["param_nx"]) == 4 and float(data["param_stiffness"]) == 50  # file's nx, command line's stiffness
    assert int(data["steps"]) == 3 and float(data["dt"]) == pytest.approx(0.002) and int(data["seed"]) == 7
    assert str(data["integrator"]) == "xpbd" and data["x_history"].shape[0] == 3  # t = 0, step 2, the end


def test_record_and_demo_take_a_scene_file_with_its_integrator_options(f64, tmp_path, capsys):
    args = parsed(tmp_path, FULL, "--out", "x.gif", "--option", "iterations=4", command="record")
    assert (args.scene, args.integrator, args.dt, args.seed, args.precision) == ("cloth", "xpbd", 0.002, 7, "f32")
    assert dict(args.assignments) == {"nx": "4", "stiffness": "100.0"}
    spec = _session_args(args)  # the file's options, the command line's winning
    assert spec["options"] == {"xpbd": {"substeps": 3, "iterations": 4}}
    session = Session(spec["scene"], spec["integrators"], params=spec["params"], integrator_options=spec["options"])
    assert (session.runners[0].integrator.substeps, session.runners[0].integrator.iterations) == (3, 4)
    args = parsed(tmp_path, FULL, "--side-by-side", "euler,rk4", command="demo")
    assert args.integrator is None and args.side_by_side == ["euler", "rk4"] and args.integrator_options == []
    err = capsys.readouterr().err  # the options it cannot apply are said, never dropped silently
    assert f"{tmp_path / 'scene.toml'}:7: --side-by-side runs each method with the scene's options or its " \
        "defaults; the file's substeps = 3, iterations = 2 are not used" in err
    stiff = tmp_path / "stiff.toml"  # the template's own choice is the scene's: nothing to warn of
    stiff.write_text(scene_file_text(scene_preset("cloth-stiff")))
    parsed_args = build_parser().parse_args(["demo", str(stiff), "--side-by-side", "xpbd,rk4"])
    apply_scene_file(parsed_args, "demo")
    assert "not used" not in capsys.readouterr().err
    args = parsed(tmp_path, FULL, "--side-by-side", "euler,rk4", "--option", "substeps=2", "--out", "x.gif",
                  command="record")
    with pytest.raises(ConfigError, match="--option .* --side-by-side"):
        _session_args(args)


def test_defaults_without_a_scene_file():
    args = build_parser().parse_args(["simulate", "spring", "--steps", "1", "--out", "a.npz"])
    assert apply_scene_file(args, "simulate") is None
    assert (args.precision, args.arch, args.seed, args.assignments) == ("f64", "cpu", 0, [])


@pytest.mark.parametrize("example", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_the_example_scene_files_run(tmp_path, example):
    loaded = load_scene_file(example)
    fmt = FORMATS[loaded.output["export_format"]]
    export = tmp_path / ("frames" if fmt.sequence else f"frames{fmt.suffixes[0]}")
    assert main(["simulate", str(example), "--steps", "2", "--out", str(tmp_path / "run.npz"),
                 "--export", str(export), "--quiet"]) == 0
    kept = np.load(tmp_path / "run.npz")["x_history"]
    if fmt.sequence:
        frames = len(list(export.iterdir()))
    else:
        stage = Usd.Stage.Open(str(export))
        frames = len(next(iter(stage.Traverse())).GetChildren()[0].GetAttribute("points").GetTimeSamples())
    assert frames == len(kept) >= 2
    assert tomllib.loads(example.read_text())["scene"] == loaded.scene
