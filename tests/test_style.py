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


def _top_level_names(tree) -> set[str]:
    import ast

    names = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names.update(n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name))
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return names


def test_every_name_the_scripts_import_exists():
    """The benchmark and demo scripts run by hand, not in the suite: a name they import from
    the package or from each other that was renamed or removed would only show when someone
    runs them (check_motion_reference.py imported a ``cloth`` that bench_vbd.py no longer had)."""
    import ast
    import importlib
    import importlib.util

    missing = []
    for folder in ("benchmarks", "demos", "examples"):
        scripts = {p.stem: p for p in (ROOT / folder).rglob("*.py")}
        for path in scripts.values():
            for node in ast.walk(ast.parse(path.read_text())):
                if not isinstance(node, ast.ImportFrom) or node.level or node.module is None:
                    continue
                wanted = [a.name for a in node.names if a.name != "*"]
                if node.module in scripts:
                    known = _top_level_names(ast.parse(scripts[node.module].read_text()))
                    missing += [f"{path.name}: {node.module}.{n}" for n in wanted if n not in known]
                elif node.module.split(".")[0] == "taichi_sim":
                    module = importlib.import_module(node.module)
                    missing += [f"{path.name}: {node.module}.{n}" for n in wanted if not hasattr(module, n)
                                and importlib.util.find_spec(f"{node.module}.{n}") is None]
    assert not missing, missing
