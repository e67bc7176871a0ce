"""taichi_sim: data-oriented particle and mass-spring simulation on Taichi.

Typical use::

    import taichi_sim as ts
    ts.init(arch="cpu", precision="f64")
    scene = ts.build_scene("cloth", {"nx": 16, "ny": 16})
    result = ts.run(scene, "symplectic_euler", dt=1e-3, steps=500)

``import taichi_sim`` does not initialise Taichi; :func:`init` does. Nor does it import Taichi:
the names below load on first use (PEP 562), so that the ``taichi-sim`` command, whose entry
point lives in this package, can take Ctrl-C over before the slow import of Taichi and of the
kernels starts (:mod:`taichi_sim.interrupt`).
"""
import importlib
import os
import sys
import types

os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")  # keep stdout for our own output

__version__ = "0.1.0"

#: Each public name and the module that defines it.
_FACE = {"init": "runtime", "build_scene": "scene", "run": "run", "create_integrator": "integrators",
         "INTEGRATORS": "integrators", "SCENES": "scene", "Scene": "scene", "SceneBuilder": "scene",
         "State": "state", "Stepper": "stepper", "Integrator": "integrators", "Status": "integrators",
         "StepReport": "integrators", "RunResult": "run", "ConfigError": "errors"}

__all__ = list(_FACE)


def __getattr__(name: str):
    """A public name (imported on first use), or a submodule (``taichi_sim.io`` without an
    explicit ``import taichi_sim.io``, as when this file imported the face eagerly)."""
    if name in _FACE:
        value = getattr(importlib.import_module(f".{_FACE[name]}", __name__), name)
        globals()[name] = value  # the next lookup is an ordinary one
        return value
    if not name.startswith("_"):
        try:
            return importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_FACE))


class _Face(types.ModuleType):
    """The package module. Importing a submodule sets it as the package's attribute of its
    name; ``taichi_sim.run`` is both a submodule and the face's ``run()``, and the function
    must win (as it did when this file imported ``from .run import run``)."""

    def __setattr__(self, name, value):
        if name in _FACE and isinstance(value, types.ModuleType) and value.__name__ == f"{__name__}.{name}":
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Face
