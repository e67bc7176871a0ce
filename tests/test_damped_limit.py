"""Explicit steps are limited by damping too: the damped-oscillator limits of symplectic Euler
and the Runge-Kutta methods, the predictions that use them, and the default steps that follow."""
import math

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim import theory
from taichi_sim.app.session import Session
from taichi_sim.cli import main
from taichi_sim.integrators import integrator_class
from taichi_sim.theory import damped_step_limit, stable_step_advice

OMEGA, GAMMA = 500.0, 3000.0  # rad/s, 1/s: damping strong enough to set the limit


def symplectic_growth(h, omega, gamma, steps=4000):
    """|x| + |v| / omega after ``steps`` steps of symplectic Euler from (1, 0)."""
    x, v = 1.0, 0.0
    for _ in range(steps):
        v += h * (-omega * omega * x - gamma * v)
        x += h * v
    return abs(x) + abs(v) / omega


def rk_growth(name, h, omega, gamma, steps=4000):
    """|y| after ``steps`` of the method's stability polynomial applied to the 2 x 2 system."""
    poly = integrator_class(name).tableau.stability_polynomial()
    a = np.array([[0.0, 1.0], [-omega * omega, -gamma]])
    step = sum(c * np.linalg.matrix_power(h * a, k) for k, c in enumerate(poly))
    y = np.linalg.matrix_power(step, steps) @ np.array([1.0, 0.0])
    return abs(y[0]) + abs(y[1]) / omega


@pytest.mark.parametrize("omega, gamma", [(OMEGA, GAMMA), (OMEGA, 10.0), (0.0, GAMMA), (OMEGA, 0.0)])
def test_symplectic_euler_is_stable_just_below_its_damped_limit_and_not_above(omega, gamma):
    limit = integrator_class("symplectic_euler").damped_limit(omega, gamma)
    if gamma == 0:
        assert limit == pytest.approx(2.0 / omega)
    assert symplectic_growth(0.99 * limit, max(omega, 1e-9), gamma) < 100.0  # bounded (eccentric near the limit)
    assert not symplectic_growth(1.02 * limit, max(omega, 1e-9), gamma) < 1e3  # (or overflowed)


@pytest.mark.parametrize("name", ["rk4"])
def test_rk4_is_stable_just_below_its_damped_limit_and_not_above(name):
    cls = integrator_class(name)
    assert cls.damped_limit(OMEGA, 0.0) == pytest.approx(cls.stability_constant / OMEGA, rel=1e-6)
    limit = cls.damped_limit(OMEGA, GAMMA)
    assert limit < 0.5 * cls.stability_constant / OMEGA  # the damping sets it here
    assert rk_growth(name, 0.99 * limit, OMEGA, GAMMA) < 100.0
    assert not rk_growth(name, 1.02 * limit, OMEGA, GAMMA) < 1e3


def test_without_a_stated_damped_limit_the_undamped_one_stands():
    assert integrator_class("implicit_euler").damped_limit(OMEGA, GAMMA) is None
    assert damped_step_limit("symplectic_euler", OMEGA, 0.0) == pytest.approx(2.0 / OMEGA)
    # A slow mode damped as hard as the fastest (drag damps every mode alike) limits RK4 at its
    # real-axis reach, 2.785 / gamma, below what the fastest mode with that damping allows.
    rk4 = integrator_class("rk4")
    assert damped_step_limit("rk4", OMEGA, GAMMA) < rk4.damped_limit(OMEGA, GAMMA)
    assert damped_step_limit("rk4", OMEGA, GAMMA) == pytest.approx(2.7853 / GAMMA, rel=1e-3)
    # symplectic Euler's limit shrinks with both: its corner is its least
    assert damped_step_limit("symplectic_euler", OMEGA, GAMMA) == pytest.approx(
        integrator_class("symplectic_euler").damped_limit(OMEGA, GAMMA))


def test_a_strongly_damped_cloth_gets_a_step_that_runs_and_an_advice_that_brackets_it(f32, tmp_path, capsys):
    # 12 dashpots of 5 N s/m on 10 g particles: gamma_max about 5000 /s, which limits
    # symplectic Euler to about 0.39 ms where the springs alone allow 3.7 ms
    scene = ts.build_scene("cloth", {"damping": 5.0})
    assert scene.default_dt < 3.9e-4
    advice = stable_step_advice(scene, "symplectic_euler")
    predicted = float(advice.split("here: ")[1].split(" s")[0])
    assert 3.5e-4 < predicted < 4.1e-4, advice  # measured: 0.39 ms runs, 0.41 ms diverges
    assert "dashpots" in advice
    ts.init(arch="cpu", precision="f32")
    assert main(["simulate", "cloth", "--set", "damping=5", "--t-end", "0.1", "--quiet",
                 "--out", str(tmp_path / "damped.npz")]) == 0
    assert "step for explicit methods" in capsys.readouterr().err
    ts.init(arch="cpu", precision="f32")
    assert main(["simulate", "cloth", "--set", "damping=5", "--dt", "0.00044", "--t-end", "0.1", "--quiet",
                 "--out", str(tmp_path / "past.npz")]) != 0
    assert "exceeds the predicted stable step" in capsys.readouterr().err


