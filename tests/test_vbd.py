"""Vertex block descent: what it converges to, the energy it never gains, the options it refuses
and the residual a run measures. Small cloths, few integrators: kernel compilation dominates."""

import numpy as np
import pytest
from helpers import cloth, swinging

import taichi_sim as ts
from taichi_sim.errors import ConfigError
from taichi_sim.integrators import check_options, create_integrator
from taichi_sim.integrators.positional.vbd import colour_vertices


def test_vertex_colouring_separates_the_ends_of_every_spring():
    ends = np.array([[0, 1], [1, 2], [2, 0], [2, 3], [3, 4], [4, 0], [1, 3]])
    order, starts = colour_vertices(6, ends)  # particle 5 has no spring
    assert sorted(order.tolist()) == list(range(6))
    colour = np.empty(6, int)
    for c in range(len(starts) - 1):
        colour[order[starts[c]:starts[c + 1]]] = c
    assert np.all(colour[ends[:, 0]] != colour[ends[:, 1]])
    assert len(starts) - 1 <= 4  # at most the largest degree (3) plus one
    with pytest.raises(ValueError, match="ends"):
        colour_vertices(2, np.array([[1, 1]]))


def test_many_sweeps_give_the_exact_backward_euler_step(f64):
    """The sweeps' fixed point is implicit_euler's equation, dashpots and drag included: on a
    6 x 6 cloth (k = 1e3 N/m, the scene's dashpots and drag) 3000 sweeps land within 1e-6 m of
    the tightly solved Newton step, 10 sweeps do not (9e-5 m off; the step moves particles ~1e-2 m). The
    other code paths (parallel colour loops, Chebyshev, the augmented springs) reach it too."""
    params = cloth(6, 1e3)
    scene = ts.build_scene("cloth", params)
    swinging(scene)
    start = scene.state.to_numpy()
    create_integrator("implicit_euler", scene.system, newton_tolerance=1e-12).step(scene.state, 0.0, 1 / 60)
    exact = scene.state.to_numpy()[0]
    assert np.abs(exact - start[0]).max() > 5e-3

    def error(integrator, iterations):
        scene.state.from_numpy(*start)
        integrator.reset()
        integrator.iterations = iterations  # a kernel argument: no recompilation
        assert integrator.step(scene.state, 0.0, 1 / 60).status.value == "ok"
        return np.abs(scene.state.to_numpy()[0] - exact).max()

    vbd = create_integrator("vbd", scene.system)
    assert vbd.serial == ts.runtime.cpu_backend()  # a small cloth on a CPU: one kernel per substep
    assert error(vbd, 10) > 1e-5
    assert error(vbd, 3000) < 1e-6
    variants = create_integrator("vbd", scene.system, chebyshev_rho=0.9, augmented=True)
    variants.serial = False  # one kernel per sweep, the colours as top-level parallel loops
    assert error(variants, 3000) < 1e-6
    # Chebyshev's weights are the same in the serial kernel and in the parallel sweeps
    serial, parallel = (create_integrator("vbd", scene.system, chebyshev_rho=0.9) for _ in range(2))
    parallel.serial = False
    assert error(serial, 3000) < 1e-6
    errors = [error(serial, 7), error(parallel, 7)]
    assert errors[0] == pytest.approx(errors[1], rel=1e-9) and errors[0] < error(vbd, 7)


def test_energy_never_rises_above_the_start_on_conservative_cloths(f64):
    """A 6 x 6 cloth without dashpots or drag, hanging from two corners, swinging: every step at
    k = 1e2, 1e4 and 1e8 N/m and h = 1/60 and 1/30 s, with the default sweeps. The same
    scene and integrator throughout (stiffness and h are not compiled in)."""
    scene = ts.build_scene("cloth", cloth(6, 1e2, damping=0.0, area_drag=0.0))
    springs = scene.springs
    base = springs.arrays()["stiffness"] / 1e2
    vbd = create_integrator("vbd", scene.system)
    for k in (1e2, 1e4, 1e8):
        springs.set_parameters(stiffness=base * k)
        for h in (1 / 60, 1 / 30):
            scene.reset()
            swinging(scene)
            vbd.reset()
            energy, t = [scene.energy()], 0.0
            for _ in range(int(round(1.0 / h))):
                assert vbd.step(scene.state, t, h).status.value == "ok"
                t += h
                energy.append(scene.energy())
            energy = np.asarray(energy)
            assert np.all(energy <= energy[0] * (1 + 1e-9)), (k, h, energy.max() - energy[0])
            assert energy[-1] < energy[0]  # it moved and damped (backward Euler), not frozen


