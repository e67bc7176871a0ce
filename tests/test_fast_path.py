"""The fast path for cloth grids (the stencil springs and the fused symplectic Euler step)
against the general spring-list path."""
import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.forces.springs.grid import grid_layout
from taichi_sim.scene import cloth as topo
from taichi_sim.scene.builder import general_paths

# Every feature the stencil path runs with (wind reads neighbours after the precompute, so the
# fused step takes its three-loop form there; sphere and plane are post-step events; grab is a
# local term), on small grids that are not square so that i and j cannot be confused.
COMBINATIONS = [
    {"nx": 7, "ny": 5},
    {"nx": 5, "ny": 6, "shear": False, "damping": 0.0, "jitter": 0.01, "pin": "pole"},
    {"nx": 6, "ny": 5, "flex": False, "structural": False, "orientation": "vertical", "pin": "sides"},
    {"nx": 6, "ny": 6, "wind": True, "sphere": True, "plane": True, "grab": True, "area_drag": 0.72},
]


def trajectory(params, integrator, *, general, steps=200, dt=2e-4):
    if general:
        with general_paths():
            scene = ts.build_scene("cloth", params)
    else:
        scene = ts.build_scene("cloth", params)
    if scene.grabber is not None:  # pull a corner toward a point, as the mouse would
        scene.grabber.grab(1, np.array([0.3, 1.2, 0.1]))
    result = ts.run(scene, integrator, dt=dt, steps=steps, energy_every=0)
    assert result.status is ts.Status.OK, result.message
    return scene, scene.state.x.to_numpy(), scene.state.v.to_numpy()


@pytest.mark.parametrize("params", COMBINATIONS)
def test_stencil_path_matches_the_spring_list_to_round_off(params, f64):
    for integrator in ("symplectic_euler", "rk4") if params is COMBINATIONS[0] else ("symplectic_euler",):
        fast, x_fast, v_fast = trajectory(params, integrator, general=False)
        slow, x_slow, v_slow = trajectory(params, integrator, general=True)
        assert fast.features["grid_stencil"] and not slow.features["grid_stencil"]
        assert np.max(np.abs(x_fast - x_slow)) < 1e-12
        assert np.max(np.abs(v_fast - v_slow)) < 1e-9
        # and they moved: the comparison is not between two resting cloths
        assert np.max(np.abs(x_fast - fast.x0)) > 1e-4


def test_fused_symplectic_step_is_eval_f_then_update(f64):
    params = {"nx": 6, "ny": 5, "wind": True, "jitter": 0.01}
    fused, split = ts.build_scene("cloth", params), ts.build_scene("cloth", params)
    one_kernel = ts.create_integrator("symplectic_euler", fused.system)
    two_kernels = ts.create_integrator("symplectic_euler", split.system)
    for k in range(50):
        one_kernel.step(fused.state, k * 1e-3, 1e-3)
        split.system.eval_f(split.state, k * 1e-3, two_kernels.derivative)  # the unfused path
        two_kernels._advance(split.state, 1e-3)
    # the same arithmetic; only the compiler's fused multiply-adds may round differently
    assert np.max(np.abs(fused.state.x.to_numpy() - split.state.x.to_numpy())) < 1e-13
    assert np.max(np.abs(fused.state.v.to_numpy() - split.state.v.to_numpy())) < 1e-11
    assert np.max(np.abs(fused.state.x.to_numpy() - fused.x0)) > 1e-3


def test_scenes_the_stencil_cannot_run_fall_back_silently(f64):
    torn = ts.build_scene("cloth", {"nx": 5, "ny": 5, "tear": True})
    assert torn.features["springs"] > 0 and not torn.features["grid_stencil"]
    assert ts.run(torn, "symplectic_euler", dt=1e-3, steps=20).status is ts.Status.OK
    chain = ts.build_scene("pendulum", {})
    assert not chain.features["grid_stencil"]


def test_grid_layout_recognises_only_stencil_grids():
    ends, _ = topo.grid_springs(4, 3)
    layout = grid_layout(ends, 0, 4, 3)
    assert layout is not None and len(layout.offsets) == 6
    assert grid_layout(ends[:, ::-1], 0, 4, 3) is not None  # either end may come first
    assert grid_layout(ends + 2, 2, 4, 3) is not None  # a grid after other particles
    assert grid_layout(ends, 0, 3, 4) is None  # the wrong shape: offsets leave the stencil
    assert grid_layout(np.concatenate([ends, ends[:1]]), 0, 4, 3) is None  # two springs, one slot
    assert grid_layout(np.array([[0, 5]]), 0, 4, 3) is None  # (0, 0) to (1, 2): not a stencil offset
    assert grid_layout(ends, 0, 4, 2) is None  # ends outside the grid
    structural, _ = topo.grid_springs(4, 3, shear=False, flex=False)
    assert grid_layout(structural, 0, 4, 3).offsets == ((1, 0), (0, 1))


