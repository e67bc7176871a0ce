"""Scene extras: spheres, the ground plane, tearing, the sprinkler, wind and grab."""
import math

import numpy as np
import pytest
from helpers import step_checked

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.scene import cloth as topo
from taichi_sim.scene.cloth import fixed_particle_cloth


def step_and_check(scene, integrator_name, dt, steps, check):
    """Step like ts.run does, calling check(scene) after every accepted step."""
    return step_checked(scene, integrator_name, dt, steps, check).t


# --- spheres -------------------------------------------------------------------------------

def test_no_particle_ends_a_step_inside_the_sphere(f64):
    scene = ts.build_scene("cloth-sphere", {"nx": 12, "ny": 12, "sphere_motion": "oscillate"})
    radius = scene.params["sphere_radius"]

    def outside(scene):
        x = scene.state.to_numpy()[0]
        center = scene.spheres.centers()[0]
        assert np.linalg.norm(x - center, axis=1).min() >= radius * (1 - 1e-12)

    step_and_check(scene, "symplectic_euler", 1e-3, 700, outside)
    x = scene.state.to_numpy()[0]
    # the cloth really is draped on the sphere: many particles touch it, or nearly (its faces
    # rest on it too: a face's diagonal sqrt(2) l holds its ends off by up to l^2 / (4 r), and
    # the face pushes go 1.5 times as far)
    spacing = scene.params["size"] / (scene.params["nx"] - 1)
    touching = np.abs(np.linalg.norm(x - scene.spheres.centers()[0], axis=1) - radius) < spacing**2 / (2 * radius)
    assert touching.sum() > 10


def test_a_resting_cloth_on_a_sphere_gains_no_energy(f64):
    scene = ts.build_scene("cloth-sphere", {"nx": 10, "ny": 10, "plane": False, "damping": 0.2,
                                            "area_drag": 2.0})
    ts.run(scene, "symplectic_euler", dt=1e-3, steps=4000, energy_every=0)  # falls and settles
    rest = ts.run(scene, "symplectic_euler", dt=1e-3, steps=1000, energy_every=50)
    e = rest.energy
    # Projection may only remove energy; allow round-off relative to the energy's scale.
    scale = abs(e).max()
    assert e.max() <= e[0] + 1e-6 * scale
    assert e[-1] <= e[0] + 1e-9 * scale


def test_sphere_friction_slows_sliding(f64):
    def slide(mu):
        scene = ts.build_scene("cloth-sphere", {"nx": 8, "ny": 8, "sphere_friction": mu, "plane": False,
                                                "sphere_x": 0.3})
        ts.run(scene, "symplectic_euler", dt=1e-3, steps=1500, energy_every=0)
        return np.abs(scene.state.to_numpy()[1]).mean()
    assert slide(0.8) < slide(0.0)


# --- plane and sprinkler -------------------------------------------------------------------

@pytest.mark.parametrize("restitution", [0.0, 0.5, 1.0])
def test_plane_bounce_keeps_restitution_times_the_normal_speed(f64, restitution):
    scene = ts.build_scene("sprinkler", {"restitution": restitution, "plane_friction": 0.0})
    scene.emitter.alive.fill(0)
    plane = scene.plane
    n = scene.particle_count
    x = np.zeros((n, 3))
    v = np.zeros((n, 3))
    x[:, 1] = -0.01                      # below the ground
    v[:] = [0.7, -3.0, 0.2]              # falling, sliding
    scene.state.from_numpy(x, v)
    scene.system.free.fill(1)
    plane(scene.state, 0.0, 1e-3)
    x2, v2 = scene.state.to_numpy()
    np.testing.assert_allclose(x2[:, 1], 0.0, atol=1e-15)
    np.testing.assert_allclose(v2[:, 1], 3.0 * restitution, rtol=1e-14)
    np.testing.assert_allclose(v2[:, [0, 2]], v[:, [0, 2]], rtol=1e-14)  # frictionless
    kinetic_normal = 0.5 * v2[:, 1] ** 2 / (0.5 * 3.0**2)
    np.testing.assert_allclose(kinetic_normal, restitution**2, rtol=1e-13)


