"""Ctrl-C for the ``taichi-sim`` command: one line and exit status 130, whenever it comes.

Python turns SIGINT into a KeyboardInterrupt raised wherever the main thread happens to be.
Inside Taichi 1.7 that goes wrong in three ways, all seen when a Ctrl-C lands in the second or
so that ``import taichi`` and the package's ``@ti.kernel`` decorators take:

- it is swallowed: Taichi has bare ``except:`` clauses in its import, in every kernel decorator
  (``kernel_impl._inside_class`` reads the caller's source) and in its source lookup when a
  kernel compiles; the command went on (a SIGINT sent at random moments of ``import taichi``
  alone vanished in 5 of 21 tries);
- it turns into another error: the decorator, having swallowed it, raised
  ``TaichiSyntaxError: Taichi kernels parameters must be type annotated`` (2 of 30 tries), and
  Taichi's C++ module, interrupted while it initialised, ``ImportError: initialization failed``;
- it marks the interpreter: after it passed through code that Taichi runs with ``PyRun_*``,
  Python killed itself with SIGINT at exit whatever status the command returned (4 of 30).

So while the package loads (:func:`deferred`) a Ctrl-C is only recorded, and raised once the
load is done; afterwards it is raised at once as usual, and also recorded, so that :func:`check`
(between steps, at the end of a command) raises it again if Taichi ate it, and the command can
tell an error caused by it from a real one. Nothing here imports Taichi.
"""
from __future__ import annotations

import contextlib
import signal
import threading

_STATE = {"pending": False, "deferring": False}


def _on_sigint(signum, frame):
    _STATE["pending"] = True
    if not _STATE["deferring"]:
        raise KeyboardInterrupt


def install():
    """Watch SIGINT until the returned function is called (it puts back the previous handler).
    Does nothing where Ctrl-C is not Python's to handle: SIGINT ignored (a command started in
    the background inherits that, and should keep it), a handler of the caller's own, or a
    thread other than the main one."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = signal.getsignal(signal.SIGINT)
    if previous is not signal.default_int_handler:
        return lambda: None
    _STATE.update(pending=False, deferring=False)
    signal.signal(signal.SIGINT, _on_sigint)

    def restore():
        _STATE.update(pending=False, deferring=False)
        signal.signal(signal.SIGINT, previous)
    return restore


@contextlib.contextmanager
def deferred():
    """Within: a Ctrl-C is recorded, not raised (Taichi's import cannot be interrupted safely);
    on leaving, KeyboardInterrupt if one came."""
    _STATE["deferring"] = True
    try:
        yield
    finally:
        _STATE["deferring"] = False
    check()


def pending() -> bool:
    """Whether a Ctrl-C came since :func:`install`."""
    return _STATE["pending"]


def check() -> None:
    """Raise KeyboardInterrupt if a Ctrl-C came (and, reaching here, was swallowed on its way)."""
    if _STATE["pending"]:
        raise KeyboardInterrupt
