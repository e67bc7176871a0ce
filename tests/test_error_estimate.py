"""Every run of a method that solves a system per step states how far (m) its steps are from
that system's solution (taichi_sim/convergence/distance.py), meets a --tolerance by raising its
work, and warns only when its answer is off."""
import math
import re

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.convergence import ConvergenceMonitor, DistanceModel, check_tolerance
from taichi_sim.errors import ConfigError
from taichi_sim.integrators.equation import EXACT, Equation
from taichi_sim.scene.cloth import fixed_particle_cloth
from taichi_sim.stepper import Stepper

BACKWARD_EULER = Equation("backward_euler", EXACT)
MIDPOINT = Equation("implicit_midpoint", EXACT)


def stiff_cloth(size=8, k=1e6, **params):
    return ts.build_scene("cloth", {"nx": size, "ny": size, "stiffness": k, **fixed_particle_cloth(size, size),
                                    **params})


def moving_start(scene, steps=3):
    """A state a few steps into the fall (v0 != 0): (x0, v0) as float64 arrays."""
    ts.run(scene, "implicit_euler", dt=1 / 60, steps=steps)
    x0, v0 = scene.state.to_numpy()
    return x0.astype(float), v0.astype(float)


@pytest.mark.parametrize("equation", [BACKWARD_EULER, MIDPOINT], ids=["backward_euler", "implicit_midpoint"])
def test_a_known_displacement_of_the_solution_is_estimated(f64, equation):
    # The converged step moved by a known field: the estimate finds that distance (to second
    # order in it, and the clamped transverse stiffness of compressed springs: 4 % at 0.3 mm on
    # a k = 1e6 cloth).
    scene = stiff_cloth()
    x0, v0 = moving_start(scene)
    model = DistanceModel(ConvergenceMonitor(scene, ts.create_integrator("implicit_euler", scene.system)).model,
                          equation)
    h = 1 / 60
    x_star, v_star = model.solve_step(x0, v0, h)
    assert model.distance(x0, v0, x_star, v_star, h) < 1e-9  # the solution is 0 from itself
    rng = np.random.default_rng(3)
    shift = rng.normal(size=x_star.shape) * 1e-4 * ~scene.static_arrays["pinned"][:, None]
    x1 = x_star + shift
    v1 = (x1 - x0) / h if equation is BACKWARD_EULER else 2 * (x1 - x0) / h - v0
    true = float(np.max(np.linalg.norm(shift, axis=1)))
    assert model.distance(x0, v0, x1, v1, h) == pytest.approx(true, rel=0.1)


def test_a_newton_step_stopped_early_is_estimated_within_a_factor_of_three(f64):
    # Implicit Euler stopped at a loose Newton tolerance: its distance from the converged step
    # (solved here to 1e-10 m) is what the estimate states, within the factor the issue asks.
    scene = stiff_cloth(size=12, k=1e6)
    integrator = ts.create_integrator("implicit_euler", scene.system, newton_tolerance=0.5)
    stepper = Stepper(scene, integrator, 1 / 60, tolerance=1.0)
    for _ in range(4):
        stepper.step()
    monitor = stepper.monitor
    x0, v0 = (a.astype(float) for a in monitor._start.to_numpy())
    x1, v1 = (a.astype(float) for a in scene.state.to_numpy())
    x_star, _ = monitor.distance_model.solve_step(x0, v0, 1 / 60, guess=x1)
    true = float(np.max(np.linalg.norm(x1 - x_star, axis=1)))
    estimate = monitor.distance_model.distance(x0, v0, x1, v1, 1 / 60)
    assert true > 1e-5  # stopped far enough to tell
    assert true / 3 <= estimate <= 3 * true


