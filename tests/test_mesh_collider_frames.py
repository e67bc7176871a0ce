"""An animated collider mesh (a sequence of frames, taichi_sim.scene.colliders.mesh_frames): it
carries the cloth as the rigid path does, drags it by friction with its surface velocity,
turns under it without letting it through, holds its last frame, and comes from numbered
files of one topology (others refused before anything runs)."""
import math

import numpy as np
import pytest
import trimesh
from test_mesh_collider import SKIN, cloth, rotation_z

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.errors import ConfigError
from taichi_sim.render.drawer import DrawOptions, SceneDrawer
from taichi_sim.scene.colliders import SpherePath, load_mesh_file
from taichi_sim.scene.visual import describe

PLATE = trimesh.creation.box(extents=(1.0, 0.02, 1.0))


def moved(vertices, offsets):
    """(F, V, 3): ``vertices`` moved by each of ``offsets`` (F, 3)."""
    return np.asarray(vertices)[None] + np.asarray(offsets, float)[:, None, :]


def rising_plate_scene(animated: bool):
    """The cloth of test_mesh_collider's fast plate: the plate rising at 5 m/s, 5 cm a step."""
    b = cloth(12, 0.5, 0.1, gravity=0.0)
    if animated:  # 11 frames 0.01 s apart, the same motion as the path's
        frames = moved(PLATE.vertices, [(0.0, 0.05 * k, 0.0) for k in range(11)])
        b.add_mesh_collider(frames, PLATE.faces, skin=SKIN, fps=100.0)
    else:
        b.add_mesh_collider(PLATE.vertices, PLATE.faces, path=SpherePath((0.0, 0.0, 0.0), velocity=(0.0, 5.0, 0.0)),
                            skin=SKIN)
    return b.finalize(name="lift", params={}, default_dt=1e-2, default_integrator="symplectic_euler")


def test_a_rising_frame_sequence_carries_the_cloth_as_the_same_rigid_motion_does(f64):
    runs = []
    for animated in (False, True):
        scene = rising_plate_scene(animated)
        assert ts.run(scene, "symplectic_euler", dt=1e-2, steps=10).status.value == "ok"
        runs.append(scene.state.to_numpy())
    (x_path, v_path), (x_frames, v_frames) = runs
    assert np.allclose(x_frames[:, 1], 0.5 + 0.01 + SKIN, atol=1e-9)  # on the plate's top
    assert np.allclose(x_frames, x_path, atol=1e-9) and np.allclose(v_frames, v_path, atol=1e-9)
    # the sequence has ended (10 segments, 0.1 s): the plate holds its last frame
    assert np.allclose(scene.part("collider_mesh").player.velocities(0.2), 0.0)
    assert np.allclose(scene.arrays["collider_mesh_vertices"], PLATE.vertices + [0.0, 0.5, 0.0])
    scene.reset()
    assert np.allclose(scene.arrays["collider_mesh_vertices"], PLATE.vertices)


def drag(friction):
    """How far (m, along x) a cloth resting on a plate moves while the plate slides 0.25 m."""
    b = cloth(8, 0.3, 0.01 + SKIN)
    frames = moved(PLATE.vertices, [(0.05 * k, 0.0, 0.0) for k in range(6)])  # 0.5 m/s at 10 fps
    b.add_mesh_collider(frames, PLATE.faces, skin=SKIN, friction=friction, fps=10.0)
    scene = b.finalize(name="drag", params={}, default_dt=5e-3, default_integrator="symplectic_euler")
    start = scene.state.to_numpy()[0].mean(axis=0)
    assert ts.run(scene, "symplectic_euler", dt=5e-3, steps=100).status.value == "ok"
    x = scene.state.to_numpy()[0]
    assert x[:, 1].min() >= 0.01 + SKIN * (1 - 1e-6)  # never into the plate
    return float(x.mean(axis=0)[0] - start[0])


def test_friction_drags_the_cloth_with_the_surface_velocity_of_the_frames(f64):
    held, free = drag(1.0), drag(0.0)
    # mu g = 9.8 m/s^2 brings the cloth to the plate's 0.5 m/s in 0.05 s: it slides with it
    assert held == pytest.approx(0.25, abs=0.02)
    assert abs(free) < 1e-9