def test_default_energy_samples_ride_on_the_guard_checks(f64):
    scene = ts.build_scene("cloth", {"nx": 4, "ny": 4})
    sparse = ts.run(scene, "symplectic_euler", dt=1e-4, steps=1000)  # longer than a short run
    # a sample at each check (1, 2, ..., 64 steps apart, then 100) and at both ends, not one per step
    assert len(sparse.energy) == 17 and sparse.guard_checks == 16  # 1, 3, 7, ..., 127, 227, ..., 927, 1000
    assert np.all(np.diff(sparse.energy_t) > 0) and sparse.energy_t[-1] == pytest.approx(0.1)
    scene.reset()
    dense = ts.run(scene, "symplectic_euler", dt=1e-4, steps=1000, energy_every=1)
    assert len(dense.energy) == 1001


def test_a_fused_step_that_produces_nan_is_caught_by_the_guard(f64):
    scene = ts.build_scene("cloth", {"nx": 4, "ny": 4, "stiffness": 1e9})
    result = ts.run(scene, "symplectic_euler", dt=1e-2, steps=400, energy_every=0)
    assert result.status is ts.Status.DIVERGED and result.failed_step <= 100
    assert np.all(np.isfinite(scene.state.x.to_numpy()))


def test_per_spring_values_leave_the_per_offset_shortcut_and_still_match(f64):
    params = {"nx": 6, "ny": 5}
    fast = ts.build_scene("cloth", params)
    with general_paths():
        slow = ts.build_scene("cloth", params)
    assert fast.springs.uniform[None] == 1  # a cloth's springs: one value per offset
    stiffness = np.linspace(100.0, 900.0, fast.springs.spring_count)
    for scene in (fast, slow):
        scene.springs.set_parameters(stiffness=stiffness)
    assert fast.springs.uniform[None] == 0
    for scene in (fast, slow):
        ts.run(scene, "symplectic_euler", dt=2e-4, steps=200, energy_every=0)
    assert np.max(np.abs(fast.state.x.to_numpy() - slow.state.x.to_numpy())) < 1e-12


@pytest.mark.parametrize("name", ["euler", "midpoint", "rk4"])
def test_fused_runge_kutta_stages_match_the_stage_by_stage_step(name, f64):
    params = {"nx": 5, "ny": 4, "wind": True}  # wind: a term that reads other particles
    fused, plain = ts.build_scene("cloth", params), ts.build_scene("cloth", params)
    one, other = ts.create_integrator(name, fused.system), ts.create_integrator(name, plain.system)
    other.fuse_stages = False
    for k in range(40):
        one.step(fused.state, k * 1e-3, 1e-3)
        other.step(plain.state, k * 1e-3, 1e-3)
    assert np.max(np.abs(fused.state.x.to_numpy() - plain.state.x.to_numpy())) < 1e-13
    assert np.max(np.abs(fused.state.v.to_numpy() - plain.state.v.to_numpy())) < 1e-10
    assert np.max(np.abs(fused.state.x.to_numpy() - fused.x0)) > 1e-4


@pytest.mark.parametrize("params", COMBINATIONS[:2])
def test_the_guard_reads_the_same_health_from_the_stencil_and_the_spring_list(params, f64):
    """The stencil sums its springs' energy and largest strain in row passes of its own; the
    guard must read what the spring list's per-particle gather reads (a jittered, moving cloth,
    with a spring stretched far beyond the rest so the strain is not the trivial 0)."""
    readings = []
    for general in (False, True):
        scene, _, _ = trajectory(params, "symplectic_euler", general=general, steps=50)
        x = scene.state.x.to_numpy()
        x[3] += np.array([0.3, -0.1, 0.05])
        scene.state.from_numpy(x, scene.state.v.to_numpy())
        readings.append(scene.system.health(scene.state, np.zeros(3)))
    fast, slow = readings
    assert fast.max_strain > 0.5
    for name in ("energy", "spring_energy", "gravity_energy", "kinetic", "max_strain", "farthest"):
        assert getattr(fast, name) == pytest.approx(getattr(slow, name), rel=1e-11, abs=1e-12), name
    assert fast.nonfinite == slow.nonfinite == 0
    # a non-finite position is counted, whichever path sums the springs
    scene = ts.build_scene("cloth", params)
    x = scene.state.x.to_numpy()
    x[2, 1] = np.nan
    scene.state.from_numpy(x)
    assert scene.system.health(scene.state, np.zeros(3)).nonfinite == 1