@pytest.mark.parametrize("size", [16, 32])
def test_xpbd_meets_a_tolerance_by_taking_more_substeps_and_lands_within_it(f64, size):
    # At k = 1e6 N/m xpbd's default 20 substeps leave each substep about a millimetre from its
    # backward Euler step; asked for 0.1 mm it takes more substeps (no warning), and its last
    # substep is within the tolerance of the converged one from the same start.
    scene = stiff_cloth(size=size, k=1e6)
    integrator = ts.create_integrator("xpbd", scene.system)
    stepper = Stepper(scene, integrator, 1 / 60, tolerance=1e-4)
    for _ in range(11):
        stepper.step()
    stepper.step(check=True)  # the last step is always sampled
    assert stepper.failure is None and not stepper.warnings
    assert integrator.substeps > 20
    monitor = stepper.monitor
    assert len(monitor.distances) >= 1 and monitor.worst_distance <= 1e-4
    x0, v0 = (a.astype(float) for a in monitor._start.to_numpy())
    x1 = scene.state.to_numpy()[0].astype(float)
    x_star, _ = monitor.distance_model.solve_step(x0, v0, integrator.solved_h, guess=x1)
    assert float(np.max(np.linalg.norm(x1 - x_star, axis=1))) <= 1e-4
    scene.reset()
    loose = ts.run(scene, ts.create_integrator("xpbd", scene.system), dt=1 / 60, steps=12, tolerance=1.0)
    assert loose.worst_error_estimate > 1e-4  # the default work alone would not have met it


def test_xpbd_at_k_1e8_raises_its_substeps_within_the_first_steps_and_does_not_blow_up(f32):
    # The warning matrix's case: a 16 x 16 cloth at k = 1e8 N/m, xpbd with its defaults, f32,
    # stepped without asking for checks. The step from rest reads 0.28 mm (the springs are not
    # loaded yet); the next ones are 1-4 mm off at 20 substeps. Sampled again only after some
    # 300 steps, the run kept its 20 substeps until the stretch's energy (k C^2 / 2 of 0.1 mm)
    # tripped the blow-up guard at step 17: the run's start is sampled where its work doubles.
    from taichi_sim.bench.stiffcloth import cloth_params

    scene = ts.build_scene("cloth", cloth_params(16, 1e8))
    integrator = ts.create_integrator("xpbd", scene.system)
    stepper = Stepper(scene, integrator, 1 / 60)
    for s in range(30):
        stepper.step(check=s == 29)
    assert stepper.failure is None
    assert stepper.monitor.times[:2] == pytest.approx([1 / 60, 2 / 60])
    assert integrator.substeps >= 80 and not stepper.warnings
    assert stepper.monitor.worst_distance <= stepper.monitor.tolerance


def test_a_stretch_the_guard_would_call_a_blow_up_is_judged_by_the_estimate_first(f32, monkeypatch):
    # The same run with none of the start's denser samples (a 64 x 64 cloth has none: they cost
    # more than EARLY_SECONDS): its stretch's energy passes the guard's bound at step 17. The
    # step is sampled before the guard judges it, found off, and solved with more substeps.
    from taichi_sim.bench.stiffcloth import cloth_params
    from taichi_sim.convergence import monitor

    monkeypatch.setattr(monitor, "EARLY_SECONDS", 0.0)
    scene = ts.build_scene("cloth", cloth_params(16, 1e8))
    integrator = ts.create_integrator("xpbd", scene.system)
    stepper = Stepper(scene, integrator, 1 / 60)
    for s in range(30):
        stepper.step(check=s == 29)
    assert stepper.failure is None and integrator.substeps > 20
    assert 2 <= len(stepper.monitor.times) <= 4 and stepper.monitor.times[0] > 10 / 60


def test_a_step_near_the_tolerance_is_decided_by_solving_it(f32):
    # vbd's first step of a 10-particle pendulum at k = 1e8 N/m lags its swing: one Newton
    # step (and its chord step) reads 0.59 mm of a true 1.02 mm, since a linear step along the
    # turn stretches the stiff springs. Against a 1 mm tolerance the sample solves the step.
    from taichi_sim.convergence import distance

    scene = ts.build_scene("pendulum", {"particle_count": 10, "stiffness": 1e8})
    stepper = Stepper(scene, ts.create_integrator("vbd", scene.system), 1 / 60, raise_work=False)
    stepper.step(check=True)
    model = stepper.monitor.distance_model
    x0, v0 = (a.astype(float) for a in stepper.monitor._start.to_numpy())
    x1, v1 = (a.astype(float) for a in scene.state.to_numpy())
    assert model.jacobians > 2
    x_star, _ = model.solve_step(x0, v0, 1 / 60, guess=x1, tolerance=1e-9)
    true = float(np.max(np.linalg.norm(x1 - x_star, axis=1)))
    assert 1e-3 < true < 1.2e-3
    assert model.distance(x0, v0, x1, v1, 1 / 60) < 0.7 * true  # the estimate alone
    assert stepper.monitor.distances == pytest.approx([true], rel=0.02)
    assert stepper.warnings  # 1.02 mm > 1 mm: the run says so
    far = model.distance(x0, v0, x1, v1, 1 / 60, tolerance=1e-1)  # far from it: not solved
    assert far < 0.7 * true and model.jacobians == 1
    assert distance.DECIDE * 1e-3 > true


