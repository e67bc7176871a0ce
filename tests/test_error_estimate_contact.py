"""vbd's contact is part of the equation its error estimate measures from: a cloth resting on
the ground or folded on itself reads as solved when it is, and a known displacement of it
reads as that displacement (taichi_sim/integrators/positional/vbd/contact_model.py)."""
import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.stepper import Stepper


def resting_cloth(iterations=200):
    """A small cloth settled on the ground with vbd (its contact in the solve, no friction)."""
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6, "pin": "none", "plane": True, "plane_friction": 0.0,
                                     "height": 0.02, "thickness": 0.01})
    integrator = ts.create_integrator("vbd", scene.system, iterations=iterations)
    stepper = Stepper(scene, integrator, 1 / 60, tolerance=1.0)
    for _ in range(60):
        stepper.step()
    stepper.step(check=True)
    return scene, integrator, stepper


def test_a_cloth_resting_on_the_ground_is_solved_and_a_push_into_it_is_measured(f64):
    # Without the contact's penalty in the model, the resting cloth's unbalanced weight would
    # read as millimetres of error at every step.
    scene, integrator, stepper = resting_cloth()
    monitor = stepper.monitor
    assert monitor.active and not monitor.reason
    assert monitor.distances[-1] < 1e-6
    x, _ = scene.state.to_numpy()
    pushed = x.copy()
    pushed[:, 1] -= 5e-4  # every vertex half a millimetre further into the ground
    scene.state.x.from_numpy(pushed)
    _, distance = monitor.measure(scene.state, stepper.t, integrator.solved_h)
    assert distance == pytest.approx(5e-4, rel=0.02)


def fold(size=16, steps=99):
    """cloth-fold at the point where its pile has settled into one piece a step, with
    self-contact pairs in the solve: (scene, integrator, stepper, saved state, t)."""
    scene = ts.build_scene("cloth-fold", {"nx": size, "ny": size})
    integrator = ts.create_integrator("vbd", scene.system)
    stepper = Stepper(scene, integrator, 1 / 60, tolerance=1.0, raise_work=False)
    for _ in range(steps):
        stepper.step()
    saved = scene.system.make_state()
    saved.copy_from(scene.state)
    return scene, integrator, stepper, saved, stepper.t


def step_from(saved, t, scene, integrator, stepper, iterations):
    """One sampled step from the saved state with ``iterations`` sweeps: (x1, estimate)."""
    scene.state.copy_from(saved)
    integrator.reset()
    integrator.iterations = iterations
    stepper.t = t
    stepper.step(check=True)
    return scene.state.to_numpy()[0].astype(float), stepper.monitor.distances[-1]


def test_a_folded_cloth_stopped_early_is_estimated_within_a_factor_of_three(f32):
    # The pile touches itself (self-contact pairs) and the ground; a step of a few sweeps is
    # compared with the same step swept 3000 times from the same start (one piece each).
    scene, integrator, stepper, saved, t = fold()
    reference, settled = step_from(saved, t, scene, integrator, stepper, 3000)
    assert integrator.contact.pair_total() > 0 and integrator.solved_h == pytest.approx(1 / 60)
    assert settled < 1e-5
    for iterations in (5, 20):
        x1, estimate = step_from(saved, t, scene, integrator, stepper, iterations)
        true = float(np.max(np.linalg.norm(x1 - reference, axis=1)))
        assert true > 1e-4  # far enough to tell
        assert true / 3 <= estimate <= 3 * true, (iterations, estimate, true)


def test_the_estimate_follows_a_self_contact_pair_that_is_pushed_closer(f32):
    # One vertex of a self-contact pair moved 0.3 mm towards its partner: the estimate reads
    # that move, within a factor of 2 (0.65-0.8 of it measured: the move also meets the pairs
    # around it).
    scene, integrator, stepper, saved, t = fold()
    _, settled = step_from(saved, t, scene, integrator, stepper, 3000)
    assert settled < 1e-5
    contact = integrator.contact
    count = contact.pair_total()
    ids = contact.pair_ids.to_numpy()[:count]
    free = scene.static_arrays["pinned"] == 0
    vertex = next(int(i[0]) for i in ids if free[i[0]])
    x, _ = scene.state.to_numpy()
    partner = x[ids[ids[:, 0] == vertex][0][1:]].mean(axis=0)
    direction = (partner - x[vertex]) / np.linalg.norm(partner - x[vertex])
    moved = x.copy()
    moved[vertex] += 3e-4 * direction
    scene.state.x.from_numpy(moved)
    _, distance = stepper.monitor.measure(scene.state, stepper.t, integrator.solved_h)
    # (the pile is chaotic: which pairs the move meets varies from run to run in the last digits)
    assert 3e-4 / 2 <= distance <= 2 * 3e-4


def test_identical_runs_with_self_contact_give_identical_answers_and_estimates(f32):
    # The detection fills its pair lists from parallel loops; the solve sums each vertex's pairs
    # in the pairs' own order, and the shift of the bounds is a sum in one order: so the pile,
    # which amplifies any last-digit difference, ends bit for bit the same (before: 5.7 mm apart
    # after 90 steps, and different estimates).
    outs = []
    for _ in range(2):
        scene = ts.build_scene("cloth-fold", {"nx": 16, "ny": 16})
        result = ts.run(scene, "vbd", dt=1 / 60, steps=90)
        outs.append((scene.state.to_numpy()[0].copy(), list(result.error_estimate)))
    assert np.array_equal(outs[0][0], outs[1][0])
    assert outs[0][1] == outs[1][1] and len(outs[0][1]) > 1


def test_with_self_contact_a_tolerance_lowers_the_share_of_vertices_a_piece_cuts(f32):
    # A 16 x 16 twist at 0.9 s: a few vertices whose start guesses leave their contact bounds
    # are cut to them rather than given a shorter piece (pace_share), which holds the step
    # 0.7 mm from its solution; with no vertex cut it is within 0.1 mm. So under a tolerance
    # vbd lowers that share first, before its substeps.
    scene = ts.build_scene("cloth-twist", {"nx": 16, "ny": 16})
    integrator = ts.create_integrator("vbd", scene.system)
    stepper = Stepper(scene, integrator, 1 / 60, raise_work=False, tolerance=1e-3)
    for _ in range(53):
        stepper.step()
    assert [name for name, _ in integrator.work_options] == ["pace_share", "substeps"]  # pins move: no active set
    start, t = scene.system.make_state(), stepper.t
    start.copy_from(scene.state)
    distances = []
    for share in (integrator.pace_share, 0.0):
        integrator.pace_share = share
        scene.state.copy_from(start)
        integrator.reset()
        stepper.monitor.before_step(scene.state)
        integrator.step(scene.state, t, 1 / 60)
        distances.append(stepper.monitor.measure(scene.state, t + 1 / 60, 1 / 60)[1])
    assert distances[0] > 5e-4 and distances[1] < 1e-4
