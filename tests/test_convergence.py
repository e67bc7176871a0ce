"""Every method that solves a system per step says how far its result is from that system's
solution (taichi_sim/convergence.py), and a run that did not converge says so."""
import math

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.convergence import (
    DEFAULT_MAX_RESIDUAL,
    ConvergenceMonitor,
    ForceModel,
    check_max_residual,
    relative_residual,
)
from taichi_sim.errors import ConfigError
from taichi_sim.integrators import Status
from taichi_sim.integrators.equation import EXACT, FIXED_WORK, Equation
from taichi_sim.scene.cloth import fixed_particle_cloth

BACKWARD_EULER = Equation("backward_euler", EXACT)
STIFF_CLOTH = {"nx": 8, "ny": 8, "stiffness": 1e6, **fixed_particle_cloth(8, 8)}


def cloth(**params):
    return ts.build_scene("cloth", {**STIFF_CLOTH, **params})


def test_a_cloth_left_where_it_was_leaves_its_whole_weight_unbalanced(f64):
    # The frozen answer the issue found (f32 implicit Euler at k = 1e8 said ok): nothing moved,
    # so gravity is all the residual there is, and the measure says about 1.
    scene = cloth()
    model = ForceModel(scene)
    x0, v0 = scene.x0, np.zeros_like(scene.x0)
    frozen = relative_residual(model, BACKWARD_EULER, x0, v0, x0, v0, 1 / 60)
    assert 0.9 < frozen <= 1.0


def test_the_exact_backward_euler_step_of_a_falling_particle_has_no_residual(f64):
    # Without springs the step is closed form: v1 = (v0 + h g) / (1 + h c / m), x1 = x0 + h v1.
    scene = ts.build_scene("cloth", {"nx": 2, "ny": 2, "stiffness": 0.0, "pin": "none", "area_drag": 1.2})
    model = ForceModel(scene)
    h, m = 0.02, model.mass[:, None]
    x0, v0 = scene.x0, np.full_like(scene.x0, 0.5)
    v1 = (m * v0 + h * m * model.gravity) / (m + h * model.drag)
    x1 = x0 + h * v1
    assert relative_residual(model, BACKWARD_EULER, x0, v0, x1, v1, h) < 1e-13
    assert relative_residual(model, BACKWARD_EULER, x0, v0, x1 + 1e-3, v1, h) > 1e-2
    # Taken explicitly (projective dynamics, XPBD), the drag is read at v0: the same state misses.
    explicit = Equation("backward_euler", FIXED_WORK, explicit_external=True)
    assert relative_residual(model, explicit, x0, v0, x1, v1, h) > 1e-3


def test_the_exact_implicit_midpoint_step_of_a_falling_particle_has_no_residual(f64):
    # Midpoint: m (v1 - v0) / h = m g - c (v0 + v1) / 2 and x1 = x0 + h (v0 + v1) / 2, closed form
    # without springs. The monitor writes it about the midpoint with a half step (h / 2): with a
    # whole step there, this exact solution would leave most of its inertia unbalanced.
    scene = ts.build_scene("cloth", {"nx": 2, "ny": 2, "stiffness": 0.0, "pin": "none", "area_drag": 1.2})
    model = ForceModel(scene)
    h, m, c = 0.02, model.mass[:, None], model.drag
    x0, v0 = scene.x0, np.full_like(scene.x0, 0.5)
    v1 = (m * v0 / h + m * model.gravity - 0.5 * c * v0) / (m / h + 0.5 * c)
    x1 = x0 + 0.5 * h * (v0 + v1)
    midpoint = Equation("implicit_midpoint", EXACT)
    assert relative_residual(model, midpoint, x0, v0, x1, v1, h) < 1e-13
    # and the backward-Euler step of the same start is not a midpoint step
    v_be = (m * v0 + h * m * model.gravity) / (m + h * c)
    assert relative_residual(model, midpoint, x0, v0, x0 + h * v_be, v_be, h) > 1e-2


