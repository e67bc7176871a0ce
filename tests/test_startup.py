"""What a command's first step costs before it steps: the kernels set-up compiles (or loads from
Taichi's cache), each a fixed cost of tens of milliseconds (docs/design-front-ends.md, "Compile
time")."""
import importlib
import os
import subprocess
import sys
import traceback

import pytest

import taichi_sim as ts

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_field_module = importlib.import_module("taichi.lang.field")  # taichi.lang.field is also a function


def _caller() -> str:
    """The package's line that asked for the kernel."""
    frames = [f for f in traceback.extract_stack() if "/taichi_sim/" in f.filename]
    return f"{frames[-1].filename.split('/taichi_sim/')[-1]}:{frames[-1].lineno}" if frames else "?"


@pytest.fixture
def setup_kernels(monkeypatch):
    """The kernels Taichi makes for plumbing while the test runs: item access from Python
    (``field[None] = v`` compiles one kernel per field, and per component of a vector) and
    Taichi's own ``to_numpy`` / ``from_numpy`` / ``fill`` kernels, each one name per instance."""
    made = []
    accessor = _field_module.SNodeHostAccessor
    original_init = accessor.__init__

    def counted_init(self, snode):
        made.append(f"item access at {_caller()}")
        original_init(self, snode)

    monkeypatch.setattr(accessor, "__init__", counted_init)
    kernel = importlib.import_module("taichi.lang.kernel_impl").Kernel
    original_materialize = kernel.materialize

    def counted_materialize(self, key=None, args=None, arg_features=None):
        if self.func.__module__ == "taichi._kernels" and (key not in self.compiled_kernels):
            made.append(f"Taichi's {self.func.__name__} at {_caller()}")
        return original_materialize(self, key, args, arg_features)

    monkeypatch.setattr(kernel, "materialize", counted_materialize)
    return made


def test_a_contact_cloth_and_its_solver_set_up_without_plumbing_kernels(f64, setup_kernels):
    # cloth-fold has every part set-up wrote from Python one value at a time: gravity, drag, the
    # floor plane, self-contact with its hash grids, and vbd's contact detection and colouring
    scene = ts.build_scene("cloth-fold", {"nx": 6, "ny": 6})
    ts.Stepper(scene, "vbd", 1 / 60)  # the stepper attaches the scene's contact to vbd's solve
    assert setup_kernels == [], "\n".join(setup_kernels)


_COMPILE_AND_EXIT = """
import taichi as ti
import taichi_sim as ts

ts.init(precision="f64")
@ti.kernel
def twice(a: ti.f64) -> ti.f64:
    return 2.0 * a
twice(1.0)
ts.init(precision="f64")  # a second program: resetting the first writes the cache
twice(2.0)
print("last line", flush=True)
"""


def test_a_process_prints_nothing_after_its_last_line_when_the_kernel_cache_is_locked(tmp_path):
    # another process holds the cache's lock (a test worker or command exiting at the same
    # moment): Taichi gives up writing after 0.2 s and warned on stderr, after the command's
    # output and after pytest's summary
    (tmp_path / "ticache.lock").touch()
    env = {**os.environ, "TI_OFFLINE_CACHE_FILE_PATH": str(tmp_path), "PYTHONPATH": ROOT}
    script = tmp_path / "compile_and_exit.py"  # a file: Taichi reads a kernel's source
    script.write_text(_COMPILE_AND_EXIT)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, cwd=ROOT,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "last line\n"
    assert done.stderr == ""


def test_the_warm_up_starts_where_the_launcher_of_taichi_sim_starts(monkeypatch):
    # every kernel the warm-up compiles is keyed by the fields made before it: a warm-up that
    # opened on another scene or method than `taichi-sim` does would fill the cache for nothing
    from taichi_sim.app import display, launcher, warm
    from taichi_sim.cli import cmd_default

    opened = []

    class Opened:
        def __init__(self, session, *args, **kwargs):
            opened.append(session)

        def run(self):
            pass

    monkeypatch.setattr(display, "display_problem", lambda: None)
    monkeypatch.setattr(launcher, "Launcher", Opened)
    assert cmd_default() == 0
    start = launcher.first_session()
    assert [(s.scene_name, s.integrators) for s in opened] == [(start.scene_name, start.integrators)]

    class Opening(Exception):
        pass

    class Window:
        def destroy(self):
            pass

    def warm_opens(session, *args, **kwargs):
        opened.append(session)
        raise Opening

    monkeypatch.setattr(launcher, "Launcher", warm_opens)
    monkeypatch.setattr("taichi_sim.render.open_window", lambda *args: Window())
    with pytest.raises(Opening):
        warm.warm_switch("cloth-sphere")
    assert [(s.scene_name, s.integrators) for s in opened[1:]] == [(start.scene_name, start.integrators)]


def test_the_warm_up_names_an_unknown_scene(capsys):
    from taichi_sim.app import warm

    assert warm.main(["no-such-scene"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no-such-scene" in err


def test_a_command_reads_no_package_metadata_unless_asked_for_the_version():
    # importlib.metadata's import and the lookup of the installed version took 0.1 s of every
    # command's start; `list` and `simulate` need neither, `--version` prints it
    code = ("import sys; from taichi_sim.cli import main; from taichi_sim.cli.parser import build_parser; "
            "build_parser(['list']).parse_args(['list']); print('importlib.metadata' in sys.modules)")
    env = {**os.environ, "PYTHONPATH": ROOT}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT, timeout=120)
    assert done.stdout.split() == ["False"], done.stderr
    version = subprocess.run([sys.executable, "-m", "taichi_sim", "--version"], capture_output=True, text=True,
                             env=env, cwd=ROOT, timeout=120)
    assert version.returncode == 0 and version.stdout.startswith("taichi-sim ") and version.stderr == ""
