"""The taichi-sim command line: list, simulate, the npz schema, and bad input."""
import os
import subprocess
import sys

import numpy as np
import pytest

from taichi_sim.cli import main
from taichi_sim.integrators import INTEGRATORS
from taichi_sim.scene import SCENES

FIXED_STEP = ["euler", "trapezoid", "midpoint", "rk4", "symplectic_euler"]
TINY = {"simple": [], "spring": [], "pendulum": ["particle_count=4"], "cloth": ["nx=4", "ny=3"]}
COMMON_KEYS = {"x0", "v0", "x", "v", "t", "steps", "f_evals", "integrator", "dt", "status", "mass",
               "pinned", "gravity", "drag", "energy", "energy_t", "accepted_steps", "rejected_steps"}
SPRING_KEYS = {"springs", "rest_length", "stiffness", "spring_damping", "spring_kind"}


def simulate(tmp_path, *args, out="run.npz"):
    path = tmp_path / out
    code = main(["simulate", *args, "--out", str(path), "--quiet"])
    return code, path


def test_list_shows_scenes_parameters_and_integrators(capsys):
    assert main(["list"]) == 0
    text = capsys.readouterr().out
    for preset in SCENES.values():
        assert f"{preset.name}:" in text
        for p in preset.params:
            assert p.name in text and p.meaning in text
    for cls in INTEGRATORS.values():
        assert cls.name in text and f"order {cls.order}" in text
    assert "N/m" in text and "kg" in text


@pytest.mark.parametrize("scene", list(TINY))
@pytest.mark.parametrize("integrator", FIXED_STEP)
def test_every_scene_runs_with_every_integrator(tmp_path, scene, integrator):
    sets = [a for s in TINY[scene] for a in ("--set", s)]
    code, path = simulate(tmp_path, scene, "--integrator", integrator, "--steps", "20", *sets)
    if integrator == "symplectic_euler" and scene == "simple":
        assert code == 2 and not path.exists()  # a first-order system has no velocities
        return
    assert code == 0
    data = np.load(path)
    assert COMMON_KEYS <= set(data.files)
    assert (SPRING_KEYS <= set(data.files)) == (scene != "simple")
    n = len(data["mass"])
    for key in ("x0", "v0", "x", "v"):
        assert data[key].shape == (n, 3) and np.isfinite(data[key]).all()
    assert data["pinned"].shape == (n,) and data["pinned"].dtype == bool
    assert data["gravity"].shape == (3,) and data["drag"].shape == ()
    assert str(data["status"]) == "ok" and str(data["integrator"]) == integrator
    assert int(data["steps"]) == 20 and float(data["t"]) == pytest.approx(20 * float(data["dt"]))
    # sampled at the start, at the guard's checks (1, 2, 4, 8, 16 f-evaluations apart: steps 1,
    # 3, 7, 15 with one f-evaluation per step, 1, 2, 4, 8, 16 with two, ...) and at the end
    assert 5 <= len(data["energy"]) <= 8 and data["energy_t"][0] == 0
    assert np.all(np.diff(data["energy_t"]) > 0) and data["energy_t"][-1] == pytest.approx(float(data["t"]))
    if scene != "simple":
        S = len(data["springs"])
        assert data["springs"].shape == (S, 2)
        for key in SPRING_KEYS - {"springs"}:
            assert data[key].shape == (S,)
        assert set(np.unique(data["spring_kind"])) <= {0, 1, 2}