def test_the_energy_cap_keeps_larger_unconverged_cloths_from_gaining_energy(f64):
    """A 16 x 16 cloth, conservative, hanging from two corners, swinging: at k = 1e4 N/m and h =
    1/60 s the default 20 sweeps stop short, and without the cap the energy rose about 12 J
    above its 25 J start. With it (the default, on a closed scene stepped by the Stepper) no step
    ends above the start at k = 1e2 to 1e8 N/m and h = 1/60 and 1/30 s, the cloth still moves,
    and the run says how many substeps it shortened."""
    scene = ts.build_scene("cloth", cloth(16, 1e4, damping=0.0, area_drag=0.0))
    base = scene.springs.arrays()["stiffness"] / 1e4

    def highest_rise(stepper, k, h):
        scene.springs.set_parameters(stiffness=base * k)
        scene.reset()
        swinging(scene)
        stepper.set_dt(h)
        stepper.restart()
        start, top = scene.energy(), -np.inf
        for _ in range(int(round(1.0 / h))):
            assert stepper.step().status.value == "ok"
            top = max(top, scene.energy())
        assert np.abs(scene.state.to_numpy()[0] - scene.x0).max() > 0.01  # not frozen
        return top - start, start

    # its work kept: the tolerance, sampling the swing's first steps, would raise the substeps
    raw = ts.Stepper(scene, create_integrator("vbd", scene.system, energy_cap=False), 1 / 60, raise_work=False)
    assert highest_rise(raw, 1e4, 1 / 60)[0] > 5.0
    capped = create_integrator("vbd", scene.system)
    stepper = ts.Stepper(scene, capped, 1 / 60)
    assert capped.cap_active
    for k in (1e2, 1e4, 1e6, 1e8):
        for h in (1 / 60, 1 / 30):
            rise, start = highest_rise(stepper, k, h)
            assert rise <= 1e-9 * abs(start), (k, h, rise)
    assert capped.capped[None] > 0 and "shortened toward their start" in capped.run_warning()
    # where the run's error estimate judged the steps (they were measured after the cap), the
    # estimate speaks for their accuracy, and the cap's own warning would only repeat or contradict it
    assert capped.run_warning(accuracy_judged=True) == ""
    capped.serial = False  # the kernels of large cloths and GPUs: one per sweep, parallel loops
    rise, start = highest_rise(stepper, 1e4, 1 / 60)
    assert rise <= 1e-9 * abs(start), rise


@pytest.mark.parametrize("params, options, on", [
    ({}, {}, True),                                                 # a hanging cloth: closed
    ({"sphere": True}, {"contact": False}, True),                   # a static sphere, outside the solve
    ({"sphere": True}, {}, False),                                  # contact in the solve
    ({"sphere": True, "sphere_motion": "drop"}, {"contact": False}, False),  # a moving object
    ({"twist": True, "pin": "sides"}, {}, False),                    # kinematic pins
    ({"wind": True}, {}, False),
])
def test_the_energy_cap_is_on_only_where_nothing_adds_energy(f64, params, options, on):
    scene = ts.build_scene("cloth", cloth(4, 1e2, **params))
    method = create_integrator("vbd", scene.system, **options)
    ts.Stepper(scene, method, 1 / 60)
    assert method.cap_active == on


def test_the_run_measures_its_residual(f64):
    """Many sweeps leave a step with a tiny relative residual; few sweeps on a stiff cloth leave
    a large one, and the run warns (a fixed amount of work: the run goes on)."""
    scene = ts.build_scene("cloth", cloth(6, 1e5))
    vbd = create_integrator("vbd", scene.system, iterations=2000)
    solved = ts.run(scene, vbd, dt=1 / 60, steps=3)
    assert solved.status.value == "ok" and not solved.warnings
    assert solved.worst_residual < 1e-6
    scene.reset()
    vbd.reset()
    vbd.iterations = 1
    rough = ts.run(scene, vbd, dt=1 / 60, steps=3, tolerance=1e-5, raise_work=False)
    assert rough.status.value == "ok"
    assert rough.worst_residual > 1e-2 and rough.worst_error_estimate > 1e-5 and rough.warnings
    assert solved.worst_error_estimate < 1e-5


def test_a_non_finite_state_is_a_diverged_step(f64):
    scene = ts.build_scene("cloth", cloth(4, 1e3))
    x, v = scene.state.to_numpy()
    x[5] = np.nan
    scene.state.from_numpy(x, v)
    report = create_integrator("vbd", scene.system, iterations=2).step(scene.state, 0.0, 1 / 60)
    assert report.status.value == "diverged" and not report.accepted


@pytest.mark.parametrize("option, value", [
    ("iterations", 0), ("substeps", 1.5), ("warm_start", "yes"), ("chebyshev_rho", 1.0),
    ("chebyshev_rho", -0.1), ("augmented", 1), ("penalty", 0.0), ("penalty_growth", -1.0),
    ("penalty", float("inf")),
])
def test_bad_options_are_refused_by_name(f64, option, value):
    scene = ts.build_scene("cloth", cloth(3, 1e3))
    with pytest.raises(ConfigError, match=option):
        create_integrator("vbd", scene.system, **{option: value})


def test_an_unknown_option_is_refused_by_name():
    with pytest.raises(ConfigError, match="tolerance"):
        check_options("vbd", {"tolerance": 1e-3})


def test_a_run_within_its_tolerance_does_not_warn_about_the_energy_cap(f32):
    """The cap shortens substeps of a stiff cloth; the run's estimate measures the shortened
    steps, and within the tolerance the run says nothing (the cap's count is still kept)."""
    scene = ts.build_scene("cloth-stiff", {"nx": 16, "ny": 16})
    vbd = create_integrator("vbd", scene.system)
    result = ts.run(scene, vbd, dt=1 / 60, steps=30)
    assert vbd.capped[None] > 0  # the cap did act
    assert result.worst_error_estimate <= result.tolerance and not result.warnings
    assert "energy_cap" in vbd.run_warning()  # what a run that is not estimated would say
