"""Open the interactive launcher on a scene (needs a display and Vulkan).

    python demos/launcher.py [SCENE]

Right-drag orbits, middle-drag zooms, h shows every key. The Session holds the scene, the
integrator and the controls; the launcher only draws them.
"""
import sys

import taichi_sim as ts
from taichi_sim.app import Session
from taichi_sim.app.launcher import Launcher
from taichi_sim.render import RenderUnavailable
from taichi_sim.scene import scene_preset


def main(scene_name: str) -> None:
    ts.init(arch="cpu", precision="f64")
    preset = scene_preset(scene_name)  # unknown names raise ConfigError
    session = Session(preset.name, [preset.default_integrator], substeps=10)
    Launcher(session, size=(1280, 800)).run()


if __name__ == "__main__":
    try:
        main(sys.argv[1] if len(sys.argv) > 1 else "cloth")
    except (ts.ConfigError, RenderUnavailable) as exc:
        sys.exit(f"error: {exc}")
