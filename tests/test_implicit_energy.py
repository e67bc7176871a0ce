"""Backward Euler never gains energy, at any step and stiffness; its one-step linearisation and
the implicit midpoint rule can, and the blow-up guard reports them when they do."""

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.integrators import Status, create_integrator

UNDAMPED = {"damping": 0.0, "drag": 0.0}
CLOTH_UNDAMPED = {"damping": 0.0, "area_drag": 0.0}  # (the grid cloth's drag is per area)


def stiff(scene: str, k: float) -> dict:
    """A conservative scene (gravity and springs only) at stiffness k (N/m; cloth: shear k/2,
    flex k/5)."""
    if scene == "pendulum":
        return {"particle_count": 10, "stiffness": k, **UNDAMPED}
    return {"nx": 6, "ny": 6, "stiffness": k, "shear_stiffness": k / 2, "flex_stiffness": k / 5, **CLOTH_UNDAMPED}


def energies(scene, integrator, h: float, steps: int) -> np.ndarray:
    """The energy (J) after each step, from the start; every step must succeed."""
    trace, t = [scene.energy()], 0.0
    for _ in range(steps):
        report = integrator.step(scene.state, t, h)
        assert report.status is Status.OK, report.message
        t += h
        trace.append(scene.energy())
    return np.asarray(trace)


def set_stiffness(scene, k: float) -> None:
    """Every spring of a scene built by :func:`stiff` to its kind's share of k, in place (one
    scene and one integrator serve every stiffness: nothing recompiles)."""
    springs = scene.springs
    springs.set_parameters(stiffness=k * np.array([1.0, 0.5, 0.2])[springs.kind_np])


@pytest.mark.parametrize("scene_name", ["pendulum", "cloth"])
@pytest.mark.cpu_only  # the direct solver
def test_backward_euler_energy_never_rises(f64, scene_name):
    # Gravity and springs only (a conservative scene), released from rest: h^2 k / m spans 3 to
    # 1e10, far past any explicit limit. Each step may only lower the energy; the allowance is
    # the rounding of the energies summed (ENERGY_ROUNDING units, ~1e-12 of their magnitude).
    scene = ts.build_scene(scene_name, stiff(scene_name, 1.0))
    integrators = {solver: create_integrator("implicit_euler", scene.system, linear_solver=solver)
                   for solver in ("cg", "direct")}
    for k, h, steps, solver in ((1e4, 1 / 60, 30, "cg"), (1e4, 1.0, 10, "cg"), (1e8, 1 / 60, 15, "cg"),
                                (1e8, 1.0, 3, "direct")):
        set_stiffness(scene, k)
        scene.reset()
        integrators[solver].reset()
        trace = energies(scene, integrators[solver], h, steps)
        scale = np.abs(trace).max() + 1.0
        assert np.max(np.diff(trace)) <= 1e-10 * scale, (k, h)
        assert trace[-1] < trace[0], (k, h)  # it fell and swung: energy went somewhere (damped)
        assert np.isfinite(scene.state.to_numpy()[0]).all()


def test_iterates_that_raise_the_energy_are_not_accepted(f64):
    # A loose Newton tolerance alone lets a stiff cloth gain energy in a step (the residual test
    # passes before the iterate has shed the energy its overshoot put in); the energy test then
    # keeps Newton going. Stiff 12 x 12 cloth, k = 1e8 N/m, h = 1/30 s, newton_tolerance 0.1.
    params = {"nx": 12, "ny": 12, "stiffness": 1e8, "shear_stiffness": 1e8, "flex_stiffness": 1e8, **CLOTH_UNDAMPED}
    scene = ts.build_scene("cloth", params)
    integrator = create_integrator("implicit_euler", scene.system, newton_tolerance=0.1)
    trace = energies(scene, integrator, 1 / 30, 6)
    assert np.max(np.diff(trace)) <= 1e-10 * (np.abs(trace).max() + 1.0)


