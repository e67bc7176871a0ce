"""Adaptive Runge-Kutta pairs (rk45, rkf45): tableaux, order, tolerance, step control, failures."""
import math

import numpy as np
import pytest
from helpers import fitted_order
from scipy.integrate import solve_ivp

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.integrators import INTEGRATORS
from taichi_sim.integrators.tableau import DORMAND_PRINCE, FEHLBERG, ButcherTableau
from taichi_sim.scene.cloth import fixed_particle_cloth

PAIRS = {"rk45": DORMAND_PRINCE, "rkf45": FEHLBERG}
# Tolerances so loose that every step is accepted: the pair then steps like a fixed-step method
# with its propagated weights b.
ACCEPT_EVERYTHING = {"rtol": 1e10, "atol": 1e10}
# A small chain whose stiffest mode (omega ~ 140 rad/s) makes large steps fail.
PENDULUM = {"particle_count": 4, "stiffness": 500.0}


def fifth_order_residuals(tableau, weights):
    """The nine order-5 conditions (rooted trees of 5 nodes; Hairer, Norsett & Wanner I, II.2),
    as residuals for the weights ``weights``."""
    A, c, b = tableau.matrix(), np.asarray(tableau.c), np.asarray(weights)
    Ac = A @ c
    return np.array([
        b @ c**4 - 1 / 5, b @ (c**2 * Ac) - 1 / 10, b @ (c * (A @ c**2)) - 1 / 15,
        b @ (c * (A @ Ac)) - 1 / 30, b @ Ac**2 - 1 / 20, b @ A @ c**3 - 1 / 20,
        b @ A @ (c * Ac) - 1 / 40, b @ A @ A @ c**2 - 1 / 60, b @ A @ A @ Ac - 1 / 120,
    ])


def particle_rhs(arrays):
    """The force model (docs/scenes.md, Force model) in numpy, from a scene's arrays: f(t, y) with
    y = (x.ravel(), v.ravel())."""
    mass, free = arrays["mass"], ~arrays["pinned"]
    gravity, drag = arrays["gravity"], float(arrays["drag"])
    i, j = arrays["springs"][:, 0], arrays["springs"][:, 1]
    k, rest, c = arrays["stiffness"], arrays["rest_length"], arrays["spring_damping"]
    n = len(mass)

    def rhs(t, y):
        x, v = y[:3 * n].reshape(n, 3), y[3 * n:].reshape(n, 3)
        force = mass[:, None] * gravity - drag * v
        d = x[i] - x[j]
        length = np.linalg.norm(d, axis=1)
        u = d / length[:, None]
        pull = -(k * (length - rest) + c * np.einsum("sk,sk->s", v[i] - v[j], u))[:, None] * u
        np.add.at(force, i, pull)
        np.add.at(force, j, -pull)
        dx = np.where(free[:, None], v, 0.0)
        dv = np.where(free[:, None], force / mass[:, None], 0.0)
        return np.concatenate([dx.ravel(), dv.ravel()])

    return rhs


def flat_state(scene):
    x, v = scene.state.to_numpy()
    return np.concatenate([x.ravel(), v.ravel()])


@pytest.mark.parametrize("name", list(PAIRS))
def test_pair_tableau_is_consistent_and_of_its_declared_orders(name):
    tableau = PAIRS[name]
    assert INTEGRATORS[name].tableau is tableau and INTEGRATORS[name].order == tableau.order
    assert INTEGRATORS[name].adaptive
    assert {tableau.order, tableau.embedded_order} == {4, 5}
    np.testing.assert_allclose(tableau.matrix().sum(axis=1), tableau.c, rtol=0, atol=1e-14)
    assert sum(tableau.b) == pytest.approx(1, abs=1e-14)
    assert sum(tableau.b_hat) == pytest.approx(1, abs=1e-14)
    assert tableau.conditions_met() == 4
    assert tableau.conditions_met(weights=tableau.b_hat) == 4
    fifth, fourth = (tableau.b, tableau.b_hat) if tableau.order == 5 else (tableau.b_hat, tableau.b)
    assert np.abs(fifth_order_residuals(tableau, fifth)).max() < 1e-14
    assert np.abs(fifth_order_residuals(tableau, fourth)).max() > 1e-4  # really only order 4
    assert tableau.fsal == (name == "rk45")
    assert tableau.citation


