"""Writing a file (or a folder of files) so that nothing half-written is ever seen under its name.

Everything is written under a temporary name in the target's own directory (a rename does not
cross file systems), flushed to disk (fsync), given the mode of a newly created file (0666 or
0777 less the umask) and renamed into place with ``os.replace``. On any failure the temporary
is removed and the target is left as it was.
"""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Callable

from .errors import ConfigError


def _umask() -> int:
    mask = os.umask(0)  # the only portable way to read it is to set it
    os.umask(mask)
    return mask


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class PendingFile:
    """A temporary file (or, with ``folder``, a folder) beside ``path``, to be written by the
    caller and then :meth:`commit`-ted into place or :meth:`discard`-ed. ``suffix`` ends the
    temporary's name (writers that go by the extension, e.g. ``".tmp.mp4"``).

    Attributes:
        path: the target; tmp: the temporary (create it or write into it).
    """

    def __init__(self, path: str | os.PathLike, *, suffix: str = ".tmp", folder: bool = False):
        self.path = Path(path)
        parent = self.path.parent if str(self.path.parent) else Path(".")
        prefix = f".{self.path.name}."
        if folder:
            self.tmp = Path(tempfile.mkdtemp(prefix=prefix, suffix=suffix, dir=parent))
        else:
            fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=parent)
            os.close(fd)
            self.tmp = Path(tmp)

    def __enter__(self) -> "PendingFile":
        return self

    def __exit__(self, kind, error, trace) -> None:
        """Leaving a ``with`` block by an exception discards the temporary (commit inside the
        block; a committed file is left alone)."""
        if kind is not None:
            self.discard()

    def commit(self) -> Path:
        """Flush the temporary to disk, give it a new file's mode and rename it to ``path``
        (replacing a file; a folder target must not exist or be empty)."""
        try:
            if self.tmp.is_dir():
                for item in self.tmp.iterdir():
                    _fsync(item)
                mode = 0o777
                if self.path.is_dir():
                    self.path.rmdir()  # an empty folder given as the target
            else:
                mode = 0o666
            _fsync(self.tmp)
            # mkstemp/mkdtemp create it private so nobody reads it half-written; the result is public
            os.chmod(self.tmp, mode & ~_umask())
            os.replace(self.tmp, self.path)
            _fsync(self.path.parent if str(self.path.parent) else Path("."))  # the rename itself
        except BaseException:
            self.discard()
            raise
        return self.path

    def discard(self) -> None:
        """Remove the temporary (whatever was written into it)."""
        if self.tmp.is_dir():
            shutil.rmtree(self.tmp, ignore_errors=True)
        else:
            self.tmp.unlink(missing_ok=True)


def write_atomically(path: str | os.PathLike, write: Callable[[Any], None], *, binary: bool = True,
                     newline: str | None = None) -> Path:
    """Create ``path`` with ``write(file)`` (an open binary or, with ``binary=False``, UTF-8 text
    file; ``newline`` as for :func:`open`), atomically (module docstring). Returns the path."""
    pending = PendingFile(path)
    try:
        mode = "wb" if binary else "w"
        text = {} if binary else {"encoding": "utf-8", "newline": newline}
        with open(pending.tmp, mode, **text) as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
    except BaseException:
        pending.discard()
        raise
    return pending.commit()


def check_can_create(target: str | os.PathLike, folder: str | os.PathLike) -> None:
    """Raise ConfigError naming ``target`` unless a file can be created in ``folder`` (where
    ``target`` will be written), before any work is done. os.access trusts the mode bits: root
    passes them everywhere, and /proc, a read-only mount or a full disk refuse what they allow.
    The write makes a temporary file beside the target, so one is made here and removed."""
    try:
        fd, probe = tempfile.mkstemp(prefix=f".{Path(target).name}.", suffix=".check", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise ConfigError(f"cannot write {os.fspath(target)!r}: creating a file in {os.fspath(folder)!r} "
                          f"fails ({exc.strerror or exc})") from None
