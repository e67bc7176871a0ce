"""The import graph of taichi_sim, read from the source (nothing is imported): no cycles, and no
import that runs up a layer (docs/design.md, "Layers"). Function-level imports count too: a lazy
import is still a dependency."""
import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "taichi_sim"

#: The layers, top to bottom (docs/design.md): a module may import its own layer and those below.
LAYERS = (
    ("entry points", {"cli", "scene_file", "__main__", "app", "bench"}),
    ("running a scene", {"run", "run_observers", "stepper", "guard", "convergence", "io", "frame_check", "theory",
                         "reference", "export"}),
    ("parameters over time, drawing", {"curves", "render"}),
    ("stepping a state", {"integrators"}),
    ("what is simulated", {"scene", "forces", "systems", "state", "mesh", "memory"}),
    ("between steps", {"collide"}),
    ("foundations", {"runtime", "frontend_cache", "errors", "loops", "atomic", "geometry", "part",
                     "field_io", "interrupt"}),
)
#: ``import taichi_sim`` gives the public face, which hands on run() and the Stepper.
FACE_LAYER = "running a scene"


def modules(root: Path = PACKAGE) -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, is a package's __init__)."""
    found = {}
    for path in root.rglob("*.py"):
        parts = path.relative_to(root.parent).with_suffix("").parts
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = (path, parts[-1] == "__init__")
    return found


def import_graph(mods: dict[str, tuple[Path, bool]]) -> dict[str, set[str]]:
    """Module -> the modules it imports. A name taken from a package's ``__init__`` counts as an
    import of the module that defines it; an ``__init__`` itself (a face) has no edges."""
    trees = {name: ast.parse(path.read_text(), str(path)) for name, (path, _) in mods.items()}

    def target(module: str, is_init: bool, node: ast.ImportFrom) -> str:
        if not node.level:
            return node.module or ""
        base = module.split(".") if is_init else module.split(".")[:-1]
        base = base[:len(base) - node.level + 1]
        return ".".join(base + ([node.module] if node.module else []))

    def defining(package: str, name: str, seen=()) -> str:
        """The module that defines ``name`` handed on by ``package``'s __init__."""
        if f"{package}.{name}" in mods:
            return f"{package}.{name}"
        for node in trees[package].body:
            if isinstance(node, ast.ImportFrom) and any((a.asname or a.name) == name for a in node.names):
                source = target(package, True, node)
                if source in mods and source not in seen:
                    return defining(source, name, seen + (package,)) if mods[source][1] else source
        return package

    graph = {}
    for name, (_, is_init) in mods.items():
        edges = set()
        if not is_init:
            for node in ast.walk(trees[name]):
                if isinstance(node, ast.ImportFrom):
                    source = target(name, False, node)
                    if source not in mods:
                        continue
                    for alias in node.names:
                        edges.add(defining(source, alias.name) if mods[source][1] else source)
                elif isinstance(node, ast.Import):
                    edges.update(a.name for a in node.names if a.name in mods)
        graph[name] = edges - {name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def layer_of(module: str) -> int:
    """Index of ``module``'s layer in LAYERS (0 = top)."""
    parts = module.split(".")
    if len(parts) == 1:
        return [n for n, _ in LAYERS].index(FACE_LAYER)
    for k, (_, members) in enumerate(LAYERS):
        if parts[1] in members:
            return k
    raise AssertionError(f"{module} is in no layer: add it to LAYERS and to docs/design.md")


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    return sorted(f"{a} ({LAYERS[layer_of(a)][0]}) imports {b} ({LAYERS[layer_of(b)][0]})"
                  for a, targets in graph.items() for b in targets if layer_of(b) < layer_of(a))


@pytest.fixture(scope="module")
def graph():
    return import_graph(modules())


def test_every_module_is_in_a_layer(graph):
    for module in graph:
        layer_of(module)


def test_no_module_imports_itself_back_through_others(graph):
    assert cycles(graph) == []


def test_no_import_runs_up_a_layer(graph):
    assert upward_imports(graph) == []


def test_the_checks_see_a_cycle_and_an_upward_import(tmp_path):
    # A small package with the two faults: the test's reading of the source finds both.
    package = tmp_path / "taichi_sim"
    (package / "scene").mkdir(parents=True)
    (package / "__init__.py").write_text("from .run import run\n")
    (package / "run.py").write_text("from .scene import build\ndef run(): pass\n")
    (package / "scene" / "__init__.py").write_text("from .builder import build\n")
    (package / "scene" / "builder.py").write_text("def build():\n    from ..run import run\n")
    (package / "errors.py").write_text("from . import cli\n")
    (package / "cli.py").write_text("from .errors import x\n")
    graph = import_graph(modules(package))
    assert graph["taichi_sim.run"] == {"taichi_sim.scene.builder"}  # through the package's face
    assert sorted(cycles(graph)) == [["taichi_sim.cli", "taichi_sim.errors"],
                                     ["taichi_sim.run", "taichi_sim.scene.builder"]]
    assert upward_imports(graph) == [
        "taichi_sim.errors (foundations) imports taichi_sim.cli (entry points)",
        "taichi_sim.scene.builder (what is simulated) imports taichi_sim.run (running a scene)"]
