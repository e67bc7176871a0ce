"""Scene files: a run described in TOML (docs/scene-files.md), read for ``simulate``, ``demo``
and ``record``, and written by ``list --scene-file``.

A file names a preset and sets its parameters, the integrator and its options, the step, the
length and the outputs. Nothing in it is executed: integrators are named as registered (built-in
or installed plug-ins); a ``module:Class`` or ``file.py:Class`` would import code the file
names, so it is refused here (give it with --integrator). Paths (parameters whose unit is
``path``, ``run.curves``, the outputs) are relative to the file's folder. Each problem is one
``FILE:LINE: problem`` ConfigError; tomllib gives lines only for syntax errors, so
:func:`key_line` finds the line of the offending key in the text.
"""
from __future__ import annotations

import difflib
import json
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import ConfigError
from .scene.colliders.mesh_frames import is_pattern, pattern_files
from .scene.params import Param

SUFFIX = ".toml"
PATH_UNIT = "path"  # a Param with this unit holds a file name, resolved against the scene file's folder

# [run] and [output]: each key as a Param (its default's type is the key's type)
RUN_KEYS = {p.name: p for p in (
    Param("dt", 0.01, "s", "step size (adaptive methods: the first step)", minimum=0.0, exclusive=True),
    Param("duration", 1.0, "s", "simulated time (simulate --t-end); or give steps", minimum=0.0, exclusive=True),
    Param("steps", 1, "", "number of steps (simulate --steps); or give duration", minimum=1),
    Param("seed", 0, "", "random seed for scenes with randomness"),
    Param("precision", "f64", "", "f32 or f64", choices=("f32", "f64")),
    Param("arch", "cpu", "", "cpu or gpu", choices=("cpu", "gpu")),
    Param("save_every", 1, "", "keep the positions every K steps (x_history; needed by an export)", minimum=1),
    Param("energy_every", 0, "", "sample energy every K steps (0: never)", minimum=0),
    Param("max_residual", 1e-2, "", "bound on a solver's relative residual", minimum=0.0, exclusive=True),
    Param("tolerance", 1e-3, "m", "how far a step may be from its method's solution", minimum=0.0, exclusive=True),
    Param("max_energy_growth", 10.0, "", "the blow-up guard's energy bound", minimum=0.0, exclusive=True),
    Param("curves", "", PATH_UNIT, "JSON file of parameter curves over time"),
)}
OUTPUT_KEYS = {p.name: p for p in (
    Param("npz", "", PATH_UNIT, "the run's .npz (simulate --out)"),
    Param("export", "", PATH_UNIT, "frames for other tools: a folder (obj, ply) or a USD file"),
    Param("export_format", "usd", "", "obj, ply or usd"),
)}
TABLES = ("parameters", "integrator", "run", "output")
# the simulate option each [run] / [output] key stands for (the argparse dest)
ARG_OF = {"dt": "dt", "duration": "t_end", "steps": "steps", "seed": "seed", "precision": "precision",
          "arch": "arch", "save_every": "save_every", "energy_every": "energy_every",
          "max_residual": "max_residual", "tolerance": "tolerance", "max_energy_growth": "max_energy_growth", "curves": "curves",
          "npz": "out", "export": "export", "export_format": "export_format"}
DEFAULTS = {"precision": "f64", "arch": "cpu", "seed": 0}  # what a command gets when nobody says


@dataclass
class SceneFile:
    """A checked scene file. ``params``: the preset's parameters it sets (typed; paths made
    absolute); ``options``: the integrator's options; ``run`` and ``output``: the [run] and
    [output] keys it sets (paths made absolute); ``lines``: (table, key) -> line, for messages."""

    path: Path
    scene: str
    params: dict[str, Any] = field(default_factory=dict)
    integrator: str | None = None
    options: dict[str, Any] = field(default_factory=dict)
    run: dict[str, Any] = field(default_factory=dict)
    output: dict[str, Any] = field(default_factory=dict)
    lines: dict[tuple[str, str], int] = field(default_factory=dict)

    def where(self, table: str, key: str) -> str:
        """``FILE:LINE`` of ``key`` in ``table`` ("" for a top-level key)."""
        return f"{self.path}:{self.lines.get((table, key), 1)}"