def test_a_converged_implicit_euler_step_is_at_its_newton_tolerance(f64):
    scene = cloth(stiffness=1e4)
    for tolerance in (1e-4, 1e-7):
        scene.reset()
        result = ts.run(scene, ts.create_integrator("implicit_euler", scene.system, newton_tolerance=tolerance),
                        dt=1 / 60, steps=6, energy_every=1)
        assert result.status is Status.OK
        assert len(result.solver_residual) == 6
        # The Newton test and the monitor measure the same share of the forces (up to how the
        # norms are grouped): the residual sits at the tolerance, not orders of magnitude off.
        assert 1e-3 * tolerance < result.worst_residual < 3 * tolerance


def test_implicit_euler_that_stops_early_is_not_converged(f64):
    # A Newton tolerance of 0.5 lets the step stop 0.1-0.3 mm from its solution: past a 10 um
    # tolerance the run says so; within the default 1 mm it does not.
    scene = cloth()
    integrator = ts.create_integrator("implicit_euler", scene.system, newton_tolerance=0.5)
    result = ts.run(scene, integrator, dt=1 / 60, steps=10, energy_every=1, tolerance=1e-5)
    assert result.status is Status.NOT_CONVERGED
    assert result.steps >= 1 and "estimated error" in result.message and "newton" in result.message
    assert result.worst_error_estimate > 1e-5
    scene.reset()
    result = ts.run(scene, ts.create_integrator("implicit_euler", scene.system, newton_tolerance=0.5),
                    dt=1 / 60, steps=3, energy_every=1)
    assert result.status is Status.OK and result.worst_error_estimate < 1e-3


@pytest.mark.cpu_only  # projective_dynamics
def test_projective_dynamics_with_few_iterations_warns_and_with_many_does_not(f64):
    # At k = 1e2 N/m local/global iterations converge (1000: 1e-10 of the forces left); ten
    # leave the steps micrometres off, past a tolerance of 1e-8 m.
    scene = cloth(stiffness=1e2, damping=0.0)
    few = ts.run(scene, ts.create_integrator("projective_dynamics", scene.system, iterations=10),
                 dt=1 / 60, steps=10, energy_every=1, tolerance=1e-8)
    assert few.status is Status.OK  # a fixed-work method goes on ...
    assert few.worst_error_estimate > 1e-8 and few.worst_residual > DEFAULT_MAX_RESIDUAL
    # ... and says so once; its iterations were given, so none were added
    assert len(few.warnings) == 1 and "--iterations" in few.warnings[0] and "cap" not in few.warnings[0]
    scene.reset()
    many = ts.run(scene, ts.create_integrator("projective_dynamics", scene.system, iterations=1000),
                  dt=1 / 60, steps=10, energy_every=1, tolerance=1e-8)
    assert many.worst_error_estimate < 1e-8 and not many.warnings


def test_xpbd_is_measured_on_its_last_substep(f64):
    scene = cloth(stiffness=1e2, damping=0.0)
    integrator = ts.create_integrator("xpbd", scene.system, substeps=4, iterations=60)
    result = ts.run(scene, integrator, dt=1 / 60, steps=4, energy_every=1)
    # Soft springs, many sweeps: each substep is solved, and measured against h / substeps
    # (against the whole step's h the same states would leave most of the forces unbalanced).
    assert result.worst_residual < DEFAULT_MAX_RESIDUAL
    assert integrator.solved_h == pytest.approx(1 / 240)


def test_single_precision_that_cannot_resolve_the_springs_is_refused(f32):
    scene = cloth()
    with pytest.raises(ConfigError, match="f32.*--precision f64"):
        ts.run(scene, "implicit_euler", dt=1 / 60, steps=1)


