"""Particle effects: the looks over a particle's life, the fire and smoke presets, turbulence.

Drawn frames (warm fire pixels, grey smoke) are in tests/test_render.py, which owns the shared
offscreen window (GGUI supports one window per process).
"""
import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.guard import injectable_energy, scene_facts
from taichi_sim.reference import particle_rhs
from taichi_sim.render.effects import LOOKS, Look, evaluate_look
from taichi_sim.scene.builder import SceneBuilder
from taichi_sim.scene.live import LIVE_SETTERS
from taichi_sim.scene.sprinkler import EFFECTS

AGES = np.linspace(0.0, 1.0, 201)


def non_increasing(a, tol=1e-6):
    return bool(np.all(np.diff(a) <= tol))


def luminance(rgb):
    return rgb @ np.array([0.2126, 0.7152, 0.0722])


def test_every_effect_the_scene_accepts_has_a_look():
    assert tuple(LOOKS) == EFFECTS


@pytest.mark.parametrize("effect", EFFECTS)
def test_each_look_fades_out_over_its_life(f32, effect):
    rgba, radius = evaluate_look(effect, AGES)
    alpha = rgba[:, 3]
    assert alpha[0] > 0.4 and alpha[-1] == 0.0 and non_increasing(alpha)
    assert non_increasing(luminance(rgba[:, :3]))  # darker with age, every look
    assert np.all(radius > 0)
    # outside [0, 1] the ends hold (a particle one step past its lifetime is drawn as dead)
    ends, _ = evaluate_look(effect, np.array([-0.5, 0.0, 1.0, 1.5]))
    np.testing.assert_array_equal(ends[0], ends[1])
    np.testing.assert_array_equal(ends[2], ends[3])


def test_fire_cools_from_yellow_to_red_and_shrinks(f32):
    rgba, radius = evaluate_look("fire", AGES)
    r, g, b = rgba[:, 0], rgba[:, 1], rgba[:, 2]
    assert np.all(r >= g) and np.all(g >= b)  # warm all its life
    assert non_increasing(g / r)  # yellow -> orange -> red
    assert g[0] / r[0] > 0.9 and g[-1] / r[-1] < 0.3
    assert non_increasing(radius) and radius[-1] < 0.5 * radius[0]
    assert r[0] > 1.0  # the glow: brighter than 1 so a lit sphere keeps the colour


def test_smoke_is_grey_and_grows(f32):
    rgba, radius = evaluate_look("smoke", AGES)
    assert np.ptp(rgba[:, :3], axis=1).max() < 0.03
    assert non_increasing(-radius) and radius[-1] > 3 * radius[0]


def test_water_stays_blue(f32):
    rgba, _ = evaluate_look("water", AGES)
    assert np.all(rgba[:, 2] > rgba[:, 0])


def test_a_look_needs_ordered_keys_and_effects_are_named():
    with pytest.raises(ValueError, match="ages"):
        Look(ages=(0.0, 0.6, 0.5, 1.0), rgba=((1, 1, 1, 1),) * 4, radius=(1.0,) * 4)
    with pytest.raises(ValueError, match="effect"):
        evaluate_look("lava", AGES)


