"""The implicit methods: backward Euler (exact, and its one-step linearisation) and the implicit
midpoint rule. Closed forms, measured orders, large steps, pinned particles, failure statuses,
options and the CLI. The linear solvers are tested in test_implicit_solvers.py, energy at the
extremes in test_implicit_energy.py."""

import numpy as np
import pytest
from helpers import fitted_order, spring_exact

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.errors import ConfigError
from taichi_sim.integrators import Status, create_integrator
from taichi_sim.integrators.implicit.common import LINEARISED_CG_TOLERANCE

STIFF_CLOTH = {"nx": 12, "ny": 12, "stiffness": 1e8, "shear_stiffness": 1e8, "flex_stiffness": 1e8}


def radius(scene) -> float:
    x, _ = scene.state.to_numpy()
    return float(np.linalg.norm(x[0]))


# ---------------------------------------------------------------- closed forms (circle ODE)

@pytest.mark.parametrize("name", ["implicit_euler", "implicit_euler_linearised"])
@pytest.mark.parametrize("h, steps", [(0.1, 100), (1.0, 20)])
def test_implicit_euler_shrinks_the_circle_by_the_closed_form(f64, name, h, steps):
    # R(z) = 1/(1 - z): |R(ih)| = (1 + h^2)^(-1/2) per step. f is linear and its Jacobian is
    # exact, so one Newton step with a tight GMRES solve IS backward Euler: the linearised step
    # and the exact method agree.
    scene = ts.build_scene("simple")
    result = ts.run(scene, name, dt=h, steps=steps)
    assert result.status is Status.OK and result.linear_iterations > 0
    expected = scene.params["radius"] * (1 + h * h) ** (-steps / 2)
    assert radius(scene) == pytest.approx(expected, rel=1e-10)


@pytest.mark.parametrize("h", [0.1, 1.0])
def test_implicit_midpoint_keeps_the_circle_radius(f64, h):
    # |R(ih)| = |1 + ih/2| / |1 - ih/2| = 1. GMRES on this 3-unknown linear system is exact after
    # at most 3 iterations, so only rounding (~1e-16 per step) is left.
    scene = ts.build_scene("simple")
    result = ts.run(scene, "implicit_midpoint", dt=h, steps=100)
    assert result.status is Status.OK
    assert radius(scene) == pytest.approx(scene.params["radius"], rel=1e-12)


def test_finite_difference_jacobian_products_reach_the_same_solution(f64):
    # Without the system's analytic Jacobian the products come from differences of f (relative
    # error ~sqrt(eps) ~ 1e-8); Newton still converges to the exact stage because its residual
    # uses the true f: each iteration gains ~8 digits, so newton_tolerance 1e-13 is reachable.
    scene = ts.build_scene("simple")
    scene.system.has_jacobian_product = False
    integrator = create_integrator("implicit_euler", scene.system, newton_iterations=5,
                                   newton_tolerance=1e-13, cg_tolerance=1e-13)
    h, steps = 0.1, 100
    result = ts.run(scene, integrator, dt=h, steps=steps)
    assert result.status is Status.OK and integrator.stats.solver == "gmres"
    assert radius(scene) == pytest.approx((1 + h * h) ** (-steps / 2), rel=1e-10)


# ---------------------------------------------------------------- measured orders

@pytest.mark.parametrize("name", ["implicit_euler", "implicit_midpoint"])
def test_measured_order_on_the_harmonic_oscillator(f64, name):
    # The spring scene (no drag, no dashpot) is a 1-D harmonic oscillator with an exact solution.
    # The spring stays stretched, so the Jacobian is exact; tight tolerances make each step the
    # exact implicit solution, leaving only the method's own error.
    scene = ts.build_scene("spring")
    integrator = create_integrator(name, scene.system, newton_iterations=20, newton_tolerance=1e-12,
                                   cg_tolerance=1e-12)
    t_end, errors, hs = 1.0, [], []
    for steps in (50, 100, 200):
        scene.reset()
        result = ts.run(scene, integrator, dt=t_end / steps, steps=steps, energy_every=0)
        assert result.status is Status.OK
        y_exact, _, _ = spring_exact(scene, t_end)
        errors.append(abs(scene.state.x.to_numpy()[1, 1] - y_exact))
        hs.append(t_end / steps)
    assert fitted_order(hs, errors) == pytest.approx(integrator.order, abs=0.1)


