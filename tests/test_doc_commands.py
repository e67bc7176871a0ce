"""The shell commands the README and docs/ show (not docs/lab/, whose logs keep their commands as
they were run): each ``taichi-sim`` (``./run.sh``, ``python -m taichi_sim``) line is parsed by the
command line's own parser in-process and checked as far as can be without running it (the
scene, its ``--set`` names and values, integrators and their options, the files it reads:
in the repository or written by an earlier line of its block); each ``python ...py`` and
``./test.sh`` line names a script that exists. Blocks marked ``<!-- command: run -->`` just
before them (cheap ones, at the sizes their page states) also run end to end, in order, in a
temporary folder. ``<!-- command: display -->`` and ``<!-- command: slow -->`` say why a block
is only parsed; an unmarked block is only parsed too."""

import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from taichi_sim.cli import main
from taichi_sim.cli.parser import build_parser
from taichi_sim.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent
MARK = re.compile(r"<!--\s*command:\s*(\w+)\s*-->\s*\n```")
BLOCK = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
MARKS = {"run", "display", "slow"}
SHELL_LANGS = {"", "bash", "sh", "shell", "console"}
# a file a line names, written by a python line before it (`make_skirt.py skirt.obj`, `.export('table.obj')`)
FILE_NAME = re.compile(r"[\w./*-]+\.(?:obj|stl|ply|off|glb|gltf|npz|toml|json|usdc|usda|usd)\b")
CLI_PREFIXES = (("taichi-sim",), ("./run.sh",), ("python", "-m", "taichi_sim"),
                (".venv/bin/python", "-m", "taichi_sim"), (".venv/bin/taichi-sim",))


@dataclass
class Block:
    page: str          # path relative to the repository
    line: int          # of the opening fence
    mark: str | None   # run, display, slow or None
    lines: list[str]   # commands: continuations joined, comments and blank lines dropped


def _pages() -> list[Path]:
    return [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))  # docs/lab/ is left out


def _command_lines(body: str) -> list[str]:
    lines, pending = [], ""
    for raw in body.splitlines():
        line = pending + raw.strip()
        if line.endswith("\\"):
            pending = line[:-1] + " "
            continue
        pending = ""
        line = re.sub(r"\s+#.*$", "", line).strip()  # a trailing comment (none of them quotes a #)
        if line and not line.startswith("#"):
            lines.append(line)
    return lines


def doc_blocks() -> list[Block]:
    blocks = []
    for page in _pages():
        text = page.read_text()
        marked = {m.end() - 3: m.group(1) for m in MARK.finditer(text)}
        for m in BLOCK.finditer(text):
            if m.group(1) not in SHELL_LANGS:
                continue
            mark = marked.get(m.start())
            assert mark is None or mark in MARKS, f"{page.name}: unknown mark {mark!r} (one of {sorted(MARKS)})"
            blocks.append(Block(str(page.relative_to(ROOT)), text[:m.start()].count("\n") + 1, mark,
                                _command_lines(m.group(2))))
    return blocks


def _words(line: str) -> list[str]:
    try:
        return shlex.split(line)
    except ValueError:  # not a command: printed output (an error message quoting a name)
        return line.split()


def _expand(line: str, variables: dict[str, str]) -> list[str]:
    return [re.sub(r"\$(\w+)", lambda v: variables.get(v.group(1), v.group(0)), w) for w in _words(line)]


def _cli_argv(words: list[str]) -> list[str] | None:
    """The arguments after the program when ``words`` run the command line, else None."""
    for prefix in CLI_PREFIXES:
        if tuple(words[:len(prefix)]) == prefix:
            return words[len(prefix):]
    return None


def _redirect(words: list[str]) -> tuple[list[str], str | None]:
    if ">" in words:
        k = words.index(">")
        return words[:k], words[k + 1]
    return words, None