def test_bad_effect_is_refused_by_name(f32, capsys, tmp_path):
    with pytest.raises(ValueError, match="effect"):
        ts.build_scene("sprinkler", {"effect": "lava"})
    out = tmp_path / "x.npz"
    assert main(["simulate", "sprinkler", "--steps", "1", "--set", "effect=lava", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "effect" in err and "water, fire, smoke" in err and len(err.splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("name, effect", [("sprinkler-fire", "fire"), ("sprinkler-smoke", "smoke")])
def test_fire_and_smoke_presets_rise(f32, name, effect):
    scene = ts.build_scene(name, {"capacity": 300})
    assert scene.params["effect"] == effect and scene.features["turbulence"]
    integrator = ts.create_integrator(scene.default_integrator, scene.system)
    result = ts.run(scene, integrator, dt=scene.default_dt, t_end=0.6)
    assert result.status == ts.Status.OK
    alive = scene.emitter.alive.to_numpy().astype(bool)
    x = scene.state.x.to_numpy()[scene.emitter.first:][alive]
    assert alive.sum() > 20
    # buoyancy beats gravity: the live particles are above the nozzle, and none fell to the floor
    assert x[:, 1].mean() > scene.params["nozzle_height"] + 0.1 and x[:, 1].min() > 0.0


def test_water_pays_for_no_turbulence(f32):
    scene = ts.build_scene("sprinkler", {"capacity": 50})
    assert not scene.features["turbulence"] and scene.system.term("turbulence") is None
    assert "turbulence_amplitude" not in scene.arrays


def _run_positions(name, seed, steps=150):
    scene = ts.build_scene(name, {"capacity": 200}, seed=seed)
    integrator = ts.create_integrator("symplectic_euler", scene.system)
    ts.run(scene, integrator, dt=scene.default_dt, steps=steps)
    return scene.state.x.to_numpy()


def test_turbulent_runs_are_deterministic_for_a_seed(f32):
    a, b = _run_positions("sprinkler-smoke", 3), _run_positions("sprinkler-smoke", 3)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - _run_positions("sprinkler-smoke", 4)).max() > 1e-3


def test_turbulence_matches_the_numpy_reference(f64, rng):
    n = 40
    b = SceneBuilder()
    b.add_particles(rng.uniform(-1, 1, (n, 3)), rng.uniform(0.5, 2.0, n), v=rng.normal(size=(n, 3)))
    b.set_turbulence(amplitude=3.0, scale=0.4, frequency=1.5)
    b.set_gravity(-2.0)  # buoyant: net upward
    b.set_drag(0.1)
    scene = b.finalize(name="t", params={}, default_dt=1e-3, default_integrator="rk4", seed=7)
    t = 0.37
    out = scene.system.make_state()
    scene.system.eval_f(scene.state, t, out)
    data = scene.arrays
    y = np.concatenate([scene.state.x.to_numpy().ravel(), scene.state.v.to_numpy().ravel()])
    expected = particle_rhs(data)(t, y)[3 * n:].reshape(n, 3)
    np.testing.assert_allclose(out.v.to_numpy(), expected, rtol=1e-12, atol=1e-12)
    # bounded by its amplitude, and not trivially zero
    accel = expected - data["gravity"] + 0.1 * scene.state.v.to_numpy() / data["mass"][:, None]
    assert 0.3 < np.linalg.norm(accel, axis=1).max() <= 3.0


def test_guard_counts_turbulence_as_a_source_for_a_lifetime(f32):
    scene = ts.build_scene("sprinkler-fire", {"capacity": 100})
    facts = scene_facts(scene)
    lifetime, amplitude = scene.params["lifetime"], scene.params["turbulence"]
    for elapsed in (0.1, 10.0):
        energy, speed = injectable_energy(scene, facts, elapsed)["turbulence"]
        assert speed == pytest.approx(amplitude * min(elapsed, lifetime))
        assert energy == pytest.approx(0.5 * facts.moving_mass * speed**2)


def test_live_gravity_keeps_the_buoyancy(f32):
    scene = ts.build_scene("sprinkler-smoke", {"capacity": 20})
    params = dict(scene.params, gravity=5.0)
    assert LIVE_SETTERS["gravity"](scene, params)
    np.testing.assert_allclose(scene.system.term("gravity").get(), [0.0, params["buoyancy"] - 5.0, 0.0])


def test_the_look_follows_a_lifetime_changed_while_running(f32):
    from taichi_sim.render.drawer import DrawOptions, SceneDrawer
    from taichi_sim.scene.visual import describe

    scene = ts.build_scene("sprinkler", {"capacity": 200, "lifetime": 0.3})
    ts.run(scene, ts.create_integrator("symplectic_euler", scene.system), dt=2e-3, steps=100)
    drawer = SceneDrawer(describe(scene))
    drawer.sync(scene.state.x)
    drawer.update(DrawOptions(particles=True), eye=(0.0, 1.0, 3.0))
    alpha = drawer.effect.colors.to_numpy()[:drawer.effect.count, 3]
    assert alpha.min() < 0.9  # the oldest are two thirds through a 0.3 s life
    assert LIVE_SETTERS["lifetime"](scene, dict(scene.params, lifetime=30.0))
    drawer.update(DrawOptions(particles=True), eye=(0.0, 1.0, 3.0))
    alpha = drawer.effect.colors.to_numpy()[:drawer.effect.count, 3]
    assert alpha.min() > 0.93  # young in a 30 s life
