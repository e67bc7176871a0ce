"""vbd and the scene's post-step self-collision stage: by default its self-contact follows the
scene, in the solve, and the scene leaves out the stage the solve took over (``takeover``)."""
import pytest

import taichi_sim as ts
from taichi_sim.cli import main


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


def test_simulate_says_the_solve_did_the_stages_work_and_names_the_options(tmp_path, capsys):
    assert main(["simulate", "cloth-fold", "--set", "nx=6", "--set", "ny=6", "--steps", "2", "--integrator", "vbd",
                 "--dt", "0.0166666666666667", "--substeps", "2", "--option", "iterations=3",
                 "--out", str(tmp_path / "a.npz")]) == 0
    out = capsys.readouterr().out
    assert "2 steps of vbd(substeps=2, iterations=3) to t = 0.0333333 s" in out
    assert "cloth-fold: self_collision: done in vbd's solve" in out and "impact zones" not in out
    assert main(["simulate", "cloth-fold", "--set", "nx=6", "--set", "ny=6", "--steps", "2", "--integrator",
                 "symplectic_euler", "--dt", "0.001", "--out", str(tmp_path / "b.npz")]) == 0
    out = capsys.readouterr().out
    assert "2 steps of symplectic_euler to" in out and "cloth-fold: self-contact:" in out
    # the preset's default is vbd at 1/60 s (docs/lab/vbd.md, "The fold's pace")
    assert main(["simulate", "cloth-fold", "--set", "nx=6", "--set", "ny=6", "--steps", "2",
                 "--out", str(tmp_path / "c.npz")]) == 0
    out = capsys.readouterr().out
    assert "2 steps of vbd to t = 0.0333333 s" in out and "self_collision: done in vbd's solve" in out


def test_without_a_stage_or_on_a_tearing_cloth_vbd_leaves_the_stage_be(f32):
    plain = ts.build_scene("cloth", {"nx": 6, "ny": 6})
    method = ts.create_integrator("vbd", plain.system, iterations=2)
    ts.Stepper(plain, method, 1 / 60)
    assert not method.has_self_contact and not method.takeover.parts
    # the solve cannot take a cloth that tears; following the scene, the stage keeps it
    torn = ts.build_scene("cloth", {"nx": 6, "ny": 6, "tear": True, "self_collision": True})
    method = ts.create_integrator("vbd", torn.system, iterations=2)
    stepper = ts.Stepper(torn, method, 1 / 60)
    assert not method.has_self_contact and not method.takeover.parts
    stepper.step()
    assert stepper.failure is None and torn.part("self_collision").t_end is not None


def test_a_refused_attach_leaves_nothing_half_bound(f32):
    """Asked for on a tearing cloth, the solve's self-contact is refused, every time it is
    tried (the launcher keeps a method whose switch failed), never silently dropped."""
    from taichi_sim.errors import ConfigError

    torn = ts.build_scene("cloth", {"nx": 6, "ny": 6, "tear": True, "self_collision": True})
    method = ts.create_integrator("vbd", torn.system, iterations=2, self_contact=True)
    for _ in range(2):
        with pytest.raises(ConfigError, match="tearing"):
            ts.Stepper(torn, method, 1 / 60)
    assert method.contact is None and not method.takeover.parts