def test_a_method_at_its_cap_warns_with_the_cap_and_the_estimate(f64):
    # xpbd's substeps do bring a stiff cloth closer (about fourfold per doubling), but a cap of
    # 40 stops them short of 1 um
    scene = stiff_cloth(size=8, k=1e6)
    integrator = ts.create_integrator("xpbd", scene.system)
    integrator.work_cap = 40  # one doubling
    result = ts.run(scene, integrator, dt=1 / 60, steps=6, tolerance=1e-6)
    assert integrator.substeps == 40
    assert len(result.warnings) == 1
    warning = result.warnings[0]
    assert "cap of substeps = 40" in warning and "estimated error" in warning and "--tolerance" in warning


def test_work_that_does_not_help_is_not_kept(f64):
    # projective dynamics' iterations on a stiff cloth: twice the iterations leave the step about
    # as far from its solution, so the run goes back to its 10 and says why, instead of paying
    # 16 times more
    scene = stiff_cloth(size=8, k=1e8)
    integrator = ts.create_integrator("projective_dynamics", scene.system)
    result = ts.run(scene, integrator, dt=1 / 60, steps=6, tolerance=1e-6)
    assert integrator.iterations == 10
    assert len(result.warnings) >= 1 and "iterations 10 -> 20 moved the estimate only" in result.warnings[0]


def test_past_a_work_option_that_does_not_help_the_next_one_is_raised(f64):
    # A method offers two kinds of work in turn (vbd with self-contact: its pace share, then its
    # substeps). The first does nothing here: the Stepper puts it back and moves on to the
    # second, which brings the stiff cloth within the tolerance, so the run does not warn.
    from taichi_sim.integrators.positional.xpbd import XPBD

    class Idle(XPBD):
        idle = 1  # doubled by the tolerance, read by nothing

        @property
        def work_options(self):
            return (("idle", 8), ("substeps", 320))

    scene = stiff_cloth(size=8, k=1e6)
    integrator = Idle(scene.system)
    result = ts.run(scene, integrator, dt=1 / 60, steps=6, tolerance=1e-5)
    assert integrator.idle == 1 and integrator.substeps > 20
    assert not result.warnings and result.worst_error_estimate <= 1e-5


def test_vbd_meets_a_tolerance_on_stiff_cloth_by_taking_substeps(f64):
    # Where its sweeps stall (k = 1e6 N/m), substeps of dt / 2^k bring each substep to its
    # solution: the run takes them and ends within the tolerance, without a warning.
    scene = stiff_cloth(size=8, k=1e6)
    integrator = ts.create_integrator("vbd", scene.system)
    result = ts.run(scene, integrator, dt=1 / 60, steps=6, tolerance=1e-4)
    assert integrator.substeps > 1 and integrator.iterations == 20
    assert not result.warnings and result.worst_error_estimate <= 1e-4


def test_a_converged_run_does_not_warn(f64):
    scene = stiff_cloth(size=8, k=1e4)
    result = ts.run(scene, ts.create_integrator("implicit_euler", scene.system, newton_tolerance=1e-8),
                    dt=1 / 60, steps=10, energy_every=1)
    assert result.status is ts.Status.OK and not result.warnings
    assert len(result.error_estimate) == 10 and result.worst_error_estimate < 1e-6


def test_identical_runs_sample_identical_steps_and_estimates(f64):
    runs = []
    for _ in range(2):
        scene = stiff_cloth(size=16, k=1e4)
        result = ts.run(scene, ts.create_integrator("xpbd", scene.system), dt=1 / 60, steps=400)
        assert result.status is ts.Status.OK
        runs.append(result)
    assert 1 < len(runs[0].residual_t) < 400  # thinned, by work
    assert np.array_equal(runs[0].residual_t, runs[1].residual_t)
    assert np.array_equal(runs[0].error_estimate, runs[1].error_estimate)


