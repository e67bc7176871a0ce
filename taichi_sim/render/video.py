"""Writing frames: MP4 (imageio-ffmpeg's own ffmpeg), GIF (Pillow) or a folder of PNGs.

Every output is written under a temporary name beside the target and renamed into place when
complete, so a failure or an interrupt never leaves a partial file. Check paths and sizes with
:func:`check_output` and :func:`parse_size` before doing any work.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
from PIL import Image, PngImagePlugin

from ..atomic import PendingFile, check_can_create
from ..errors import ConfigError

MAX_SIDE = 4096  # pixels
MAX_FPS = 240.0
KINDS = ("mp4", "gif", "png")


def parse_size(text: str) -> tuple[int, int]:
    """``"WxH"`` -> (width, height) in pixels, each an integer in 16..4096."""
    parts = str(text).lower().split("x")
    try:
        if len(parts) != 2:
            raise ValueError
        width, height = int(parts[0]), int(parts[1])
    except ValueError:
        raise ConfigError(f"--size expects WIDTHxHEIGHT in pixels, e.g. 1280x720, got {text!r}") from None
    for side in (width, height):
        if not 16 <= side <= MAX_SIDE:
            raise ConfigError(f"--size sides must be integers in 16..{MAX_SIDE}, got {text!r}")
    return width, height


def output_kind(path: str | os.PathLike) -> str:
    """"mp4", "gif" or "png" (a folder of PNG frames: a path ending in / or an existing folder)."""
    text = os.fspath(path)
    if text.endswith(("/", os.sep)) or Path(text).is_dir():
        return "png"
    suffix = Path(text).suffix.lower()
    if suffix in (".mp4", ".gif"):
        return suffix[1:]
    raise ConfigError(f"output {text!r} must end in .mp4, .gif, or / (a folder of PNG frames)")


def check_output(path: str | os.PathLike, size: tuple[int, int], fps: float) -> tuple[str, Path]:
    """Fail early (ConfigError) when ``path`` cannot take a video of ``size`` at ``fps``.

    Returns (kind, path). An MP4 needs even sides (its yuv420p pixels come in 2x2 blocks); a
    PNG folder must be new or empty.
    """
    kind = output_kind(path)
    if not (math.isfinite(fps) and 0 < fps <= MAX_FPS):
        raise ConfigError(f"--fps must be a number in (0, {MAX_FPS:g}], got {fps}")
    if kind == "mp4" and (size[0] % 2 or size[1] % 2):
        raise ConfigError(f"an .mp4 needs an even width and height, got {size[0]}x{size[1]}")
    target = Path(os.fspath(path).rstrip("/" + os.sep) or ".")
    parent = target.parent
    if kind == "png":
        if target.exists() and not target.is_dir():
            raise ConfigError(f"frame folder {str(target)!r} is a file")
        if target.exists() and any(target.iterdir()):
            raise ConfigError(f"frame folder {str(target)!r} exists and is not empty")
    elif target.is_dir():
        raise ConfigError(f"output path {str(target)!r} is a directory")
    if not parent.is_dir():
        raise ConfigError(f"cannot write {str(target)!r}: directory {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK) or (target.exists() and not os.access(target, os.W_OK)):
        raise ConfigError(f"cannot write {str(target)!r}: permission denied")
    check_can_create(target, parent)
    return kind, target


class VideoWriter:
    """Collects (H, W, 3) uint8 frames into ``path``; use as a context manager.

    The output appears only when the block ends without an exception; otherwise the temporary
    file or folder is removed.

    Args:
        path: the output (see :func:`output_kind`).
        size: (width, height) of every frame in pixels.
        fps: frames per second.
        colors: palette size of a GIF (2..256; fewer colours, smaller file).
    """

    def __init__(self, path: str | os.PathLike, size: tuple[int, int], fps: float, *, colors: int = 128):
        self.kind, self.path = check_output(path, size, fps)
        self.size = (int(size[0]), int(size[1]))
        self.fps = float(fps)
        self.colors = int(colors)
        self.count = 0
        self._gif_frames: list[Image.Image] = []
        self._writer = None
        self._pending = PendingFile(self.path, folder=self.kind == "png",
                                    suffix=".tmp" if self.kind == "png" else f".tmp.{self.kind}")
        self._tmp = self._pending.tmp
        if self.kind == "mp4":
            import imageio.v2 as imageio

            self._writer = imageio.get_writer(self._tmp, format="FFMPEG", mode="I", fps=self.fps,
                                              codec="libx264", pixelformat="yuv420p", quality=7,
                                              macro_block_size=1, ffmpeg_log_level="error")

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def append(self, frame: np.ndarray) -> None:
        """Add one (H, W, 3) uint8 frame."""
        frame = np.ascontiguousarray(frame, dtype=np.uint8)
        if frame.shape != (self.size[1], self.size[0], 3):
            raise ValueError(f"frame shape {frame.shape} != {(self.size[1], self.size[0], 3)}")
        if self.kind == "mp4":
            self._writer.append_data(frame)
        elif self.kind == "gif":
            self._gif_frames.append(Image.fromarray(frame).quantize(
                colors=self.colors, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE))
        else:
            Image.fromarray(frame).save(self._tmp / f"frame_{self.count:05d}.png", optimize=True)
        self.count += 1

    def close(self) -> Path:
        """Finish the file and move it into place; returns its path. On failure nothing is left
        behind."""
        try:
            if self.count == 0:
                raise ValueError("no frames were written")
            if self.kind == "mp4":
                writer, self._writer = self._writer, None
                writer.close()
            elif self.kind == "gif":
                first, *rest = self._gif_frames
                first.save(self._tmp, format="GIF", save_all=True, append_images=rest, loop=0,
                           duration=max(20, round(1000.0 / self.fps)), optimize=True)
                self._gif_frames = []
            self._pending.commit()  # a PNG folder target was checked empty before any work
        except BaseException:
            self.abort()
            raise
        return self.path

    def abort(self) -> None:
        """Drop everything written so far."""
        if self._writer is not None:
            writer, self._writer = self._writer, None
            try:
                writer.close()
            except Exception:  # the writer may be why we abort; its file is deleted anyway
                pass
        self._pending.discard()


def save_png(image: np.ndarray, path: str | os.PathLike, *, text: dict[str, str] | None = None) -> Path:
    """Write one (H, W, 3) uint8 image to ``path`` atomically (temporary file, then rename),
    with ``text`` (key -> value) as PNG text chunks (tEXt; Pillow reads them back in
    ``Image.open(path).text``)."""
    pending = PendingFile(path, suffix=".tmp.png")
    info = None
    if text:
        info = PngImagePlugin.PngInfo()
        for key, value in text.items():
            info.add_text(key, value)
    try:
        Image.fromarray(np.ascontiguousarray(image, np.uint8)).save(pending.tmp, optimize=True, pnginfo=info)
    except BaseException:
        pending.discard()
        raise
    return pending.commit()