def test_a_plate_turning_under_a_resting_cloth_lifts_it_without_letting_a_vertex_through(f64):
    turns = [rotation_z(math.radians(2.0 * k)) for k in range(16)]  # 30 degrees in 0.3 s at 50 fps
    frames = np.stack([PLATE.vertices @ r.T for r in turns])
    b = cloth(12, 0.6, 0.01 + SKIN, gravity=9.81)
    b.add_mesh_collider(frames, PLATE.faces, skin=SKIN, friction=0.8, fps=50.0)
    scene = b.finalize(name="tilt", params={}, default_dt=5e-3, default_integrator="symplectic_euler")
    player = scene.part("collider_mesh").player
    visual = describe(scene)
    drawer = SceneDrawer(visual)  # built with the plate level, drawn as it turns
    stepper = ts.Stepper(scene, "symplectic_euler", 5e-3)
    for step in range(1, 81):
        stepper.step(check=True)
        assert stepper.failure is None
        normal = rotation_z(math.radians(min(100 * step * 5e-3, 30.0)))[:, 1]
        height = scene.state.to_numpy()[0] @ normal  # above the plate's middle plane
        assert height.min() >= 0.01 + SKIN * (1 - 1e-3), step
        assert np.allclose(scene.arrays["collider_mesh_vertices"], player.vertices(step * 5e-3))
    assert np.allclose(height, 0.01 + SKIN, atol=1e-4)  # friction 0.8 > tan 30 holds it on the plate
    assert scene.state.to_numpy()[0][:, 1].max() > 0.15  # turned with it, one side lifted
    (solid,) = visual.solids
    shape, normals = solid.pose()
    assert np.allclose(shape, frames[-1][PLATE.faces].reshape(-1, 3))
    assert np.allclose(normals, np.repeat(scene.part("collider_mesh").normals_np, 3, axis=0))
    drawer.sync(scene.state.x)
    drawer.update(DrawOptions(), eye=(0.0, 1.0, 3.0))
    assert np.allclose(drawer.solid_vertices.to_numpy(), shape, atol=1e-6)
    assert np.allclose(drawer.solid_normals.to_numpy(), normals, atol=1e-6)


def write_frames(folder, offsets, name="plate"):
    folder.mkdir(exist_ok=True)
    for k, offset in enumerate(offsets):
        trimesh.Trimesh(PLATE.vertices + offset, PLATE.faces, process=False).export(folder / f"{name}_{k}.obj")
    return str(folder / f"{name}_*.obj")


def test_numbered_files_load_as_frames_in_natural_order_and_other_topologies_are_refused(tmp_path):
    pattern = write_frames(tmp_path / "ok", [(0.0, 0.01 * k, 0.0) for k in range(12)])
    frames, triangles = load_mesh_file(pattern)
    assert frames.shape == (12, 8, 3) and np.array_equal(triangles, PLATE.faces)
    assert np.allclose(frames[:, :, 1].mean(axis=1), 0.01 * np.arange(12))  # plate_10 after plate_9
    bad = write_frames(tmp_path / "bad", [(0.0, 0.0, 0.0)] * 2)
    trimesh.creation.icosphere().export(tmp_path / "bad" / "plate_2.obj")
    with pytest.raises(ConfigError, match="frame 2 .*differs in topology"):
        load_mesh_file(bad)
    with pytest.raises(ConfigError, match="no file matches"):
        load_mesh_file(str(tmp_path / "none_*.obj"))


def test_the_cli_and_a_scene_file_play_numbered_frames_and_refuse_a_bad_sequence(f64, tmp_path, capsys):
    pattern = write_frames(tmp_path / "frames", [(0.0, 0.2 + 0.01 * k, 0.0) for k in range(4)])
    out = tmp_path / "run.npz"
    common = ["--set", "nx=6", "--set", "ny=6", "--set", "pin=none", "--set", "height=0.3", "--steps", "200"]
    assert main(["simulate", "cloth", "--set", f"collider_mesh={pattern}", "--set", "collider_mesh_fps=20",
                 *common, "--out", str(out)]) == 0
    saved = np.load(out)
    assert np.allclose(saved["collider_mesh_vertices"], PLATE.vertices + [0.0, 0.23, 0.0])  # the last, held
    scene_file = tmp_path / "scene.toml"
    scene_file.write_text('scene = "cloth"\n[parameters]\ncollider_mesh = "frames/plate_*.obj"\nnx = 6\nny = 6\n'
                          '[run]\nsteps = 2\n[output]\nnpz = "file.npz"\n')
    assert main(["simulate", str(scene_file)]) == 0 and (tmp_path / "file.npz").exists()
    scene_file.write_text('scene = "cloth"\n[parameters]\ncollider_mesh = "frames/other_*.obj"\n')
    assert main(["simulate", str(scene_file)]) == 2
    assert "no file matches 'frames/other_*.obj'" in capsys.readouterr().err
    trimesh.creation.icosphere().export(tmp_path / "frames" / "plate_4.obj")
    refused = tmp_path / "refused.npz"
    assert main(["simulate", "cloth", "--set", f"collider_mesh={pattern}", *common, "--out", str(refused)]) == 2
    assert "differs in topology" in capsys.readouterr().err and not refused.exists()