class Checker:
    """Checks a block's lines in order, with the files its earlier lines write."""

    def __init__(self, block: Block):
        self.block = block
        self.written: set[str] = set()
        self.variables: dict[str, str] = {}
        self.scene_of: dict[str, str] = {}  # a scene file written by `list --scene-file PRESET > FILE`

    def fail(self, line: str, why: str):
        pytest.fail(f"{self.block.page}:{self.block.line}: `{line}`: {why}", pytrace=False)

    def need_file(self, line: str, name: str, what: str):
        name = name.rstrip("/")
        if name in self.written or Path(name).name in {Path(w).name for w in self.written}:
            return
        path = ROOT / name
        if any(c in name for c in "*?[") and list(path.parent.glob(path.name)):
            return
        if not path.exists():
            self.fail(line, f"{what} {name} is neither in the repository nor written by an earlier line")

    def check(self, line: str):
        assignment = re.fullmatch(r"(\w+)=(\S+)", line)
        if assignment:
            self.variables[assignment.group(1)] = assignment.group(2)
            return
        words, redirected = _redirect(_expand(line, self.variables))
        if redirected:
            self.written.add(redirected)
        argv = _cli_argv(words)
        if argv is not None:
            self.check_cli(line, argv)
            if redirected and argv[:2] == ["list", "--scene-file"] and len(argv) > 2:
                self.scene_of[redirected] = argv[2]
        elif words[0] in ("./test.sh", "./run.sh", "bash"):
            script = words[1] if words[0] == "bash" else words[0]
            self.need_file(line, script, "script")
        elif re.fullmatch(r"(\.venv/bin/)?python3?", words[0]) and len(words) > 1:
            if words[1].endswith(".py"):
                self.need_file(line, words[1], "script")
            self.written.update(FILE_NAME.findall(" ".join(words[2:] if words[1].endswith(".py") else words[1:])))

    def check_cli(self, line: str, argv: list[str]):
        if not argv or argv[0] == "COMMAND":  # `taichi-sim` alone, `taichi-sim COMMAND --help`
            return
        try:
            args = build_parser().parse_args(argv)
        except ConfigError as exc:
            self.fail(line, str(exc))
        except SystemExit:  # --help, --version
            return
        try:
            self.check_args(line, args)
        except (ConfigError, ValueError) as exc:
            self.fail(line, str(exc))

    def check_args(self, line: str, args):
        from taichi_sim.integrators import integrator_class, parse_options
        from taichi_sim.scene import scene_preset
        from taichi_sim.scene.params import resolve, scene_assignments
        from taichi_sim.scene_file import PATH_UNIT, apply_scene_file, is_scene_file

        if args.command in ("check", "export"):
            self.need_file(line, args.npz, "the run")
        scene = getattr(args, "scene", None)
        if args.command in ("simulate", "demo", "record") and scene is not None:
            if is_scene_file(scene):
                self.need_file(line, scene, "scene file")
                if scene in self.scene_of:  # written by `list --scene-file`: the package's own
                    scene = self.scene_of[scene]
                else:
                    apply_scene_file(args, args.command)
                    scene = args.scene
            preset = scene_preset(scene)
            values = resolve(preset.params, preset.name, scene_assignments(args.assignments))
            for param in preset.params:
                if param.unit == PATH_UNIT and values[param.name] and param.name in dict(args.assignments):
                    self.need_file(line, values[param.name], f"--set {param.name}:")
            names = getattr(args, "side_by_side", None) or [args.integrator or preset.default_integrator]
            for name in names:
                self.plugin_file(line, name)
                integrator_class(name)
            if args.integrator_options:
                parse_options(names[0], scene_assignments(args.integrator_options, "--option"))
        if args.command == "advise":
            preset = scene_preset(args.scene)
            resolve(preset.params, preset.name, scene_assignments(args.assignments))
        for name in (getattr(args, "integrators", None) or "").split(","):
            if name:
                self.plugin_file(line, name)
                integrator_class(name)
        if getattr(args, "curves", None):
            self.need_file(line, args.curves, "--curves")
        if args.command == "list" and args.scene_file:
            scene_preset(args.scene_file)
        for out in (getattr(args, "out", None), getattr(args, "export", None)):
            if out:
                self.written.add(out)

    def plugin_file(self, line: str, name: str):
        if ".py:" in name:
            self.need_file(line, name.split(":", 1)[0], "plug-in")


BLOCKS = doc_blocks()
# Commands known to be broken on a page this test cannot fix, each with why (strict: once the
# page is fixed the entry must go).
KNOWN_BROKEN: dict[tuple[str, str], str] = {}  # (page, text in the block) -> why it is broken, while it is


def _block_id(block: Block) -> str:
    return f"{block.page}:{block.line}"


def test_the_pages_show_commands():
    """The patterns still find the blocks and the commands in them."""
    cli = [b for b in BLOCKS if any(_cli_argv(_words(line)) is not None for line in b.lines)]
    assert {b.page for b in cli} >= {"README.md", "docs/cli.md", "docs/scene-files.md"}
    assert len(cli) >= 15, [_block_id(b) for b in cli]
    assert any(b.mark == "run" for b in BLOCKS if b.page == "README.md")


def _parse_case(block):
    broken = [why for (page, text), why in KNOWN_BROKEN.items()
              if page == block.page and any(text in line for line in block.lines)]
    return pytest.param(block, id=_block_id(block),
                        marks=[pytest.mark.xfail(reason=broken[0], strict=True)] if broken else [])


@pytest.mark.parametrize("block", [_parse_case(b) for b in BLOCKS])
def test_every_command_parses(block, monkeypatch):
    monkeypatch.chdir(ROOT)  # scene files name their files relative to themselves, from here
    checker = Checker(block)
    for line in block.lines:
        checker.check(line)


@pytest.mark.parametrize("block", [b for b in BLOCKS if b.mark == "run"], ids=_block_id)
def test_cheap_blocks_run(block, tmp_path, monkeypatch, capsys):
    """A block marked run, line by line in a temporary folder holding the repository's examples."""
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    monkeypatch.chdir(tmp_path)
    variables: dict[str, str] = {}
    for line in block.lines:
        assignment = re.fullmatch(r"(\w+)=(\S+)", line)
        if assignment:
            variables[assignment.group(1)] = assignment.group(2)
            continue
        words, redirected = _redirect(_expand(line, variables))
        argv = _cli_argv(words)
        if argv is not None:
            code = main(argv)
            output = capsys.readouterr()
            if redirected:
                Path(redirected).write_text(output.out)
            assert code == 0, f"{_block_id(block)}: `{line}` exited {code}:\n{output.err}"
        else:
            assert re.fullmatch(r"(\.venv/bin/)?python3?", words[0]), f"{_block_id(block)}: cannot run `{line}`"
            done = subprocess.run([sys.executable, *words[1:]], capture_output=True, text=True, timeout=120,
                                  env={**os.environ, "PYTHONPATH": str(ROOT)})
            assert done.returncode == 0, f"{_block_id(block)}: `{line}` exited {done.returncode}:\n{done.stderr}"