def test_implicit_midpoint_conserves_the_energy_of_a_linear_spring(f64):
    # The midpoint rule conserves quadratic invariants; the bob's energy (kinetic + linear spring +
    # gravity, motion along y only) is one. The stage is linear, so each solve is exact to rounding.
    scene = ts.build_scene("spring")
    result = ts.run(scene, "implicit_midpoint", dt=0.05, steps=200)
    assert result.status is Status.OK
    assert np.max(np.abs(result.energy - result.energy[0])) <= 1e-10 * abs(result.energy[0])


# ---------------------------------------------------------------- large steps

def test_pendulum_at_one_second_steps_does_not_blow_up(f64):
    # omega h ~ 200 for the stiff links (k = 1000 N/m, m = 0.1 kg): far past any explicit limit.
    scene = ts.build_scene("pendulum")
    result = ts.run(scene, "implicit_euler", dt=1.0, steps=20)
    assert result.status is Status.OK, result.message
    x, v = scene.state.to_numpy()
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(v))
    # Backward Euler damps: from rest, the energy can only fall (up to the solve tolerance).
    assert np.max(np.diff(result.energy)) <= 1e-10 * np.abs(result.energy).max()
    # The chain hangs below its pin at roughly its length: nothing flew off.
    chain = (scene.params["particle_count"] - 1) * scene.params["segment_length"]
    assert np.max(np.linalg.norm(x - x[0], axis=1)) < 2 * chain


def test_linearised_step_at_one_second_steps_is_caught(f64):
    # The same chain with one linearised step per second: released horizontally, the links have
    # no stiffness across themselves, so the step swings the particles straight down along the
    # tangent and stretches every link; the energy jumps ten thousand energy scales at once.
    scene = ts.build_scene("pendulum")
    result = ts.run(scene, "implicit_euler_linearised", dt=1.0, steps=20)
    assert result.status is Status.DIVERGED and result.failed_step == 1 and "energy rose" in result.message
    assert result.steps == 0 and np.array_equal(scene.state.x.to_numpy(), scene.x0)


# ---------------------------------------------------------------- pinned particles, failures

# the direct solver is scipy's, on the CPU backend only
@pytest.mark.parametrize("name, solver", [("implicit_euler", "cg"),
                                          pytest.param("implicit_euler", "direct", marks=pytest.mark.cpu_only),
                                          ("implicit_euler_linearised", "cg"), ("implicit_midpoint", "cg")])
def test_pinned_particles_stay_bit_identical(f64, name, solver):
    scene = ts.build_scene("cloth", {"nx": 8, "ny": 8, "pin": "edge"})
    pinned = scene.arrays["pinned"]
    x0 = scene.state.x.to_numpy()
    result = ts.run(scene, create_integrator(name, scene.system, linear_solver=solver), dt=1 / 60, steps=10)
    assert result.status is Status.OK
    x, v = scene.state.to_numpy()
    assert np.array_equal(x[pinned].view(np.uint64), x0[pinned].view(np.uint64))
    assert np.all(v[pinned] == 0.0)
    assert not np.allclose(x[~pinned], x0[~pinned])


@pytest.mark.cpu_only  # the direct solver
def test_newton_iteration_cap_is_not_converged(f64):
    # Two quasi-Newton iterations cannot gain 8 digits on the strongly nonlinear stiff cloth
    # (the exact solve above takes dozens).
    scene = ts.build_scene("cloth", STIFF_CLOTH)
    integrator = create_integrator("implicit_midpoint", scene.system, linear_solver="direct",
                                   newton_iterations=2, max_subdivisions=0)
    report = integrator.step(scene.state, 0.0, 1 / 30)
    assert report.status is Status.NOT_CONVERGED and "newton_iterations=2" in report.message


@pytest.mark.parametrize("scene_name, name", [("cloth", "implicit_euler"), ("cloth", "implicit_midpoint"),
                                              ("cloth", "implicit_euler_linearised"), ("simple", "implicit_euler")])
def test_non_finite_state_is_diverged(f64, scene_name, name):
    # In the cloth, particle 1 is free and particle -1 a pinned corner: a NaN must be caught in
    # either (a spring of non-finite length exerts no force, so it would not spread).
    scene = ts.build_scene(scene_name, {"nx": 6, "ny": 6} if scene_name == "cloth" else {})
    integrator = create_integrator(name, scene.system)
    for particle in ((1, -1) if scene_name == "cloth" else (0,)):
        scene.reset()
        x, v = scene.state.to_numpy()
        x[particle, 0] = np.nan
        scene.state.from_numpy(x, v)
        assert integrator.step(scene.state, 0.0, 0.01).status is Status.DIVERGED


