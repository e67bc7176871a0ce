"""Style as code: ``ruff check`` (its configuration is pyproject.toml's [tool.ruff]) finds nothing."""
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CHECKED = ["taichi_sim", "tests", "benchmarks", "demos", "scripts"]


def _ruff() -> list[str] | None:
    beside = Path(sys.executable).with_name("ruff")  # the test extra installs it into the venv
    if beside.exists():
        return [str(beside)]
    found = shutil.which("ruff")
    return [found] if found else None


def test_ruff_finds_nothing():
    ruff = _ruff()
    assert ruff is not None, "ruff is not installed: ./test.sh installs the test extra, which has it"
    done = subprocess.run([*ruff, "check", "--no-cache", "--output-format", "concise", *CHECKED],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
