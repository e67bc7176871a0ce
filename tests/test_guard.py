"""The blow-up guard: its bounds, its verdicts, and what a run returns when it trips."""
import math

import numpy as np
import pytest
from helpers import cloth_builder

import taichi_sim as ts
from taichi_sim.errors import ConfigError
from taichi_sim.guard import MAX_STRAIN, Guard, GuardLimits, injectable_energy, scene_facts
from taichi_sim.scene.cloth import fixed_particle_cloth


@pytest.mark.parametrize("field, value", [
    ("energy_growth", 0), ("energy_growth", -1.0), ("energy_growth", math.inf), ("energy_growth", math.nan),
    ("reach", 0.0), ("strain", "10"), ("strain", True), ("check_work", 0), ("check_work", 2.5),
])
def test_bad_limits_are_refused_naming_the_limit(field, value):
    with pytest.raises(ConfigError, match=field):
        GuardLimits(**{field: value})


def test_the_exploding_pendulum_is_diverged_and_returns_its_last_good_state(f64):
    # The run from the issue: exit 0, "ok", 2.4e181 J before the guard existed. With a sample
    # (and so a check) every step, the state returned is the one just before the energy bound.
    scene = ts.build_scene("pendulum")
    result = ts.run(scene, "euler", dt=0.008, t_end=3.0, progress=False, energy_every=1)
    assert result.status is ts.Status.DIVERGED
    assert result.message.startswith(f"diverged at step {result.failed_step} (t = ")
    for part in ("with euler, h = 0.008 s", "energy rose to", "the state returned is that of step",
                 "euler grows at every step on undamped oscillations", "symplectic_euler "):
        assert part in result.message
    assert 0 < result.steps < result.failed_step and result.t < result.failed_t < 3.0
    # What comes back is the last state that passed: finite and within the bound.
    x, v = scene.state.to_numpy()
    assert np.isfinite(x).all() and np.isfinite(v).all()
    guard = Guard(ts.build_scene("pendulum"))
    bound, _, _ = guard.energy_bound(result.t)
    assert np.isfinite(result.energy).all() and result.energy.max() <= bound
    assert result.energy_t[-1] <= result.t
    assert scene.system.energy(scene.state) == pytest.approx(result.energy[-1], rel=1e-9)


def test_the_guard_checks_when_energy_sampling_is_off_at_about_one_f_evaluation_in_a_hundred(f64):
    scene = ts.build_scene("pendulum")
    result = ts.run(scene, "rk4", dt=0.02, t_end=3.0, energy_every=0, progress=False)
    assert result.status is ts.Status.DIVERGED and "energy rose to" in result.message
    assert "predicted stable step of rk4 here" in result.message
    assert len(result.energy) == 0
    quiet = ts.build_scene("pendulum")
    ok = ts.run(quiet, "rk4", dt=1e-3, steps=1000, energy_every=0, progress=False)
    assert ok.status is ts.Status.OK
    # plus the first checks, 1, 2, 4, ..., 64 units of work apart
    assert ok.guard_checks == pytest.approx(ok.f_evals / 100 + 7, abs=2)


def test_by_default_a_blow_up_is_found_at_the_next_check(f64):
    scene = ts.build_scene("pendulum")
    result = ts.run(scene, "euler", dt=0.008, t_end=3.0, progress=False)
    # checks 1, 2, 4, ... steps apart: the first that fails ends the run, with the state of the
    # last that passed, at most as many steps back as it is from the start
    assert result.status is ts.Status.DIVERGED
    assert 0 < result.steps < result.failed_step <= 2 * result.steps + 1
    assert np.isfinite(scene.state.to_numpy()[0]).all()


def test_a_tighter_limit_trips_sooner(f64):
    loose = ts.run(ts.build_scene("pendulum"), "euler", dt=0.008, t_end=3.0, progress=False, energy_every=1)
    tight = ts.run(ts.build_scene("pendulum"), "euler", dt=0.008, t_end=3.0, progress=False, energy_every=1,
                   guard=GuardLimits(energy_growth=0.1))
    assert tight.status is ts.Status.DIVERGED and tight.failed_step < loose.failed_step


def test_each_bound_names_what_grew(f64):
    scene = ts.build_scene("cloth", {"nx": 5, "ny": 5, **fixed_particle_cloth(5, 5)})
    x0, v0 = scene.state.to_numpy()
    guard = Guard(scene)
    assert guard.check(0.0, 0) is None

    scene.state.from_numpy(x0, v0 + 1e3)  # 1e6 times the kinetic energy a fall could give
    assert guard.check(0.0, 0).what == "energy"

    x = x0.copy()
    x[7] = np.nan
    scene.state.from_numpy(x, v0)
    assert guard.check(0.0, 0).what == "non-finite"

    lenient = Guard(scene, GuardLimits(energy_growth=1e30))
    scene.state.from_numpy(x0, v0)
    lenient.rebase()
    x = x0.copy()
    x[7, 1] += 1e6
    scene.state.from_numpy(x, v0)
    breach = lenient.check(0.0, 0)
    assert breach.what == "reach" and breach.value > breach.bound

    x = x0.copy()
    x[7, 1] += 3.0  # the springs around particle 7 are 0.25 or 0.5 m long: strain over 10
    scene.state.from_numpy(x, v0)
    breach = lenient.check(0.0, 0)
    assert breach.what == "strain" and breach.value > 10

    # restore() puts back the last state that passed (the one from rebase()).
    lenient.restore()
    np.testing.assert_array_equal(scene.state.to_numpy()[0], x0)