def test_the_launcher_takes_a_fine_cloths_own_default_step_for_explicit_methods_only(f32):
    session = Session("cloth", ["symplectic_euler"], params={"nx": 96, "ny": 96})
    assert session.dt == session.runners[0].scene.default_dt < 1e-3
    session.set_dt(2e-4)
    assert not session.follow_default_dt
    assert math.isclose(session.dt, 2e-4)
    session.select_scene("cloth")  # back to the preset's defaults: 32 x 32 runs its 1 ms
    assert session.follow_default_dt and session.dt == 1e-3
    implicit = Session("cloth", ["implicit_euler"], params={"nx": 96, "ny": 96})
    assert implicit.dt == 1e-3  # no stable step to keep: the preset's


def test_simulate_keeps_the_presets_step_for_an_implicit_method(tmp_path, capsys):
    assert main(["simulate", "cloth", "--set", "nx=96", "--set", "ny=96", "--integrator", "implicit_euler",
                 "--steps", "1", "--quiet", "--out", str(tmp_path / "i.npz")]) == 0
    assert "step for explicit methods" not in capsys.readouterr().err
    assert float(np.load(tmp_path / "i.npz")["dt"]) == 1e-3


def test_the_contact_cloths_give_an_explicit_method_a_step_of_its_own(tmp_path, capsys):
    """cloth-fold, cloth-spin and cloth-twist run vbd at 1/60 s by default; symplectic Euler
    named without --dt takes the 1 ms it had as their default (at 1/60 s it blew up at step 7),
    in simulate and in the launcher, and vbd beside it in the launcher shares that step."""
    assert main(["simulate", "cloth-fold", "--set", "nx=8", "--set", "ny=8", "--integrator", "symplectic_euler",
                 "--steps", "3", "--quiet", "--out", str(tmp_path / "f.npz")]) == 0
    assert "explicit methods, 0.001 s, not the default 0.0166667 s" in capsys.readouterr().err
    assert float(np.load(tmp_path / "f.npz")["dt"]) == 1e-3
    assert Session("cloth-spin", ["vbd", "symplectic_euler"], params={"nx": 8, "ny": 8}).dt == 1e-3
    assert math.isclose(Session("cloth-spin", ["vbd"], params={"nx": 8, "ny": 8}).dt, 1 / 60)


def test_a_large_scenes_messages_take_the_bounds_without_iterating(f32, monkeypatch):
    scene = ts.build_scene("cloth", {"damping": 5.0})  # 1024 particles
    monkeypatch.setattr(theory, "POWER_PARTICLES", 1000)

    def no_iteration(*args, **kwargs):
        raise AssertionError("power iteration on a scene above POWER_PARTICLES")

    monkeypatch.setattr(theory, "omega_max_power", no_iteration)
    advice = stable_step_advice(scene, "symplectic_euler")
    predicted = float(advice.split("here: ")[1].split(" s")[0])
    bound = integrator_class("symplectic_euler").damped_limit(theory.omega_max_bound(scene.arrays),
                                                              theory.damping_rate_bound(scene.arrays))
    assert "Gershgorin bounds" in advice and predicted == pytest.approx(bound, rel=2e-3)
    assert "Gershgorin bounds" in theory.stability_warning(scene, "symplectic_euler", 1e-3)


@pytest.mark.parametrize("name", ["rk4", "symplectic_euler"])
def test_the_integrator_itself_runs_below_its_damped_limit_and_diverges_above(f64, name):
    """The method's damped_limit against its own step on a strongly damped spring, one axial mode
    (omega = 100 rad/s, gamma = 300 /s: the damping sets the limit), not against the formula it
    came from. (A prediction for a scene takes the least over all modes the bounds allow, which
    here is the undamped transverse mode's and a pure-damping one's: more cautious still.)"""
    params = {"stiffness": 1e4, "particle_mass": 1.0, "damping": 300.0, "gravity": 0.0}
    scene = ts.build_scene("spring", params)
    omega = theory.scene_omega_max(scene, "power", max_iterations=2000, tol=1e-12)
    gamma = theory.scene_damping_rate(scene, "power", 2000)
    assert omega == pytest.approx(100.0) and gamma == pytest.approx(300.0)
    limit = integrator_class(name).damped_limit(omega, gamma)
    assert limit < 0.5 * integrator_class(name).stability_constant / omega
    assert damped_step_limit(name, omega, gamma) <= limit
    assert ts.run(scene, name, dt=0.97 * limit, t_end=4.0, energy_every=0).status.value == "ok"
    scene = ts.build_scene("spring", params)
    assert ts.run(scene, name, dt=1.05 * limit, t_end=4.0, energy_every=0).status.value == "diverged"
