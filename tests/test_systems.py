"""The eval_f contract, the force model and the cloth topology (docs/design.md, Contracts;
docs/scenes.md, Force model)."""
import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.reference import particle_energy, particle_rhs
from taichi_sim.scene import cloth as topo

SMALL_SCENES = {
    "simple": {},
    "spring": {"drag": 0.3, "damping": 0.2},
    "pendulum": {"particle_count": 6, "drag": 0.1, "damping": 0.5},
    "cloth": {"nx": 5, "ny": 4, "area_drag": 4.0, "damping": 0.4},
}


def random_state(scene, rng):
    n = scene.particle_count
    x = scene.x0 + rng.normal(scale=0.05, size=(n, 3))
    v = rng.normal(size=(n, 3)) if scene.system.second_order else None
    y = scene.system.make_state()
    y.from_numpy(x, v)
    return y, x, v


@pytest.mark.parametrize("name", list(SMALL_SCENES))
def test_eval_f_reads_only_its_input_and_writes_all_of_its_output(f64, rng, name):
    scene = ts.build_scene(name, SMALL_SCENES[name])
    y, x, v = random_state(scene, rng)
    before = y.to_numpy()
    out = scene.system.make_state()
    n = scene.particle_count
    out.from_numpy(np.full((n, 3), np.nan), np.full((n, 3), np.nan))
    current_before = scene.state.to_numpy()
    scene.system.eval_f(y, 0.25, out)
    after = y.to_numpy()
    np.testing.assert_array_equal(after[0], before[0])
    if after[1] is not None:
        np.testing.assert_array_equal(after[1], before[1])
    dx, dv = out.to_numpy()
    assert np.isfinite(dx).all() and (dv is None or np.isfinite(dv).all())
    # The scene's own state is not what eval_f looked at, and it is left alone.
    np.testing.assert_array_equal(scene.state.to_numpy()[0], current_before[0])
    if name == "simple":
        np.testing.assert_array_equal(dx[:, 0], -x[:, 1])
        np.testing.assert_array_equal(dx[:, 1], x[:, 0])
    else:
        expected = particle_rhs(scene.arrays)(0.25, np.concatenate([x.ravel(), v.ravel()]))
        np.testing.assert_allclose(np.concatenate([dx.ravel(), dv.ravel()]), expected,
                                   rtol=1e-12, atol=1e-12)
        pinned = scene.arrays["pinned"]
        assert pinned.any()
        assert not dx[pinned].any() and not dv[pinned].any()


def test_internal_forces_obey_newtons_third_law(f64, rng):
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 5, "gravity": 0.0, "area_drag": 0.0,
                                     "damping": 0.7, "pin": "none"})
    y, _, _ = random_state(scene, rng)
    forces = ts.State(scene.particle_count, False).x
    scene.system.forces(y, forces)
    f = forces.to_numpy()
    assert np.abs(f).sum() > 1.0  # the test state really is loaded
    np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-12 * np.abs(f).sum())


def test_spring_and_gravity_forces_are_minus_the_energy_gradient(f64, rng):
    scene = ts.build_scene("cloth", {"nx": 4, "ny": 3, "damping": 0.0, "area_drag": 0.0, "pin": "none",
                                     "shear_stiffness": 70.0, "flex_stiffness": 30.0})
    n = scene.particle_count
    x = scene.x0 + rng.normal(scale=0.03, size=(n, 3))
    y = scene.system.make_state()
    y.from_numpy(x)
    forces = ts.State(n, False).x
    scene.system.forces(y, forces)
    eps = 1e-6
    gradient = np.zeros((n, 3))
    for i in range(n):
        for k in range(3):
            for sign in (1, -1):
                shifted = x.copy()
                shifted[i, k] += sign * eps
                y.from_numpy(shifted)
                gradient[i, k] += sign * scene.system.energy(y) / (2 * eps)
    np.testing.assert_allclose(forces.to_numpy(), -gradient, rtol=1e-6, atol=1e-6)
    # the Taichi energy is the exported model's energy
    y.from_numpy(x)
    assert scene.system.energy(y) == pytest.approx(particle_energy(scene.arrays, x, np.zeros_like(x)),
                                                   rel=1e-12)