def test_sprinkler_invariants_hold_after_every_step(f64):
    capacity, lifetime = 120, 0.4
    scene = ts.build_scene("sprinkler", {"capacity": capacity, "lifetime": lifetime, "rate": 500.0,
                                         "sphere": True, "sphere_x": 0.3, "sphere_y": 0.3})
    emitter = scene.emitter
    seen = {"max_live": 0}

    def check(scene):
        alive = emitter.alive.to_numpy().astype(bool)
        live = int(emitter.live_count[None])
        assert live == alive.sum() <= capacity
        seen["max_live"] = max(seen["max_live"], live)
        x = scene.state.to_numpy()[0][emitter.first:emitter.first + capacity]
        assert (x[alive, 1] >= -1e-12).all()
        center, radius = scene.spheres.centers()[0], scene.params["sphere_radius"]
        assert (np.linalg.norm(x[alive] - center, axis=1) >= radius * (1 - 1e-12)).all()
        age = emitter.age.to_numpy()
        assert (age[alive] <= lifetime + 1e-12).all() and (age[alive] >= 0).all()
        free = scene.system.free.to_numpy().astype(bool)
        np.testing.assert_array_equal(free[emitter.first:], alive)

    step_and_check(scene, "symplectic_euler", 2e-3, 400, check)
    assert seen["max_live"] >= capacity - 2  # the ring buffer filled and recycled


def test_sprinkler_same_seed_same_particles(f64):
    def spray(seed):
        scene = ts.build_scene("sprinkler", {"capacity": 300}, seed=seed)
        ts.run(scene, "rk4", dt=2e-3, steps=150, energy_every=0)
        return scene.state.to_numpy()[0], scene.emitter.alive.to_numpy()
    x1, a1 = spray(7)
    x2, a2 = spray(7)
    x3, _ = spray(8)
    np.testing.assert_array_equal(x1, x2)
    np.testing.assert_array_equal(a1, a2)
    assert a1.sum() > 100 and not np.array_equal(x1, x3)


# --- tearing -------------------------------------------------------------------------------

def strains(scene):
    x = scene.state.to_numpy()[0]
    a = scene.springs.arrays()
    ends = a["springs"]
    return np.linalg.norm(x[ends[:, 0]] - x[ends[:, 1]], axis=1) / a["rest_length"] - 1, a


def test_tearing_invariants_and_a_loaded_cloth_tears(f64):
    scene = ts.build_scene("cloth-tear", {"nx": 14, "ny": 14})
    history = [scene.springs.alive_count()]

    def check(scene):
        strain, a = strains(scene)
        alive = a["alive"]
        assert (strain[alive] <= a["tear_strain"][alive]).all()
        history.append(int(alive.sum()))
        assert history[-1] <= history[-2]
        # the mesh never shows a triangle with a torn edge
        tris = scene.mesh.index_buffer().astype(np.int64)
        shown = tris[(tris[:, 0] != tris[:, 1]) | (tris[:, 1] != tris[:, 2])]
        n = scene.particle_count
        key = lambda p, q: np.minimum(p, q) * n + np.maximum(p, q)  # noqa: E731
        springs = a["springs"].astype(np.int64)
        torn_keys = key(springs[~alive, 0], springs[~alive, 1])
        for p, q in ((0, 1), (1, 2), (2, 0)):
            assert not np.isin(key(shown[:, p], shown[:, q]), torn_keys).any()
        assert np.isfinite(scene.state.to_numpy()[0]).all()

    step_and_check(scene, "symplectic_euler", 1e-3, 2600, check)
    assert history[-1] < history[0]  # it tore
    torn = scene.mesh.index_buffer()
    assert (torn[:, 0] == torn[:, 1]).any()  # and the mesh has a hole


def test_an_infinite_threshold_never_tears(f64):
    scene = ts.build_scene("cloth-tear", {"nx": 10, "ny": 10, "tear_strain": math.inf})
    ts.run(scene, "symplectic_euler", dt=1e-3, steps=2600, energy_every=0)
    assert scene.springs.alive_count() == scene.features["springs"]