@pytest.mark.parametrize("b_hat, embedded_order, problem", [
    ((1.0, 0.0), None, "go together"),
    ((1.0,), 1, "one weight per stage"),
    ((0.6, 0.5), 1, "embedded weights sum"),
    ((0.5, 0.5), 2, "equals b"),
    ((1.0, 0.0), 2, "declared embedded order 2"),
])
def test_tableau_validation_rejects_inconsistent_embedded_weights(b_hat, embedded_order, problem):
    heun = dict(a=((), (1.0,)), b=(0.5, 0.5), c=(0.0, 1.0), order=2)
    assert ButcherTableau(**heun, b_hat=(1.0, 0.0), embedded_order=1).b_hat == (1.0, 0.0)
    with pytest.raises(ValueError, match=problem):
        ButcherTableau(**heun, b_hat=b_hat, embedded_order=embedded_order)


@pytest.mark.parametrize("name", list(PAIRS))
def test_fixed_steps_converge_at_the_declared_order(f64, name):
    # Circle ODE from (1, 0, 0): the exact solution at T is (cos T, sin T, 0).
    scene = ts.build_scene("simple")
    integrator = ts.create_integrator(name, scene.system, **ACCEPT_EVERYTHING)
    T, counts = 2.0, (16, 32, 64)
    errors = []
    for n in counts:
        scene.reset()
        t, h = 0.0, T / n
        for _ in range(n):
            report = integrator.step(scene.state, t, h)
            assert report.accepted and report.status is ts.Status.OK
            t += h
        x = scene.state.to_numpy()[0][0]
        errors.append(math.hypot(x[0] - math.cos(T), x[1] - math.sin(T)))
    assert min(errors) > 1e-12  # far above round-off, so the slope measures truncation error
    slope = fitted_order(T / np.array(counts), errors)
    assert abs(slope - INTEGRATORS[name].order) < 0.1, (slope, errors)


def test_rk45_meets_its_tolerance_and_works_harder_for_tighter_ones(f64):
    scene = ts.build_scene("pendulum", PENDULUM)
    t_end = 0.5
    y0 = np.concatenate([scene.x0.ravel(), scene.v0.ravel()])
    reference = solve_ivp(particle_rhs(scene.arrays), (0.0, t_end), y0, method="DOP853",
                          rtol=1e-12, atol=1e-12).y[:, -1]
    integrator = ts.create_integrator("rk45", scene.system)
    assert (integrator.rtol, integrator.atol) == (1e-6, 1e-9)
    steps, errors = [], []
    for rtol in (1e-4, 1e-6, 1e-8):
        integrator.rtol, integrator.atol = rtol, rtol * 1e-3  # 1e-6, 1e-9: the defaults
        scene.reset()
        result = ts.run(scene, integrator, dt=None, t_end=t_end, energy_every=0)
        assert result.status is ts.Status.OK and result.t == t_end
        error = flat_state(scene) - reference
        # The global error in the controller's own norm. Each accepted step keeps the local
        # error estimate (of the embedded 4th-order solution) <= 1 in this norm; the propagated
        # 5th-order solution errs less per step, and N steps (100-500 here) add their errors
        # along an undamped flow, so N is the worst case. Allowing 100, below N, checks that the
        # errors do not simply pile up; a run that ignored the tolerance would miss by orders.
        scaled = error / (integrator.atol + rtol * np.abs(reference))
        assert np.sqrt(np.mean(scaled**2)) <= 100, rtol
        steps.append(result.steps)
        errors.append(np.abs(error).max())
    assert steps[0] < steps[1] < steps[2], steps
    # Tolerance proportionality: 100x tighter tolerances buy at least 10x smaller errors.
    assert errors[1] < errors[0] / 10 and errors[2] < errors[1] / 10, errors