def is_scene_file(name: str | None) -> bool:
    return name is not None and name.endswith(SUFFIX)


_HEADER = re.compile(r"^\s*\[\[?\s*([^\]]*?)\s*\]\]?\s*(#.*)?$")
_KEY = re.compile(r"""^\s*((?:[A-Za-z0-9_-]+|"[^"]*"|'[^']*')(?:\s*\.\s*(?:[A-Za-z0-9_-]+|"[^"]*"|'[^']*'))*)\s*=""")


def _dotted(text: str) -> tuple[str, ...]:
    return tuple(part.strip().strip("\"'") for part in re.findall(r"""[A-Za-z0-9_-]+|"[^"]*"|'[^']*'""", text))


def key_line(text: str, table: tuple[str, ...], key: str | None = None) -> int:
    """The 1-based line of ``key`` in ``table`` (``()``: the top level) in TOML ``text``, whether
    written under a ``[table]`` header or as a dotted key (``run.dt = 0.01``); with ``key`` None,
    the table's header (or its first key); a ``key`` that is itself a table: its header. 1 when
    not found (a table written inline)."""
    current: tuple[str, ...] = ()
    first_in_table = None
    for number, line in enumerate(text.splitlines(), start=1):
        header = _HEADER.match(line)
        if header and not _KEY.match(line):
            current = _dotted(header.group(1))
            if (key is None and current == tuple(table)) or (key is not None and current == (*table, key)):
                return number
            continue
        found = _KEY.match(line)
        if not found:
            continue
        path = current + _dotted(found.group(1))
        if key is not None and path == (*table, key):
            return number
        if key is None and first_in_table is None and path[:len(table)] == tuple(table) and len(path) > len(table):
            first_in_table = number
    return first_in_table or 1


def _unknown(kind: str, name: str, known) -> str:
    known = list(known)
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
    if close:
        return f"{kind} {name!r}: did you mean {close[0]!r}?"
    return f"{kind} {name!r} (choose from {', '.join(known)})"


def load_scene_file(path: str | Path) -> SceneFile:
    """Read and check the scene file at ``path`` (ConfigError ``FILE:LINE: problem``)."""
    from .integrators import integrator_class, is_spec, parse_options
    from .scene.presets import scene_preset

    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"scene file {str(path)!r} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read scene file {str(path)!r}: {getattr(exc, 'strerror', None) or exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        line = getattr(exc, "lineno", None) or _line_in_message(str(exc))
        raise ConfigError(f"{path}:{line}: not valid TOML: {str(exc).split(' (at line')[0]}") from None
    folder = path.parent

    def fail(table: str | None, key: str | None, problem: str):
        line = key_line(text, (table,) if table else (), key)
        raise ConfigError(f"{path}:{line}: {problem}")

    for key, value in data.items():
        if key not in ("scene", *TABLES):
            fail(None, key, _unknown("unknown table" if isinstance(value, dict) else "unknown key", key,
                                     ("scene", *TABLES)))
        if key in TABLES and not isinstance(value, dict):
            fail(None, key, f"{key} must be a table ([{key}]), got {_toml_type(value)}")
    if "scene" not in data:
        raise ConfigError(f"{path}:1: no `scene = \"NAME\"` (the preset to run; `taichi-sim list` shows them)")
    if not isinstance(data["scene"], str):
        fail(None, "scene", f"scene must be a string, got {_toml_type(data['scene'])}")
    try:
        preset = scene_preset(data["scene"])
    except ConfigError as exc:
        fail(None, "scene", str(exc))
    found = SceneFile(path=path, scene=preset.name)

    by_name = {p.name: p for p in preset.params}
    for key, value in data.get("parameters", {}).items():
        if key not in by_name:
            fail("parameters", key, _unknown(f"scene {preset.name!r} has no parameter", key, by_name))
        found.params[key] = _checked(by_name[key], value, folder, lambda problem, k=key: fail("parameters", k, problem),
                                     allow_empty=True)

    table = data.get("integrator", {})
    if table:
        if "name" not in table:
            fail("integrator", None, "[integrator] needs name = \"METHOD\" (`taichi-sim list` shows them)")
        name = table["name"]
        if not isinstance(name, str):
            fail("integrator", "name", f"integrator name must be a string, got {_toml_type(name)}")
        if is_spec(name):
            fail("integrator", "name", f"integrator {name!r}: a scene file names registered integrators only "
                 "(a module:Class would run code the file names); give it with --integrator instead")
        try:
            integrator_class(name)
        except ConfigError as exc:
            fail("integrator", "name", str(exc))
        found.integrator = name
        for key, value in table.items():
            if key == "name":
                continue
            if isinstance(value, (dict, list)) or value is None:
                fail("integrator", key, f"integrator option {key} must be a number, boolean or string, "
                     f"got {_toml_type(value)}")
            try:
                found.options.update(parse_options(name, {key: _option_text(value)}))
            except ConfigError as exc:
                fail("integrator", key, str(exc))

    for table_name, keys, into in (("run", RUN_KEYS, found.run), ("output", OUTPUT_KEYS, found.output)):
        for key, value in data.get(table_name, {}).items():
            if key not in keys:
                fail(table_name, key, _unknown(f"unknown key in [{table_name}]:", key, keys))
            into[key] = _checked(keys[key], value, folder, lambda problem, t=table_name, k=key: fail(t, k, problem),
                                 must_exist=table_name == "run", allow_empty=False)
    if "steps" in found.run and "duration" in found.run:
        fail("run", "steps", "give [run] steps or duration, not both")
    if "export_format" in found.output:
        from .export import export_format

        try:
            export_format(found.output["export_format"])
        except ConfigError as exc:
            fail("output", "export_format", str(exc))
    found.lines = {(t, k): key_line(text, (t,) if t else (), k)
                   for t, keys in (("parameters", found.params), ("integrator", found.options),
                                   ("run", found.run), ("output", found.output)) for k in keys}
    return found


