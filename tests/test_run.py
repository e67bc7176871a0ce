"""The run loop: pinned particles, energy behaviour, divergence, landing on t_end."""
import math

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.guard import GuardLimits

EXPLICIT = ["euler", "trapezoid", "midpoint", "rk4", "symplectic_euler"]


@pytest.mark.parametrize("name", EXPLICIT)
def test_pinned_particles_never_move(f64, name):
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6, "jitter": 0.01}, seed=3)
    pinned = scene.arrays["pinned"]
    x0 = scene.state.to_numpy()[0]
    # Explicit Euler gains energy at every step (x (1 + h^2 w^2) on the stiffest mode, w = 530
    # rad/s here): at 1e-3 s this cloth blows up within 25 steps and is reported diverged.
    dt = 1e-4 if name == "euler" else 1e-3
    result = ts.run(scene, name, dt=dt, steps=200, energy_every=0)
    assert result.status is ts.Status.OK, result.message
    x, v = scene.state.to_numpy()
    np.testing.assert_array_equal(x[pinned], x0[pinned])
    assert not v[pinned].any()
    assert np.abs(x[~pinned] - x0[~pinned]).max() > 1e-3  # the rest of the cloth did move


def oscillator():
    return ts.build_scene("spring", {"gravity": 0.0, "stiffness": 10.0, "particle_mass": 1.0,
                                     "stretch": 0.5})


def test_explicit_euler_energy_grows_exactly_by_one_plus_h2w2_per_step(f64):
    scene = oscillator()
    h, n = 0.01, 1000  # the amplitude stays below the rest length: the spring stays linear
    omega = math.sqrt(10.0)
    result = ts.run(scene, "euler", dt=h, steps=n, energy_every=100)
    ratio = result.energy / result.energy[0]
    steps_done = np.round(result.energy_t / h)
    np.testing.assert_allclose(ratio, (1 + (h * omega) ** 2) ** steps_done, rtol=1e-9)
    assert ratio[-1] > 2.5


def test_symplectic_euler_energy_stays_bounded(f64):
    scene = oscillator()
    h, n = 0.01, 20000  # about 100 periods
    h_omega = h * math.sqrt(10.0)
    result = ts.run(scene, "symplectic_euler", dt=h, steps=n, energy_every=7)
    ratio = result.energy / result.energy[0]
    # Its modified energy is conserved exactly, which confines E/E0 to
    # [(1 - hw/2)/(1 + hw/2), (1 + hw/2)/(1 - hw/2)].
    bound = (1 + h_omega / 2) / (1 - h_omega / 2)
    assert ratio.max() <= bound and ratio.min() >= 1 / bound
    assert abs(ratio[-1] - 1) < 0.05


def test_divergence_stops_the_run_and_says_where(f64):
    scene = ts.build_scene("cloth", {"nx": 8, "ny": 8, "stiffness": 1e5})
    result = ts.run(scene, "euler", dt=0.01, t_end=20.0, energy_every=1)
    assert result.status is ts.Status.DIVERGED
    assert 0 < result.steps < 2000
    assert "step " in result.message and "t = " in result.message
    assert np.isfinite(result.energy).all()  # the trace stops before the non-finite state


@pytest.mark.parametrize("name", EXPLICIT)
def test_ok_runs_are_finite(f64, name):
    scene = ts.build_scene("pendulum", {"particle_count": 8})
    result = ts.run(scene, name, dt=1e-3, steps=300)
    x, v = scene.state.to_numpy()
    assert result.status is ts.Status.OK and np.isfinite(x).all() and np.isfinite(v).all()
    assert result.f_evals == 300 * {"euler": 1, "symplectic_euler": 1, "rk4": 4}.get(name, 2)


def test_fixed_step_run_lands_exactly_on_t_end(f64):
    scene = ts.build_scene("simple")
    result = ts.run(scene, "rk4", dt=0.03, t_end=1.0)
    assert result.t == 1.0 and result.steps == 34 and result.energy_t[-1] == 1.0
    x, _ = scene.state.to_numpy()
    assert x[0, 0] == pytest.approx(math.cos(1.0), abs=1e-8)
    assert x[0, 1] == pytest.approx(math.sin(1.0), abs=1e-8)


