"""A new collider shape is one file: the capped cylinder of tests/cylinder_shape.py, which no
file of the package names, keeps a cloth out inside vbd's solve and in the post-step pass of
another method, and `check` and the start warning judge it (docs/collisions.md, "Adding a
collider shape")."""
import numpy as np
import pytest
from cylinder_shape import Cylinder, CylinderColliders

import taichi_sim as ts
from taichi_sim import io
from taichi_sim.cli import main
from taichi_sim.geometry.inside import INSIDE_TOLERANCE
from taichi_sim.integrators import create_integrator
from taichi_sim.scene import cloth as topo
from taichi_sim.scene.builder import SceneBuilder
from taichi_sim.scene.colliders import SpherePath, shapes

H = 1 / 60
CENTER, RADIUS, HALF = np.array([0.0, 0.2, 0.0]), 0.15, 0.1  # an upright cylinder: its flat top at y = 0.3
TOP = CENTER[1] + HALF


def cloth_over_cylinder(n: int = 12, size: float = 0.6, height: float = 0.45):
    """An n x n cloth of ``size`` (m), flat at ``height`` (m) over the cylinder: its middle lands
    on the flat top, its sides fall past the rim."""
    b = SceneBuilder()
    x = topo.grid_positions(n, n, size, size, origin=(-size / 2, height, -size / 2), u_axis=(1, 0, 0),
                            v_axis=(0, 0, 1))
    b.add_particles(x, 0.01)
    ends, kind = topo.grid_springs(n, n)
    b.add_springs(ends, stiffness=topo.kind_stiffness(kind, {"stiffness": 500.0, "shear_stiffness": 250.0,
                                                             "flex_stiffness": 100.0}), damping=0.01, kind=kind)
    b.add_triangles(topo.grid_triangles(n, n))
    b.set_gravity(9.8)
    b.add_part(Cylinder(SpherePath(tuple(CENTER)), RADIUS, (0.0, HALF, 0.0), friction=0.3))
    return b.finalize(name="cloth-cylinder", params={"thickness": 0.005}, default_dt=H, default_integrator="vbd")


def depth_inside(scene, x) -> float:
    """How deep (m) the deepest vertex of ``x`` lies inside the cylinder (negative: outside)."""
    return float(CylinderColliders.point_depths(x, {**scene.arrays, **scene.object_centers(0.0)}).max())


def test_the_cylinder_is_registered_by_its_own_file_and_its_spec_is_checked():
    assert [kind.key for kind in shapes()][:4] == ["sphere", "capsule", "box", "cylinder"]
    assert shapes()[-1].key == "plane"
    with pytest.raises(ValueError, match="cylinder_radius must be > 0"):
        Cylinder(SpherePath((0.0, 0.0, 0.0)), 0.0, (0.0, 1.0, 0.0))
    with pytest.raises(ValueError, match="half_axis must be a nonzero 3-vector"):
        Cylinder(SpherePath((0.0, 0.0, 0.0)), 1.0, (0.0, 0.0, 0.0))


@pytest.mark.parametrize("args, message", [
    (((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.5), "plane_normal must be a nonzero 3-vector"),
    (((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 1.5), r"restitution must be in \[0, 1\]"),
    (((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 0.5, -0.1), "plane_friction must be >= 0")])
def test_the_ground_plane_spec_refuses_bad_values_by_name(args, message):
    with pytest.raises(ValueError, match=message):
        SceneBuilder().set_plane(*args)


def test_vbd_solve_keeps_a_cloth_falling_on_the_cylinder_out(f64):
    """Every vbd solve ends with no vertex inside the cylinder (measured before the post-step
    events, which are a fail-safe here), and the cloth rests on the flat top, not on the dome of
    the enclosing capsule whose face bound the cylinder falls back to beside its cap planes."""
    scene = cloth_over_cylinder()
    vbd = create_integrator("vbd", scene.system)
    stepper = ts.Stepper(scene, vbd, H)
    for _ in range(45):
        report = vbd.step(scene.state, stepper.t, H)
        assert report.status.value == "ok"
        assert depth_inside(scene, scene.state.to_numpy()[0]) <= INSIDE_TOLERANCE
        stepper.t += H
        scene.after_step(stepper.t, H)
    x = scene.state.to_numpy()[0]
    over_top = np.linalg.norm(x[:, [0, 2]], axis=1) < 0.5 * RADIUS
    assert over_top.sum() >= 4 and np.abs(x[over_top, 1] - TOP).max() < 0.02  # resting on the top


def test_the_post_step_pass_of_another_method_keeps_the_cloth_out_and_check_passes_the_run(f64, tmp_path, capsys):
    scene = cloth_over_cylinder()
    euler = create_integrator("symplectic_euler", scene.system)
    result = ts.run(scene, euler, dt=1e-3, steps=750, save_every=50)
    assert result.status.value == "ok"
    assert max(depth_inside(scene, x) for x in result.x_history) <= INSIDE_TOLERANCE
    x = result.x_history[-1]
    over_top = np.linalg.norm(x[:, [0, 2]], axis=1) < 0.5 * RADIUS
    assert over_top.sum() >= 4 and np.abs(x[over_top, 1] - TOP).max() < 0.02
    path = io.save_npz(tmp_path / "run.npz", io.run_arrays(scene, result, integrator=euler, dt=1e-3))
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert "cloth-cylinder: no vertex inside the cylinders in any frame" in out
    assert "cloth-cylinder: no face reaches into the cylinders in any frame" in out


def hand_made_run(tmp_path, points) -> str:
    """An npz as a run writes it: one frame of a triangle far off and the ``points``, a
    cylinder of radius 0.15 m round the y axis from y = 0.1 to 0.3."""
    x = np.concatenate([[[5.0, 0.0, 0.0], [6.0, 0.0, 0.0], [5.0, 0.0, 1.0]], points]).astype(np.float64)
    path = tmp_path / "hand.npz"
    np.savez(path, scene=np.str_("hand"), triangles=np.array([[0, 1, 2]]), x=x, t=np.float64(0.0),
             cylinder_center=CENTER[None], cylinder_radius=np.array([RADIUS]),
             cylinder_half_axis=np.array([[0.0, HALF, 0.0]]))
    return str(path)


def test_check_judges_the_cylinder_in_a_hand_made_npz(tmp_path, capsys):
    # inside: 1 cm below the top near the rim; outside: 5 cm over the top, within the enclosing
    # capsule (whose test would call it inside)
    inside, outside = [0.14, TOP - 0.01, 0.0], [0.05, TOP + 0.05, 0.0]
    assert main(["check", hand_made_run(tmp_path, [inside])]) == 1
    assert "1 of 1 frame(s) have vertices inside an object; first at t = 0 s, most (1 inside the cylinders)" \
        in capsys.readouterr().out
    assert main(["check", hand_made_run(tmp_path, [outside])]) == 0
    assert "hand: no vertex inside the cylinders in any frame" in capsys.readouterr().out


def test_the_start_warning_names_the_cylinder(f64):
    assert cloth_over_cylinder().start_warning() == ""
    scene = cloth_over_cylinder(height=0.25)
    assert "the cloth starts inside an object (" in scene.start_warning()
    assert "inside the cylinder, of 144 vertices" in scene.start_warning()
