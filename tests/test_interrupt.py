"""Ctrl-C ends a command with one line and exit status 130, whenever it comes: while Taichi and
the package load (Taichi swallows a KeyboardInterrupt there, or fails in its place), while the
first kernels compile, and mid-run (taichi_sim/interrupt.py)."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from taichi_sim import interrupt

ROOT = Path(__file__).resolve().parent.parent


def _taichi_loading(pid: int) -> bool:
    """Whether process ``pid`` has mapped Taichi's C++ extension: its ``import taichi`` is under
    way (and so, the command's own start is behind it)."""
    try:
        return "taichi_python" in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


def _interrupt_after(seconds: float, tmp_path: Path) -> tuple[int, str, Path]:
    """Start ``simulate``, wait until Taichi is loading and ``seconds`` more, send SIGINT."""
    out = tmp_path / f"run-{seconds:g}.npz"
    command = [sys.executable, "-m", "taichi_sim", "simulate", "cloth", "--steps", "1000000", "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    # A suite started in the background of a script inherits SIGINT ignored (POSIX), and so
    # would the command: give it Ctrl-C's default so that it reacts as it does at a terminal.
    proc = subprocess.Popen(command, env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    # Not a fixed delay from the start: on a loaded machine Python's own start-up can take
    # longer, and a Ctrl-C before the command's first line is Python's, not the command's.
    deadline = time.monotonic() + 60
    while not _taichi_loading(proc.pid) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.002)
    time.sleep(seconds)
    proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:  # the Ctrl-C was lost: the million steps go on
        proc.kill()
        _, err = proc.communicate()
        pytest.fail(f"SIGINT {seconds} s into Taichi's load was lost:\n{err}")
    return proc.returncode, err, out


# 0 s: Taichi is loading; 0.4 s: the package's kernels are being declared (the load takes about
# a second here); 4 s: the run (or, on a loaded machine, its first compile) is under way.
@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="reads /proc/PID/maps (Linux)")
@pytest.mark.parametrize("seconds", [0.0, 0.4, 4.0])
def test_ctrl_c_ends_simulate_with_one_line_and_status_130(tmp_path, seconds):
    code, err, out = _interrupt_after(seconds, tmp_path)
    assert code == 130, err
    assert err.splitlines() == ["taichi-sim: interrupted"], err
    assert not out.exists()


@pytest.fixture
def ctrl_c_as_at_a_terminal():
    """SIGINT at Python's default for the test: a suite started in the background of a script
    inherits it ignored, and :func:`interrupt.install` then rightly leaves it alone."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_a_ctrl_c_while_loading_is_held_until_the_load_is_done(ctrl_c_as_at_a_terminal):
    restore = interrupt.install()
    try:
        with pytest.raises(KeyboardInterrupt):
            with interrupt.deferred():
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)  # the handler runs here, and must not raise
                loaded = True
        assert loaded
    finally:
        restore()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_ctrl_c_that_taichi_swallows_is_raised_again(ctrl_c_as_at_a_terminal):
    restore = interrupt.install()
    try:
        try:  # what Taichi's kernel decorator does with any exception
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
        except:  # noqa: E722
            pass
        with pytest.raises(KeyboardInterrupt):
            interrupt.check()
    finally:
        restore()