def test_tearing_cloth_has_no_strain_bound(f64):
    scene = ts.build_scene("cloth", {"nx": 5, "ny": 5, "tear": True})
    assert Guard(scene).strain_bound() is None


def test_springs_stretched_past_the_strain_limit_by_their_own_weight_are_not_a_blow_up(f64):
    """A chain of 5 x 0.1 kg particles hanging on 1 N/m springs of 0.25 m: the weight of the 4
    moving particles alone (3.92 N) stretches the top spring to strain 15.7, past MAX_STRAIN
    (10), and the fall from rest at rest length overshoots to 21. The sag allowance widens the
    bound to 10 x 3.92 / (1 x 0.25) = 157, so this healthy run is OK (with the plain bound of 10
    it was called diverged at t = 1.2 s, strain 10.4); a state stretched past the widened bound,
    and a real blow-up of the same scene, are still caught."""
    chain = {"particle_count": 5, "stiffness": 1.0, "angle": 0.0, "damping": 0.5, "drag": 0.0}
    scene = ts.build_scene("pendulum", chain)
    x0, v0 = scene.state.to_numpy()
    static = 4 * 0.1 * np.linalg.norm(scene.arrays["gravity"]) / (1.0 * 0.25)  # the top spring's strain
    assert Guard(scene).strain_bound() == pytest.approx(MAX_STRAIN * static)

    result = ts.run(scene, "symplectic_euler", dt=1e-3, t_end=6.0, save_every=20, progress=False)
    assert result.status is ts.Status.OK, result.message
    ends, rest = scene.arrays["springs"], scene.arrays["rest_length"]
    x = np.asarray(result.x_history)
    strain = np.linalg.norm(x[:, ends[:, 0]] - x[:, ends[:, 1]], axis=2) / rest - 1
    assert MAX_STRAIN < strain.max() < 2 * static  # 21: a fall's overshoot, not a blow-up
    assert strain[-1].max() > MAX_STRAIN  # what the guard saw at the end

    # The widened bound still bounds: the bottom particle 50 m down (strain 200) is a breach,
    # named as such when the energy and reach bounds are out of the way.
    lenient = Guard(scene, GuardLimits(energy_growth=1e30))
    stretched = scene.state.to_numpy()[0]
    stretched[-1, 1] -= 50.0
    scene.state.from_numpy(stretched, np.zeros_like(stretched))
    breach = lenient.check(0.0, 0)
    assert breach.what == "strain" and breach.value > breach.bound
    assert breach.bound == pytest.approx(MAX_STRAIN * static)

    # Symplectic Euler past its stable step on the same soft chain still blows up and is caught.
    scene.state.from_numpy(x0, v0)
    blow_up = ts.run(scene, "symplectic_euler", dt=0.3, t_end=20.0, progress=False)
    assert blow_up.status is ts.Status.DIVERGED


def test_energy_sources_widen_the_energy_bound(f64):
    calm = ts.build_scene("cloth", {"nx": 8, "ny": 8, **fixed_particle_cloth(8, 8)})
    windy = ts.build_scene("cloth", {"nx": 8, "ny": 8, "wind": True, "wind_speed": 10.0, "wind_gust": 0.5,
                                     **fixed_particle_cloth(8, 8)})
    assert injectable_energy(calm, scene_facts(calm), 1.0) == {}
    sources = injectable_energy(windy, scene_facts(windy), 1.0)
    mass = 64 * 0.01 - 2 * 0.01  # two pinned corners
    assert sources["wind"][0] == pytest.approx(0.5 * mass * 20.0**2)
    assert Guard(windy).energy_bound(1.0)[0] > Guard(calm).energy_bound(1.0)[0]
    # A windy cloth flaps for seconds without tripping the guard.
    result = ts.run(windy, "symplectic_euler", dt=1e-3, t_end=3.0, energy_every=50, progress=False)
    assert result.status is ts.Status.OK and result.guard_checks > 0


def test_a_weightless_cloth_at_rest_is_not_diverged_by_its_rounding(f64):
    # No gravity, unstretched springs, at rest: the energy scale's other terms are all zero, and
    # the first step's rounding (about 1e-35 J) read as a blow-up before the springs' rounding
    # energy, sum k (eps L)^2 / 2, bounded the scale from below.
    scene = cloth_builder(n=4, size=0.3, height=0.12).finalize(name="t", params={}, default_dt=1e-3,
                                                               default_integrator="symplectic_euler")
    result = ts.run(scene, "symplectic_euler", dt=1e-3, steps=50, progress=False)
    assert result.status.value == "ok", result.message
    # the floor stays at rounding's size: any real gain of energy is still a blow-up
    guard = Guard(scene)
    assert 0 < guard.scale < 1e-25
