"""What a new user meets first: option spelling, help, version, file modes, sizes, messages."""
import argparse
import os
import tomllib
from pathlib import Path

import numpy as np
import pytest

from taichi_sim.cli import build_parser, main
from taichi_sim.integrators import integrator_class

ROOT = Path(__file__).resolve().parent.parent


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("taichi-sim: error: "), err
    assert "Traceback" not in err
    return lines[0]


@pytest.mark.parametrize("argv, problem", [
    (["simulate", "simple", "--steps", "3", "--set", "radius=1", "--set", "radius=2"], "radius given twice"),
    (["simulate", "simple", "--t-end", "1", "--step", "5"], "unrecognized arguments: --step"),
    (["simulate", "simple", "--steps", "3", "--integ", "rk4"], "unrecognized arguments: --integ"),
    (["advise", "spring", "--set", "stiffness=1", "--set", "stiffness=2"], "stiffness given twice"),
    (["record", "cloth", "--set", "nx=4", "--set", "nx=5", "--out", "x.gif"], "nx given twice"),
    (["bench", "extremes", "--out", "x", "--step-s", "1"], "unrecognized arguments: --step-s"),
])
def test_repeated_set_and_abbreviated_options_are_errors(tmp_path, capsys, argv, problem):
    argv = [str(tmp_path / a) if a in ("x.gif", "x") else a for a in argv]
    out = tmp_path / "run.npz"
    extra = ["--out", str(out)] if argv[0] == "simulate" else []
    assert main(argv + extra) == 2
    assert problem in _one_line_error(capsys)
    assert not out.exists() and not (tmp_path / "x.gif").exists() and not (tmp_path / "x").exists()


def _parsers(parser: argparse.ArgumentParser):
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _parsers(sub)


def test_every_parser_refuses_abbreviations():
    parsers = list(_parsers(build_parser()))
    assert len(parsers) >= 10  # the top level, 6 commands, 5 benchmarks
    assert all(p.allow_abbrev is False for p in parsers)


