"""Integrators from outside the package: ``package.module:Class`` or ``path/to/file.py:Class``
specs, and classes installed under the entry-point group ``taichi_sim.integrators``.

A plug-in is an :class:`~.base.Integrator` subclass with every fact declared
(:func:`~.base.missing_facts`); it is checked once, when first loaded, and refused with a
one-line ConfigError otherwise (docs/plugins.md has the checklist).
"""
from __future__ import annotations

import importlib
import importlib.util
import os
import sys
from pathlib import Path

from ..errors import ConfigError
from .base import Integrator, missing_facts

ENTRY_POINT_GROUP = "taichi_sim.integrators"
_LOADED: dict[str, type[Integrator]] = {}
_BY_NAME: dict[str, type[Integrator]] = {}  # a loaded plug-in is also known by its own name


def loaded_plugin(name: str) -> type[Integrator] | None:
    """The plug-in class loaded in this process whose ``name`` is ``name`` (so that what holds
    only ``integrator.name``, e.g. a failure message, finds its facts), or None."""
    return _BY_NAME.get(name)


def is_spec(name: str) -> bool:
    """Whether ``name`` names a class by where it lives (``module:Class``) rather than by a
    registry name."""
    return ":" in name


def installed_plugins() -> dict:
    """Entry points of the group ``taichi_sim.integrators``, by name (nothing is imported)."""
    from importlib.metadata import entry_points  # 20 ms of imports a command without plug-ins skips

    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def load_spec(spec: str, builtin_names) -> type[Integrator]:
    """The class named by ``spec`` (``package.module:Class`` or ``path/to/file.py:Class``),
    checked (:func:`check_plugin`); ConfigError with one line when it cannot be had."""
    if spec in _LOADED:
        return _LOADED[spec]
    where, _, attribute = spec.rpartition(":")
    dotted = all(part.isidentifier() for part in where.split("."))
    if not where or not (where.endswith(".py") or dotted) or not all(
            part.isidentifier() for part in attribute.split(".")):
        raise ConfigError(f"integrator {spec!r}: a plug-in is named package.module:Class or "
                          f"path/to/file.py:Class")
    module = _import_file(spec, where) if where.endswith(".py") else _import_module(spec, where)
    found = module
    for part in attribute.split("."):
        found = getattr(found, part, None)
        if found is None:
            raise ConfigError(f"integrator {spec!r}: {where} has no {attribute!r}")
    _LOADED[spec] = check_plugin(found, spec, builtin_names)
    return _LOADED[spec]


def load_entry_point(name: str, entry_point, builtin_names) -> type[Integrator]:
    """The class the installed entry point ``name`` names, checked."""
    key = f"entry point {name}"
    if key not in _LOADED:
        try:
            found = entry_point.load()
        except Exception as exc:  # a broken plug-in is the user's to fix: say what broke, in one line
            raise ConfigError(f"integrator {name!r} (entry point {entry_point.value}, group "
                              f"{ENTRY_POINT_GROUP}) failed to load: {_one_line(exc)}") from None
        _LOADED[key] = check_plugin(found, f"{name} ({entry_point.value})", builtin_names)
    return _LOADED[key]


def check_plugin(cls, label: str, builtin_names) -> type[Integrator]:
    """``cls`` when it is a complete Integrator subclass (ConfigError naming ``label`` and the
    first problem otherwise)."""
    if not (isinstance(cls, type) and issubclass(cls, Integrator)):
        raise ConfigError(f"integrator {label!r} is not a subclass of taichi_sim.integrators.Integrator")
    missing = missing_facts(cls)
    if missing:
        raise ConfigError(f"integrator {label!r} does not declare {', '.join(missing)} (see docs/plugins.md)")
    if cls.name in builtin_names:
        raise ConfigError(f"integrator {label!r} calls itself {cls.name!r}, the name of a built-in "
                          f"integrator; give it a name of its own")
    if _BY_NAME.setdefault(cls.name, cls) is not cls:
        raise ConfigError(f"integrator {label!r} calls itself {cls.name!r}, as does the plug-in "
                          f"{_BY_NAME[cls.name].__module__}.{_BY_NAME[cls.name].__qualname__}; give it a "
                          f"name of its own")
    return cls


def _import_module(spec: str, module_name: str):
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name and (module_name == exc.name or module_name.startswith(exc.name + ".")):
            if _search_working_directory():  # `python -m taichi_sim` looks there, the console script not
                return _import_module(spec, module_name)
            raise ConfigError(f"integrator {spec!r}: no module named {exc.name!r} on the Python path "
                              f"(or give the file: path/to/file.py:Class)") from None
        raise ConfigError(f"integrator {spec!r}: importing {module_name} failed: {_one_line(exc)}") from None
    except Exception as exc:
        raise ConfigError(f"integrator {spec!r}: importing {module_name} failed: {_one_line(exc)}") from None


def _search_working_directory() -> bool:
    """Append the working directory to ``sys.path`` when neither it nor ``''`` is there (True
    when it was added), so that a plug-in module beside the user is found by the installed
    ``taichi-sim`` as by ``python -m taichi_sim``; appended, so it never shadows a package."""
    cwd = os.getcwd()
    if "" in sys.path or any(os.path.abspath(entry) == cwd for entry in sys.path):
        return False
    sys.path.append(cwd)
    importlib.invalidate_caches()
    return True


def _import_file(spec: str, filename: str):
    path = Path(filename).expanduser().resolve()
    if not path.is_file():
        raise ConfigError(f"integrator {spec!r}: no file {filename}")
    # one module per file, under a name of its own (Taichi reads kernels' source from the file)
    module_name = f"taichi_sim_plugin_{abs(hash(str(path))):x}_{path.stem}"
    if module_name in sys.modules:
        return sys.modules[module_name]
    loader = importlib.util.spec_from_file_location(module_name, path)
    module = importlib.util.module_from_spec(loader)
    sys.modules[module_name] = module
    try:
        loader.loader.exec_module(module)
    except Exception as exc:
        del sys.modules[module_name]
        raise ConfigError(f"integrator {spec!r}: running {filename} failed: {_one_line(exc)}") from None
    return module


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0][:200]}" if text else type(exc).__name__
