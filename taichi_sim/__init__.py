"""taichi_sim: data-oriented particle and mass-spring simulation on Taichi.

Typical use::

    import taichi_sim as ts
    ts.init(arch="cpu", precision="f64")
    scene = ts.build_scene("cloth", {"nx": 16, "ny": 16})
    result = ts.run(scene, "symplectic_euler", dt=1e-3, steps=500)

``import taichi_sim`` does not initialise Taichi; :func:`init` does.
"""
import os

os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")  # keep stdout for our own output

from .errors import ConfigError  # noqa: E402
from .integrators import INTEGRATORS, Integrator, Status, StepReport, create_integrator  # noqa: E402
from .run import RunResult, run  # noqa: E402
from .runtime import init  # noqa: E402
from .scene import SCENES, Scene, SceneBuilder, build_scene  # noqa: E402
from .state import State  # noqa: E402
from .stepper import Stepper  # noqa: E402

__version__ = "0.1.0"

__all__ = ["init", "build_scene", "run", "create_integrator", "INTEGRATORS", "SCENES", "Scene",
           "SceneBuilder", "State", "Stepper", "Integrator", "Status", "StepReport", "RunResult", "ConfigError"]
