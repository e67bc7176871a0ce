"""A membrane cloth's runs are measured with its membrane and bending in the estimate's model
(taichi_sim/convergence/terms.py): a Newton step stopped early reads as far as it is from the
converged one."""
import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.stepper import Stepper


@pytest.mark.parametrize("method", ["implicit_euler", "implicit_midpoint"])
def test_a_membrane_step_stopped_early_is_estimated_within_a_factor_of_three(f64, method):
    scene = ts.build_scene("cloth-membrane", {"nx": 8, "ny": 8})
    integrator = ts.create_integrator(method, scene.system, newton_tolerance=1e-10)
    stepper = Stepper(scene, integrator, 1 / 60, tolerance=1.0, raise_work=False)
    for _ in range(3):
        stepper.step()
    assert stepper.monitor.active and not stepper.monitor.reason
    start = scene.system.make_state()
    start.copy_from(scene.state)
    t = stepper.t

    def step(newton_tolerance):
        scene.state.copy_from(start)
        stepper.t = t
        integrator.newton_tolerance = newton_tolerance
        integrator.reset()
        stepper.step(check=True)
        return scene.state.to_numpy()[0].astype(float), stepper.monitor.distances[-1]

    reference, converged = step(1e-10)
    assert converged < 1e-7  # the converged step reads as converged
    rough, estimate = step(0.3)
    true = float(np.max(np.linalg.norm(rough - reference, axis=1)))
    assert true > 1e-6  # stopped far enough to tell (the converged step reads 1e-7 at most)
    assert true / 3 <= estimate <= 3 * true, (estimate, true)