def test_version_comes_from_the_package_metadata(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert capsys.readouterr().out.strip() == f"taichi-sim {version}"


def test_simulate_help_explains_every_option(capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for words in ("--steps N number of steps", "--precision {f32,f64} floating-point precision",
                  "--arch {cpu,gpu} where the simulation runs", "--seed SEED random seed"):
        assert words in text
    sim = next(p for p in _parsers(build_parser()) if p.prog.endswith("simulate"))
    assert all(a.help for a in sim._actions), [a.dest for a in sim._actions if not a.help]


def test_bench_all_help_says_what_all_runs(capsys):
    with pytest.raises(SystemExit):
        main(["bench", "all", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "work-precision, stability and throughput, one after the other" in text
    assert "all.csv" not in text and "extremes is not included" in text


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_npz_respects_the_umask(tmp_path, umask, mode):
    from taichi_sim import io

    old = os.umask(umask)
    try:
        path = io.save_npz(tmp_path / "run.npz", {"t": np.float64(0.2), "x": np.zeros((4, 3))})
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == mode
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.npz"]  # no temporary left
    assert float(np.load(path)["t"]) == 0.2


def test_a_failed_npz_write_leaves_nothing(tmp_path):
    from taichi_sim import io

    class Unsaveable:
        def __array__(self, *args, **kwargs):
            raise RuntimeError("cannot convert")

    with pytest.raises(RuntimeError):
        io.save_npz(tmp_path / "run.npz", {"x": Unsaveable()})
    assert list(tmp_path.iterdir()) == []


def test_an_impossible_cloth_is_refused_with_its_size(tmp_path, capsys):
    out = tmp_path / "run.npz"
    assert main(["simulate", "cloth", "--set", "nx=100000", "--set", "ny=100000", "--steps", "1",
                 "--out", str(out)]) == 2
    line = _one_line_error(capsys)
    assert "nx = 100000, ny = 100000" in line and "needs about" in line and "TB" in line
    assert "10,000,000,000 particles" in line and "available" in line
    assert not out.exists()


def test_the_api_refuses_a_scene_larger_than_memory_naming_the_parameter(f64):
    import taichi_sim as ts

    with pytest.raises(ts.ConfigError, match="capacity = 2000000000"):
        ts.build_scene("sprinkler", {"capacity": 2_000_000_000})
    with pytest.raises(ValueError, match="particle_count = 1000000000"):
        ts.build_scene("pendulum", {"particle_count": 10**9})


def test_memory_check_against_what_is_available():
    from taichi_sim.memory import Size, check_size, estimate_bytes

    size = Size(1000, 6000, 2000)
    need = estimate_bytes(size, integrators=(integrator_class("rk4"),))
    assert check_size(size, "nx = 10", integrators=(integrator_class("rk4"),), available=need) == need
    with pytest.raises(ValueError, match=rf"nx = 10: the scene needs about {need / 1e6:.3g} MB .* only 1 MB"):
        check_size(size, "nx = 10", integrators=(integrator_class("rk4"),), available=10**6)
    # scratch grows with the method; f32 halves the reals; side-by-side copies add up
    assert estimate_bytes(size, integrators=(integrator_class("implicit_euler"),)) > need > estimate_bytes(size, integrators=(integrator_class("euler"),))
    assert estimate_bytes(size, precision="f32") < estimate_bytes(size)
    assert estimate_bytes(size, copies=2) > 1.9 * estimate_bytes(size)
    with pytest.raises(ValueError, match="32-bit field indices"):
        check_size(Size(3 * 10**9, 0), "capacity = 3000000000", available=10**15)


def test_the_estimate_covers_what_a_build_allocates_in_numpy(f64):
    import tracemalloc

    import taichi_sim as ts
    from taichi_sim.memory import estimate_bytes
    from taichi_sim.scene import SCENES
    from taichi_sim.scene.params import resolve

    values = resolve(SCENES["cloth"].params, "cloth", {"nx": 64, "ny": 64})
    size = SCENES["cloth"].size(values)
    tracemalloc.start()
    try:
        scene = ts.build_scene("cloth", {"nx": 64, "ny": 64})
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert (size.particles, size.springs, size.triangles) == (
        scene.particle_count, scene.features["springs"], scene.features["triangles"])
    assert peak < estimate_bytes(size) < 4 * peak


LAVAPIPE_LOG = (  # what Taichi 1.7.4 logs at trace level on a machine without CUDA, in part
    "[W 11/23/26 22:41:42.519 3134] [cuda_driver.cpp:load_lib@36] libcuda.so lib not found.\n"
    "[T 11/23/26 22:41:42.566 3134] [vulkan_device_creator.cpp:pick_physical_device@439] "
    "RHI Debug : Found Vulkan Device 0 (llvmpipe (LLVM 15.0.6, 256 bits))\n")


@pytest.mark.parametrize("backend, log, expected", [
    ("vulkan", LAVAPIPE_LOG,
     "no CUDA driver (libcuda.so not found); running on Vulkan with a software device, "
     "llvmpipe (LLVM 15.0.6, 256 bits): it computes on the CPU, usually slower than --arch cpu"),
    ("vulkan", LAVAPIPE_LOG.replace("llvmpipe", "NVIDIA RTX A4000"),
     "no CUDA driver (libcuda.so not found); running on Vulkan (NVIDIA RTX A4000 (LLVM 15.0.6, 256 bits))"),
    ("cuda", "", "running on CUDA"),
    ("x64", LAVAPIPE_LOG.splitlines()[0], "no CUDA driver (libcuda.so not found); no GPU backend available, "
                                          "running on the CPU (x64)"),
])
def test_gpu_choice_in_one_line(backend, log, expected):
    from taichi_sim.runtime import describe_gpu_choice

    assert describe_gpu_choice(backend, log) == expected


def test_arch_gpu_never_probes_opengl(monkeypatch, capfd):
    """On a machine with Mesa's EGL and no Vulkan driver, Taichi's probe of OpenGL (next in
    its own GPU list) ends the process with a segmentation fault: --arch gpu must stop at
    the backends the package supports and fall back to the CPU."""
    import taichi as ti
    from taichi.lang import misc

    import taichi_sim as ts

    asked = []

    def no_gpu(arch):
        asked.append(arch)
        return arch == ti.cpu

    monkeypatch.setattr(misc, "is_arch_supported", no_gpu)
    try:
        ts.init(arch="gpu", precision="f32")
        backend = ts.runtime.backend()
    finally:
        monkeypatch.undo()
        ts.init(arch="cpu", precision="f64")
    assert ti.opengl not in asked and ti.gles not in asked, asked
    assert ti.vulkan in asked and backend in ("x64", "arm64")
    assert "no GPU backend available, running on the CPU" in capfd.readouterr().err


def test_arch_gpu_says_what_it_chose_without_taichis_raw_log(capfd):
    import taichi_sim as ts

    try:
        ts.init(arch="gpu", precision="f32")
        backend = ts.runtime.backend()
    finally:
        ts.init(arch="cpu", precision="f64")
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines == [lines[0]] and lines[0].startswith("taichi_sim: --arch gpu: "), err
    assert "[W " not in err and "[T " not in err
    assert {"cuda": "CUDA", "vulkan": "Vulkan", "x64": "CPU", "metal": "metal"}[backend] in lines[0]


def test_bench_says_what_it_skips_without_scipy_or_matplotlib(tmp_path, monkeypatch, capsys):
    from taichi_sim.bench import common

    monkeypatch.setattr(common, "have_scipy", lambda: False)
    monkeypatch.setattr(common, "have_matplotlib", lambda: False)
    out = tmp_path / "bench"
    assert main(["bench", "work-precision", "--out", str(out), "--quick", "--quiet",
                 "--scenes", "spring,pendulum,cloth", "--integrators", "rk4"]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert err[0].startswith("taichi-sim: work-precision skips pendulum, cloth: ")
    assert "scipy is not installed" in err[0] and "./run.sh installs it" in err[0]
    assert err[1] == ("taichi-sim: no plot written (work-precision.png): matplotlib is not installed "
                      "(./run.sh installs it, or .venv/bin/pip install -e '.[bench]')")
    assert len(err) == 2
    document = (out / "work-precision.json").read_text()
    assert '"spring"' in document and '"pendulum"' not in document
    assert not (out / "work-precision.png").exists()
    # nothing left to measure: refused before any work
    assert main(["bench", "work-precision", "--out", str(tmp_path / "b2"), "--quick", "--scenes", "cloth"]) == 2
    assert "cannot measure cloth" in _one_line_error(capsys)


def test_run_sh_installs_the_extras_the_readme_examples_use():
    run_sh = (ROOT / "run.sh").read_text()
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    chosen = next(line for line in run_sh.splitlines() if "source scripts/bootstrap.sh" in line)
    names = chosen.split("TS_EXTRAS=", 1)[1].split()[0].split(",")
    requirements = project["dependencies"] + [req for name in names if name for req in extras[name]]
    installed = {req.split(">")[0].split("=")[0].split("[")[0] for req in requirements}
    assert {"scipy", "matplotlib"} <= installed  # the npz check, bench plots and references
    readme = (ROOT / "README.md").read_text()
    assert "\npip install -e" not in readme and "\n pip install" not in readme


def _section(readme: str, heading: str) -> str:
    start = readme.index(f"\n## {heading}\n")
    return readme[start:readme.index("\n## ", start + 1)]


def test_readme_gallery_states_the_media_sizes_it_shows():
    from PIL import Image

    gallery = _section((ROOT / "README.md").read_text(), "Gallery")
    shown = [ROOT / path for path in __import__("re").findall(r"\((media/[^)]+\.gif)\)", gallery)]
    assert len(shown) >= 8
    real = {Image.open(p).size for p in shown} | {Image.open(p.with_suffix(".png")).size for p in shown}
    stated = {(int(w), int(h)) for w, h in __import__("re").findall(r"(\d+) × (\d+)", gallery)}
    assert stated == real
    for p in shown:
        with Image.open(p) as gif:
            assert gif.n_frames == 48 and gif.info["duration"] == pytest.approx(1000 / 12, abs=4)  # 4 s at 12 fps


def test_readme_links_resolve():
    import re

    readme = (ROOT / "README.md").read_text()
    slugs = {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-")
             for h in re.findall(r"^#+ (.+)$", readme, flags=re.M)}
    for target in re.findall(r"\]\(([^)\s]+)\)", readme):
        if target.startswith(("http://", "https://")):
            continue
        path, _, anchor = target.partition("#")
        if path:
            assert (ROOT / path).exists(), target
        elif anchor:
            assert anchor in slugs, target
    assert "](docs/design.md)" in readme and "DESIGN.md" not in readme


def test_api_page_example_continues_from_the_run(capsys):
    import re

    api = (ROOT / "docs" / "api.md").read_text()
    code = re.search(r"```python\n(.*?)```", api, flags=re.S).group(1)
    shown = re.search(r"prints .*?```text\n(.*?)```", api, flags=re.S).group(1).splitlines()
    # a smaller cloth without wind (whose kernels take seconds to compile) for a shorter run
    small = (code.replace('"nx": 32, "ny": 32, "wind": True', '"nx": 6, "ny": 6')
             .replace("t_end=2.0", "t_end=0.05"))
    assert small != code
    try:
        exec(compile(small, "docs/api.md", "exec"), {})
    finally:
        import taichi_sim as ts
        ts.init(arch="cpu", precision="f64")
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith("ok 0.05 50 200 ")
    accepted = printed[-1]
    h, t = (float(v) for v in re.match(r"accepted h = (\S+) s -> t = (\S+) s", accepted).groups())
    assert t == pytest.approx(0.05 + h, rel=1e-5) and h > 0  # the step continued from t_end, not from 0
    assert shown[0].startswith("ok 2.0 2000 8000 ") and shown[-1].startswith("accepted h = ")
    assert all(line.startswith("rejected h = ") for line in shown[1:-1])


@pytest.mark.parametrize("argv", [["list"], ["simulate", "--help"], ["advise", "spring"]])
def test_a_closed_stdout_ends_quietly(argv):
    """``taichi-sim ... | head -0``: the reader is gone before the first line; the command ends
    as a program ended by SIGPIPE would (exit 141), without a traceback."""
    import subprocess
    import sys

    read, write = os.pipe()
    os.close(read)  # nobody will read: every write to the pipe fails
    try:
        done = subprocess.run([sys.executable, "-m", "taichi_sim", *argv], stdout=write,
                              stderr=subprocess.PIPE, text=True, timeout=300, cwd=ROOT)
    finally:
        os.close(write)
    # argparse drops a failed write of --help itself, then exits 0: quiet too
    assert done.stderr == "" and done.returncode in ((0, 141) if "--help" in argv else (141,)), done.stderr


@pytest.mark.parametrize("argv, expected", [
    (["cloth", "--set", "stifness=5"], "scene 'cloth' has no parameter 'stifness': did you mean 'stiffness'?"),
    (["cloht"], "unknown scene 'cloht': did you mean 'cloth'?"),
    (["cloth", "--integrator", "sympletic_euler"],
     "unknown integrator 'sympletic_euler': did you mean 'symplectic_euler'?"),
])
def test_a_misspelt_name_gets_a_suggestion(tmp_path, capsys, argv, expected):
    out = tmp_path / "run.npz"
    assert main(["simulate", *argv, "--steps", "1", "--out", str(out)]) == 2
    line = _one_line_error(capsys)
    assert expected in line and len(line) < 160  # not every one of the cloth's 70-odd names
    assert not out.exists()


def test_a_name_far_from_all_lists_them_all(tmp_path, capsys):
    assert main(["simulate", "spring", "--set", "wibble=1", "--steps", "1", "--out", str(tmp_path / "r.npz")]) == 2
    line = _one_line_error(capsys)
    assert "no parameter 'wibble' (choose from stiffness, rest_length," in line and "did you mean" not in line


@pytest.mark.parametrize("argv, expected", [
    (["simple", "--steps", "100000000000000"],
     "--steps 100,000,000,000,000 is over the limit of 100,000,000 steps"),
    (["spring", "--t-end", "1000000", "--dt", "1e-6"],
     "--t-end 1e+06 s at --dt 1e-06 s is 1,000,000,000,000 steps, over the limit of 100,000,000"),
    (["spring", "--t-end", "10000000"], "at --dt 0.01 s is 1,000,000,000 steps, over the limit"),  # the scene's dt
])
def test_an_absurd_step_count_is_refused_naming_the_limit(tmp_path, capsys, argv, expected):
    out = tmp_path / "run.npz"
    assert main(["simulate", *argv, "--out", str(out)]) == 2
    assert expected in _one_line_error(capsys)
    assert not out.exists()


def test_the_step_limit_itself_is_allowed():
    from taichi_sim.cli import MAX_STEPS, _check_step_count
    from taichi_sim.run import planned_steps

    _check_step_count(MAX_STEPS, 1e-3, None, planned_steps)
    _check_step_count(None, 1e-3, MAX_STEPS * 1e-3, planned_steps)
    _check_step_count(None, None, 1e9, planned_steps)  # adaptive: the count is not known


@pytest.mark.parametrize("minor", [10, 11, 12, 13, 14])
def test_bootstrap_takes_the_pythons_that_taichi_has_wheels_for(tmp_path, minor):
    """pyproject and scripts/bootstrap.sh agree: Python 3.11, 3.12 and 3.13 (taichi 1.7.4's
    wheels), and the refusal says which ones to install."""
    import subprocess
    import sys

    requires = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    assert requires == ">=3.11,<3.14"
    stub = tmp_path / f"python3.{minor}"  # answers bootstrap's version check as Python 3.<minor>
    stub.write_text(f"#!{sys.executable}\nimport sys\nsys.version_info = (3, {minor}, 0, 'final', 0)\n"
                    "exec(sys.argv[2])\n")
    stub.chmod(0o755)
    script = (f"set -euo pipefail; eval \"$(sed -n '/^find_python()/,/^}}/p' scripts/bootstrap.sh)\"; "
              f"PYTHON={stub} find_python")
    done = subprocess.run(["bash", "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=60)
    if 11 <= minor <= 13:
        assert done.returncode == 0 and done.stdout.strip() == str(stub), done.stderr
    else:
        assert done.returncode == 1 and "needs Python 3.11, 3.12 or 3.13" in done.stderr
