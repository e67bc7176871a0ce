"""Closed forms and convergence orders of the explicit methods (docs/integrators.md, Stability on
an oscillator)."""
import math

import numpy as np
import pytest
import taichi as ti
from helpers import fitted_order, run_fixed, spring_exact

import taichi_sim as ts
from taichi_sim.integrators import INTEGRATORS
from taichi_sim.integrators.tableau import RK4, ButcherTableau

# R(z) of each method: x + iy is multiplied by R(ih) every step.
STABILITY_POLYNOMIAL = {
    "euler": lambda z: 1 + z,
    "trapezoid": lambda z: 1 + z + z**2 / 2,
    "midpoint": lambda z: 1 + z + z**2 / 2,
    "rk4": lambda z: 1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24,
}


@pytest.mark.parametrize("name", list(STABILITY_POLYNOMIAL))
def test_circle_matches_closed_form(f64, name):
    h, n, r0 = 0.01, 1000, 1.0
    scene = ts.build_scene("simple", {"radius": r0})
    result = ts.run(scene, name, dt=h, steps=n, energy_every=0)
    assert result.status is ts.Status.OK and result.steps == n
    x, _ = scene.state.to_numpy()
    expected = r0 * STABILITY_POLYNOMIAL[name](1j * h) ** n
    assert x[0, 0] + 1j * x[0, 1] == pytest.approx(expected, rel=1e-12)
    assert abs(x[0, 0] + 1j * x[0, 1]) == pytest.approx(abs(expected), rel=1e-12)
    if name == "euler":  # the table in docs/integrators.md, stated directly
        assert abs(expected) == pytest.approx(r0 * (1 + h * h) ** (n / 2), rel=1e-13)
    assert x[0, 2] == 0.0


@pytest.mark.parametrize("name", ["euler", "trapezoid", "midpoint", "rk4", "symplectic_euler"])
def test_measured_order_matches_declared(f64, name):
    """Global error at t = 1 on the spring (an exact harmonic oscillator) against step size."""
    declared = INTEGRATORS[name].order
    scene = ts.build_scene("spring", {"stiffness": 10.0, "particle_mass": 1.0})
    t_end = 1.0
    steps = (100, 200, 400, 800) if declared < 4 else (25, 50, 100, 200)
    y_exact, v_exact, omega = spring_exact(scene, t_end)
    hs, errors = [], []
    for n in steps:
        result = run_fixed(scene, name, t_end / n, t_end)
        assert result.status is ts.Status.OK and result.t == t_end
        x, v = scene.state.to_numpy()
        # Position and velocity/omega together: this error has no zero crossings in t.
        errors.append(math.hypot(x[1, 1] - y_exact, (v[1, 1] - v_exact) / omega))
        hs.append(t_end / n)
    assert fitted_order(hs, errors) == pytest.approx(declared, abs=0.1)


def test_trapezoid_is_the_seed_rule(f64):
    """X += h/2 (f0 + f1) with f1 = f(X + h f0), written out by hand on the circle."""
    h = 0.3
    scene = ts.build_scene("simple")
    ts.run(scene, "trapezoid", dt=h, steps=1, energy_every=0)
    X = np.array([1.0, 0.0])
    f = lambda p: np.array([-p[1], p[0]])  # noqa: E731
    f0 = f(X)
    f1 = f(X + h * f0)
    expected = X + h / 2 * (f0 + f1)
    np.testing.assert_allclose(scene.state.to_numpy()[0][0, :2], expected, rtol=0, atol=1e-15)


def test_tableaux_declare_true_orders():
    for cls in INTEGRATORS.values():
        tableau = getattr(cls, "tableau", None)
        if tableau is not None:
            assert tableau.conditions_met() >= min(tableau.order, 4), cls.name
    assert RK4.conditions_met() == 4


@pytest.mark.parametrize("a, b, c, order, problem", [
    (((), (0.5,)), (0.0, 1.0), (0.0, 0.4), 2, "row 1"),
    (((), (1.0,)), (0.5, 0.6), (0.0, 1.0), 1, "weights sum"),
    (((), (1.0,)), (0.5, 0.5), (0.0, 1.0), 3, "declared order 3"),
    (((0.0,),), (1.0,), (0.0,), 1, "row 0"),
])
def test_tableau_validation_rejects_inconsistent_coefficients(a, b, c, order, problem):
    with pytest.raises(ValueError, match=problem):
        ButcherTableau(a=a, b=b, c=c, order=order)


def test_f32_precision_runs_in_single_precision(f32):
    scene = ts.build_scene("simple")
    assert scene.state.x.dtype == ti.f32
    result = ts.run(scene, "rk4", dt=0.01, steps=100, energy_every=0)
    x, _ = scene.state.to_numpy()
    assert x.dtype == np.float32
    assert result.status is ts.Status.OK
    assert x[0, 0] == pytest.approx(math.cos(1.0), abs=1e-5)
    assert x[0, 1] == pytest.approx(math.sin(1.0), abs=1e-5)