# ---------------------------------------------------------------- options and the CLI

def test_bad_options_are_config_errors(f64):
    system = ts.build_scene("spring").system
    for options in ({"linear_solver": "lu"}, {"newton_iterations": 0}, {"newton_iterations": 1.5},
                    {"cg_tolerance": 0.0}, {"newton_tolerance": 2.0}, {"newton_tolerance": float("nan")},
                    {"cg_max_iterations": 0}, {"tolerance": 1e-6}, {"warm_start": 1},
                    {"preconditioner": "ilu"}, {"preconditioner": "jacobi", "linear_solver": "direct"},
                    {"max_subdivisions": -1}, {"max_subdivisions": 31}, {"max_subdivisions": True}):
        with pytest.raises(ConfigError):
            create_integrator("implicit_euler", system, **options)
    for options in ({"newton_iterations": 3}, {"newton_tolerance": 1e-6}, {"max_subdivisions": 2}):
        with pytest.raises(ConfigError, match="takes no option"):
            create_integrator("implicit_euler_linearised", system, **options)


def test_direct_solver_needs_spring_jacobians(f64):
    with pytest.raises(ConfigError, match="direct"):
        create_integrator("implicit_midpoint", ts.build_scene("simple").system, linear_solver="direct")


@pytest.mark.parametrize("solver", ["direct", "cg"])
def test_cli_cloth_records_linear_solver_work(tmp_path, solver):
    path = tmp_path / "c.npz"
    code = main(["simulate", "cloth", "--integrator", "implicit_euler_linearised", "--dt", "0.0166",
                 "--steps", "5", "--set", "nx=8", "--set", "ny=8", "--linear-solver", solver, "--out", str(path),
                 "--quiet"])
    assert code == 0
    data = np.load(path)
    assert str(data["status"]) == "ok" and int(data["linear_iterations"]) >= 5
    # Without --cg-tolerance CG runs at the default of the one-step Baraff-Witkin method;
    # test_tight_cg_tolerance_is_met keeps the 1e-8 check for CG.
    bound = 1e-8 if solver == "direct" else LINEARISED_CG_TOLERANCE
    assert 0 <= float(data["linear_residual"]) < bound
    assert int(data["newton_iterations"]) == 0 and int(data["substeps"]) == 5


def test_cli_exact_backward_euler_records_its_newton_work(tmp_path):
    path = tmp_path / "e.npz"
    assert main(["simulate", "cloth", "--integrator", "implicit_euler", "--dt", "0.0166", "--steps", "5",
                 "--set", "nx=8", "--set", "ny=8", "--newton-tolerance", "1e-5", "--out", str(path),
                 "--quiet"]) == 0
    data = np.load(path)
    assert str(data["status"]) == "ok" and int(data["newton_iterations"]) >= 5
    assert int(data["substeps"]) >= 5


@pytest.mark.parametrize("name", ["implicit_euler", "implicit_midpoint"])
def test_cli_runs_implicit_methods_on_the_circle(tmp_path, name):
    path = tmp_path / "s.npz"
    code = main(["simulate", "simple", "--integrator", name, "--dt", "0.1", "--steps", "10",
                 "--newton-iterations", "3", "--newton-tolerance", "1e-12", "--out", str(path), "--quiet"])
    assert code == 0
    data = np.load(path)
    assert str(data["status"]) == "ok" and "linear_iterations" in data and "linear_residual" in data
    expected = 1.0 if name == "implicit_midpoint" else (1 + 0.01) ** -5
    assert np.linalg.norm(data["x"][0]) == pytest.approx(expected, rel=1e-10)


def test_cli_cg_tolerance_is_honoured(tmp_path):
    from taichi_sim.cli import main

    path = tmp_path / "tight.npz"
    assert main(["simulate", "cloth", "--integrator", "implicit_euler_linearised", "--dt", "0.0166",
                 "--steps", "3", "--set", "nx=8", "--set", "ny=8", "--cg-tolerance", "1e-9", "--out", str(path),
                 "--quiet"]) == 0
    data = np.load(path)
    assert float(data["linear_residual"]) < 1e-9
