"""Kinematic pins (taichi_sim.scene.kinematic) and the cloth-twist scene they drive."""
import math

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.errors import ConfigError
from taichi_sim.scene.builder import SceneBuilder
from taichi_sim.scene.kinematic import TwistPath


def expected_side(t, ny, *, side, rate=0.5, duration=3.0, approach=0.3, size=1.0, height=1.0):
    """Where the held side i = 0 (side +1) or i = nx-1 (side -1) of a horizontal cloth is at t:
    turned by side * 2 pi rate t about +x through (0, height, 0), slid toward the middle."""
    s = min(t, duration)
    theta = side * 2 * math.pi * rate * s
    z = np.linspace(-size / 2, size / 2, ny)
    x = -side * size / 2 + side * 0.5 * approach * size * s / duration
    return np.stack([np.full(ny, x), height - z * math.sin(theta), z * math.cos(theta)], axis=1)


@pytest.mark.parametrize("integrator, dt", [("symplectic_euler", 1e-3), ("implicit_euler", 1 / 60),
                                            ("xpbd", 1 / 60)])
def test_every_integrator_leaves_the_held_sides_where_the_script_puts_them(f64, integrator, dt):
    nx = ny = 6
    scene = ts.build_scene("cloth-twist", {"nx": nx, "ny": ny, "self_collision": False})
    assert scene.features["kinematic"] == 2 * ny and scene.features["pinned"] == 2 * ny
    steps = int(round(0.6 / dt))
    result = ts.run(scene, integrator, dt=dt, steps=steps)
    assert result.status.value == "ok"
    x, v = scene.state.to_numpy()
    grid = x.reshape(nx, ny, 3)
    t = steps * dt
    np.testing.assert_allclose(grid[0], expected_side(t, ny, side=1), atol=1e-12)
    np.testing.assert_allclose(grid[-1], expected_side(t, ny, side=-1), atol=1e-12)
    # the pins carry the script's velocity (what dashpots and the contact stage see)
    h = 1e-6
    rate = (expected_side(t + h, ny, side=1) - expected_side(t - h, ny, side=1)) / (2 * h)
    np.testing.assert_allclose(v.reshape(nx, ny, 3)[0], rate, atol=1e-6)
    assert np.isfinite(x).all()


def test_the_sides_stop_after_the_duration_and_a_reset_puts_them_back(f64):
    scene = ts.build_scene("cloth-twist", {"nx": 5, "ny": 5, "self_collision": False, "twist_duration": 0.1,
                                           "twist_rate": 1.0})
    ts.run(scene, "symplectic_euler", dt=1e-3, steps=150)
    x, v = scene.state.to_numpy()
    np.testing.assert_allclose(x.reshape(5, 5, 3)[0], expected_side(0.15, 5, side=1, rate=1.0, duration=0.1),
                               atol=1e-12)
    assert not v.reshape(5, 5, 3)[[0, -1]].any()
    scene.reset()
    np.testing.assert_array_equal(scene.state.to_numpy()[0], scene.x0)


def test_twist_parameters_are_validated(f64):
    with pytest.raises(ConfigError, match="twist_rate"):
        ts.build_scene("cloth-twist", {"nx": 4, "ny": 4, "twist_rate": 0.0})
    with pytest.raises(ConfigError, match="twist_duration"):
        ts.build_scene("cloth-twist", {"nx": 4, "ny": 4, "twist_duration": -1.0})
    with pytest.raises(ConfigError, match="twist_approach"):
        ts.build_scene("cloth-twist", {"nx": 4, "ny": 4, "twist_approach": 1.0})
    with pytest.raises(ConfigError, match="parameter twist: .*pin=sides"):
        ts.build_scene("cloth-twist", {"nx": 4, "ny": 4, "pin": "corners"})
    with pytest.raises(ValueError, match="twist_rate"):
        TwistPath(np.zeros((1, 3)), np.ones(1), np.zeros(1), (0, 0, 0), (1, 0, 0), math.nan, 1.0)
    b = SceneBuilder()
    b.add_particles(np.eye(3), 0.01, pinned=np.array([True, False, False]))
    path = TwistPath(np.eye(3)[1:], np.ones(2), np.zeros(2), (0, 0, 0), (1, 0, 0), 1.0, 1.0)
    with pytest.raises(ValueError, match="must be pinned"):
        b.add_kinematic([1, 2], path)
    with pytest.raises(ValueError, match="start where its particles are"):
        b.add_kinematic([0, 0], path)


def test_the_wrung_cloth_never_passes_through_itself_with_the_stage_on(f64):
    """cloth-twist as the preset has it (self-collision on), with xpbd at one step a frame: no
    kept frame has intersecting triangles, where the same run without the stage has them in
    most frames (so the twist really brings the cloth against itself)."""
    from taichi_sim.geometry import self_intersections

    counts = {}
    for stage in (True, False):
        scene = ts.build_scene("cloth-twist", {"nx": 9, "ny": 9, "self_collision": stage})
        result = ts.run(scene, "xpbd", dt=1 / 60, steps=120, save_every=5)
        assert result.status.value == "ok"
        tris = scene.mesh.triangles_np
        counts[stage] = [self_intersections(x, tris).count for x in result.x_history]
    assert len(counts[True]) == 25 and max(counts[True]) == 0
    assert sum(c > 0 for c in counts[False]) > 10