def test_energy_trace_sampling(f64):
    scene = ts.build_scene("spring")
    short = ts.run(scene, "symplectic_euler", dt=0.01, steps=50)
    np.testing.assert_allclose(short.energy_t, [0, 0.01, 0.03, 0.07, 0.15, 0.31, 0.5])
    scene.reset()
    sparse = ts.run(scene, "symplectic_euler", dt=0.01, steps=95, energy_every=10)
    np.testing.assert_allclose(sparse.energy_t, [0, *np.arange(10, 100, 10) * 0.01, 0.95])
    scene.reset()
    # longer runs: a sample at each of the guard's checks (1, 2, 4, ..., 64 steps apart, then
    # every 100 f-evaluations) ...
    long = ts.run(scene, "symplectic_euler", dt=0.001, steps=10000)
    checks = [1, 3, 7, 15, 31, 63, 127, *range(227, 10000, 100), 10000]
    assert long.guard_checks == len(checks)
    # (samples at least 10000 / 2000 = 5 steps apart: not at steps 1 and 3)
    np.testing.assert_allclose(long.energy_t, np.array([0, *checks[2:]]) * 0.001)
    scene.reset()
    # ... thinned to about 2000 samples when the checks are more frequent than that
    dense = ts.run(scene, "symplectic_euler", dt=0.001, steps=4000, guard=GuardLimits(check_work=1))
    assert len(dense.energy) == 2001 and dense.guard_checks == 4000


@pytest.mark.parametrize("kwargs, problem", [
    ({"dt": 0.0, "steps": 3}, "dt"), ({"dt": float("nan"), "steps": 3}, "dt"),
    ({"dt": -1.0, "steps": 3}, "dt"), ({"dt": 0.1}, "steps or t_end"),
    ({"dt": 0.1, "steps": 2, "t_end": 1.0}, "steps or t_end"), ({"dt": 0.1, "steps": 0}, "steps"),
    ({"dt": 0.1, "t_end": float("inf")}, "t_end"),
])
def test_run_rejects_bad_arguments_with_value_errors(f64, kwargs, problem):
    scene = ts.build_scene("simple")
    with pytest.raises(ValueError, match=problem):
        ts.run(scene, "rk4", **kwargs)


@pytest.mark.parametrize("name, params, problem", [
    ("cloth", {"nx": 1}, "nx"), ("spring", {"particle_mass": 0.0}, "particle_mass"),
    ("pendulum", {"stiffness": -1.0}, "stiffness"), ("cloth", {"bogus": 1}, "bogus"),
    ("cloth", {"pin": "middle"}, "pin"), ("nope", {}, "nope"),
])
def test_build_scene_names_the_bad_parameter(f64, name, params, problem):
    with pytest.raises(ValueError, match=problem):
        ts.build_scene(name, params)


def test_symplectic_euler_refuses_a_first_order_system(f64):
    with pytest.raises(ValueError, match="second-order"):
        ts.create_integrator("symplectic_euler", ts.build_scene("simple").system)


def test_steps_per_second_leaves_the_first_step_out(f64, monkeypatch):
    """The rate is that of the steps after the first, whose compiling it must not count: a
    first step made to take 0.3 s (as compiling would) leaves the rate of 20 fast steps far
    above 19 / 0.3 steps/s."""
    from helpers import slow_first_step

    scene = oscillator()
    integrator = ts.create_integrator("symplectic_euler", scene.system)
    slow_first_step(monkeypatch, integrator)
    result = ts.run(scene, integrator, dt=0.01, steps=20, energy_every=0)
    assert result.wall_time >= 0.3
    assert result.warm_time < result.wall_time - 0.25
    assert result.steps_per_second == pytest.approx(19 / result.warm_time)
    assert result.steps_per_second > 10 * 19 / 0.3  # the 0.3 s first step is not in it
    single = ts.run(scene, "symplectic_euler", dt=0.01, steps=1, energy_every=0)
    assert math.isnan(single.steps_per_second)  # one step: nothing but its compiling to rate