@pytest.mark.parametrize("weak", ["i", "j"])
def test_anisotropic_thresholds_tear_the_weaker_direction_first(f64, weak):
    params = {"nx": 12, "ny": 12, "pin": "border", "tear_noise": 0.0, "tear_shear_factor": 3.0,
              "tear_flex_factor": 3.0, f"tear_{weak}_factor": 0.5}
    scene = ts.build_scene("cloth-tear", params)
    ends, ny = scene.arrays["springs"], 12
    along_i = (ends[:, 0] % ny) == (ends[:, 1] % ny)
    first = {}

    def check(scene):
        if not first:
            alive = scene.springs.arrays()["alive"]
            if not alive.all():
                first["torn"] = ~alive

    step_and_check(scene, "symplectic_euler", 1e-3, 2600, check)
    torn = first["torn"]
    weak_springs = along_i if weak == "i" else ~along_i & (scene.arrays["spring_kind"] == topo.STRUCTURAL)
    assert torn.any() and (torn <= weak_springs).all()


def test_threshold_maps_seam_and_noise(f64):
    scene = ts.build_scene("cloth", {"nx": 9, "ny": 7, "tear": True, "tear_strain": 0.2,
                                     "tear_seam": "across-i", "tear_seam_factor": 0.5})
    a = scene.arrays
    ends = a["springs"]
    i = ends // 7
    crosses = (i.min(axis=1) < 4) & (i.max(axis=1) > 4)
    structural = a["spring_kind"] == topo.STRUCTURAL
    np.testing.assert_allclose(a["tear_strain"][crosses & structural], 0.1)
    np.testing.assert_allclose(a["tear_strain"][~crosses & structural], 0.2)
    noisy = ts.build_scene("cloth", {"nx": 9, "ny": 7, "tear": True, "tear_noise": 0.5}, seed=1)
    t = noisy.arrays["tear_strain"][structural]
    assert t.std() > 0.01 and t.min() > 0
    again = ts.build_scene("cloth", {"nx": 9, "ny": 7, "tear": True, "tear_noise": 0.5}, seed=1)
    np.testing.assert_array_equal(again.arrays["tear_strain"], noisy.arrays["tear_strain"])


# --- wind ----------------------------------------------------------------------------------

def test_wind_switched_off_is_bit_identical_to_no_wind(f64):
    def hang(wind):
        scene = ts.build_scene("cloth-wind", {"nx": 8, "ny": 8, "wind": wind})
        if wind:
            scene.system.term("wind").set(enabled=False)
        ts.run(scene, "rk4", dt=1e-3, steps=150, energy_every=0)
        return scene.state.to_numpy()
    x_off, v_off = hang(True)
    x_none, v_none = hang(False)
    np.testing.assert_array_equal(x_off, x_none)
    np.testing.assert_array_equal(v_off, v_none)


@pytest.mark.parametrize("heading, axis, sign", [(90.0, 2, 1), (-90.0, 2, -1)])
def test_wind_pushes_a_hanging_cloth_downwind(f64, heading, axis, sign):
    scene = ts.build_scene("cloth-wind", {"nx": 10, "ny": 10, "wind_heading": heading, "jitter": 0.0})
    x0 = scene.state.to_numpy()[0]
    ts.run(scene, "symplectic_euler", dt=1e-3, steps=400, energy_every=0)
    shift = (scene.state.to_numpy()[0] - x0)[:, axis].mean()
    assert sign * shift > 0.02


def test_wind_force_is_zero_edge_on_and_scales_with_area(f64):
    """A flat cloth with the wind in its plane feels no wind; facing it, F = c A u^2 in total."""
    scene = ts.build_scene("cloth", {"nx": 5, "ny": 5, "wind": True, "wind_gust": 0.0, "gravity": 0.0,
                                     "pin": "none", "wind_speed": 4.0, "wind_heading": 0.0})
    forces = ts.State(scene.particle_count, False).x
    scene.system.forces(scene.state, forces)
    np.testing.assert_allclose(forces.to_numpy(), 0.0, atol=1e-12)   # horizontal cloth, wind along x
    scene.system.term("wind").direction[None] = [0.0, -1.0, 0.0]     # now blowing down onto it
    scene.system.forces(scene.state, forces)
    total = forces.to_numpy().sum(axis=0)
    c, u, area = scene.params["wind_drag"], 4.0, scene.params["size"] ** 2
    np.testing.assert_allclose(total, [0.0, -c * area * u * u, 0.0], rtol=1e-12, atol=1e-12)


