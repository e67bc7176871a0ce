"""A run's frames out of its ``.npz``, for other tools: a numbered sequence of OBJ or PLY files
in a folder, or one USD file with a time sample per frame (docs/export.md).

Every format stores positions in single precision (USD's ``points`` are float3 by schema; OBJ
gets 9 significant digits, PLY binary floats): enough for a picture, and the same in each.
"""
from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..atomic import PendingFile, check_can_create
from ..errors import ConfigError, unknown_name
from . import obj, ply, usd
from .usd import time_codes


@dataclass(frozen=True)
class Frames:
    """What an export writes.

    Attributes:
        positions: (S, n, 3) positions (m) of each frame.
        times: (S,) each frame's time (s), increasing.
        triangles: (F, 3) particle ids of the surface's triangles, or None (points only).
        name: the scene's name.
    """

    positions: np.ndarray
    times: np.ndarray
    triangles: np.ndarray | None
    name: str


@dataclass(frozen=True)
class Format:
    """One export format: ``sequence`` formats write a folder of ``frame_NNNN.<suffix>`` files,
    each with the writer ``frame_writer(triangles, name)`` returns (called as ``write(binary
    file, positions (n, 3), t)``; what is the same in every frame is prepared once), the others
    one file (suffix one of ``suffixes``) with ``write_file(path, frames, on_frame)``."""

    name: str
    sequence: bool
    suffixes: tuple[str, ...]
    frame_writer: Callable | None = None
    write_file: Callable | None = None


FORMATS: dict[str, Format] = {f.name: f for f in (
    Format("obj", True, (".obj",), frame_writer=obj.frame_writer),
    Format("ply", True, (".ply",), frame_writer=ply.frame_writer),
    Format("usd", False, usd.SUFFIXES, write_file=usd.write_stage),
)}


def export_format(name: str) -> Format:
    """The format called ``name`` (ConfigError with a did-you-mean otherwise)."""
    if name not in FORMATS:
        import difflib

        close = difflib.get_close_matches(name.lower(), FORMATS, n=1, cutoff=0.6)  # three letters: plx, USD
        if close:
            raise ConfigError(f"unknown export format {name!r}: did you mean {close[0]!r}? (obj, ply or usd)")
        raise ConfigError(unknown_name("unknown export format", name, FORMATS))
    return FORMATS[name]


def check_export_path(path: str | os.PathLike, fmt: Format) -> Path:
    """Fail early (ConfigError naming ``path``) when the export cannot be written there, before
    any work is done: a sequence goes into a folder that must not exist yet or be empty, a USD
    file needs one of its suffixes and a writable folder."""
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if fmt.sequence:
        if path.exists() and not path.is_dir():
            raise ConfigError(f"export folder {str(path)!r} is a file")
        if path.is_dir() and any(path.iterdir()):
            raise ConfigError(f"export folder {str(path)!r} is not empty: give a new or empty folder "
                              "(frames are never written over other files)")
    else:
        if path.suffix not in fmt.suffixes:
            raise ConfigError(f"{fmt.name} export path {str(path)!r} must end in "
                              f"{', '.join(fmt.suffixes)}")
        if path.is_dir():
            raise ConfigError(f"export path {str(path)!r} is a directory")
    if not parent.is_dir():
        raise ConfigError(f"cannot write {str(path)!r}: directory {str(parent)!r} does not exist")
    check_can_create(path, parent)
    return path


def frames_of(arrays: dict, source: str) -> Frames:
    """The frames of a run's arrays (``x_history``, ``t_history``, ``triangles``, ``scene``);
    ConfigError naming ``source`` and what is missing."""
    if "x_history" not in arrays:
        raise ConfigError(f"{source} has no frames (no `x_history`): run `simulate` with --save-every K "
                          "to keep them")
    positions = np.asarray(arrays["x_history"], np.float64)
    if positions.ndim != 3 or positions.shape[2] != 3 or len(positions) == 0:
        raise ConfigError(f"{source}: `x_history` has shape {positions.shape}, not (frames, particles, 3) "
                          "(a first-order system's state is no set of positions)")
    if "t_history" not in arrays or np.shape(arrays["t_history"]) != (len(positions),):
        raise ConfigError(f"{source} has no frame times (`t_history`) matching its {len(positions)} frame(s)")
    times = np.asarray(arrays["t_history"], np.float64)
    if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise ConfigError(f"{source}: `t_history` is not increasing")
    triangles = arrays.get("triangles")
    if triangles is not None:
        triangles = np.asarray(triangles, np.int64)
        if triangles.ndim != 2 or triangles.shape[1] != 3 or (
                triangles.size and (triangles.min() < 0 or triangles.max() >= positions.shape[1])):
            raise ConfigError(f"{source}: `triangles` are not (F, 3) ids of its {positions.shape[1]} particles")
    return Frames(positions, times, triangles, str(arrays.get("scene", "run")))


def load_frames(npz: str | os.PathLike) -> Frames:
    """The frames of a run's ``.npz`` (ConfigError naming the file when it is not one)."""
    npz = os.fspath(npz)
    if not os.path.isfile(npz):
        raise ConfigError(f"{npz}: no such file")
    if not zipfile.is_zipfile(npz):  # np.load would try it as a pickle
        raise ConfigError(f"{npz} is not a run's npz (not a zip archive): give a file written by "
                          "`taichi-sim simulate --out RUN.npz --save-every K`")
    try:
        with np.load(npz) as data:
            arrays = {k: data[k] for k in ("x_history", "t_history", "triangles", "scene") if k in data.files}
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise ConfigError(f"cannot read {npz} as a run's npz: {exc}") from None
    return frames_of(arrays, npz)


def frame_name(k: int, count: int, suffix: str) -> str:
    """``frame_0007.obj``: zero-padded to at least 4 digits, so names sort in frame order."""
    return f"frame_{k:0{max(4, len(str(count - 1)))}d}{suffix}"


def export(frames: Frames, fmt: Format, path: str | os.PathLike, *, progress: bool | None = None) -> Path:
    """Write ``frames`` as ``fmt`` to ``path`` (checked first, :func:`check_export_path`),
    atomically: a sequence is written into a temporary folder renamed into place, a USD file
    into a temporary file. ``progress``: a bar on stderr (None: only on a terminal). Returns
    the path."""
    path = check_export_path(path, fmt)
    bar = _bar(len(frames.times), progress)
    if fmt.sequence:
        with bar, PendingFile(path, folder=True) as pending:
            write = fmt.frame_writer(frames.triangles, frames.name)
            for k in range(len(frames.times)):
                target = pending.tmp / frame_name(k, len(frames.times), fmt.suffixes[0])
                with open(target, "wb") as f:
                    write(f, frames.positions[k], frames.times[k])
                bar.update()
            return pending.commit()
    # USD picks its encoding by the suffix
    with bar, PendingFile(path, suffix=".tmp" + path.suffix) as pending:
        fmt.write_file(pending.tmp, frames, on_frame=bar.update)
        return pending.commit()


def _bar(total: int, progress: bool | None):
    from tqdm import tqdm

    return tqdm(total=total, unit="frame", leave=False, disable=None if progress is None else not progress,
                mininterval=0.5, desc="export")


__all__ = ["FORMATS", "Format", "Frames", "check_export_path", "export", "export_format", "frame_name", "time_codes",
           "frames_of", "load_frames"]