@pytest.mark.cpu_only  # the direct solver
def test_a_step_newton_cannot_solve_is_split(f64):
    # A 10-particle chain of k = 1e8 N/m released horizontally, h = 1 s: Newton cannot swing the
    # near-rigid chain down in one step within 50 iterations, so the step is taken in pieces. With
    # splitting off the same step is NOT_CONVERGED and leaves the state alone.
    scene = ts.build_scene("pendulum", stiff("pendulum", 1e8))
    x0, v0 = scene.state.to_numpy()
    unsplit = create_integrator("implicit_euler", scene.system, linear_solver="direct", max_subdivisions=0)
    report = unsplit.step(scene.state, 0.0, 1.0)
    assert report.status is Status.NOT_CONVERGED and "newton_iterations=50" in report.message
    x, v = scene.state.to_numpy()
    assert np.array_equal(x, x0) and np.array_equal(v, v0)
    split = create_integrator("implicit_euler", scene.system, linear_solver="direct")
    report = split.step(scene.state, 0.0, 1.0)
    assert report.status is Status.OK and report.h == 1.0
    assert split.stats.substeps > 1
    assert scene.energy() < ts.build_scene("pendulum", stiff("pendulum", 1e8)).energy()


def test_linearised_step_gains_energy_on_stiff_cloth_and_the_guard_stops_it(f64):
    # Baraff & Witkin's single linearised step on a 12 x 12 cloth of k = 1e8 N/m at h = 1/30 s:
    # flat at rest length the springs have no transverse stiffness, so the first step lets the
    # particles next to the pins fall freely and stretch their springs; the energy jumps from
    # 14 J to ~8e3 J (more than ten energy scales): reported, never `ok`.
    params = {"nx": 12, "ny": 12, "stiffness": 1e8, "shear_stiffness": 1e8, "flex_stiffness": 1e8}
    scene = ts.build_scene("cloth", params)
    result = ts.run(scene, "implicit_euler_linearised", dt=1 / 30, steps=30)
    assert result.status is Status.DIVERGED and "energy rose" in result.message
    assert result.steps < result.failed_step <= 30
    assert np.max(result.energy) <= result.energy[0] + 10 * 40.0  # the trace ends where the state is good


def test_implicit_midpoint_on_a_stiff_spring_is_bounded_or_reported(f64):
    # One spring of k = 1e8 N/m (omega = 1e4 rad/s) at h = 1/60 s: h omega ~ 170. The midpoint
    # rule conserves the energy of linear springs only; here it either stays within the guard's
    # bound or is stopped, never silently past it.
    scene = ts.build_scene("spring", {"stiffness": 1e8, **UNDAMPED})
    result = ts.run(scene, "implicit_midpoint", dt=1 / 60, t_end=3.0)
    if result.status is Status.OK:
        assert np.max(result.energy) - result.energy[0] <= 10 * (abs(result.energy[0]) + 1e8 * 0.25)
    else:
        assert result.status in (Status.DIVERGED, Status.NOT_CONVERGED) and result.message


def test_a_chain_almost_at_rest_converges_at_huge_steps(f64):
    # Gravity off, the chain 1e-6 of a rest length from rest: the energies are ~1e-12 J, and a
    # spring's |d| - r loses most of its digits to the rounding of the positions (~eps |x|).
    # The test that an iterate's energy is at most the start's must allow for that rounding, or
    # Newton never passes it (it used to report not_converged here at h = 1000 / omega_max).
    from taichi_sim.bench.stability import SYSTEMS, perturbed_start, set_stiffness
    from taichi_sim.theory import scene_omega_max

    chain = SYSTEMS["chain"]
    scene = ts.build_scene(chain.scene, chain.params)
    set_stiffness(scene, chain, 1e3)
    perturbed_start(scene, chain.noise)
    omega = scene_omega_max(scene, "power", max_iterations=300, tol=1e-8)
    trace = energies(scene, create_integrator("implicit_euler", scene.system), 1000 / omega, 40)
    assert np.max(np.diff(trace)) <= 1e-9 * np.abs(trace).max()
