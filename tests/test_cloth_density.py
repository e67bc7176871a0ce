"""The grid cloth's mass and drag are per area: a finer grid is the same cloth with more detail
(docs/scenes.md, "The grid cloth's mass and drag: per area")."""
import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.integrators.symplectic import SymplecticEuler
from taichi_sim.scene.cloth import fixed_particle_cloth
from taichi_sim.scene.cloth_scenes import GRID_DENSITY
from taichi_sim.scene.live import LIVE_SETTERS, applies_live
from taichi_sim.theory import damping_rate_power, omega_max_power


def test_a_finer_grid_weighs_and_drags_as_the_coarser_one(f64):
    for n in (8, 16, 33):
        scene = ts.build_scene("cloth", {"nx": n, "ny": n, "size": 0.5, "density": 2.0, "area_drag": 3.0})
        share = 0.25 / (n * n)  # m^2 a particle
        np.testing.assert_allclose(scene.arrays["mass"], 2.0 * share, rtol=1e-12)
        assert scene.arrays["mass"].sum() == pytest.approx(0.5, rel=1e-12)  # 2 kg/m^2 x 0.25 m^2
        assert float(scene.arrays["drag"]) == pytest.approx(3.0 * share, rel=1e-12)


def test_the_default_32_by_32_cloth_keeps_its_particles(f64):
    """The defaults give the 32 x 32 cloth the 0.01 kg and 0.005 N s/m a particle it always had
    (so its figures hold), and fixed_particle_cloth builds that cloth of fixed particles at any size."""
    scene = ts.build_scene("cloth", {})
    np.testing.assert_allclose(scene.arrays["mass"], 0.01, rtol=1e-12)
    assert float(scene.arrays["drag"]) == pytest.approx(0.005, rel=1e-12)
    old = ts.build_scene("cloth", {"nx": 64, "ny": 40, **fixed_particle_cloth(64, 40)})
    np.testing.assert_allclose(old.arrays["mass"], 0.01, rtol=1e-12)
    assert float(old.arrays["drag"]) == pytest.approx(0.005, rel=1e-12)
    assert ts.build_scene("cloth", {"nx": 64, "ny": 64}).arrays["mass"].sum() == pytest.approx(10.24, rel=1e-12)


def test_an_explicit_preset_shortens_its_default_step_on_a_fine_grid(f64):
    """1 ms on the default grid; on a 128 x 128 one (particles 16 times lighter than at 32 x 32)
    below symplectic Euler's limit (2 / omega_max, shortened by the dashpots' damping), where 1 ms
    diverges; a preset with an implicit default keeps its step. The runs are on a 32 x 32 grid
    of the same particles (a sixteenth of the density): the same spectrum and step at an
    eighth of the time."""
    assert ts.build_scene("cloth", {}).default_dt == 1e-3
    fine_step = ts.build_scene("cloth", {"nx": 128, "ny": 128}).default_dt
    fine = ts.build_scene("cloth", {"density": GRID_DENSITY / 16})
    assert fine.default_dt == fine_step
    omega = omega_max_power(fine.arrays, fine.x0, max_iterations=300)[0]  # within 0.1 % of 2190
    limit = SymplecticEuler.damped_limit(omega, damping_rate_power(fine.arrays, fine.x0, 300))
    assert limit < 0.9 * 2.0 / omega  # the dashpots take a tenth of it off
    assert 0.8 * limit < fine.default_dt <= 0.9 * limit < 1e-3
    assert ts.run(fine, "symplectic_euler", dt=fine.default_dt, t_end=0.3, energy_every=0).status.value == "ok"
    fine.reset()
    assert ts.run(fine, "symplectic_euler", dt=1e-3, t_end=0.3, energy_every=0).status.value == "diverged"
    assert ts.build_scene("cloth-stiff", {"nx": 128, "ny": 128}).default_dt == pytest.approx(1 / 60)


def test_area_drag_changes_while_the_cloth_runs(f64):
    scene = ts.build_scene("cloth", {"nx": 10, "ny": 5})
    assert applies_live(scene, "area_drag") and not applies_live(scene, "drag")
    assert LIVE_SETTERS["area_drag"](scene, dict(scene.params, area_drag=20.0))
    assert scene.system.term("drag").get() == pytest.approx(20.0 / 50, rel=1e-12)
    spring = ts.build_scene("spring", {"drag": 0.3})
    assert LIVE_SETTERS["drag"](spring, dict(spring.params, drag=0.7))
    assert spring.system.term("drag").get() == pytest.approx(0.7)


def test_the_old_particle_parameters_are_refused_by_name_on_the_grid_cloth(f64):
    with pytest.raises(ts.ConfigError, match="no parameter 'particle_mass': .*per area now: density"):
        ts.build_scene("cloth", {"particle_mass": 0.01})
    with pytest.raises(ts.ConfigError, match="no parameter 'drag': .*per area now: area_drag"):
        ts.build_scene("cloth", {"drag": 0.005})
    with pytest.raises(ts.ConfigError, match="did you mean 'stiffness'"):  # other names as before
        ts.build_scene("cloth", {"stifness": 5.0})
