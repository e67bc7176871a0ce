"""taichi_sim: data-oriented particle and mass-spring simulation on Taichi.

Typical use::

    import taichi_sim as ts
    ts.init(arch="cpu", precision="f64")
    scene = ts.build_scene("cloth", {"nx": 16, "ny": 16})
    result = ts.run(scene, "symplectic_euler", dt=1e-3, steps=500)

``import taichi_sim`` does not initialise Taichi; :func:`init` does.
"""
from .errors import ConfigError
from .integrators import INTEGRATORS, Integrator, Status, StepReport, create_integrator
from .run import RunResult, run
from .runtime import init
from .scene import SCENES, Scene, SceneBuilder, build_scene
from .state import State

__version__ = "0.1.0"

__all__ = ["init", "build_scene", "run", "create_integrator", "INTEGRATORS", "SCENES", "Scene",
           "SceneBuilder", "State", "Integrator", "Status", "StepReport", "RunResult", "ConfigError"]