@pytest.mark.parametrize("name", list(PAIRS))
def test_rejection_keeps_the_state_and_the_retry_does_not_grow(f64, name):
    scene = ts.build_scene("pendulum", PENDULUM)
    integrator = ts.create_integrator(name, scene.system)
    stage_count = PAIRS[name].stage_count
    before = flat_state(scene)
    h = 0.5  # ~10 periods of the stiffest mode: hopeless at rtol 1e-6
    report = integrator.step(scene.state, 0.0, h)
    assert not report.accepted and report.status is ts.Status.OK
    assert report.h == 0.0 and 0 < report.next_h < h
    assert report.f_evals == stage_count
    np.testing.assert_array_equal(flat_state(scene), before)
    attempts = 1
    while not report.accepted:
        h = report.next_h
        report = integrator.step(scene.state, 0.0, h)
        assert report.f_evals == stage_count - 1  # f(y0, 0) is kept from the first attempt
        attempts += 1
        assert attempts < 10
    assert report.h == h and report.next_h <= h  # never grow right after a rejection
    assert not np.array_equal(flat_state(scene), before)
    # Without a rejection, growth is allowed, up to 10x: a tiny step has a tiny error.
    t = h
    report = integrator.step(scene.state, t, 1e-7)
    assert report.accepted and report.next_h == pytest.approx(1e-6, rel=1e-12)


def test_first_stage_is_reused_only_while_it_is_current(f64):
    scene = ts.build_scene("simple")
    integrator = ts.create_integrator("rk45", scene.system, **ACCEPT_EVERYTHING)
    t, h = 0.0, 0.1
    counts = []

    def step():
        nonlocal t
        report = integrator.step(scene.state, t, h)
        assert report.accepted
        counts.append(report.f_evals)
        t += h

    step()
    step()  # FSAL: the last stage was f at this state
    # A post-step event moving the state (here: radius 1 -> 1.01) makes the kept stage stale.
    scene.state.from_numpy(scene.state.to_numpy()[0] * 1.01)
    step()
    # A stale first stage would err by ~h * b_1 * 0.01 ~ 1e-4 in the radius; DOPRI's own
    # error at h = 0.1 is ~1e-9.
    assert np.linalg.norm(scene.state.to_numpy()[0][0]) == pytest.approx(1.01, abs=1e-7)
    step()
    integrator.reset()  # e.g. after changing the system's parameters
    step()
    t = 0.0  # the caller restarted the clock
    step()
    assert counts == [7, 6, 7, 6, 7, 7]


def test_initial_step_is_positive_finite_and_capped_by_the_end_time(f64):
    scene = ts.build_scene("simple")
    integrator = ts.create_integrator("rkf45", scene.system)
    h = integrator.initial_step(scene.state, 0.0, 10.0)
    assert math.isfinite(h) and 0 < h < 10
    assert integrator.initial_step(scene.state, 0.0, h / 4) == h / 4
    result = ts.run(scene, integrator, dt=None, t_end=1.0, energy_every=0)
    assert result.status is ts.Status.OK and result.t == 1.0 and result.steps > 0
    x = scene.state.to_numpy()[0][0]
    assert math.hypot(x[0] - math.cos(1.0), x[1] - math.sin(1.0)) < 1e-4


