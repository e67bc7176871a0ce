"""Checks that an output can really be written, before any work is done."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

from .errors import ConfigError


def check_can_create(target: str | os.PathLike, folder: str | os.PathLike) -> None:
    """Raise ConfigError naming ``target`` unless a file can be created in ``folder`` (where
    ``target`` will be written). os.access trusts the mode bits: root passes them everywhere,
    and /proc, a read-only mount or a full disk refuse what they allow. Outputs are written as a
    temporary file beside the target, then renamed, so one is made here and removed."""
    try:
        fd, probe = tempfile.mkstemp(prefix=f".{Path(target).name}.", suffix=".check", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise ConfigError(f"cannot write {os.fspath(target)!r}: creating a file in {os.fspath(folder)!r} "
                          f"fails ({exc.strerror or exc})") from None