def _checked(param: Param, value: Any, folder: Path, fail, *, must_exist: bool = True, allow_empty: bool) -> Any:
    """``value`` checked as ``param`` would check it: a path made absolute against ``folder``
    and, with ``must_exist``, checked to exist; an empty path refused unless ``allow_empty`` (a
    preset's parameter may leave its file out, [run] and [output] keys are then left out)."""
    if isinstance(value, (dict, list)):
        fail(f"{param.name} must be a {param.kind.__name__}, got {_toml_type(value)}")
    try:
        value = param.check(value)
    except ConfigError as exc:
        fail(str(exc))
    if param.unit == PATH_UNIT and not value and not allow_empty:
        fail(f"{param.name}: an empty path (leave the key out instead)")
    if param.unit == PATH_UNIT and value:
        resolved = (folder / Path(value).expanduser()).resolve()
        if must_exist and is_pattern(value):  # a sequence of files (a collider mesh's frames)
            if not pattern_files(str(resolved)):
                fail(f"{param.name}: no file matches {value!r} (looked for {str(resolved)!r}; paths in a scene "
                     "file are relative to its folder)")
        elif must_exist and not resolved.exists():
            fail(f"{param.name}: no such file {value!r} (looked for {str(resolved)!r}; paths in a scene file "
                 "are relative to its folder)")
        value = str(resolved)
    return value


