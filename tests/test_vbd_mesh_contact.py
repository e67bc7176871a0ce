"""A moving collider mesh inside vbd's solve (integrators/positional/vbd/mesh_contact.py),
judged through the CLI by `taichi-sim check` on every saved frame: a skirt with self-contact on
a body whose right leg kicks forward 60 degrees in 1/3 s, and a paddle turning through a
hanging sheet faster than the sheet's spacing a step. Only the vertices are judged: the cloth's
triangles against the mesh's edges are not in the solve (a box's edge pokes between vertices).
Both fail with the mesh met after the step instead (its post-step pass, vbd option contact=0)."""
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
    x = np.load(tmp_path / "paddle.npz")["x_history"]
    assert x[-1][:, 2].max() > 0.1  # the paddle swept the sheet's lower part forward