def test_single_precision_agrees_with_double_where_it_is_accepted():
    positions = {}
    for precision in ("f32", "f64"):
        ts.init(arch="cpu", precision=precision)
        scene = cloth(stiffness=1e4)
        result = ts.run(scene, "implicit_euler", dt=1 / 60, steps=30)
        assert result.status is Status.OK, result.message
        positions[precision] = scene.state.x.to_numpy().astype(float)
    fell = scene.params["height"] - positions["f64"][:, 1].mean()
    assert fell > 0.3  # the cloth is not frozen
    rms = math.sqrt(np.mean(np.sum((positions["f32"] - positions["f64"]) ** 2, axis=1)))
    assert rms < 0.02


def test_explicit_methods_and_unmodelled_forces_are_not_measured(f64):
    scene = cloth(stiffness=1e2)
    assert not ConvergenceMonitor(scene, ts.create_integrator("rk4", scene.system)).active
    result = ts.run(scene, "symplectic_euler", dt=1e-3, steps=3)
    assert len(result.solver_residual) == 0
    windy = ts.build_scene("cloth", {"nx": 4, "ny": 4, "wind": True})
    monitor = ConvergenceMonitor(windy, ts.create_integrator("xpbd", windy.system))
    assert not monitor.active and "wind" in monitor.reason


@pytest.mark.parametrize("value", [0, -1, 1.5, math.nan, True, "0.1"])
def test_bad_max_residual_is_refused_naming_it(value):
    with pytest.raises(ConfigError, match="max_residual"):
        check_max_residual(value)


def test_simulate_reports_the_residual_and_exits_1_when_the_exact_step_is_not_reached(tmp_path, capsys):
    from taichi_sim.cli import main

    out = tmp_path / "run.npz"
    common = ["simulate", "cloth", "--set", "nx=6", "--set", "ny=6", "--set", "stiffness=1e4",
              "--integrator", "implicit_euler", "--dt", "0.02", "--steps", "4", "--out", str(out)]
    assert main(common) == 0
    data = np.load(out)
    assert len(data["solver_residual"]) == len(data["residual_t"]) == len(data["error_estimate_m"]) >= 1
    assert float(data["error_estimate_m"].max()) <= float(data["tolerance_m"]) == 1e-3
    assert "estimated error <=" in capsys.readouterr().out
    assert main(common + ["--newton-tolerance", "0.5", "--tolerance", "1e-7"]) == 1
    assert str(np.load(out)["status"]) == "not_converged"
    assert "--newton-iterations" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["0", "-1", "2", "nan", "x"])
def test_simulate_refuses_a_bad_max_residual_before_writing(tmp_path, capsys, value):
    from taichi_sim.cli import main

    out = tmp_path / "run.npz"
    code = main(["simulate", "cloth", "--steps", "1", "--max-residual", value, "--out", str(out)])
    assert code == 2 and not out.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "max-residual" in err[0].replace("_", "-")


def test_samples_keep_to_their_share_of_the_run_but_the_last_step_is_always_measured(f64, monkeypatch):
    from taichi_sim.convergence import monitor

    scene = cloth(stiffness=1e2)
    monkeypatch.setattr(monitor, "BUDGET", 1e-9)  # no sample pays for itself
    result = ts.run(scene, ts.create_integrator("xpbd", scene.system, substeps=2), dt=1 / 60, steps=20)
    # a scene this small has its start sampled where the run's work doubled (EARLY_SECONDS), and
    # the last step always
    assert result.residual_t == pytest.approx([s / 60 for s in (1, 2, 4, 8, 16, 20)])
    monkeypatch.setattr(monitor, "EARLY_SECONDS", 0.0)
    scene.reset()
    result = ts.run(scene, ts.create_integrator("xpbd", scene.system, substeps=2), dt=1 / 60, steps=20)
    assert result.residual_t == pytest.approx([20 / 60])
    monkeypatch.setattr(monitor, "BUDGET", 1e9)
    scene.reset()
    result = ts.run(scene, ts.create_integrator("xpbd", scene.system, substeps=2), dt=1 / 60, steps=20)
    assert len(result.residual_t) == 20  # every step