def _option_text(value: Any) -> str:
    """An option's TOML value as command-line text, so it is typed as --option would be."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value) if isinstance(value, float) else str(value)


def _toml_type(value: Any) -> str:
    return {dict: "a table", list: "an array", bool: "a boolean", int: "an integer", float: "a float",
            str: "a string"}.get(type(value), type(value).__name__)


def _line_in_message(message: str) -> int:
    found = re.search(r"line (\d+)", message)
    return int(found.group(1)) if found else 1


def apply_scene_file(args, command: str) -> SceneFile | None:
    """Fold a scene file named as ``args.scene`` into ``args`` (a command line's namespace for
    ``simulate``, ``demo`` or ``record``): what the command line gives wins, per parameter and
    per option; then the defaults nobody gave. Returns the file, or None when ``args.scene``
    is a scene name."""
    import sys

    from .scene.presets import scene_preset

    found = None
    if is_scene_file(getattr(args, "scene", None)):
        found = load_scene_file(args.scene)
        args.scene = found.scene
        given = {name for name, _ in args.assignments}
        args.assignments = [(k, _param_text(v)) for k, v in found.params.items() if k not in given] + args.assignments
        same_method = args.integrator is None or args.integrator == found.integrator
        if args.integrator is None and not getattr(args, "side_by_side", None):
            args.integrator = found.integrator
        # options the scene gives that method itself (a written template's) are not lost
        own = scene_preset(found.scene).options_for(found.integrator)
        dropped = {k: v for k, v in found.options.items() if own.get(k) != v}
        if dropped and getattr(args, "side_by_side", None):
            listed = ", ".join(f"{k} = {_option_text(v)}" for k, v in dropped.items())
            print(f"taichi-sim: warning: {found.where('integrator', next(iter(dropped)))}: --side-by-side "
                  f"runs each method with the scene's options or its defaults; the file's {listed} are not used",
                  file=sys.stderr)
        elif same_method:
            cli_options = {name for name, _ in args.integrator_options}
            args.integrator_options = [(k, _option_text(v)) for k, v in found.options.items()
                                       if k not in cli_options and k not in getattr(args, "flag_options", {})
                                       ] + args.integrator_options
        if command == "simulate":
            if args.steps is None and args.t_end is None:
                args.steps, args.t_end = found.run.get("steps"), found.run.get("duration")
            for key, value in {**found.run, **found.output}.items():
                if key not in ("steps", "duration") and getattr(args, ARG_OF[key], None) is None:
                    setattr(args, ARG_OF[key], value)
        else:
            for key in ("dt", "seed", "precision", "arch", "curves"):
                if key in found.run and getattr(args, key, None) is None:
                    setattr(args, key, found.run[key])
    for key, value in DEFAULTS.items():
        if getattr(args, key, None) is None:
            setattr(args, key, value)
    return found


def _param_text(value: Any) -> str:
    """A checked parameter value as the text --set would give (parsed back to the same value)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value) if isinstance(value, float) else str(value)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "inf" if value == math.inf else ("-inf" if value == -math.inf else repr(value))
    if isinstance(value, int):
        return str(value)
    return json.dumps(value)  # a TOML basic string is a JSON string


def scene_file_text(preset) -> str:
    """The preset as a scene file: every parameter at its default with its unit and meaning as
    a comment, the default integrator and step, one second of simulated time, an npz beside the
    file. ``simulate`` runs it as it is."""
    from .integrators import integrator_class

    lines = [f"# {preset.name}: {preset.description}",
             "# A taichi-sim scene file (docs/scene-files.md): edit, then `taichi-sim simulate THIS.toml`.",
             "# Options on the command line override these values; paths are relative to this file.",
             f"scene = {_toml_value(preset.name)}", "", "[parameters]"]
    width = max((len(f"{p.name} = {_toml_value(p.default)}") for p in preset.params), default=0)
    for p in preset.params:
        assignment = f"{p.name} = {_toml_value(p.default)}"
        unit = f"[{p.unit}] " if p.unit else ""
        choices = f" (one of: {', '.join(p.choices)})" if p.choices else ""
        lines.append(f"{assignment:<{width}}  # {unit}{p.meaning}{choices}")
    lines += ["", "[integrator]", f"name = {_toml_value(preset.default_integrator)}"]
    chosen = preset.options_for(preset.default_integrator)
    lines += [f"{k} = {_toml_value(v)}  # this scene's choice" for k, v in chosen.items()]
    shown = [f"{k} = {_toml_value(v)}" for k, v in integrator_class(preset.default_integrator).options().items()
             if isinstance(v, (bool, int, float, str)) and k not in chosen]  # None: chosen automatically
    if shown:
        lines.append(f"# its {'other ' if chosen else ''}options, at their defaults: {', '.join(shown)}")
    lines += ["", "[run]", f"dt = {_toml_value(preset.default_dt)}  # [s] step size",
              "duration = 1.0  # [s] simulated time (or: steps = N)", "seed = 0", 'precision = "f64"',
              'arch = "cpu"', "# save_every = 10  # keep every 10th step's positions (needed by an export)",
              "", "[output]", f"npz = {_toml_value(preset.name + '.npz')}",
              f'# export = {_toml_value(preset.name + ".usda")}  # with save_every; or a folder for obj/ply frames',
              '# export_format = "usd"']
    return "\n".join(lines) + "\n"
