"""Draw one frame of a scene into a PNG with the renderer directly (no video, no window).

    python demos/render_frame.py cloth-sphere frame.png

The renderer reads a scene; it never steps one. Here we step the scene ourselves with
`ts.run`, then describe what to draw (`describe`), open an offscreen window, render and read
the pixels back.
"""
import sys

from PIL import Image

import taichi_sim as ts
from taichi_sim.render import DrawOptions, Renderer, RenderUnavailable, open_window
from taichi_sim.scene.visual import describe


def main(scene_name: str, out: str) -> None:
    ts.init(arch="cpu", precision="f64")
    scene = ts.build_scene(scene_name)
    ts.run(scene, scene.default_integrator, dt=scene.default_dt, t_end=1.0)  # 1 s of motion

    size = (960, 540)
    window = open_window("frame", size)  # offscreen; never call window.show() on it
    visual = describe(scene)  # what to draw: surface, springs, spheres, ground...
    renderer = Renderer(window, [visual], size)
    renderer.render([scene.state.x], DrawOptions.for_visual(visual))
    image = renderer.read_image()  # (height, width, 3) uint8; reading consumes the frame
    window.destroy()
    Image.fromarray(image).save(out)
    print(f"wrote {out}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: python demos/render_frame.py SCENE OUT.png   (scenes: taichi-sim list)")
    try:
        main(sys.argv[1], sys.argv[2])
    except (ts.ConfigError, RenderUnavailable) as exc:
        sys.exit(f"error: {exc}")