def test_zero_length_spring_exerts_no_force_and_no_nan(f64):
    scene = ts.build_scene("pendulum", {"particle_count": 3, "gravity": 0.0})
    x = scene.x0.copy()
    x[2] = x[1]  # the last link collapses to a point
    y = scene.system.make_state()
    y.from_numpy(x)
    out = scene.system.make_state()
    scene.system.eval_f(y, 0.0, out)
    assert np.isfinite(out.to_numpy()[1]).all()


@pytest.mark.parametrize("nx, ny", [(2, 2), (2, 7), (7, 2), (3, 3), (5, 8), (16, 9)])
def test_cloth_spring_counts_and_lengths_by_kind(f64, nx, ny):
    size = 1.5
    scene = ts.build_scene("cloth", {"nx": nx, "ny": ny, "size": size})
    kinds = scene.arrays["spring_kind"]
    expected = topo.spring_counts(nx, ny)
    assert expected[topo.STRUCTURAL] == (nx - 1) * ny + nx * (ny - 1)
    for kind, count in expected.items():
        assert np.count_nonzero(kinds == kind) == count
    ends = scene.arrays["springs"]
    assert len({tuple(sorted(e)) for e in ends}) == len(ends)  # no duplicates
    dx, dz = size / (nx - 1), size / (ny - 1)
    lengths = np.linalg.norm(scene.x0[ends[:, 0]] - scene.x0[ends[:, 1]], axis=1)
    allowed = {topo.STRUCTURAL: (dx, dz), topo.SHEAR: (np.hypot(dx, dz),), topo.FLEX: (2 * dx, 2 * dz)}
    for kind, lengths_ok in allowed.items():
        sel = lengths[kinds == kind]
        assert np.all(np.min([np.abs(sel - L) for L in lengths_ok], axis=0) < 1e-12)
    np.testing.assert_allclose(scene.arrays["rest_length"], lengths, rtol=1e-15)


def test_cloth_kinds_switch_off_and_have_their_own_stiffness(f64):
    scene = ts.build_scene("cloth", {"nx": 4, "ny": 5, "shear": False, "stiffness": 11.0,
                                     "flex_stiffness": 3.0})
    kinds, k = scene.arrays["spring_kind"], scene.arrays["stiffness"]
    assert not np.any(kinds == topo.SHEAR)
    assert np.all(k[kinds == topo.STRUCTURAL] == 11.0) and np.all(k[kinds == topo.FLEX] == 3.0)
    assert scene.features["springs"] == len(kinds) == (3 * 5 + 4 * 4) + (2 * 5 + 4 * 3)


@pytest.mark.parametrize("pin, expected", [("corners", 2), ("edge", 4), ("none", 0)])
def test_cloth_pins(f64, pin, expected):
    scene = ts.build_scene("cloth", {"nx": 4, "ny": 3, "pin": pin})
    pinned = scene.arrays["pinned"]
    assert pinned.sum() == expected
    if pin == "corners":
        ids = np.flatnonzero(pinned)
        np.testing.assert_array_equal(ids, [topo.grid_index(4, 3)[0, -1], topo.grid_index(4, 3)[-1, -1]])


def test_large_cloth_topology_is_exact():
    ends, kind = topo.grid_springs(256, 256)
    counts = topo.spring_counts(256, 256)
    assert len(ends) == sum(counts.values())
    assert np.bincount(kind).tolist() == [counts[0], counts[1], counts[2]]


def test_scenes_without_a_feature_do_not_allocate_it(f64):
    scene = ts.build_scene("spring", {"drag": 0.0, "gravity": 0.0})
    assert scene.features["drag"] is False and scene.features["gravity"] is False
    assert scene.system.term("drag") is None and scene.system.term("gravity") is None
    assert "dashpots" in scene.features and scene.features["dashpots"] is False