@pytest.mark.parametrize("value", [0, -1, math.nan, math.inf, True, "0.1"])
def test_bad_tolerance_is_refused_naming_it(value):
    with pytest.raises(ConfigError, match="tolerance"):
        check_tolerance(value)


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "x"])
def test_simulate_refuses_a_bad_tolerance_before_writing(tmp_path, capsys, value):
    from taichi_sim.cli import main

    out = tmp_path / "run.npz"
    code = main(["simulate", "cloth", "--steps", "1", "--tolerance", value, "--out", str(out)])
    assert code == 2 and not out.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--tolerance" in err[0]


def test_newton_tightens_its_own_test_to_meet_a_tolerance_in_metres(f64):
    # The default relative test leaves a 16 x 16 cloth at k = 1e4 N/m some 1e-8 m from its step;
    # asked for 1e-10 m, implicit_euler solves the steps it samples again to tighter tests.
    scene = stiff_cloth(size=16, k=1e4)
    loose = ts.run(scene, ts.create_integrator("implicit_euler", scene.system), dt=1 / 60, steps=4,
                   energy_every=1, tolerance=1.0)
    assert loose.worst_error_estimate > 1e-10
    scene.reset()
    integrator = ts.create_integrator("implicit_euler", scene.system)
    result = ts.run(scene, integrator, dt=1 / 60, steps=4, energy_every=1, tolerance=1e-10)
    assert result.status is ts.Status.OK, result.message
    assert integrator.newton_tolerance < loose_tolerance(scene)
    assert result.worst_error_estimate <= 1e-10


def loose_tolerance(scene) -> float:
    return ts.create_integrator("implicit_euler", scene.system).newton_tolerance


def test_simulate_lets_the_tolerance_raise_the_scenes_options_but_not_the_callers(tmp_path, capsys):
    # cloth-stiff carries xpbd's 50 substeps as the scene's option: a tolerance may raise them
    # (they were passed as the caller's, kept as given, so its 64 x 64 run at k = 1e8 stopped
    # diverged); --substeps 50 is the caller's and stays.
    from taichi_sim.cli import main

    common = ["simulate", "cloth-stiff", "--set", "nx=8", "--set", "ny=8", "--steps", "2", "--tolerance", "1e-7"]
    assert main(common + ["--out", str(tmp_path / "scene.npz")]) == 0
    assert int(np.load(tmp_path / "scene.npz")["f_evals"]) > 2 * 50
    summary = capsys.readouterr().out
    assert re.search(r"of xpbd\(substeps=50->\d+\)", summary), summary  # the work it paid for
    assert main(common + ["--substeps", "50", "--out", str(tmp_path / "given.npz")]) == 0
    assert int(np.load(tmp_path / "given.npz")["f_evals"]) == 2 * 50
    assert "exceeds --tolerance" in capsys.readouterr().err


def test_a_solve_stopped_short_adds_the_tail_of_its_corrections(f32):
    # vbd's first step of a 16 x 16 cloth at k = 1e8 N/m, its work kept: Newton from the
    # step's result gets 1.28 of 2.08 mm in 4 steps (it takes the stiff turn a part at a time);
    # the decision's figure adds the corrections' geometric tail and reads at least the truth.
    from taichi_sim.bench.stiffcloth import cloth_params

    scene = ts.build_scene("cloth", cloth_params(16, 1e8))
    stepper = Stepper(scene, ts.create_integrator("vbd", scene.system), 1 / 60, raise_work=False)
    stepper.step(check=True)
    model = stepper.monitor.distance_model
    x0, v0 = (a.astype(float) for a in stepper.monitor._start.to_numpy())
    x1, v1 = (a.astype(float) for a in scene.state.to_numpy())
    x_star, _ = model.solve_step(x0, v0, 1 / 60, guess=x1, tolerance=1e-8, max_iterations=3000)
    true = float(np.max(np.linalg.norm(x1 - x_star, axis=1)))
    partial, _ = model.solve_step(x0, v0, 1 / 60, guess=x1, tolerance=1e-5, max_iterations=4, strict=False)
    assert not model.converged and float(np.max(np.linalg.norm(x1 - partial, axis=1))) < 0.7 * true
    figure = model.distance(x0, v0, x1, v1, 1 / 60, tolerance=1e-3, refine=4)
    assert not model.converged and model.jacobians == 5
    assert true <= figure < 2 * true
