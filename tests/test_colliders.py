"""Object colliders: continuous sphere tests, spin, capsules, boxes, friction, energy, bad input."""
import math

import numpy as np
import pytest
from helpers import cloth_builder, step_checked

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.scene.builder import SceneBuilder
from taichi_sim.scene.colliders import SpherePath


def advance(scene, dt, steps, integrator="symplectic_euler", check=None):
    step_checked(scene, integrator, dt, steps, check)
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


def test_a_fast_capsule_and_box_do_not_tunnel(f64):
    # each moves 0.3 m per step (three times its half thickness 0.1 m) down through a cloth
    middle = 7 * 15 + 7
    for kind in ("capsule", "box"):
        b = cloth_builder(n=15)
        path = SpherePath((0.0, 0.15, 0.0), velocity=(0.0, -30.0, 0.0))
        if kind == "capsule":
            b.add_capsule(path, 0.1, (0.1, 0.0, 0.0))
        else:
            b.add_box(path, (0.1, 0.1, 0.1))
        scene = b.finalize(name="t", params={}, default_dt=1e-2, default_integrator="symplectic_euler")
        colliders = scene.part("capsules" if kind == "capsule" else "boxes")

        def carried_and_outside(scene):
            q = scene.state.to_numpy()[0] - colliders.centers()[0]
            if kind == "capsule":  # distance to the axis segment, minus the radius
                u = np.clip(q[:, 0], -0.1, 0.1)
                dist = np.linalg.norm(q - np.stack([u, 0 * u, 0 * u], axis=1), axis=1) - 0.1
            else:
                over = np.abs(q) - 0.1
                dist = np.linalg.norm(np.maximum(over, 0), axis=1) + np.minimum(over.max(axis=1), 0)
            assert dist.min() >= -1e-9, kind
            assert q[middle, 1] < -0.1 * (1 - 1e-6), kind  # on its leading face, never passed

        advance(scene, 1e-2, 2, check=carried_and_outside)


# --- friction -------------------------------------------------------------------------------

@pytest.mark.parametrize("tilt_deg, sticks", [(20.0, True), (35.0, False)])
def test_friction_holds_a_particle_on_a_plane_below_the_friction_angle(f64, tilt_deg, sticks):
    mu, g, dt, steps = 0.5, 9.81, 1e-3, 1000  # tan 20 deg = 0.36 < mu < tan 35 deg = 0.70
    theta = math.radians(tilt_deg)
    normal = (-math.sin(theta), math.cos(theta), 0.0)
    b = SceneBuilder()
    b.add_particles(np.zeros((1, 3)), 0.01)
    b.set_gravity((0.0, -g, 0.0))
    b.set_plane((0.0, 0.0, 0.0), normal, restitution=0.0, friction=mu)
    scene = b.finalize(name="t", params={}, default_dt=dt, default_integrator="symplectic_euler")
    x = advance(scene, dt, steps)
    travel = float(np.linalg.norm(x[0]))
    t = steps * dt
    if sticks:
        # the projection leaves a drift of at most g sin(theta) h per second: 3.4 mm here
        assert travel <= g * math.sin(theta) * dt * t * 1.01
        assert float(np.linalg.norm(scene.state.to_numpy()[1][0])) < 1e-9
    else:
        expected = 0.5 * g * (math.sin(theta) - mu * math.cos(theta)) * t**2
        assert travel == pytest.approx(expected, rel=0.02)


def test_a_spinning_sphere_drags_a_particle_round(f64):
    # a particle resting on top of a sphere spinning about y, offset from the pole, is carried
    # round (angular momentum about y grows from zero); without spin it stays put
    def swing(spin):
        b = SceneBuilder()
        b.add_particles(np.array([[0.1, 0.3 * math.cos(math.asin(0.1 / 0.3)), 0.0]]), 0.01)
        b.set_gravity((0.0, -9.81, 0.0))
        b.add_sphere(SpherePath((0.0, 0.0, 0.0), spin=spin), 0.3, friction=1.0)
        scene = b.finalize(name="t", params={}, default_dt=1e-3, default_integrator="symplectic_euler")
        x0 = scene.state.to_numpy()[0][0].copy()
        x = advance(scene, 1e-3, 100)[0]
        return math.atan2(-x[2], x[0]) - math.atan2(-x0[2], x0[0])  # angle turned about +y
    assert swing(5.0) > 0.2
    assert abs(swing(0.0)) < 1e-9


# --- energy ---------------------------------------------------------------------------------