# --- grab ----------------------------------------------------------------------------------

def test_grab_picks_along_a_ray_and_pulls(f64):
    scene = ts.build_scene("cloth", {"nx": 8, "ny": 8, "grab": True, "pin": "corners", **fixed_particle_cloth(8, 8)})
    x0 = scene.state.to_numpy()[0]
    target_id = topo.grid_index(8, 8)[3, 2]
    eye = x0[target_id] + np.array([0.0, 2.0, 0.0])
    picked = scene.grabber.pick(eye, [0.0, -1.0, 0.0])
    assert picked == target_id
    assert scene.grabber.pick(eye, [0.0, 1.0, 0.0]) is None  # nothing behind the eye
    goal = x0[target_id] + np.array([0.0, 0.4, 0.0])
    scene.grabber.grab(picked)
    scene.grabber.drag_to(goal)
    ts.run(scene, "symplectic_euler", dt=1e-3, steps=800, energy_every=0)
    pulled = scene.state.to_numpy()[0][target_id]
    assert np.linalg.norm(pulled - goal) < 0.5 * np.linalg.norm(x0[target_id] - goal)
    scene.grabber.release()
    assert scene.grabber.spring.particle[None] == -1


# --- a scene pays only for what it asks for --------------------------------------------------

def test_scenes_without_extras_allocate_none_of_their_fields(f64):
    scene = ts.build_scene("cloth", {"nx": 4, "ny": 4})
    f = scene.features
    assert not f["wind"] and not f.get("spheres") and not f["plane"] and not f["tearing"]
    assert f["emitter"] == 0 and not f["grab"]
    assert scene.spheres is None and scene.plane is None and scene.emitter is None
    assert scene.grabber is None and scene.post_step == []
    assert {t.name for t in scene.system.terms} == {"gravity", "drag", "springs"}
    assert not hasattr(scene.springs, "alive") and not scene.mesh.tearable
    for key in ("alive", "age", "sphere_center", "plane_point", "tear_strain"):
        assert key not in scene.arrays
    full = ts.build_scene("cloth", {"nx": 4, "ny": 4, "wind": True, "sphere": True, "plane": True,
                                    "tear": True, "grab": True})
    assert {t.name for t in full.system.terms} == {"gravity", "drag", "springs", "wind", "grab"}
    assert len(full.post_step) == 3 and full.features["spheres"] == 1


# --- CLI -------------------------------------------------------------------------------------

EXTRA_KEYS = {
    "cloth-sphere": {"sphere_center", "sphere_radius", "plane_point", "plane_normal"},
    "cloth-tear": {"sphere_center", "sphere_radius", "alive", "tear_strain"},
    "cloth-wind": set(),
    "sprinkler": {"alive", "age", "plane_point", "plane_normal"},
}


@pytest.mark.parametrize("scene", list(EXTRA_KEYS))
@pytest.mark.parametrize("integrator", ["euler", "trapezoid", "midpoint", "rk4", "symplectic_euler"])
def test_presets_run_from_the_cli_with_every_integrator(tmp_path, scene, integrator):
    sets = ["--set", "capacity=50"] if scene == "sprinkler" else ["--set", "nx=5", "--set", "ny=5"]
    path = tmp_path / "e.npz"
    assert main(["simulate", scene, "--integrator", integrator, "--steps", "30", *sets,
                 "--out", str(path), "--quiet"]) == 0
    data = np.load(path)
    assert EXTRA_KEYS[scene] <= set(data.files) and str(data["status"]) == "ok"
    assert np.isfinite(data["x"]).all()
