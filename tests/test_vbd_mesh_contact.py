"""A moving collider mesh inside vbd's solve (integrators/positional/vbd/mesh_contact.py),
judged through the CLI by `taichi-sim check` on every saved frame: a skirt with self-contact on
a body whose right leg kicks forward 60 degrees in 1/3 s, and a paddle turning through a
hanging sheet faster than the sheet's spacing a step; and, through the API, a thin plate on a
fast rigid path lifting a free cloth. The CLI tests judge the vertices and the faces (the
coarse body's and the paddle's edges against the cloth's triangles: mesh_faces.py).
The CLI tests fail with the mesh met after the step instead (its post-step pass), and the first
three without the contact planes carried to the piece's end; the plate coming at a sheet past a
nearer wall fails with the body's pace taken from each vertex's nearest triangle alone."""
import kicking_body as body
import numpy as np

from taichi_sim.cli import main

DT = "0.016666666666666666"


def simulate_and_check(capsys, args: list[str], out: str) -> str:
    """Run ``simulate`` with ``args`` and return what ``check`` prints about ``out``."""
    assert main(["simulate", *args, "--integrator", "vbd", "--precision", "f32", "--dt", DT, "--save-every", "1",
                 "--out", out, "--quiet"]) == 0
    capsys.readouterr()
    main(["check", out])
    return capsys.readouterr().out


def test_a_skirt_with_self_contact_on_a_kicking_leg_is_not_passed_through(tmp_path, capsys):
    frames, triangles = body.body_frames(sections=12)
    pattern = body.write_frames(str(tmp_path / "body"), frames, triangles)
    skirt = str(tmp_path / "skirt.obj")
    body.write_skirt(skirt, gores=8, gore_columns=6, rows=12, length=0.35, hem_radius=0.22)
    report = simulate_and_check(capsys, [
        "mesh", "--set", f"file={skirt}", "--set", "pin=top:0.005", "--set", "self_collision=1",
        "--set", f"collider_mesh={pattern}", "--t-end", "0.45"], str(tmp_path / "kick.npz"))
    assert "no triangles intersect" in report
    assert "no vertex inside the collider mesh in any frame" in report
    assert "no face reaches into the collider mesh in any frame" in report  # the coarse body's edges
    # the leg reached the cloth: it is pushed forward (+z) at the front
    x = np.load(tmp_path / "kick.npz")["x_history"]
    assert x[-1][:, 2].max() > x[0][:, 2].max() + 0.05


def test_a_fast_paddle_through_a_hanging_sheet_does_not_pass_it(tmp_path, capsys):
    frames, triangles = body.paddle_frames(duration=0.4)  # its tip at 3.5 m/s: 59 mm, 1.8 spacings a step
    pattern = body.write_frames(str(tmp_path / "paddle"), frames, triangles, name="paddle")
    sheet = str(tmp_path / "sheet.obj")
    body.write_sheet(sheet, n=16)  # 33 mm apart
    report = simulate_and_check(capsys, [
        "mesh", "--set", f"file={sheet}", "--set", "pin=top:0.005", "--set", f"collider_mesh={pattern}",
        "--set", "collider_mesh_fps=60", "--t-end", "0.45"], str(tmp_path / "paddle.npz"))
    assert "no vertex inside the collider mesh in any frame" in report
    assert "no face reaches into the collider mesh in any frame" in report  # the paddle's edges
    x = np.load(tmp_path / "paddle.npz")["x_history"]
    assert x[-1][:, 2].max() > 0.1  # the paddle swept the sheet's lower part forward


def test_a_thin_plate_on_a_fast_path_lifts_a_cloth_in_the_solve(f64):
    """A 2 cm plate rising at 3 m/s, 5 cm (2.4 cloth spacings) a step, under a free cloth: in
    vbd's solve it lifts the cloth, no vertex inside it after any step."""
    import trimesh
    from test_mesh_collider import SKIN, box_distance, cloth

    from taichi_sim.integrators import create_integrator
    from taichi_sim.scene.colliders import SpherePath
    from taichi_sim.stepper import Stepper

    plate = trimesh.creation.box(extents=(0.3, 0.02, 0.3))
    b = cloth(12, 0.5, 0.5, gravity=0.0)
    path = SpherePath((0.0, 0.3, 0.0), velocity=(0.0, 3.0, 0.0))
    b.add_mesh_collider(plate.vertices, plate.faces, path=path, skin=SKIN)
    scene = b.finalize(name="lift", params={}, default_dt=1 / 60, default_integrator="vbd")
    vbd = create_integrator("vbd", scene.system)
    stepper = Stepper(scene, vbd, dt=1 / 60)
    assert "collider_mesh" in vbd.takeover.parts
    for _ in range(15):  # the plate from 0.3 m to 1.05 m
        stepper.step()
        x = scene.state.to_numpy()[0]
        centre = path.at(stepper.t)[0]
        assert box_distance(x, centre, [0.15, 0.01, 0.15]).min() > 0.0, stepper.t
    top = path.at(stepper.t)[0][1] + 0.01
    # carried on the plate (its free sides trail and wrap round the plate's edges)
    assert x[:, 1].max() > top + SKIN and x[:, 1].mean() > 0.5 + 0.3


def test_a_plate_coming_at_a_sheet_past_a_nearer_wall_pushes_it(tmp_path, capsys):
    """A static wall 30 mm behind a hanging sheet and a 20 mm plate 40 mm in front of it that
    comes at it at 3 m/s (50 mm, 1.5 spacings, in the first step) and stops 20 mm before the
    wall, in one mesh: every sheet vertex has the wall nearest, so a pace judged on the nearest
    triangle alone lets the plate pass over the sheet in one piece (vertices left inside it);
    the pace over every triangle within reach pushes the sheet into the gap."""
    import trimesh

    wall = trimesh.creation.box(extents=(0.3, 0.3, 0.03))
    wall.apply_translation((0.0, 0.75, -0.045))  # its front face at z = -0.03
    plate = trimesh.creation.box(extents=(0.12, 0.12, 0.02))
    plate.apply_translation((0.0, 0.75, 0.05))  # its back face at z = 0.04, then at -0.01
    triangles = np.concatenate([wall.faces, plate.faces + len(wall.vertices)])
    frames = [np.concatenate([wall.vertices, plate.vertices + (0.0, 0.0, dz)]) for dz in (0.0, -0.05, -0.05, -0.05)]
    pattern = body.write_frames(str(tmp_path / "wall"), np.stack(frames), triangles, name="wall")
    sheet = str(tmp_path / "sheet.obj")
    body.write_sheet(sheet, n=16)  # 33 mm apart
    report = simulate_and_check(capsys, [
        "mesh", "--set", f"file={sheet}", "--set", "pin=top:0.005", "--set", f"collider_mesh={pattern}",
        "--set", "collider_mesh_fps=60", "--option", "object_faces=0", "--t-end", "0.05"], str(tmp_path / "w.npz"))
    assert "no vertex inside the collider mesh in any frame" in report
    x = np.load(tmp_path / "w.npz")["x_history"]
    behind = (np.abs(x[0][:, 0]) < 0.05) & (np.abs(x[0][:, 1] - 0.75) < 0.05)  # under the plate's middle
    assert behind.any() and (x[1][behind, 2] < -0.01).all()  # in the gap behind the plate after one step