def test_simulate_prints_and_saves_steps_per_second_after_the_first(tmp_path, capsys):
    path = tmp_path / "rate.npz"
    assert main(["simulate", "spring", "--steps", "50", "--out", str(path)]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    data = np.load(path)
    rate, wall = float(data["steps_per_second"]), float(data["wall_time"])
    assert rate > 49 / wall  # the first step (compiling) left out: faster than over the whole run
    assert f"({rate:,.0f} steps/s after the first)" in line


def test_set_values_reach_the_scene_and_t_end_lands(tmp_path):
    code, path = simulate(tmp_path, "cloth", "--set", "nx=5", "--set", "ny=3", "--set", "stiffness=123",
                          "--set", "density=0.3", "--set", "area_drag=7.5", "--set", "gravity=3",
                          "--dt", "0.004", "--t-end", "0.01", "--precision", "f32")
    assert code == 0
    data = np.load(path)
    assert len(data["mass"]) == 15 and np.allclose(data["mass"], 0.02, rtol=1e-12)
    assert np.all(data["stiffness"][data["spring_kind"] == 0] == 123)
    assert np.isclose(float(data["drag"]), 0.5, rtol=1e-12) and data["gravity"].tolist() == [0, -3, 0]
    assert float(data["t"]) == 0.01 and int(data["steps"]) == 3


@pytest.mark.parametrize("args, problem", [
    (["nosuch", "--steps", "3"], "nosuch"),
    (["cloth", "--integrator", "leapfrog", "--steps", "3"], "leapfrog"),
    (["cloth", "--set", "wobble=3", "--steps", "3"], "wobble"),
    (["cloth", "--set", "nx", "--steps", "3"], "NAME=VALUE"),
    (["cloth", "--set", "nx=three", "--steps", "3"], "nx"),
    (["cloth", "--dt", "0", "--steps", "3"], "--dt"),
    (["cloth", "--dt", "-0.1", "--steps", "3"], "--dt"),
    (["cloth", "--dt", "nan", "--steps", "3"], "--dt"),
    (["cloth", "--dt", "inf", "--steps", "3"], "--dt"),
    (["spring", "--set", "particle_mass=0", "--steps", "3"], "particle_mass"),
    (["pendulum", "--set", "particle_mass=-1", "--steps", "3"], "particle_mass"),
    (["cloth", "--set", "nx=1", "--steps", "3"], "nx"),
    (["cloth", "--set", "stiffness=-5", "--steps", "3"], "stiffness"),
    (["cloth", "--set", "gravity=nan", "--steps", "3"], "gravity"),
    (["cloth"], "--steps"),
    (["cloth", "--steps", "0"], "--steps"),
    (["cloth", "--steps", "3", "--t-end", "1"], "--t-end"),
    (["cloth", "--steps", "3", "--precision", "f16"], "precision"),
    (["cloth", "--steps", "3", "--rtol", "1e-3"], "rtol"),
    (["spring", "--steps", "3", "--max-energy-growth", "0"], "--max-energy-growth"),
    (["spring", "--steps", "3", "--max-energy-growth", "nan"], "--max-energy-growth"),
    (["spring", "--steps", "3", "--integrator", "implicit_euler", "--newton-tolerance", "2"],
     "--newton-tolerance: must be a finite number in (0, 1), got 2"),
    (["spring", "--steps", "3", "--integrator", "implicit_euler", "--newton-tolerance", "0"],
     "--newton-tolerance"),
    (["spring", "--steps", "3", "--integrator", "implicit_euler", "--newton-iterations", "0"],
     "--newton-iterations"),
    (["spring", "--steps", "3", "--integrator", "implicit_euler", "--cg-tolerance", "-1"],
     "--cg-tolerance"),
    (["spring", "--steps", "3", "--newton-tolerance", "1e-6"], "newton_tolerance"),
])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, args, problem):
    code, path = simulate(tmp_path, *args)
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert problem in err and len(err.splitlines()) == 1 and err.startswith("taichi-sim: error:")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("out, problem", [
    ("missing_dir/run.npz", "does not exist"), ("run.txt", ".npz"), ("adir.npz", "directory"),
])
def test_unwritable_output_exits_2_before_running(tmp_path, capsys, out, problem):
    (tmp_path / "adir.npz").mkdir()
    code = main(["simulate", "spring", "--steps", "3", "--out", str(tmp_path / out)])
    err = capsys.readouterr().err
    assert code == 2 and problem in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir.npz"]


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc")
def test_an_output_folder_that_refuses_files_exits_2_before_running(capsys):
    """/proc passes os.access for root, but no file can be created there: refused at once."""
    code = main(["simulate", "spring", "--steps", "3", "--out", "/proc/taichi-sim-run.npz"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("taichi-sim: error: cannot write '/proc/taichi-sim-run.npz': ")
    assert len(err.splitlines()) == 1 and "spring:" not in err
    assert not os.path.exists("/proc/taichi-sim-run.npz")
    assert main(["record", "spring", "--out", "/proc/taichi-sim-clip.gif"]) == 2
    assert capsys.readouterr().err.startswith("taichi-sim: error: cannot write '/proc/taichi-sim-clip.gif': ")


def test_diverged_run_writes_status_and_exits_1(tmp_path, capsys):
    code, path = simulate(tmp_path, "cloth", "--set", "nx=6", "--set", "ny=6", "--set", "stiffness=1e6",
                          "--integrator", "euler", "--dt", "0.01", "--t-end", "30")
    assert code == 1
    assert "diverged at step" in capsys.readouterr().err
    data = np.load(path)
    assert str(data["status"]) == "diverged" and float(data["t"]) < 30
    # The state written is the last that passed the blow-up check, before the failing step
    assert np.isfinite(data["x"]).all() and np.isfinite(data["v"]).all()
    # (the guard looks at sampled states, so that may be a few steps before the failing one)
    assert 0 <= int(data["steps"]) < int(data["failed_step"])
    assert float(data["failed_t"]) == pytest.approx(0.01 * int(data["failed_step"]))
    assert np.isfinite(data["energy"]).all()


def test_a_lower_energy_bound_reports_sooner(tmp_path, capsys):
    args = ["pendulum", "--integrator", "euler", "--dt", "0.008", "--t-end", "3", "--energy-every", "1"]
    default = np.load(simulate(tmp_path, *args, out="a.npz")[1])
    tight_code, tight_path = simulate(tmp_path, *args, "--max-energy-growth", "0.5", out="b.npz")
    tight = np.load(tight_path)
    assert tight_code == 1 and "past the bound" in capsys.readouterr().err
    assert 0 < int(tight["failed_step"]) < int(default["failed_step"])


def test_module_and_console_script_entry_points(tmp_path):
    out = subprocess.run([sys.executable, "-m", "taichi_sim", "list"], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0 and "cloth" in out.stdout
    script = os.path.join(os.path.dirname(sys.executable), "taichi-sim")
    path = tmp_path / "s.npz"
    done = subprocess.run([script, "simulate", "spring", "--steps", "5", "--out", str(path)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("spring: 5 steps") and path.exists()
    assert "[Taichi]" not in done.stdout