@pytest.mark.parametrize("collider", ["sphere", "capsule", "box", "plane"])
def test_collisions_never_add_energy(f64, collider):
    # a damped cloth falls onto a static collider; with no source, energy only falls. Symplectic
    # Euler's own energy error oscillates by < 1e-4 of the energy scale at this step.
    b = cloth_builder(n=10, size=0.6, height=0.5, stiffness=200.0)
    b.set_gravity((0.0, -9.81, 0.0))
    b.set_drag(0.01)
    at = SpherePath((0.1, 0.2, 0.05))
    if collider == "sphere":
        b.add_sphere(at, 0.2, friction=0.3)
    elif collider == "capsule":
        b.add_capsule(at, 0.1, (0.2, 0.0, 0.0), friction=0.3)
    elif collider == "box":
        b.add_box(at, (0.2, 0.1, 0.15), friction=0.3)
    else:
        b.set_plane((0.0, 0.2, 0.0), (0.1, 1.0, 0.0), restitution=0.0, friction=0.3)
    scene = b.finalize(name="t", params={}, default_dt=1e-3, default_integrator="symplectic_euler")
    result = ts.run(scene, "symplectic_euler", dt=1e-3, steps=800, energy_every=20)
    e = result.energy
    scale = abs(e).max()
    assert np.all(np.diff(e) <= 1e-4 * scale)
    assert e[-1] < e[0] - 0.01 * scale  # it did hit something


# --- bad input ------------------------------------------------------------------------------

def test_degenerate_colliders_are_refused_naming_the_parameter(f64):
    b = SceneBuilder()
    at = SpherePath((0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="sphere_radius"):
        b.add_sphere(at, 0.0)
    with pytest.raises(ValueError, match="capsule_radius"):
        b.add_capsule(at, -1.0, (1.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="capsule_length"):
        b.add_capsule(at, 0.1, (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="half_extents"):
        b.add_box(at, (0.1, 0.0, 0.1))
    with pytest.raises(ValueError, match="plane_normal"):
        b.set_plane((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), restitution=0.0)
    with pytest.raises(ValueError, match="spin_axis"):
        SpherePath((0.0, 0.0, 0.0), spin=1.0, spin_axis=(0.0, 0.0, 0.0))


@pytest.mark.parametrize("setting, name", [("sphere_radius=0", "sphere_radius"),
                                           ("capsule_length=0", "capsule_length"),
                                           ("box_half_y=-1", "box_half_y")])
def test_cli_refuses_degenerate_colliders_with_exit_2(tmp_path, capsys, setting, name):
    out = tmp_path / "o.npz"
    assert main(["simulate", "cloth-spin", "--set", setting, "--steps", "1", "--out", str(out)]) == 2
    assert name in capsys.readouterr().err
    assert not out.exists()


# --- drawing --------------------------------------------------------------------------------

def test_capsules_and_boxes_are_drawn_as_closed_outward_meshes(f64):
    from taichi_sim.geometry.primitives import box, capsule
    from taichi_sim.scene.visual import describe

    scene = ts.build_scene("cloth", {"nx": 4, "ny": 4, "capsule": True, "box": True, "box_x": 0.5})
    solids = describe(scene).solids
    assert [p.name for p in scene.parts] == ["capsules", "boxes"] and len(solids) == 2
    assert np.allclose([s.place() for s in solids], [[0.0, 0.4, 0.0], [0.5, 0.2, 0.0]])
    assert np.allclose(solids[0].reach, [0.3 + 0.1, 0.1, 0.1])  # capsule_length 0.6, radius 0.1
    assert ts.build_scene("cloth", {"nx": 4, "ny": 4}).part("capsules") is None  # absent: nothing built
    for (verts, normals, tris), half_axis in ((capsule(np.array([0.3, 0.0, 0.0]), 0.1), 0.3),
                                              (box(np.array([0.2, 0.1, 0.3])), 0.0)):
        a, b, c = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
        face = np.cross(b - a, c - a)
        big = np.linalg.norm(face, axis=1) > 1e-12  # a sphere's poles have degenerate slivers
        centroid = (a + b + c) / 3
        axis_point = np.zeros_like(centroid)
        axis_point[:, 0] = np.clip(centroid[:, 0], -half_axis, half_axis)
        # wound counter-clockwise seen from outside (away from the shape's core), with vertex
        # normals on the same side
        assert np.all(np.einsum("ij,ij->i", face[big], (centroid - axis_point)[big]) > 0)
        assert np.all(np.einsum("ij,ij->i", normals[tris[big, 0]], face[big]) > 0)
