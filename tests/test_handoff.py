"""The handoff between a scene and its integrator (taichi_sim/scene/handoff.py): the scene
offers its contact in one object, the integrator answers what it took over, and the scene
alone applies that; a plug-in takes over the self-collision stage by the same contract as vbd.
And the bare Stepper the benchmarks measure a method's own step with."""
import textwrap

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.errors import ConfigError
from taichi_sim.scene.handoff import NOTHING_TAKEN, ContactTakeover
from taichi_sim.stepper import Stepper

# A plug-in (a file the command line loads by path) whose solve, it says, keeps the cloth off
# itself: it takes the scene's self-collision stage over, as vbd does.
TAKES_THE_STAGE = """
    from taichi_sim.integrators.symplectic import SymplecticEuler
    from taichi_sim.scene.handoff import NOTHING_TAKEN, ContactTakeover

    class TakesTheStage(SymplecticEuler):
        name = "takes_the_stage"
        description = "symplectic Euler that says it does the self-collision stage's work"
        offered = None

        def bind_contact(self, inputs):
            self.offered = inputs
            stage = inputs.self_collision
            return NOTHING_TAKEN if stage is None else ContactTakeover(parts={stage.name})
"""


@pytest.fixture(scope="module")
def plugin(tmp_path_factory):
    """The plug-in's spec (one file for the module: a second file would load a second class of
    the same name, which is refused)."""
    path = tmp_path_factory.mktemp("plugin") / "stage_plugin.py"
    path.write_text(textwrap.dedent(TAKES_THE_STAGE))
    return f"{path}:TakesTheStage"


def _fold():
    return ts.build_scene("cloth-fold", {"nx": 6, "ny": 6})


def test_a_plugin_that_takes_the_stage_over_has_its_event_left_out(f32, plugin):
    scene = _fold()
    stage = scene.part("self_collision")
    stepper = Stepper(scene, plugin, 1e-3)
    offered = stepper.integrator.offered
    assert offered.self_collision is stage and offered.cloth is scene.mesh
    assert offered.thickness == scene.params["thickness"]
    stepper.run_until(steps=3)
    assert stepper.failure is None and scene.takeover.parts == {"self_collision"}
    assert stage.t_end is None  # the stage's event never ran
    # a method switched to that takes nothing hands the stage back to the scene
    stepper.set_integrator(ts.create_integrator("symplectic_euler", scene.system))
    stepper.step()
    assert scene.takeover is NOTHING_TAKEN and stage.t_end == pytest.approx(stepper.t)


def test_simulate_says_the_plugins_solve_did_the_stages_work(plugin, tmp_path, capsys):
    assert main(["simulate", "cloth-fold", "--set", "nx=6", "--set", "ny=6", "--steps", "2", "--dt", "0.001",
                 "--integrator", plugin, "--out", str(tmp_path / "a.npz")]) == 0
    out = capsys.readouterr().out
    assert "self_collision: done in" in out and "self-contact:" not in out


def test_the_scene_offers_its_contact_objects_and_settings(f32):
    scene = ts.build_scene("cloth-fold", {"nx": 6, "ny": 6, "box": True, "thickness": 0.02, "self_friction": 0.3})
    inputs = scene.contact_inputs()
    assert inputs.shapes == (scene.part("boxes"),) and inputs.has_objects
    assert inputs.self_collision is scene.part("self_collision") and inputs.collider_mesh is None
    assert (inputs.thickness, inputs.self_friction) == (0.02, 0.3)
    assert inputs.closed and inputs.rest().shape == (36, 3)
    assert inputs.same_as(scene.contact_inputs())  # nothing changed: a bound method need not bind again
    windy = ts.build_scene("cloth", {"nx": 4, "ny": 4, "wind": True}).contact_inputs()
    assert not windy.closed and not windy.has_objects and windy.self_collision is None


def test_the_scene_applies_a_takeover_to_its_own_parts(f32):
    scene = ts.build_scene("cloth-fold", {"nx": 6, "ny": 6, "box": True})
    box = scene.part("boxes")
    scene.hand_over(ContactTakeover(parts={"self_collision"}, pauses_object_faces=True))
    assert box.faces_paused and scene.takeover.parts == {"self_collision"}
    scene.hand_over(NOTHING_TAKEN)
    assert not box.faces_paused


def test_a_takeover_that_does_not_fit_the_scene_is_refused_by_name(f32):
    scene = ts.build_scene("cloth", {"nx": 4, "ny": 4})
    with pytest.raises(ConfigError, match="takes over self_collision, which scene cloth does not have"):
        scene.hand_over(ContactTakeover(parts={"self_collision"}))
    with pytest.raises(ConfigError, match="must answer a ContactTakeover"):
        scene.hand_over({"self_collision"})
    with pytest.raises(ValueError, match="parts must be part names"):
        ContactTakeover(parts="self_collision")
    assert scene.takeover is NOTHING_TAKEN  # nothing half-applied


def test_a_bare_stepper_takes_the_methods_own_steps(f64):
    """The same steps as the method called by hand with the scene's events after each (what
    the benchmarks measured before): no guard, no convergence sample, no work raised, where a
    run's Stepper raises vbd's substeps to meet the tolerance."""
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6})
    run = Stepper(scene, ts.create_integrator("vbd", scene.system, iterations=2), 1 / 60, tolerance=1e-7)
    run.run_until(steps=5)
    assert run.integrator.substeps > 1 and run.monitor.distances and run.guard.checks

    scene.reset()
    bare = Stepper(scene, ts.create_integrator("vbd", scene.system, iterations=2), 1 / 60, tolerance=1e-7,
                   bare=True)
    bare.run_until(steps=5)
    assert bare.guard is None and bare.integrator.substeps == 1 and not bare.monitor.distances
    x_bare = scene.state.to_numpy()[0]

    scene.reset()
    method = ts.create_integrator("vbd", scene.system, iterations=2)
    scene.hand_over(method.bind_contact(scene.contact_inputs()))
    for k in range(5):
        assert method.step(scene.state, k / 60, 1 / 60).status is ts.Status.OK
        scene.after_step((k + 1) / 60, 1 / 60)
    assert np.array_equal(scene.state.to_numpy()[0], x_bare)


def test_a_bare_stepper_checks_nothing_and_leaves_a_failed_state_as_it_is(f64):
    from test_stepper import Faulty

    scene = ts.build_scene("spring", {})
    bare = Stepper(scene, "symplectic_euler", 0.01, bare=True)
    with pytest.raises(ConfigError, match="bare Stepper has no guard"):
        bare.check()
    with pytest.raises(ConfigError, match="bare Stepper has no guard"):
        bare.run_until(steps=2, check_every=1)
    scene.reset()
    bare = Stepper(scene, Faulty(ts.create_integrator("symplectic_euler", scene.system), 3,
                                 ts.Status.DIVERGED, poison=True), 0.01, bare=True)
    bare.run_until(steps=10)
    assert bare.failure.status is ts.Status.DIVERGED and bare.failure.step == 3 and bare.steps == 2
    assert bare.failure.good_step is None and np.isnan(scene.state.to_numpy()[0][0]).all()
