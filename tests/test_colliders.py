"""Object colliders: continuous sphere tests, spin, capsules, boxes, friction, energy, bad input."""
import math

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.scene import cloth as topo
from taichi_sim.scene.builder import SceneBuilder
from taichi_sim.scene.colliders import SpherePath


def cloth_builder(n=16, size=0.5, height=0.0, stiffness=5.0, mass=0.01):
    """A free horizontal n x n cloth of side ``size`` (m) at ``height``, soft enough for
    symplectic Euler at h = 10 ms."""
    x = topo.grid_positions(n, n, size, size, origin=(-size / 2, height, -size / 2),
                            u_axis=(1, 0, 0), v_axis=(0, 0, 1))
    b = SceneBuilder()
    b.add_particles(x, mass)
    ends, kind = topo.grid_springs(n, n)
    b.add_springs(ends, stiffness=stiffness, damping=0.0, kind=kind)
    b.add_triangles(topo.grid_triangles(n, n))
    return b


def advance(scene, dt, steps, integrator="symplectic_euler", check=None):
    stepper = ts.create_integrator(integrator, scene.system)
    t = 0.0
    for k in range(steps):
        assert stepper.step(scene.state, t, dt).status is ts.Status.OK
        t = (k + 1) * dt
        scene.after_step(t, dt)
        if check is not None:
            check(scene)
    return scene.state.to_numpy()[0]


# --- no tunnelling --------------------------------------------------------------------------

@pytest.mark.parametrize("continuous", [True, False])
def test_a_fast_small_sphere_does_not_tunnel_through_a_cloth(f64, continuous):
    # r = 0.1 m at 30 m/s and h = 10 ms: the sphere moves 0.3 m (3 radii) per step, and its
    # ends (0.15 m above, then 0.15 m below the cloth) never overlap it; spacing 0.036 m < r.
    radius, dt = 0.1, 1e-2
    b = cloth_builder(n=15)
    b.add_sphere(SpherePath((0.0, 0.15, 0.0), velocity=(0.0, -30.0, 0.0)), radius, continuous=continuous)
    scene = b.finalize(name="t", params={}, default_dt=dt, default_integrator="symplectic_euler")
    middle = 7 * 15 + 7  # straight under the sphere's path

    def carried_and_outside(scene):
        x, c = scene.state.to_numpy()[0], scene.spheres.centers()[0]
        assert np.linalg.norm(x - c, axis=1).min() >= radius * (1 - 1e-9)
        # the particle the sphere meets head-on rides on its leading pole, never passed
        assert x[middle, 1] < c[1] - 0.99 * radius

    if continuous:
        advance(scene, dt, 2, check=carried_and_outside)
        assert scene.state.to_numpy()[0][middle, 1] < -0.5  # carried 0.55 m down with the sphere
    else:  # the old end-only test: the sphere passes straight through the cloth
        with pytest.raises(AssertionError):
            advance(scene, dt, 2, check=carried_and_outside)
        assert abs(scene.state.to_numpy()[0][middle, 1]) < 1e-9  # never touched
