"""The ``taichi-sim`` command line: :func:`main` runs one command.

Its parts: :mod:`.parser` (every command's options), :mod:`.integrator_flags` (``simulate``'s
flags, from the integrators' declared options), :mod:`.simulate`, :mod:`.views` (``demo``,
``record``, the bare command), :mod:`.listing` (``list``, ``check``, ``bench``, ``advise``) and
:mod:`.export`.
"""
from __future__ import annotations

import sys
import warnings

from .. import interrupt
from ..errors import ConfigError, InputNote, InputWarning
from .export import cmd_export
from .integrator_flags import command_of
from .listing import cmd_advise, cmd_bench, cmd_check, cmd_list
from .parser import EXIT_USAGE, build_parser
from .simulate import MAX_STEPS, _check_step_count, cmd_simulate
from .views import cmd_default, cmd_demo, cmd_record

__all__ = ["main", "build_parser", "EXIT_USAGE", "MAX_STEPS", "_check_step_count"]

EXIT_CLOSED_PIPE = 128 + 13  # what a shell reports for a program ended by SIGPIPE


def _stdout_closed() -> bool:
    """Whether stdout is a pipe whose reader has gone (``| head`` has read its lines)."""
    import select

    try:
        poll = select.poll()
        poll.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poll.poll(0))
    except (AttributeError, OSError, ValueError):  # not a file (captured), or already closed
        return False


def _closed_pipe() -> int:
    """End quietly after the reader of stdout went away: what is still buffered goes to
    /dev/null (else Python's final flush reports the broken pipe), and the exit status is a
    closed pipe's."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (AttributeError, OSError, ValueError):
        pass
    return EXIT_CLOSED_PIPE


def main(argv: list[str] | None = None) -> int:
    """Run one command; its exit status (0 done, 1 the run or check failed, 2 bad input, 130
    interrupted, 141 stdout closed by its reader)."""
    restore = interrupt.install()  # before Taichi loads: Ctrl-C in its import is not lost
    try:
        try:
            code = _main(argv)
        except Exception:
            if interrupt.pending():  # Taichi swallowed the KeyboardInterrupt and failed in its place
                return _interrupted()
            raise
        if code != EXIT_INTERRUPTED and interrupt.pending():  # one Taichi swallowed after the last check
            return _interrupted()
        sys.stdout.flush()  # a closed pipe shows here, not in Python's flush at exit
        return code
    except SystemExit:  # --help and --version print, then exit
        try:
            sys.stdout.flush()
        except BrokenPipeError:
            if _stdout_closed():
                raise SystemExit(_closed_pipe()) from None
            raise
        raise
    except BrokenPipeError:
        if not _stdout_closed():  # another pipe (ffmpeg's, say) broke: a real error
            raise
        return _closed_pipe()
    finally:
        restore()


EXIT_INTERRUPTED = 128 + 2  # what a shell reports for a program ended by SIGINT


def _interrupted() -> int:
    print("taichi-sim: interrupted", file=sys.stderr)
    return EXIT_INTERRUPTED


def _load_package() -> None:
    """Import Taichi and the package's kernels (a second or more) with Ctrl-C held back until
    they are loaded (:mod:`taichi_sim.interrupt`)."""
    with interrupt.deferred():
        from .. import integrators, run, scene  # noqa: F401 - loaded for their kernels


def _main(argv: list[str] | None) -> int:
    try:
        tokens = sys.argv[1:] if argv is None else list(argv)
        if command_of(tokens) == "simulate":  # its flags come from the integrators: loaded first
            _load_package()
        args = build_parser(tokens).parse_args(tokens)
        if args.command != "export":  # export reads and writes files only
            _load_package()
        if args.command in ("simulate", "demo", "record"):
            from ..scene_file import apply_scene_file

            apply_scene_file(args, args.command)  # the file's values, then the defaults
        if args.command == "export":
            return cmd_export(args)
        if args.command is None:
            return cmd_default()
        with warnings.catch_warnings():  # input warnings and notes as one line each, like the errors
            shown = warnings.showwarning
            warnings.showwarning = lambda message, category, *rest, **kw: (
                print(f"taichi-sim: warning: {message}", file=sys.stderr) if issubclass(category, InputWarning)
                else print(f"taichi-sim: {message}", file=sys.stderr) if issubclass(category, InputNote)
                else shown(message, category, *rest, **kw))
            return {"list": cmd_list, "simulate": cmd_simulate, "demo": cmd_demo,
                    "record": cmd_record, "bench": cmd_bench, "advise": cmd_advise,
                    "check": cmd_check}[args.command](args)
    except ConfigError as exc:
        print(f"taichi-sim: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return _interrupted()

