"""Constraint forces (Lagrange multipliers): the bead on a wire and the pendulum of rods."""
import math

import numpy as np
import pytest
from helpers import fitted_order

import taichi_sim as ts
from taichi_sim.app.session import Session, compatible_integrators
from taichi_sim.cli import main
from taichi_sim.errors import ConfigError
from taichi_sim.guard import Guard
from taichi_sim.reference import constraint_violation, particle_energy, particle_rhs, solve_reference
from taichi_sim.scene import SceneBuilder, build_scene
from taichi_sim.scene.live import LIVE_SETTERS, applies_live
from taichi_sim.systems.constraints import Constraints


def test_rk4_keeps_the_bead_on_its_wire_within_a_micrometre_for_10_s(f64):
    scene = build_scene("bead", {"initial_speed": 1.0})
    integrator = ts.create_integrator("rk4", scene.system)
    e0 = scene.energy()
    h, worst = 2.5e-3, 0.0
    for step in range(4000):  # 10 s, checked every 10 ms
        integrator.step(scene.state, step * h, h)
        if step % 4 == 3:
            worst = max(worst, scene.constraint_violation())
    assert worst < 1e-6
    x = scene.state.x.to_numpy()[0]
    assert math.hypot(x[0], x[1]) == pytest.approx(1.0, abs=1e-6) and abs(x[2]) < 1e-12
    assert scene.energy() == pytest.approx(e0, abs=1e-6)  # J, of a bead with m g R = 0.98 J


def _energy_error(scene, integrator, h, t_end=1.0):
    scene.reset()
    integrator.reset()
    e0 = scene.energy()
    worst = 0.0
    for step in range(round(t_end / h)):
        integrator.step(scene.state, step * h, h)
        if step % 5 == 4:  # every 20 ms at the larger step, every 10 ms at the smaller
            worst = max(worst, abs(scene.energy() - e0))
    return worst


@pytest.mark.parametrize("name, order", [("rk4", 4), ("midpoint", 2)])
def test_double_pendulum_conserves_energy_to_the_integrators_order(f64, name, order):
    scene = build_scene("rod-pendulum", {"angle": 60.0, "angle2": 100.0})
    integrator = ts.create_integrator(name, scene.system)
    hs = [4e-3, 2e-3] if name == "rk4" else [2e-3, 1e-3]
    errors = [_energy_error(scene, integrator, h) for h in hs]
    measured = fitted_order(hs, errors)
    assert abs(measured - order) < 0.4, (errors, measured)


@pytest.mark.parametrize("sign", [+1, -1])
def test_small_oscillations_have_the_normal_mode_frequencies(f64, sign):
    """Equal masses and rods: omega^2 = (g/L)(2 -+ sqrt 2), theta2 = +-sqrt(2) theta1."""
    g, rod, eps = 9.8, 1.0, 0.01
    scene = build_scene("rod-pendulum", {"angle": math.degrees(eps),
                                         "angle2": math.degrees(sign * math.sqrt(2) * eps)})
    result = ts.run(scene, "rk4", dt=5e-3, t_end=6.0, energy_every=0, save_every=1)
    x1 = result.x_history[:, 1, :]
    theta1 = np.arctan2(x1[:, 0], -x1[:, 1])
    t = result.t_history
    cross = np.flatnonzero(np.sign(theta1[:-1]) != np.sign(theta1[1:]))
    times = t[cross] - theta1[cross] * (t[cross + 1] - t[cross]) / (theta1[cross + 1] - theta1[cross])
    omega = math.pi * (len(times) - 1) / (times[-1] - times[0])
    expected = math.sqrt(g / rod * (2 - sign * math.sqrt(2)))
    assert omega == pytest.approx(expected, rel=1e-3)
    # a pure mode: the second rod keeps its ratio to the first
    x2 = result.x_history[:, 2, :] - x1
    theta2 = np.arctan2(x2[:, 0], -x2[:, 1])
    peak = np.argmax(np.abs(theta1))
    assert theta2[peak] / theta1[peak] == pytest.approx(sign * math.sqrt(2), rel=2e-3)


