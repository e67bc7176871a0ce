"""Writes tilting-tray/tray_00.obj ... tray_10.obj: a 0.8 m square tray, 4 cm thick, 0.4 m up,
tilting about its z axis from level to 25 degrees over one second (ten frames a second), the
frames of the animated collider mesh in cloth-on-tilting-tray.toml. Every frame has the same
vertices in the same order, as a frame sequence must:

    python examples/scenes/make_tilting_tray.py
"""
import math
from pathlib import Path

import numpy as np
import trimesh

FRAMES = 11
TILT = math.radians(25.0)


def main() -> None:
    tray = trimesh.creation.box(extents=(0.8, 0.04, 0.8))
    folder = Path(__file__).resolve().parent / "tilting-tray"
    folder.mkdir(exist_ok=True)
    for k in range(FRAMES):
        angle = TILT * k / (FRAMES - 1)
        c, s = math.cos(angle), math.sin(angle)
        turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        frame = trimesh.Trimesh(tray.vertices @ turn.T + [0.0, 0.4, 0.0], tray.faces, process=False)
        frame.export(folder / f"tray_{k:02d}.obj", digits=6)
    print(f"wrote {FRAMES} frames to {folder}")


if __name__ == "__main__":
    main()
