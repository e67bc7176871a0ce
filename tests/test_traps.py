"""Traps a first user fell into: each one line naming the real problem, in one round."""
import io

import numpy as np
import pytest
from PIL import Image

from taichi_sim.cli import main
from taichi_sim.render.overlay import WARNING, Label, burn, font, word_layout


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("taichi-sim: error: "), err
    assert "Traceback" not in err
    return lines[0]


@pytest.mark.parametrize("names, expected", [
    ("rk4,vdb", "unknown integrator 'vdb': did you mean 'vbd'?"),  # two letters swapped
    ("implicit", "did you mean 'implicit_euler', 'implicit_euler_linearised' or 'implicit_midpoint'?"),
])
def test_advise_suggests_the_integrator_meant(capsys, names, expected):
    assert main(["advise", "spring", "--integrators", names]) == 2
    line = _one_line_error(capsys)
    assert expected in line and "choose from" not in line


@pytest.mark.parametrize("argv, expected", [
    (["advise", "--frobnicate"], "unrecognized arguments: --frobnicate"),  # not "required: scene"
    (["advise", "--frobnicate=3", "--integrators", "rk4"], "unrecognized arguments: --frobnicate=3"),
    (["advise", "spring", "--integrator", "rk4"], "unrecognized arguments: --integrator; did you mean --integrators?"),
    (["simulate", "--steps", "1", "--stepz", "2"], "unrecognized arguments: --stepz; did you mean --steps?"),
])
def test_an_unknown_option_is_named_before_a_missing_argument(capsys, argv, expected):
    assert main(argv) == 2
    assert expected in _one_line_error(capsys)


def test_a_negative_number_is_still_a_value_not_an_unknown_option(capsys, tmp_path):
    assert main(["simulate", "spring", "--steps", "1", "--dt", "-1", "--out", str(tmp_path / "r.npz")]) == 2
    assert "argument --dt: must be a finite number > 0, got -1" in _one_line_error(capsys)


def test_a_picture_named_stl_is_not_a_readable_mesh(tmp_path, capsys):
    png = io.BytesIO()
    Image.fromarray(np.full((64, 64, 3), 200, np.uint8)).save(png, format="PNG")
    path = tmp_path / "shirt.stl"
    path.write_bytes(png.getvalue())
    out = tmp_path / "run.npz"
    assert main(["simulate", "mesh", "--set", f"file={path}", "--steps", "1", "--out", str(out)]) == 2
    line = _one_line_error(capsys)
    assert f"mesh file {path}: is not a readable STL mesh" in line and "module" not in line
    assert not out.exists()


def test_simulate_names_every_missing_thing_at_once(capsys):
    assert main(["simulate", "cloth"]) == 2
    line = _one_line_error(capsys)
    assert "--steps N or --t-end T" in line and "--out FILE.npz" in line


def test_spaces_in_a_label_stay_visible_at_the_smallest_size():
    size = 11  # what a 300-pixel-tall GIF gets (the integrators strip)
    words, width = word_layout("diverged at t = 0.248 s", size)
    assert [w for w, _ in words] == ["diverged", "at", "t", "=", "0.248", "s"]
    f = font(size)
    gaps = [x - (px + f.getlength(pw)) for (pw, px), (_, x) in zip(words, words[1:])]
    assert min(gaps) >= 0.4 * size
    assert width == pytest.approx(words[-1][1] + f.getlength("s"))
    # In the burnt frame "at t" shows two groups of ink with a gap of blank columns between
    # them: Pillow's own 2-pixel space, next to the letters' bearings, left at most one.
    image = burn(np.zeros((300, 200, 3), np.uint8), [Label("at t", 20, 50, WARNING, anchor="lt")])
    columns = np.flatnonzero((image[..., 0] > 80).any(axis=0))  # red ink, not the dark box
    assert np.diff(columns).max() - 1 >= 3, columns
