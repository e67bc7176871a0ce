"""A scene's own integrator options (cloth-stiff runs XPBD with 50 substeps): every path that
binds a method by name takes them, and whatever a caller sets wins."""
import numpy as np

import taichi_sim as ts
from taichi_sim.app.session import Session
from taichi_sim.cli import main
from taichi_sim.scene import scene_preset
from taichi_sim.scene_file import load_scene_file, scene_file_text
from taichi_sim.stepper import Stepper, bind_integrator

SMALL = {"nx": 4, "ny": 4}
STIFF_SUBSTEPS = 50  # docs/lab/vbd.md, "cloth-stiff's default": 20 substeps end 5 cm off at 64 x 64


def test_the_stiff_cloth_binds_xpbd_with_its_substeps_and_a_caller_overrides_them(f64):
    scene = ts.build_scene("cloth-stiff", SMALL)
    assert scene.options_for("xpbd") == {"substeps": STIFF_SUBSTEPS}
    assert scene.options_for("vbd") == {}
    assert Stepper(scene, "xpbd", 1 / 60).integrator.substeps == STIFF_SUBSTEPS
    assert bind_integrator(scene, "xpbd", substeps=7).substeps == 7
    assert bind_integrator(scene, "xpbd", iterations=2).substeps == STIFF_SUBSTEPS  # merged, not replaced
    scene.options_for("xpbd")["substeps"] = 3  # a copy: the scene keeps its own
    assert scene.options_for("xpbd") == {"substeps": STIFF_SUBSTEPS}
    result = ts.run(scene, "xpbd", dt=1 / 60, steps=1, energy_every=0, progress=False)
    assert result.status.value == "ok"
    plain = ts.build_scene("cloth", SMALL)
    assert plain.options_for("xpbd") == {} and Stepper(plain, "xpbd", 1 / 60).integrator.substeps == 20


def test_the_launcher_runs_the_scene_with_its_options_unless_told(f64):
    session = Session("cloth-stiff", ["xpbd"], params=SMALL)
    assert session.runners[0].integrator.substeps == STIFF_SUBSTEPS
    told = Session("cloth-stiff", ["xpbd"], params=SMALL, integrator_options={"xpbd": {"substeps": 4}})
    assert told.runners[0].integrator.substeps == 4
    session.select_scene("cloth")
    session.runners[0].set_integrator("xpbd")
    assert session.runners[0].integrator.substeps == 20


def test_simulate_list_and_the_scene_file_say_the_scenes_choice(f64, tmp_path, capsys):
    args = ["simulate", "cloth-stiff", "--set", "nx=4", "--set", "ny=4", "--steps", "1"]
    assert main([*args, "--out", str(tmp_path / "a.npz")]) == 0
    assert f"of xpbd(substeps={STIFF_SUBSTEPS}) to t" in capsys.readouterr().out
    assert main([*args, "--substeps", "6", "--out", str(tmp_path / "b.npz")]) == 0
    assert "of xpbd(substeps=6) to t" in capsys.readouterr().out
    assert main([*args, "--option", "substeps=5", "--out", str(tmp_path / "c.npz")]) == 0
    assert "of xpbd(substeps=5) to t" in capsys.readouterr().out
    assert str(np.load(tmp_path / "c.npz")["status"]) == "ok"
    assert main(["list"]) == 0
    listing = capsys.readouterr().out
    stiff = listing[listing.index("  cloth-stiff:"):]
    assert f"default integrator xpbd(substeps={STIFF_SUBSTEPS})," in stiff.splitlines()[1]
    text = scene_file_text(scene_preset("cloth-stiff"))
    assert f"substeps = {STIFF_SUBSTEPS}  # this scene's choice" in text
    path = tmp_path / "stiff.toml"
    path.write_text(text)
    assert load_scene_file(path).options == {"substeps": STIFF_SUBSTEPS}


def test_every_scenes_options_are_options_its_methods_take():
    """A preset's options are checked when a method is bound, which a scene's tests may never
    do: a misspelt one (``substep``) would only fail when someone runs that method there."""
    from taichi_sim.integrators import check_options
    from taichi_sim.scene import SCENES

    chosen = {name: preset.integrator_options for name, preset in SCENES.items() if preset.integrator_options}
    assert chosen["cloth-stiff"] == {"xpbd": {"substeps": STIFF_SUBSTEPS}}
    for options in chosen.values():
        for method, values in options.items():
            check_options(method, values)
