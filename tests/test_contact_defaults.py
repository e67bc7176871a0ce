"""cloth-fold's default: vbd with the self-contact in its solve, taking over the scene's post-step
self-collision stage, with the scene's own options (ScenePreset.default_options)."""
import pytest

import taichi_sim as ts
from taichi_sim.app.session import Session
from taichi_sim.cli import main
from taichi_sim.scene_file import scene_file_text


def _fold(n: int = 8):
    return ts.build_scene("cloth-fold", {"nx": n, "ny": n})


@pytest.mark.parametrize("self_contact, in_solve, stage_runs", [
    (None, True, False),   # following the scene: the solve replaces the stage
    (True, True, True),    # asked for: in the solve, the stage kept as a fail-safe
    (False, False, True),  # off: the stage alone
])
def test_vbd_replaces_the_stage_only_when_it_follows_the_scene(f32, self_contact, in_solve, stage_runs):
    scene = _fold()
    options = {} if self_contact is None else {"self_contact": self_contact}
    method = ts.create_integrator("vbd", scene.system, iterations=2, **options)
    stepper = ts.Stepper(scene, method, 1 / 60)
    stepper.step()
    assert method.has_self_contact == in_solve
    assert (scene.part("self_collision").t_end is not None) == stage_runs


def test_the_stage_runs_again_once_another_method_steps_the_scene(f32):
    scene = _fold()
    stepper = ts.Stepper(scene, ts.create_integrator("vbd", scene.system, iterations=2), 1 / 60)
    stepper.step()
    assert scene.part("self_collision").t_end is None
    stepper.set_integrator(ts.create_integrator("symplectic_euler", scene.system))
    stepper.set_dt(1e-3)
    stepper.step()
    assert scene.part("self_collision").t_end == pytest.approx(stepper.t)


def test_simulate_runs_cloth_fold_with_the_scenes_options_and_says_so(tmp_path, capsys):
    assert main(["simulate", "cloth-fold", "--set", "nx=6", "--set", "ny=6", "--steps", "2",
                 "--out", str(tmp_path / "a.npz")]) == 0
    out = capsys.readouterr().out
    assert "2 steps of vbd(substeps=4, iterations=5) to t = 0.0333333 s" in out
    assert "cloth-fold: self_collision: done in vbd's solve" in out
    # another method gets none of them (symplectic Euler has no substeps), and the stage runs
    assert main(["simulate", "cloth-fold", "--set", "nx=6", "--set", "ny=6", "--steps", "2", "--integrator",
                 "symplectic_euler", "--dt", "0.001", "--out", str(tmp_path / "b.npz")]) == 0
    out = capsys.readouterr().out
    assert "2 steps of symplectic_euler to" in out and "cloth-fold: self-contact:" in out


def test_the_command_line_and_a_scene_file_override_the_scenes_options(tmp_path, capsys):
    assert main(["simulate", "cloth-fold", "--set", "nx=6", "--set", "ny=6", "--steps", "1", "--substeps", "2",
                 "--option", "iterations=3", "--out", str(tmp_path / "a.npz")]) == 0
    assert "of vbd(substeps=2, iterations=3)" in capsys.readouterr().out
    text = scene_file_text(ts.SCENES["cloth-fold"])
    assert "\nsubsteps = 4\niterations = 5\n" in text and "substeps = 1" not in text
    path = tmp_path / "fold.toml"
    path.write_text(text.replace("iterations = 5", "iterations = 7").replace("nx = 32", "nx = 6")
                    .replace("ny = 32", "ny = 6").replace("duration = 1.0", "steps = 1")
                    .replace('npz = "cloth-fold.npz"', f'npz = "{tmp_path / "f.npz"}"'))
    assert main(["simulate", str(path)]) == 0
    assert "of vbd(substeps=4, iterations=7)" in capsys.readouterr().out


def test_the_launcher_steps_cloth_fold_with_the_scenes_options(f32):
    session = Session("cloth-fold", ["vbd"], params={"nx": 6, "ny": 6})
    method = session.runners[0].integrator
    assert (method.substeps, method.iterations) == (4, 5)
    session.select_scene("cloth-spin")  # a scene without options: vbd's own defaults there
    assert session.runners[0].integrator.substeps == 1
    session.select_scene("cloth-fold")
    assert session.runners[0].integrator.substeps == 4