@pytest.mark.parametrize("name, params", [
    ("bead", {"initial_speed": 0.7, "drag": 0.05}),
    ("rod-pendulum", {"links": 3, "planar": True, "angle": 40.0, "angle2": -70.0, "drag": 0.1}),
])
def test_eval_f_matches_the_numpy_model_off_the_constraint(f64, rng, name, params):
    scene = build_scene(name, params)
    data = dict(scene.arrays)
    n = scene.particle_count
    free = ~data["pinned"]
    x = scene.x0 + 0.01 * rng.standard_normal((n, 3)) * free[:, None]
    v = rng.standard_normal((n, 3)) * free[:, None]
    state, out = scene.system.make_state(), scene.system.make_state()
    state.from_numpy(x, v)
    scene.system.eval_f(state, 0.0, out)
    expected = particle_rhs(data)(0.0, np.concatenate([x.ravel(), v.ravel()]))
    assert np.allclose(out.v.to_numpy().ravel(), expected[3 * n:], rtol=1e-10, atol=1e-10)
    assert np.allclose(out.x.to_numpy().ravel(), expected[:3 * n])
    assert scene.system.constraint_violation(state) == pytest.approx(constraint_violation(data, x), rel=1e-12)
    # forces() is the same stage: the net force, constraint force included
    forces = scene.system.make_state().x
    scene.system.forces(state, forces)
    accel = expected[3 * n:].reshape(n, 3)
    assert np.allclose(forces.to_numpy(), data["mass"][:, None] * accel, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("name, dt, bound", [("symplectic_euler", 1e-3, 1e-2), ("rk45", None, 1e-5)])
def test_symplectic_euler_and_rk45_step_constrained_scenes(f64, name, dt, bound):
    scene = build_scene("bead", {"initial_speed": 2.0})
    result = ts.run(scene, name, dt=dt, t_end=0.5)
    assert result.status.value == "ok"
    assert 0 < result.constraint_violation[-1] < bound


def test_implicit_and_positional_methods_refuse_a_constrained_scene(f64):
    scene = build_scene("rod-pendulum")
    allowed = compatible_integrators(scene)
    assert {"rk4", "rk45", "symplectic_euler", "euler"} <= set(allowed)
    for name in ("implicit_euler", "implicit_midpoint", "implicit_euler_linearised", "xpbd",
                 "projective_dynamics"):
        assert name not in allowed
        with pytest.raises(ConfigError, match=r"rod-pendulum.*explicit method \(rk4"):
            ts.create_integrator(name, scene.system)
    assert main(["simulate", "bead", "--integrator", "implicit_euler", "--t-end", "0.1", "--quiet"]) == 2


@pytest.mark.parametrize("name, params, parameter", [
    ("bead", {"ks": -1.0}, "ks"), ("bead", {"kd": -0.5}, "kd"), ("bead", {"radius": 0.0}, "radius"),
    ("bead", {"radius": -1.0}, "radius"), ("rod-pendulum", {"rod_length": 0.0}, "rod_length"),
    ("rod-pendulum", {"ks": -3.0}, "ks"), ("rod-pendulum", {"links": 0}, "links"),
    ("rod-pendulum", {"links": 300}, "links"),
])
def test_bad_parameters_name_themselves(f64, name, params, parameter):
    with pytest.raises(ValueError, match=rf"parameter {parameter}\b"):
        build_scene(name, params)


def test_builder_rejects_bad_constraints(f64):
    b = SceneBuilder()
    b.add_particles([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], 1.0, pinned=[True, False, False])
    with pytest.raises(ValueError, match="rod length"):
        b.add_rod(0, 1)  # the two particles coincide: zero length
    with pytest.raises(ValueError, match="rod length"):
        b.add_rod(0, 2, length=0.0)
    with pytest.raises(ValueError, match="wire radius"):
        b.add_circle_wire(2, (0, 0, 0), (0, 0, 1), 0.0)
    with pytest.raises(ValueError, match="kd"):
        b.set_constraint_feedback(1.0, -1.0)
    with pytest.raises(ValueError, match="ks"):
        b.set_constraint_feedback(float("nan"), 1.0)
    b.add_rod(0, 2)
    constraints = b.finalize(name="t", params={}, default_dt=1e-3, default_integrator="rk4").constraints
    with pytest.raises(ValueError, match="ks"):
        constraints.set_gains(-1.0, 0.0)
    pinned_only = SceneBuilder()
    pinned_only.add_particles([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], 1.0, pinned=[True, True])
    pinned_only.add_rod(0, 1)
    with pytest.raises(ValueError, match="only pinned"):
        pinned_only.finalize(name="t", params={}, default_dt=1e-3, default_integrator="rk4")


def test_new_scenes_allocate_only_what_they_use(f64):
    bead = build_scene("bead")
    assert [t.name for t in bead.system.terms] == ["gravity"]
    assert bead.springs is None and bead.mesh is None and bead.grabber is None and not bead.post_step
    assert bead.features["constraints"] == 2 and bead.features["springs"] == 0
    rods = build_scene("rod-pendulum")
    assert rods.springs is None and rods.features["constraints"] == 2
    assert isinstance(rods.constraints, Constraints) and rods.constraints.row_count == 2
    assert build_scene("rod-pendulum", {"planar": True}).constraints.row_count == 4
    # and a scene without constraints has no constraint stage at all
    spring = build_scene("pendulum")
    assert spring.constraints is None and spring.system.constraints is None
    assert spring.features["constraints"] == 0 and spring.constraint_violation() is None
    assert not any(k.startswith("constraint") for k in spring.arrays)
    # the gains are live parameters of a constrained scene only
    assert applies_live(bead, "ks") and applies_live(bead, "kd") and not applies_live(spring, "ks")
    assert LIVE_SETTERS["kd"](bead, {"ks": 4.0, "kd": 3.0}) and bead.constraints.gains() == (4.0, 3.0)


def test_npz_records_the_violation_at_each_energy_sample(f64, tmp_path):
    path = tmp_path / "bead.npz"
    assert main(["simulate", "bead", "--t-end", "1.0", "--set", "initial_speed=1.5",
                 "--set", "ks=0", "--set", "kd=0", "--out", str(path), "--quiet"]) == 0
    data = dict(np.load(path))
    assert data["constraint_violation"].shape == data["energy_t"].shape
    assert data["constraint_violation"][0] == pytest.approx(0.0, abs=1e-15)
    assert data["constraint_violation"][-1] == pytest.approx(constraint_violation(data, data["x"]), rel=1e-9)
    assert data["constraint_violation"][-1] > 0  # without feedback the drift is there to see
    # the energy is kinetic + gravitational: the constraint force stores none
    assert data["energy"][-1] == pytest.approx(particle_energy(data, data["x"], data["v"]), rel=1e-12)
    assert float(data["constraint_ks"]) == 0.0 and data["constraint_kind"].tolist() == [0, 2]
    # the whole run against scipy's DOP853 on the numpy model rebuilt from the file
    x_ref, v_ref = solve_reference(data, float(data["t"]))
    assert np.abs(data["x"] - x_ref).max() < 1e-7 and np.abs(data["v"] - v_ref).max() < 1e-6


def test_guard_counts_the_whole_wire_and_the_hud_shows_the_drift(f64):
    scene = build_scene("bead", {"radius": 5.0, "angle": 0.0})
    guard = Guard(scene)
    assert guard.size >= 10.0  # the wire's diameter, not the bead's single point
    assert guard.scale >= scene.params["particle_mass"] * 9.8 * 10.0
    session = Session("bead", ["rk4"], substeps=5)
    session.frame(0.05)
    assert any("max |C| = " in line for line in session.hud_lines())
    assert session.runners[0].drift is not None