def test_failures_end_the_run_with_a_status(f64):
    scene = ts.build_scene("pendulum", PENDULUM)
    # A tolerance below round-off cannot be met: the step shrinks to the smallest step and the
    # run stops (it must not crawl on with steps of 1e-15 s).
    impossible = ts.create_integrator("rk45", scene.system, rtol=1e-30, atol=1e-30)
    result = ts.run(scene, impossible, dt=None, t_end=1.0, energy_every=0)
    assert result.status is ts.Status.STEP_TOO_SMALL and "cannot be met" in result.message
    assert result.steps == 0 and result.rejected_steps < 40
    np.testing.assert_array_equal(scene.state.to_numpy()[0], scene.x0)

    # min_step: 0.5 s fails and the largest shrink (0.2) proposes 0.1 s, below the 0.2 s floor.
    scene.reset()
    floored = ts.create_integrator("rk45", scene.system, min_step=0.2)
    report = floored.step(scene.state, 0.0, 0.5)
    assert report.status is ts.Status.STEP_TOO_SMALL and not report.accepted
    assert report.next_h == pytest.approx(0.1)

    # A non-finite state is never accepted: rejected down to the smallest step, then DIVERGED.
    x = scene.x0.copy()
    x[2, 0] = np.nan
    scene.state.from_numpy(x, scene.v0)
    result = ts.run(scene, ts.create_integrator("rkf45", scene.system), dt=1e-3, t_end=1.0,
                    energy_every=0)
    assert result.status is ts.Status.DIVERGED and result.steps == 0


@pytest.mark.parametrize("name, rtol", [("rk45", 1e-3), ("rk45", 1e-6), ("rkf45", 1e-3)])
def test_a_stiff_problem_stops_early_with_advice(f64, name, rtol):
    # A 2 x 2 cloth with every spring at 1e8 N/m: before the stiffness check rk45 ground on for
    # a minute and returned energy x 9e6 as "ok". Steps bounded by stability, not by rtol (Hairer's
    # estimate of h |lambda| at the stability boundary), stop the run within a few thousand steps.
    stiff = {"nx": 2, "ny": 2, "stiffness": 1e8, "shear_stiffness": 1e8, "flex_stiffness": 1e8,
             **fixed_particle_cloth(2, 2)}
    scene = ts.build_scene("cloth", stiff)
    result = ts.run(scene, ts.create_integrator(name, scene.system, rtol=rtol), dt=None, t_end=1.0,
                    energy_every=0, progress=False)
    assert result.status is ts.Status.STIFF
    assert result.message.startswith(f"stiff at step {result.failed_step} ")
    assert "use an implicit method (implicit_euler)" in result.message
    assert result.steps < 5000 and result.t < 0.05
    x, v = scene.state.to_numpy()
    assert np.isfinite(x).all() and np.isfinite(v).all()


def test_a_soft_cloth_is_not_called_stiff(f64):
    scene = ts.build_scene("cloth", {"nx": 8, "ny": 8})
    result = ts.run(scene, "rk45", dt=None, t_end=0.5, energy_every=0, progress=False)
    assert result.status is ts.Status.OK and result.t == 0.5


@pytest.mark.parametrize("options, problem", [
    ({"rtol": -1.0}, "rtol"), ({"atol": 0.0}, "atol"), ({"safety": 1.5}, "safety"),
    ({"min_step": 0.0}, "min_step"), ({"tolerance": 1e-3}, "tolerance"),
])
def test_bad_options_are_config_errors(f64, options, problem):
    scene = ts.build_scene("simple")
    with pytest.raises(ts.ConfigError, match=problem):
        ts.create_integrator("rk45", scene.system, **options)


def test_cli_runs_rk45_to_the_end_time(tmp_path):
    path = tmp_path / "a.npz"
    code = main(["simulate", "pendulum", "--integrator", "rk45", "--t-end", "0.5", "--rtol", "1e-7",
                 "--out", str(path), "--quiet"])
    assert code == 0
    data = np.load(path)
    assert str(data["status"]) == "ok" and str(data["integrator"]) == "rk45"
    assert data["accepted_steps"] > 0 and data["rejected_steps"] >= 0
    assert float(data["t"]) == 0.5
    assert np.isnan(data["dt"])  # the method chose its steps


def test_cli_rejects_a_tolerance_for_a_fixed_step_integrator(tmp_path, capsys):
    code = main(["simulate", "pendulum", "--integrator", "rk4", "--steps", "3", "--rtol", "1e-3",
                 "--out", str(tmp_path / "b.npz"), "--quiet"])
    assert code == 2
    assert "rtol" in capsys.readouterr().err
    assert not (tmp_path / "b.npz").exists()
