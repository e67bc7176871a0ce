"""Where a mesh collider's vertices are at time t: one frame (a rigid mesh), or a sequence of
frames of one topology (an animated body) played at ``fps``, linear between frames, the last
held; and the files such meshes come from."""
import glob
import math
import os
import re

import numpy as np

from ...errors import ConfigError

GLOB_CHARACTERS = "*?["


def is_pattern(path: str) -> bool:
    """Whether ``path`` is a glob pattern (names a sequence of files) rather than one file."""
    return any(c in os.path.basename(path) for c in GLOB_CHARACTERS)


def _natural_key(path: str):
    """Sort key putting body_2.obj before body_10.obj."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path)]


def pattern_files(pattern: str) -> list[str]:
    """The files a glob ``pattern`` names, in natural order (frame 2 before frame 10)."""
    return sorted((p for p in glob.glob(pattern) if os.path.isfile(p)), key=_natural_key)


def _read(path: str, keep_order: bool):
    import trimesh

    try:
        # keep_order: no merging nor reordering of vertices, so frames keep one numbering
        mesh = trimesh.load(path, force="mesh", process=not keep_order)
    except Exception as exc:  # trimesh raises many kinds on a bad file
        raise ConfigError(f"parameter collider_mesh: cannot read {path!r} as a mesh ({exc})") from None
    if not hasattr(mesh, "faces") or len(mesh.faces) == 0:
        raise ConfigError(f"parameter collider_mesh: {path!r} holds no triangles")
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)


def load_mesh_file(path: str) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles) of a collider mesh: ``path`` one mesh file (any format trimesh
    reads: OBJ, STL, PLY, GLB, ...), vertices (V, 3) float64 m; or a glob pattern of numbered
    files (``body_*.obj``), one frame each in natural order, vertices (F, V, 3), every frame
    with the first's vertex count and triangles. ConfigError naming ``collider_mesh`` when
    there is no such file, a file is not a mesh, or the frames differ in topology."""
    if not is_pattern(path):
        if not os.path.isfile(path):
            raise ConfigError(f"parameter collider_mesh: no such file {path!r}")
        return _read(path, keep_order=False)
    files = pattern_files(path)
    if not files:
        raise ConfigError(f"parameter collider_mesh: no file matches {path!r}")
    vertices, triangles = _read(files[0], keep_order=True)
    frames = [vertices]
    for index, name in enumerate(files[1:], start=1):
        v, t = _read(name, keep_order=True)
        if v.shape != vertices.shape or not np.array_equal(t, triangles):
            raise ConfigError(
                f"parameter collider_mesh: frame {index} ({name!r}: {len(v)} vertices, {len(t)} triangles) "
                f"differs in topology from frame 0 ({files[0]!r}: {len(vertices)} vertices, {len(triangles)} "
                "triangles); the frames of a sequence share one vertex numbering and one triangle list")
        frames.append(v)
    return (np.stack(frames) if len(frames) > 1 else vertices), triangles


class FramePlayer:
    """Plays ``frames`` (F, V, 3) m at ``fps`` (frames per second): at time t the vertices
    are linear between frames floor(t fps) and the next, and the last frame is held from
    t = (F - 1) / fps on (velocity zero); before t = 0, the first."""

    def __init__(self, frames: np.ndarray, fps: float):
        self.frames = np.asarray(frames, np.float64)
        self.fps = float(fps)
        self.count = len(self.frames)

    @property
    def animated(self) -> bool:
        return self.count > 1

    @property
    def duration(self) -> float:
        """Seconds until the last frame (0 for one frame)."""
        return (self.count - 1) / self.fps

    def segment(self, t: float) -> tuple[int, float]:
        """(k, w): at t the vertices are (1 - w) frame k + w frame k + 1 (k = 0, w = 0 for one
        frame)."""
        if not self.animated:
            return 0, 0.0
        u = min(max(t * self.fps, 0.0), self.count - 1.0)
        k = min(int(math.floor(u)), self.count - 2)
        return k, u - k

    def vertices(self, t: float) -> np.ndarray:
        """(V, 3) m at time t (s)."""
        k, w = self.segment(t)
        if w == 0.0:
            return self.frames[k].copy()
        return (1.0 - w) * self.frames[k] + w * self.frames[k + 1]

    def velocities(self, t: float) -> np.ndarray:
        """(V, 3) m/s at time t (s): the current segment's, zero once the last frame is held."""
        if not self.animated or not 0.0 <= t * self.fps < self.count - 1:
            return np.zeros_like(self.frames[0])
        k, _ = self.segment(t)
        return (self.frames[k + 1] - self.frames[k]) * self.fps

    def fastest_speed(self) -> float:
        """The largest vertex speed (m/s) over the sequence."""
        if not self.animated:
            return 0.0
        return float(np.linalg.norm(np.diff(self.frames, axis=0), axis=2).max() * self.fps)

    def segment_boxes(self, triangles: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Each triangle's box (lo, hi), each (T, 3) m, over segment k (frames k and k + 1):
        the triangle stays in it all segment long, since it moves linearly between them."""
        corners = self.frames[k:k + 2][:, triangles]  # (1 or 2, T, 3, 3)
        return corners.min(axis=(0, 2)), corners.max(axis=(0, 2))

    @property
    def segment_count(self) -> int:
        return max(1, self.count - 1)
